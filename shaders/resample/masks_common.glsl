// Inputs shared by the passes of the Vulkan masks (shaders/resample/*; host side
// acquire/resample/vulkan_masks.cc): the bindings of set 0, the light-map test and small helpers.
//
// Bindings (set 0): 0 = MaskParams, 1 = MaskCorner[] (draws), 2 = per-triangle geometric normals
// (camera pass), 3 = light map (sampler2DArray of distances / scale), 4 = camera map
// (sampler2DArray: distance, lit, hit), 5 = MaskTexel[], 6 = pixel rays (vec2 per photograph
// pixel: undistorted normalised coordinates), 7 = photograph pixels (float RGB), 8 = outcomes,
// 9 = MaskSample[], 10 = the photograph's variance image (float RGB; masks.comp), 11 = camera
// normal map, 12 = the atlas's texel_of_pixel (int per atlas pixel, -1 = none; camera pass). A
// pass declares only what it reads (#define REFLCAP_MASK_* before including).
//
// Light-map test (LightShadowed): the GLSL twin of the Vulkan renderer's InShadow
// (shaders/render/shading.glsl explains the receiver-plane depth and the slope-scaled bias): p is
// in shadow when the stored distance < t_plane - bias, t_plane being where the light-map texel's
// ray meets the plane through p with normal n_g (limited to bias.y footprints behind p), and
//   bias = surface offset + bias.x * footprint * (1 + min(tan θ, kMaxLightMapSlope)),
// computed by common/light_map.glsl's LightMapShadowed, which InShadow calls too.
// The CPU's shadow ray starts at p + offset n_g; the constant term is that same offset (float
// rounding of positions), the footprint term covers what the plane does not model (a concave
// receiver whose neighbouring facets, met by the texel's ray up to half a texel beside p, come
// closer to the light by that offset times the slope).
#ifndef REFLCAP_SHADERS_RESAMPLE_MASKS_COMMON_GLSL_
#define REFLCAP_SHADERS_RESAMPLE_MASKS_COMMON_GLSL_

#include "shared/resample_masks.h"

layout(std430, set = 0, binding = 0) readonly buffer ParamsBuffer { MaskParams params; };

#ifdef REFLCAP_MASK_CORNERS
layout(std430, set = 0, binding = 1) readonly buffer CornerBuffer { MaskCorner corners[]; };
#endif
#ifdef REFLCAP_MASK_TRIANGLES
layout(std430, set = 0, binding = 2) readonly buffer TriangleBuffer { vec4 triangle_normals[]; };
#endif
#ifdef REFLCAP_MASK_LIGHT_MAP
layout(set = 0, binding = 3) uniform sampler2DArray light_map;
#endif
#ifdef REFLCAP_MASK_TEXEL_OF_PIXEL
#include "common/texel_atlas.glsl"

layout(std430, set = 0, binding = 12) readonly buffer TexelOfPixelBuffer { int texel_of_pixel[]; };

// TexelAtlas::TexelUnderUv: the texel under uv, else the first of its 3x3 neighbourhood (rows,
// then columns); -1 when there is none.
int MaskTexelUnderUv(vec2 uv) {
  // The atlas size rides in params.map_intrinsics_extra.yz (resample_masks.h).
  ivec2 size = ivec2(params.map_intrinsics_extra.yz);
  ivec2 px = AtlasPixelOfUv(uv, uvec2(size));
  int t = texel_of_pixel[px.y * size.x + px.x];
  if (t >= 0) return t;
  for (int dy = -1; dy <= 1; ++dy) {
    for (int dx = -1; dx <= 1; ++dx) {
      ivec2 q = px + ivec2(dx, dy);
      if (q.x < 0 || q.y < 0 || q.x >= size.x || q.y >= size.y) continue;
      t = texel_of_pixel[q.y * size.x + q.x];
      if (t >= 0) return t;
    }
  }
  return -1;
}
#endif
#ifdef REFLCAP_MASK_CAMERA_MAP
layout(set = 0, binding = 4) uniform sampler2DArray camera_map;
// The camera pass's second attachment: the hit's unit shading normal (xyz) and the texel under
// its UV (w, a float; -1 = none); 0 = background.
layout(set = 0, binding = 11) uniform sampler2DArray camera_normal_map;
#endif

// rows (4x4, row-major) times (p, 1).
vec4 MaskTransformRows(vec4 rows[4], vec3 p) {
  precise vec4 q = vec4(p, 1.0);
  return vec4(dot(rows[0], q), dot(rows[1], q), dot(rows[2], q), dot(rows[3], q));
}

