// The cast-shadow test against a light map — distances rendered from the light: one view, or the
// six faces of a cube map for a point light — shared by the Vulkan renderer's InShadow
// (shaders/render/shading.glsl, whose file comment explains the receiver-plane depth and the
// slope-scaled bias) and the Vulkan masks' LightShadowed (shaders/resample/masks_common.glsl).
// Both hold their views as shared/light_map_view.h's LightMapView, keep their own bias
// parameters, and pass the fields here.
#ifndef REFLCAP_SHADERS_COMMON_LIGHT_MAP_GLSL_
#define REFLCAP_SHADERS_COMMON_LIGHT_MAP_GLSL_

// Slope term of the bias: tan θ of the light at the geometric normal, at most kMaxLightMapSlope
// (θ = 84°; cos θ >= kMinLightMapCos keeps the division finite).
const float kMaxLightMapSlope = 10.0;
const float kMinLightMapCos = 0.0995;

// The view that holds the direction from the light to p: the cube face by the major axis of
// p - light (+X, -X, +Y, -Y, +Z, -Z) when there are six views, else the only one.
int LightMapViewOf(vec3 p, vec3 light, uint num_views) {
  if (num_views < 6u) return 0;
  vec3 d = p - light;
  vec3 a = abs(d);
  if (a.x >= a.y && a.x >= a.z) return d.x >= 0.0 ? 0 : 1;
  if (a.y >= a.z) return d.y >= 0.0 ? 2 : 3;
  return d.z >= 0.0 ? 4 : 5;
}

// The light-map texel holding clip position `clip` (NDC x, y mapped to [0, resolution)).
// Clamped: a point exactly on the frustum's border (NDC ±1) still reads the edge texel.
vec2 LightMapTexelOf(vec4 clip, uint resolution) {
  vec2 ndc = clip.xy / clip.w;
  float res = float(resolution);
  return clamp(floor((ndc * 0.5 + 0.5) * res), vec2(0.0), vec2(res - 1.0));
}

// Whether p (geometric normal n_g, facing the light) is in cast shadow by light-map texel
// `texel` of view `view` (layer of `map`; origin, forward, right, up as in LightMapView): stored
// distance < t_plane - bias, bias = bias.x + bias.y * footprint * (1 + min(tan θ,
// kMaxLightMapSlope)), t_plane (where the texel's ray meets the plane through p with normal n_g)
// at most bias.z footprints behind p.
bool LightMapTexelShadowed(sampler2DArray map, int view, vec2 texel, vec4 origin4, vec4 forward,
                           vec4 right, vec4 up, uint resolution, vec3 p, vec3 n_g, vec3 bias) {
  float res = float(resolution);
  vec2 centre = (texel + 0.5) / res * 2.0 - 1.0;
  bool perspective = origin4.w > 0.5;
  vec3 origin = origin4.xyz;
  vec3 dir = forward.xyz;
  float t_p;
  float footprint;
  if (perspective) {
    dir = normalize(forward.xyz + centre.x * right.w * right.xyz + centre.y * up.w * up.xyz);
    t_p = length(p - origin);
    footprint = 2.0 * right.w / res * t_p;
  } else {
    origin += centre.x * right.w * right.xyz + centre.y * up.w * up.xyz;
    t_p = dot(p - origin4.xyz, forward.xyz);
    footprint = 2.0 * right.w / res;
  }
  float t_plane = t_p;
  float denom = dot(dir, n_g);
  if (denom < 0.0) {
    t_plane = min(dot(p - origin, n_g) / denom, t_p + bias.z * footprint);
  }
  float stored = texelFetch(map, ivec3(ivec2(texel), view), 0).r * forward.w;
  float cos_g = max(-dot(dir, n_g), kMinLightMapCos);
  float tan_g = sqrt(max(1.0 - cos_g * cos_g, 0.0)) / cos_g;  // max: rounding of cos_g near 1
  float total_bias = bias.x + bias.y * footprint * (1.0 + min(tan_g, kMaxLightMapSlope));
  return stored < t_plane - total_bias;
}

// Whether p, at clip position `clip` in view `view`, is in cast shadow: the test of the texel
// holding it (LightMapTexelShadowed).
bool LightMapShadowed(sampler2DArray map, int view, vec4 clip, vec4 origin4, vec4 forward,
                      vec4 right, vec4 up, uint resolution, vec3 p, vec3 n_g, vec3 bias) {
  // w > 0 inside every view the hosts build (the object lies in front of the light); guard the
  // division anyway so that no NaN reaches the comparison.
  if (!(clip.w > 0.0)) return false;
  return LightMapTexelShadowed(map, view, LightMapTexelOf(clip, resolution), origin4, forward,
                               right, up, resolution, p, n_g, bias);
}

// Whether the light map cannot tell p's shadow to within a texel: some texel of the 3 x 3 around
// the one holding p decides otherwise than `shadowed` (an occluder's silhouette, seen from the
// light, passes within a texel of p). There the map's answer may differ from the exact ray's —
// at 1024 px and the default resolution, ~100 pixels an image flipped between lit and shadow —
// so the Vulkan renderer has the host shade those pixels with rays (vulkan_renderer.cc).
bool LightMapShadowEdge(sampler2DArray map, int view, vec4 clip, vec4 origin4, vec4 forward,
                        vec4 right, vec4 up, uint resolution, vec3 p, vec3 n_g, vec3 bias,
                        bool shadowed) {
  if (!(clip.w > 0.0)) return false;
  vec2 texel = LightMapTexelOf(clip, resolution);
  float last = float(resolution) - 1.0;
  for (int dy = -1; dy <= 1; ++dy) {
    for (int dx = -1; dx <= 1; ++dx) {
      vec2 q = texel + vec2(dx, dy);
      if ((dx == 0 && dy == 0) || q.x < 0.0 || q.y < 0.0 || q.x > last || q.y > last) continue;
      if (LightMapTexelShadowed(map, view, q, origin4, forward, right, up, resolution, p, n_g,
                                bias) != shadowed) {
        return true;
      }
    }
  }
  return false;
}

#endif  // REFLCAP_SHADERS_COMMON_LIGHT_MAP_GLSL_
