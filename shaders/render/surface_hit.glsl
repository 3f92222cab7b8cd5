// Exact ray hits for the Vulkan renderer's shading: the camera ray of a pixel (or sub-pixel
// sample) and its intersection with one triangle, with the surface attributes interpolated at the
// intersection's barycentrics — as the CPU reference renderer traces them. The rasteriser decides
// only *which* triangle a sample sees; where on it comes from here. (Interpolated fragment
// attributes would carry the rasteriser's sub-pixel snapping: with 8 sub-pixel bits, a hit point
// off by up to 1/256 pixel — 1e-4 relative in shading on curved surfaces, and a different texel
// near texel boundaries. Measured on an NVIDIA H100: up to 3.6e-4 relative, and 34 dB PSNR where
// texel boundaries fall on pixel centres.)
// Used by surface.frag (undistorted pinhole and orthographic cameras) and distort_resolve.comp.
// C++ twins: Camera::PixelRay (engine/camera/camera.cc) and the hit interpolation of
// render/reference/reference_renderer.cc.
#ifndef REFLCAP_SHADERS_RENDER_SURFACE_HIT_GLSL_
#define REFLCAP_SHADERS_RENDER_SURFACE_HIT_GLSL_

#include "common/ray_triangle.glsl"
#include "render/camera.glsl"
#include "render/render_inputs.glsl"

#ifndef REFLCAP_RENDER_CORNERS
#error "surface_hit.glsl reads the corner buffer: define REFLCAP_RENDER_CORNERS before the first include of render_inputs.glsl"
#endif

// t along the (unit) ray and the barycentrics (b0, b1, b2) of the point where it meets the plane
// of triangle `tri` (common/ray_triangle.glsl). False for a ray parallel to the plane.
bool IntersectPlane(vec3 o, vec3 d, uint tri, out float t, out vec3 b) {
  return RayTrianglePlane(o, d, corners[3u * tri].position_u.xyz,
                          corners[3u * tri + 1u].position_u.xyz,
                          corners[3u * tri + 2u].position_u.xyz, t, b);
}

// The surface of triangle `tri` at barycentrics (1 - b1 - b2, b1, b2): position, unit shading
// normal and UV.
struct SurfacePoint {
  vec3 p;
  vec3 n_s;
  vec2 uv;
};
SurfacePoint SurfaceAt(uint tri, float b1, float b2) {
  uint i0 = 3u * tri;
  float b0 = 1.0 - b1 - b2;
  RenderCorner c0 = corners[i0], c1 = corners[i0 + 1u], c2 = corners[i0 + 2u];
  SurfacePoint s;
  s.p = b0 * c0.position_u.xyz + b1 * c1.position_u.xyz + b2 * c2.position_u.xyz;
  s.n_s = normalize(b0 * c0.normal_v.xyz + b1 * c1.normal_v.xyz + b2 * c2.normal_v.xyz);
  s.uv = b0 * vec2(c0.position_u.w, c0.normal_v.w) + b1 * vec2(c1.position_u.w, c1.normal_v.w) +
         b2 * vec2(c2.position_u.w, c2.normal_v.w);
  return s;
}

// The object-frame ray (origin o, unit direction d) through `pixel` of the output camera (pixel
// centres at integer coordinates) without lens distortion: Camera::PixelRay for a pinhole camera
// (from the camera centre) and an orthographic one (parallel to the axis, from the plane z = 0;
// cx = (width - 1) / 2 as Camera::PixelRay).
void UndistortedPixelRay(vec2 pixel, out vec3 o, out vec3 d) {
  if ((params.flags & kRenderFlagPinhole) != 0u) {
    vec3 d_cam = PixelRay(pixel, params.intrinsics, params.intrinsics_extra.x, false,
                          params.distortion, params.distortion_extra.x);
    d = normalize(vec3(dot(params.object_from_cam[0].xyz, d_cam),
                       dot(params.object_from_cam[1].xyz, d_cam),
                       dot(params.object_from_cam[2].xyz, d_cam)));
    o = params.camera_origin.xyz;
    return;
  }
  float pixel_m = params.intrinsics_extra.y;
  vec3 o_cam = vec3((pixel.x - 0.5 * float(params.width - 1u)) * pixel_m,
                    (pixel.y - 0.5 * float(params.height - 1u)) * pixel_m, 0.0);
  o = params.camera_origin.xyz + vec3(dot(params.object_from_cam[0].xyz, o_cam),
                                      dot(params.object_from_cam[1].xyz, o_cam),
                                      dot(params.object_from_cam[2].xyz, o_cam));
  d = params.camera_axis.xyz;
}

#endif  // REFLCAP_SHADERS_RENDER_SURFACE_HIT_GLSL_
