// Inputs shared by the passes of the Vulkan masks (shaders/resample/*; host side
// acquire/resample/vulkan_masks.cc): the bindings of set 0, the light-map test and small helpers.
//
// Bindings (set 0): 0 = MaskParams, 1 = MaskCorner[] (draws), 2 = per-triangle geometric normals
// (camera pass), 3 = light map (sampler2DArray of distances / scale), 4 = camera map
// (sampler2DArray: distance, lit, hit), 5 = MaskTexel[], 6 = pixel rays (vec2 per photograph
// pixel: undistorted normalised coordinates), 7 = photograph pixels (float RGB), 8 = outcomes,
// 9 = MaskSample[]. A pass declares only what it reads (#define REFLCAP_MASK_* before including).
//
// Light-map test (LightShadowed): the GLSL twin of the Vulkan renderer's InShadow
// (shaders/render/shading.glsl explains the receiver-plane depth and the slope-scaled bias): p is
// in shadow when the stored distance < t_plane - bias, t_plane being where the light-map texel's
// ray meets the plane through p with normal n_g (limited to bias.y footprints behind p), and
//   bias = surface offset + bias.x * footprint * (1 + min(tan θ, kMaxMaskSlope)).
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
#ifdef REFLCAP_MASK_CAMERA_MAP
layout(set = 0, binding = 4) uniform sampler2DArray camera_map;
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
// Slope term of the light-map bias: tan θ of the light at the geometric normal, at most
// kMaxMaskSlope (θ = 84°; cos θ >= kMinMaskCos keeps the division finite). As the renderer's.
const float kMaxMaskSlope = 10.0;
const float kMinMaskCos = 0.0995;

// The light-map view that holds the direction from the light to p: the cube face by the major
// axis of p - light (+X, -X, +Y, -Y, +Z, -Z), or the only view.
int LightViewOf(vec3 p) {
  if (params.num_light_views < 6u) return 0;
  vec3 d = p - params.light.xyz;
  vec3 a = abs(d);
  if (a.x >= a.y && a.x >= a.z) return d.x >= 0.0 ? 0 : 1;
  if (a.y >= a.z) return d.y >= 0.0 ? 2 : 3;
  return d.z >= 0.0 ? 4 : 5;
}

// Whether p (geometric normal n_g, facing the light) lies in cast shadow; see the file comment.
bool LightShadowed(vec3 p, vec3 n_g) {
  int v = LightViewOf(p);
  MaskView view = params.views[v];
  vec4 clip = MaskTransformRows(view.clip_from_object, p);
  // w > 0 inside every view the host builds (the object lies in front of the light); guard the
  // division anyway so that no NaN reaches the comparison.
  if (!(clip.w > 0.0)) return false;
  vec2 ndc = clip.xy / clip.w;
  float res = float(params.light_resolution);
  // Clamped: a point exactly on the frustum's border (NDC ±1) still reads the edge texel.
  vec2 texel = clamp(floor((ndc * 0.5 + 0.5) * res), vec2(0.0), vec2(res - 1.0));
  vec2 centre = (texel + 0.5) / res * 2.0 - 1.0;
  bool perspective = view.origin.w > 0.5;
  vec3 origin = view.origin.xyz;
  vec3 dir = view.forward.xyz;
  float t_p;
  float footprint;
  if (perspective) {
    dir = normalize(view.forward.xyz + centre.x * view.right.w * view.right.xyz +
                    centre.y * view.up.w * view.up.xyz);
    t_p = length(p - origin);
    footprint = 2.0 * view.right.w / res * t_p;
  } else {
    origin += centre.x * view.right.w * view.right.xyz + centre.y * view.up.w * view.up.xyz;
    t_p = dot(p - view.origin.xyz, view.forward.xyz);
    footprint = 2.0 * view.right.w / res;
  }
  float t_plane = t_p;
  float denom = dot(dir, n_g);
  if (denom < 0.0) {
    t_plane = min(dot(p - origin, n_g) / denom, t_p + params.bias.y * footprint);
  }
  float stored = texelFetch(light_map, ivec3(ivec2(texel), v), 0).r * view.forward.w;
  float cos_g = max(-dot(dir, n_g), kMinMaskCos);
  float tan_g = sqrt(max(1.0 - cos_g * cos_g, 0.0)) / cos_g;  // max: rounding of cos_g near 1
  float bias = params.tests.w + params.bias.x * footprint * (1.0 + min(tan_g, kMaxMaskSlope));
  return stored < t_plane - bias;
}
#endif  // REFLCAP_MASK_LIGHT_MAP

#endif  // REFLCAP_SHADERS_RESAMPLE_MASKS_COMMON_GLSL_