// [R | t] rows (3x4) times (p, w): w = 1 for points, 0 for directions.
vec3 MaskTransform3(vec4 rows[3], vec3 p, float w) {
  precise vec4 q = vec4(p, w);
  return vec3(dot(rows[0], q), dot(rows[1], q), dot(rows[2], q));
}

// The object-frame ray through camera-map texel centre `t` (centres at integer coordinates): the
// map's pinhole intrinsics (the photograph's, or the undistorted grid's of a distorted camera;
// vulkan_masks.cc CameraGrid) from the camera centre, or an orthographic camera's parallel ray
// from the plane z = 0 (Camera::PixelRay's cx = (width - 1) / 2; the map is the photograph's grid).
void MaskMapTexelRay(vec2 t, out vec3 origin, out vec3 dir) {
  if ((params.flags & kMaskFlagPinhole) != 0u) {
    float yc = (t.y - params.map_intrinsics.w) / params.map_intrinsics.y;
    float xc = (t.x - params.map_intrinsics.z - params.map_intrinsics_extra.x * yc) /
               params.map_intrinsics.x;
    origin = params.camera_centre.xyz;
    dir = normalize(MaskTransform3(params.object_from_cam, vec3(xc, yc, 1.0), 0.0));
  } else {
    float ps = params.intrinsics_extra.y;
    vec2 c = 0.5 * vec2(float(params.map_width - 1u), float(params.map_height - 1u));
    origin = MaskTransform3(params.object_from_cam, vec3((t - c) * ps, 0.0), 1.0);
    dir = -params.toward_cam.xyz;
  }
}

#ifdef REFLCAP_MASK_CORNERS
#include "common/ray_triangle.glsl"

// Where the ray (origin, dir) meets the plane of triangle `tri`, ahead of the origin: its distance
// t and barycentrics b (common/ray_triangle.glsl). False for a ray parallel to the plane or
// meeting it behind the origin.
bool MaskRayMeetsTriangle(vec3 origin, vec3 dir, uint tri, out float t, out vec3 b) {
  return RayTrianglePlane(origin, dir, corners[3u * tri].position.xyz,
                          corners[3u * tri + 1u].position.xyz,
                          corners[3u * tri + 2u].position.xyz, t, b) &&
         t > 0.0;
}

// Triangle `tri`'s corners interpolated at barycentrics b: position, shading normal (not
// normalised) and UV — as CastPixels interpolates them at Embree's hit.
struct MaskSurface {
  vec3 p;
  vec3 n;
  vec2 uv;
};
MaskSurface MaskSurfaceAt(uint tri, vec3 b) {
  MaskCorner c0 = corners[3u * tri], c1 = corners[3u * tri + 1u], c2 = corners[3u * tri + 2u];
  MaskSurface s;
  s.p = b.x * c0.position.xyz + b.y * c1.position.xyz + b.z * c2.position.xyz;
  s.n = b.x * c0.normal.xyz + b.y * c1.normal.xyz + b.z * c2.normal.xyz;
  s.uv = b.x * vec2(c0.position.w, c0.normal.w) + b.y * vec2(c1.position.w, c1.normal.w) +
         b.z * vec2(c2.position.w, c2.normal.w);
  return s;
}
#endif  // REFLCAP_MASK_CORNERS

// Unit direction from p towards the light and its distance (1 for a directional light, whose
// irradiance does not fall off).
vec3 ToLight(vec3 p, out float dist) {
  if ((params.flags & kMaskFlagPointLight) != 0u) {
    vec3 d = params.light.xyz - p;
    dist = length(d);
    return d / dist;
  }
  dist = 1.0;
  return params.light.xyz;
}

#ifdef REFLCAP_MASK_LIGHT_MAP
#include "common/light_map.glsl"

// Whether p (geometric normal n_g, facing the light) lies in cast shadow; see the file comment.
bool LightShadowed(vec3 p, vec3 n_g) {
  int v = LightMapViewOf(p, params.light.xyz, params.num_light_views);
  LightMapView view = params.views[v];
  vec4 clip = MaskTransformRows(view.clip_from_object, p);
  return LightMapShadowed(light_map, v, clip, view.origin, view.forward, view.right, view.up,
                          params.light_resolution, p, n_g,
                          vec3(params.tests.w, params.bias.x, params.bias.y));
}
#endif  // REFLCAP_MASK_LIGHT_MAP

#endif  // REFLCAP_SHADERS_RESAMPLE_MASKS_COMMON_GLSL_
