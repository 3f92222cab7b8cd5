#version 460
// Fragment stage of the Vulkan renderer's camera passes: shades the surface point under the
// sample (render/shading.glsl, the twin of the CPU reference renderer's per-ray shading). The
// rasteriser gives the nearest triangle; the point is where the sample's exact camera ray meets
// it (render/surface_hit.glsl says why), so the shaded point is the CPU's to float rounding.
// The fragment at framebuffer coordinate (X + 0.5, Y + 0.5) of a pass rasterised at N x N per
// pixel (RenderParams intrinsics_extra.z = N: 1, or the supersampled pass's N) is the sample at
// output pixel ((X + 0.5) / N - 0.5, (Y + 0.5) / N - 0.5): a stratum centre, as the CPU samples.
//
// Bindings (set 0): 0 RenderParams, 1 RenderCorner[], 2 RenderTriangle[], 3 material, 4 frame,
//                   5 shadow map
//                   (render/render_inputs.glsl).
// Outputs: location 0 = (exposure-weighted radiance, 1 + kShadowEdgeAlpha at a shadow edge),
//          location 1 = aux (cast_shadow,
//          cos_theta_i, cos_theta_o, curvature). Background pixels keep the clear value 0.
// C++ twin: `shade` in render/reference/reference_renderer.cc.
#extension GL_GOOGLE_include_directive : require

#define REFLCAP_RENDER_CORNERS
#include "render/shading.glsl"
#include "render/surface_hit.glsl"

layout(location = 0) in vec3 in_position;
layout(location = 1) in vec3 in_normal;
layout(location = 2) in vec2 in_uv;
layout(location = 3) flat in uint in_triangle;

layout(location = 0) out vec4 out_radiance_mask;
layout(location = 1) out vec4 out_aux;

void main() {
  vec3 p = in_position;
  vec3 n_s = normalize(in_normal);
  vec2 uv = in_uv;
  float samples_per_side = params.intrinsics_extra.z;
  vec2 pixel = gl_FragCoord.xy / samples_per_side - 0.5;
  vec3 o, d;
  UndistortedPixelRay(pixel, o, d);
  float t;
  vec3 b;
  // A ray parallel to the triangle's plane (seen edge-on) keeps the interpolated attributes.
  if (IntersectPlane(o, d, in_triangle, t, b) && t > 0.0) {
    SurfacePoint sp = SurfaceAt(in_triangle, b.y, b.z);
    p = sp.p;
    n_s = sp.n_s;
    uv = sp.uv;
  }
  vec4 tri = triangles[in_triangle].normal_curvature;
  vec3 wo = (params.flags & kRenderFlagPinhole) != 0u ? normalize(params.camera_origin.xyz - p)
                                                       : -params.camera_axis.xyz;
  Shade s = ShadeSurface(p, n_s, tri.xyz, uv, wo, tri.w);
  out_radiance_mask =
      vec4(s.radiance * params.intensity.w, 1.0 + (s.shadow_edge ? kShadowEdgeAlpha : 0.0));
  out_aux = s.aux;
}
