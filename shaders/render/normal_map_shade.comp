#version 460
// Shading of a normal-map capture (no mesh, nothing to rasterise): one invocation per texel (=
// masked pixel of the capture's camera), shaded from its own normal and tangent frame with the
// directional light, as RenderNormalMapImage does — cast shadows from the height field
// integrated from the normal map (common/height_field.glsl's march, when push.march.steps > 0),
// no supersampling. wo = -camera axis (orthographic) or minus the pixel's ray (pinhole,
// undistorted by render/camera.glsl's PixelRay), all in the world frame (object_from_cam holds
// world_from_cam's rotation here).
//
// Bindings (set 0): 0 RenderParams, 3 material (render/render_inputs.glsl), 7 out radiance
//   vec4[width * height] (rgb exposure-weighted, a = mask), 8 out aux vec4[width * height]
//   (cast_shadow, cos_theta_i, cos_theta_o, curvature), 9 NormalMapTexel[], 10 height field
//   float[width * height] (heights towards the camera in pixels, kHeightFieldOutside off the
//   object; one float when the scene has none).
// Push constants: NormalMapPush {texels, march}.
// C++ twin: RenderNormalMapImage in render/reference/reference_renderer.cc (and
// HeightFieldShadowed in engine/mesh/height_field.cc).
#extension GL_GOOGLE_include_directive : require

#include "render/camera.glsl"
#include "render/material.glsl"

layout(local_size_x = 64) in;

layout(std430, set = 0, binding = 7) buffer OutRadiance { vec4 out_radiance[]; };
layout(std430, set = 0, binding = 8) buffer OutAux { vec4 out_aux[]; };
layout(std430, set = 0, binding = 9) readonly buffer TexelBlock { NormalMapTexel texels[]; };
layout(std430, set = 0, binding = 10) readonly buffer HeightFieldBlock { float height_field_px[]; };
layout(push_constant) uniform Push { NormalMapPush push; };

#include "common/height_field.glsl"

void main() {
  uint t = gl_GlobalInvocationID.x;
  if (t >= push.texels) return;
  NormalMapTexel tx = texels[t];
  uvec2 px = tx.pixel.xy;
  vec3 wo = -params.camera_axis.xyz;
  if ((params.flags & kRenderFlagPinhole) != 0u) {
    vec3 d_cam = PixelRay(vec2(px), params.intrinsics, params.intrinsics_extra.x,
                          (params.flags & kRenderFlagDistortion) != 0u, params.distortion,
                          params.distortion_extra.x);
    wo = -normalize(vec3(dot(params.object_from_cam[0].xyz, d_cam),
                         dot(params.object_from_cam[1].xyz, d_cam),
                         dot(params.object_from_cam[2].xyz, d_cam)));
  }
  vec3 n = tx.normal_curvature.xyz;
  vec3 wi = params.light.xyz;
  float cos_i = dot(n, wi), cos_o = dot(n, wo);
  uint index = px.y * params.width + px.x;
  bool shadowed = cos_i > 0.0 && push.march.steps > 0u &&
                  HeightFieldShadowed(push.march, int(px.x), int(px.y));
  out_aux[index] = vec4(shadowed ? 1.0 : 0.0, cos_i, cos_o, tx.normal_curvature.w);
  vec3 value = vec3(0.0);
  if (cos_i > 0.0 && cos_o > 0.0 && !shadowed) {
    vec3 wi_local = vec3(dot(tx.tangent.xyz, wi), dot(tx.bitangent.xyz, wi), cos_i);
    vec3 wo_local = vec3(dot(tx.tangent.xyz, wo), dot(tx.bitangent.xyz, wo), cos_o);
    vec3 f = EvalRgbAt(ivec2(px), wi_local, wo_local);
    value = f * params.intensity.rgb * (cos_i * params.intensity.w);
  }
  out_radiance[index] = vec4(value, 1.0);
}
