#version 460
// Fragment stage of the Vulkan renderer's camera pass: shades the surface point under the pixel
// centre (render/shading.glsl, the twin of the CPU reference renderer's per-ray shading) with
// the interpolated position, shading normal and UV of the nearest triangle.
//
// Bindings (set 0): 0 RenderParams, 2 RenderTriangle[], 3 material, 4 frame, 5 shadow map
//                   (render/render_inputs.glsl).
// Outputs: location 0 = (exposure-weighted radiance, mask 1), location 1 = aux (cast_shadow,
//          cos_theta_i, cos_theta_o, curvature). Background pixels keep the clear value 0.
// C++ twin: `shade` in render/reference/reference_renderer.cc.
#extension GL_GOOGLE_include_directive : require

#include "render/shading.glsl"

layout(location = 0) in vec3 in_position;
layout(location = 1) in vec3 in_normal;
layout(location = 2) in vec2 in_uv;
layout(location = 3) flat in uint in_triangle;

layout(location = 0) out vec4 out_radiance_mask;
layout(location = 1) out vec4 out_aux;

void main() {
  vec3 p = in_position;
  vec3 n_s = normalize(in_normal);
  vec4 tri = triangles[in_triangle].normal_curvature;
  vec3 wo = (params.flags & kRenderFlagPinhole) != 0u ? normalize(params.camera_origin.xyz - p)
                                                       : -params.camera_axis.xyz;
  Shade s = ShadeSurface(p, n_s, tri.xyz, in_uv, wo, tri.w);
  out_radiance_mask = vec4(s.radiance * params.intensity.w, 1.0);
  out_aux = s.aux;
}
