#version 460
// Fragment stage of the camera pass of the Vulkan masks: the "pixel map" of the CPU path
// (ImageResampler::CastPixels) for every camera-map texel at once. At each texel centre it stores
// what the camera ray through it hits: the distance along the ray (|p - centre| for a pinhole
// camera, the depth p_cam.z for an orthographic one) and whether that point is lit as the
// renderer decides it — both normals face the light and the light map holds no occluder
// (LightShadowed) — and marks the texel as a hit. The depth test (LESS, on the projective depth)
// keeps the nearest surface, as the CPU's first hit. The rasteriser only picks the triangle: the
// point, its normal and its UV come from the texel's exact ray meeting that triangle
// (common/ray_triangle.glsl), since interpolated attributes carry the rasteriser's sub-pixel
// snapping (measured on an NVIDIA H200: kept samples' values up to past the 1e-3 tolerance of
// vulkan_masks_test at grazing light, where cos θi is small and its error is amplified).
//
// Bindings (set 0): 0 = MaskParams, 1 = MaskCorner[], 2 = triangle normals, 3 = light map,
// 12 = the atlas's texel_of_pixel. Push constants: MaskDrawPush {view = kMaskCameraView}.
// Outputs: location 0 (RGBA32F) = (distance, lit 0/1, hit = 1, the triangle index as a float:
// exact below 2^24, which vulkan_masks.cc checks; masks.comp meets each photograph pixel's own ray
// with it); location 1 (RGBA32F) = (the
// hit's unit shading normal, the texel under its UV as a float, -1 = none), what
// SamplePoint::kPixel measures a sample with and which texel it measured; the clear value 0 =
// background.
#extension GL_GOOGLE_include_directive : require

#define REFLCAP_MASK_CORNERS
#define REFLCAP_MASK_TRIANGLES
#define REFLCAP_MASK_LIGHT_MAP
#define REFLCAP_MASK_TEXEL_OF_PIXEL
#include "resample/masks_common.glsl"

layout(push_constant) uniform Push { MaskDrawPush push; };

layout(location = 0) in vec3 in_position;
layout(location = 1) in vec3 in_normal;
layout(location = 2) in vec2 in_uv;
layout(location = 0) out vec4 out_map;
layout(location = 1) out vec4 out_normal;

void main() {
  vec3 p = in_position;
  vec3 n_interp = in_normal;
  vec2 uv = in_uv;
  uint tri = uint(gl_PrimitiveID);
  vec3 o, d;
  MaskMapTexelRay(gl_FragCoord.xy - 0.5, o, d);
  float t;
  vec3 b;
  // A ray parallel to the triangle's plane (seen edge-on) keeps the interpolated attributes.
  if (MaskRayMeetsTriangle(o, d, tri, t, b)) {
    MaskSurface hit = MaskSurfaceAt(tri, b);
    p = hit.p;
    n_interp = hit.n;
    uv = hit.uv;
  }
  vec3 centre = params.camera_centre.xyz;
  float distance = (params.flags & kMaskFlagPinhole) != 0u ? length(p - centre)
                                                           : dot(p - centre, -params.toward_cam.xyz);
  vec3 n_g = triangle_normals[tri].xyz;
  // A degenerate interpolated normal (opposite corner normals) cannot face the light.
  float len = length(n_interp);
  vec3 n_s = len > 0.0 ? n_interp / len : vec3(0.0);
  float dist;
  vec3 wi = ToLight(p, dist);
  bool lit = dot(n_s, wi) > 0.0 && dot(n_g, wi) > 0.0 && !LightShadowed(p, n_g);
  out_map = vec4(distance, lit ? 1.0 : 0.0, 1.0, float(tri));
  out_normal = vec4(n_s, float(MaskTexelUnderUv(uv)));
}
