#version 460
// Box filter of the supersampled camera pass: output pixel (x, y) = sum of the N x N texels
// (x N + i, y N + j) of the high-resolution radiance image, whose fragments already carry the
// weight exposure_s / N² (so the sum is the CPU renderer's average of its N x N stratified
// samples times exposure_s).
//
// Bindings (set 0): 6 source (sampler2DArray, RGBA32F, layer 0), 7 out vec4[width * height]
//   (rgb = radiance, a = 2 when any of the N x N samples lies on a shadow edge, else 0; the mask
//   comes from the 1x pass).
// Push constants: DownsamplePush {width, height, factor}.
// C++ twin: the supersampling loop of RenderImage (render/reference/reference_renderer.cc).
#extension GL_GOOGLE_include_directive : require

#include "shared/render_params.h"

layout(local_size_x = 8, local_size_y = 8) in;

layout(set = 0, binding = 6) uniform sampler2DArray source;
layout(std430, set = 0, binding = 7) writeonly buffer OutRadiance { vec4 out_radiance[]; };
layout(push_constant) uniform Push { DownsamplePush push; };

void main() {
  uvec2 px = gl_GlobalInvocationID.xy;
  if (px.x >= push.width || px.y >= push.height) return;
  vec3 sum = vec3(0.0);
  bool edge = false;
  for (uint j = 0u; j < push.factor; ++j) {
    for (uint i = 0u; i < push.factor; ++i) {
      vec4 texel = texelFetch(source, ivec3(px * push.factor + uvec2(i, j), 0), 0);
      sum += texel.rgb;
      // The alpha is 1 (+ 2 at a shadow edge, render/shading.glsl kShadowEdgeAlpha): 0, 1 or 3.
      edge = edge || texel.a > 2.0;
    }
  }
  out_radiance[px.y * push.width + px.x] = vec4(sum, edge ? 2.0 : 0.0);
}
