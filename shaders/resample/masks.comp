#version 460
// masks.comp: one invocation per texel of one photograph — the GLSL twin of
// ImageResampler::ProcessMeshBlock + MakeSample (acquire/resample/image_resampler.cc), with the
// same tests in the same order and the same outcome codes (shared/resample_masks.h), except that
// visibility and cast shadow are looked up in the camera and light maps the draws before it
// rasterised, instead of Embree's occlusion rays:
//   view grazing -> projection (four bilinear taps inside the image) -> camera map (occluded) ->
//   light grazing -> light map (shadowed) -> footprint: every tap's camera-map texel is a hit
//   within the edge depth tolerance of the texel, and lit -> pixel values (invalid, clipped,
//   invalid below the noise, dark) -> the BRDF sample. Each tap's hit is where the pixel's own
//   ray meets the triangle its camera-map texel saw (the map's w; common/ray_triangle.glsl), as
//   the CPU's pixel map (ImageResampler::CastPixels) traces it: distance, shading normal and the
//   texel under its UV are the CPU's to float rounding on any device — neither the rasteriser's
//   sub-pixel snapping nor, for a distorted camera, the up to half a texel between a pixel's ray
//   and its map texel's ray moves them. With kMaskFlagPixelSample (SamplePoint::kPixel) the sample
//   is the tap whose hit lies in the texel nearest its centre, else — kMaskFlagPointPixels, the
//   texel resolved: kMaskEdgeTexel — the tap whose hit is nearest, with the hit's position,
//   shading normal, directions and light distance, as the CPU's; else the bilinear value at the
//   texel centre's geometry.
// Loops: at most 4 taps x 3 channels (twice with a variance image) per invocation, far below
// lavapipe's 65,535-step cut.
//
// Bindings (set 0): 0 = MaskParams, 1 = MaskCorner[], 3 = light map, 4 = camera map,
// 5 = MaskTexel[] (this chunk),
// 6 = pixel rays (vec2 per pixel, pinhole cameras), 7 = photograph (float RGB, row-major),
// 8 = outcome per texel (this chunk), 9 = MaskSample per texel (this chunk; written when kept),
// 10 = the photograph's variance image (float RGB, row-major; read only when
// params.relative_sigma_floor.y = 1, see "Noise" below), 11 = camera normal map (a tap whose ray
// is parallel to its triangle keeps the map's attributes), 12 = the atlas's texel_of_pixel.
//
// Noise: with the variance image, a sample's variance is MeasuredVariance (Σ w_k² var_k over the
// bilinear taps) plus the relative floor, and its invalid / dark tests compare each channel with
// kInvalidSigmas / kDarkSigmas (relative_sigma_floor.w / .z) of its own σ — the twins of
// MeasuredVariance, MeasuredInvalid, MeasuredDark and MeasuredPixelVariance
// (acquire/resample/image_resampler.h); without it, the noise model (params.noise) as before.
// Push constants: MaskTexelPush {first_texel, count}. Specialization constant 0: local_size_x.
#extension GL_GOOGLE_include_directive : require

#define REFLCAP_MASK_CORNERS
#define REFLCAP_MASK_LIGHT_MAP
#define REFLCAP_MASK_CAMERA_MAP
#define REFLCAP_MASK_TEXEL_OF_PIXEL
#include "resample/masks_common.glsl"

layout(local_size_x = 64, local_size_x_id = 0) in;

layout(push_constant) uniform Push { MaskTexelPush push; };

layout(std430, set = 0, binding = 5) readonly buffer TexelBuffer { MaskTexel texels[]; };
layout(std430, set = 0, binding = 6) readonly buffer RayBuffer { vec2 pixel_rays[]; };
layout(std430, set = 0, binding = 7) readonly buffer PixelBuffer { float pixels[]; };
layout(std430, set = 0, binding = 8) writeonly buffer OutcomeBuffer { uint outcomes[]; };
layout(std430, set = 0, binding = 9) writeonly buffer SampleBuffer { MaskSample samples[]; };
layout(std430, set = 0, binding = 10) readonly buffer VarianceBuffer { float variances[]; };

// The projection must be far inside int range before floor() is converted (as the CPU's).
const float kMaxPixelCoordinate = 1e8;
// Largest weight written: float's largest value (the CPU clamps 1 / variance the same way).
const float kMaxWeight = 3.402823e38;
// A tangent closer than this (squared) to the normal's direction is replaced (as the CPU's).
const float kTinyTangent2 = 1e-12;
const float kSqrt2 = 1.41421356;

bool Pinhole() { return (params.flags & kMaskFlagPinhole) != 0u; }

// Camera::Distort (engine/camera/camera.cc) in float.
vec2 Distort(vec2 xy) {
  float r2 = dot(xy, xy);
  float radial = 1.0 + r2 * (params.distortion.x + r2 * (params.distortion.y +
                                                           r2 * params.distortion_extra.x));
  float p1 = params.distortion.z, p2 = params.distortion.w;
  return vec2(xy.x * radial + 2.0 * p1 * xy.x * xy.y + p2 * (r2 + 2.0 * xy.x * xy.x),
              xy.y * radial + p1 * (r2 + 2.0 * xy.y * xy.y) + 2.0 * p2 * xy.x * xy.y);
}

// The camera ray through the centre of photograph pixel (x, y), object frame (Frame::PixelRay).
void PixelRay(int x, int y, out vec3 origin, out vec3 dir) {
  if (Pinhole()) {
    vec2 xy = pixel_rays[y * int(params.width) + x];
    origin = params.camera_centre.xyz;
    dir = normalize(MaskTransform3(params.object_from_cam, vec3(xy, 1.0), 0.0));
  } else {
    float ps = params.intrinsics_extra.y;
    vec3 o = vec3((float(x) - 0.5 * float(params.width - 1u)) * ps,
                  (float(y) - 0.5 * float(params.height - 1u)) * ps, 0.0);
    origin = MaskTransform3(params.object_from_cam, o, 1.0);
    dir = -params.toward_cam.xyz;
  }
}

// Camera-map texel of undistorted normalised coordinates xy (pinhole) or of photograph pixel
// coordinates (orthographic, whose map is the photograph's grid): the nearest texel centre.
ivec2 MapTexelOfXy(vec2 xy) {
  float u = params.map_intrinsics.x * xy.x + params.map_intrinsics_extra.x * xy.y +
            params.map_intrinsics.z;
  float v = params.map_intrinsics.y * xy.y + params.map_intrinsics.w;
  return ivec2(floor(vec2(u, v) + 0.5));
}

// The camera-map texel whose centre is photograph pixel (x, y)'s ray.
ivec2 MapTexelOfPixel(int x, int y) {
  // Without distortion the map is the photograph's grid itself: the same ray, exactly.
  if (!Pinhole() || (params.flags & kMaskFlagDistortion) == 0u) return ivec2(x, y);
  return MapTexelOfXy(pixel_rays[y * int(params.width) + x]);
}

bool InMap(ivec2 t) {
  return t.x >= 0 && t.y >= 0 && t.x < int(params.map_width) && t.y < int(params.map_height);
}

// What photograph pixel ray (origin, dir) hits, from its camera-map texel t (a hit, m its first
// attachment): the ray met with the triangle the texel saw (m.w) — distance along the ray, unit
// shading normal and the texel under the UV (-1 = none), as CastPixels interpolates them at
// Embree's barycentrics. A ray parallel to that triangle's plane, or meeting it behind the camera,
// keeps the map texel's own values.
struct TapHit {
  float distance;
  vec3 n_s;
  float texel;
};
TapHit TapHitOf(vec3 origin, vec3 dir, ivec2 t, vec4 m) {
  uint tri = uint(m.w);
  float dist;
  vec3 b;
  TapHit h;
  if (MaskRayMeetsTriangle(origin, dir, tri, dist, b)) {
    MaskSurface hit = MaskSurfaceAt(tri, b);
    float len = length(hit.n);
    // A degenerate interpolated normal (opposite corner normals) faces nothing, as the camera pass.
    h.n_s = len > 0.0 ? hit.n / len : vec3(0.0);
    h.distance = dist;
    h.texel = float(MaskTexelUnderUv(hit.uv));
    return h;
  }
  vec4 a = texelFetch(camera_normal_map, ivec3(t, 0), 0);
  h.distance = m.x;
  h.n_s = a.xyz;
  h.texel = a.w;
  return h;
}

// Whether the camera map holds a surface in front of texel p (geometric normal n_g) along the
// ray of p's camera-map texel: stored < t_plane - bias, with the receiver-plane distance t_plane
// of LightShadowed (a planar receiver cannot occlude itself at any slope) limited to bias.w pixel
// footprints behind p, and bias = surface offset (float rounding, the CPU's ray offset) + bias.z
// pixel footprints x (1 + min(tan θo, kMaxLightMapSlope)) for concave neighbours met half a texel
// beside p. Rays of map texels that see the background never occlude.
bool CameraOccluded(vec3 p, vec3 n_g, vec3 p_cam, float footprint, float tan_v) {
  ivec2 t;
  vec3 origin, dir;
  float t_p;
  if (Pinhole()) {
    t = MapTexelOfXy(p_cam.xy / p_cam.z);
  } else {
    vec2 c = 0.5 * vec2(float(params.width - 1u), float(params.height - 1u));
    t = ivec2(floor(p_cam.xy / params.intrinsics_extra.y + c + 0.5));
  }
  MaskMapTexelRay(vec2(t), origin, dir);
  t_p = Pinhole() ? length(p - origin) : p_cam.z;
  if (!InMap(t)) return false;
  vec4 m = texelFetch(camera_map, ivec3(t, 0), 0);
  if (!(m.z > 0.5)) return false;
  float t_plane = t_p;
  float denom = dot(dir, n_g);
  if (denom < 0.0) t_plane = min(dot(p - origin, n_g) / denom, t_p + params.bias.w * footprint);
  float bias = params.tests.w + params.bias.z * footprint * (1.0 + min(tan_v, kMaxLightMapSlope));
  return m.x < t_plane - bias;
}

vec3 PixelAt(int x, int y) {
  int i = 3 * (y * int(params.width) + x);
  return vec3(pixels[i], pixels[i + 1], pixels[i + 2]);
}

bool AllFinite(vec3 v) { return !any(isnan(v)) && !any(isinf(v)); }

bool UseVarianceImage() { return params.relative_sigma_floor.y == 1.0; }

vec3 VarianceAt(int x, int y) {
  int i = 3 * (y * int(params.width) + x);
  return vec3(variances[i], variances[i + 1], variances[i + 2]);
}

// Σ_k w_k² var_k over the taps of non-zero weight (image_resampler.h MeasuredVariance).
vec3 MeasuredVariance(ivec2 tap[4], float w[4]) {
  vec3 var = vec3(0.0);
  for (int k = 0; k < 4; ++k) {
    if (w[k] == 0.0) continue;
    float w2 = w[k] * w[k];
    var += w2 * VarianceAt(tap[k].x, tap[k].y);
  }
  return var;
}

// Some channel below -kInvalidSigmas of its own σ (MeasuredInvalid).
bool MeasuredInvalid(vec3 value, vec3 var) {
  for (int c = 0; c < 3; ++c) {
    if (value[c] < -params.relative_sigma_floor.w * sqrt(var[c])) return true;
  }
  return false;
}

// Every channel at or below kDarkSigmas of its own σ (MeasuredDark).
bool MeasuredDark(vec3 value, vec3 var) {
  for (int c = 0; c < 3; ++c) {
    if (!(value[c] <= params.relative_sigma_floor.z * sqrt(var[c]))) return false;
  }
  return true;
}

// Eigen's unitOrthogonal() for a 3-vector (float precision 1e-5), as the CPU's ToTangentFrame.
vec3 UnitOrthogonal(vec3 v) {
  const float kPrecision = 1e-5;
  if (!(abs(v.x) <= abs(v.z) * kPrecision) || !(abs(v.y) <= abs(v.z) * kPrecision)) {
    return vec3(-v.y, v.x, 0.0) / length(v.xy);
  }
  return vec3(0.0, -v.z, v.y) / length(v.yz);
}

void main() {
  uint local = gl_GlobalInvocationID.x;
  if (local >= push.count) return;
  MaskTexel tx = texels[local];
  vec3 p = tx.position.xyz;
  vec3 n_s = tx.shading_normal.xyz;
  vec3 n_g = tx.geometric_normal.xyz;
  float min_cos = params.tests.x;

  // 1. View grazing.
  vec3 v = Pinhole() ? normalize(params.camera_centre.xyz - p) : params.toward_cam.xyz;
  float cos_v = dot(n_s, v);
  if (!(cos_v > min_cos) || !(dot(n_g, v) > 0.0)) {
    outcomes[local] = kMaskGrazingView;
    return;
  }
  // 2. Projection: the four bilinear taps must lie inside the image.
  vec3 p_cam = MaskTransform3(params.cam_from_object, p, 1.0);
  vec2 px;
  if (Pinhole()) {
    if (!(p_cam.z > 0.0)) {
      outcomes[local] = kMaskEdgeOutside;
      return;
    }
    vec2 xy = p_cam.xy / p_cam.z;
    if ((params.flags & kMaskFlagDistortion) != 0u) xy = Distort(xy);
    px = vec2(params.intrinsics.x * xy.x + params.intrinsics_extra.x * xy.y + params.intrinsics.z,
              params.intrinsics.y * xy.y + params.intrinsics.w);
  } else {
    px = p_cam.xy / params.intrinsics_extra.y +
         0.5 * vec2(float(params.width - 1u), float(params.height - 1u));
  }
  if (!(abs(px.x) < kMaxPixelCoordinate) || !(abs(px.y) < kMaxPixelCoordinate)) {
    outcomes[local] = kMaskEdgeOutside;
    return;
  }
  vec2 f0 = floor(px);
  vec2 fr = px - f0;
  int x0 = int(f0.x), y0 = int(f0.y);
  ivec2 tap[4] = ivec2[4](ivec2(x0, y0), ivec2(x0 + 1, y0), ivec2(x0, y0 + 1),
                          ivec2(x0 + 1, y0 + 1));
  float w[4] = float[4]((1.0 - fr.x) * (1.0 - fr.y), fr.x * (1.0 - fr.y), (1.0 - fr.x) * fr.y,
                        fr.x * fr.y);
  bool inside = true;
  for (int k = 0; k < 4; ++k) {
    if (w[k] == 0.0) continue;
    inside = inside && tap[k].x >= 0 && tap[k].x < int(params.width) && tap[k].y >= 0 &&
             tap[k].y < int(params.height);
  }
  if (!inside) {
    outcomes[local] = kMaskEdgeOutside;
    return;
  }
  // 3. Visibility from the camera map.
  float footprint = Pinhole() ? p_cam.z * params.intrinsics_extra.z : params.intrinsics_extra.z;
  // max: rounding of cos_v near 1; the division is safe since cos_v > min_cos >= 0.
  float tan_v = sqrt(max(0.0, 1.0 - cos_v * cos_v)) / cos_v;
  if (CameraOccluded(p, n_g, p_cam, footprint, tan_v)) {
    outcomes[local] = kMaskOccluded;
    return;
  }
  // 4. Light grazing.
  float dist;
  vec3 wi = ToLight(p, dist);
  float cos_i = dot(n_s, wi);
  if (!(cos_i > min_cos) || !(dot(n_g, wi) > 0.0)) {
    outcomes[local] = kMaskGrazingLight;
    return;
  }
  float inv_d2 = (params.flags & kMaskFlagPointLight) != 0u ? 1.0 / (dist * dist) : 1.0;
  // 5. Cast shadow from the light map.
  if (LightShadowed(p, n_g)) {
    outcomes[local] = kMaskShadowed;
    return;
  }
  // 6. Footprint: each tap's camera ray hits the texel's own, lit surface.
  float tolerance = params.tests.z * footprint * (1.0 + kSqrt2 * tan_v);
  uint outcome = kMaskKept;
  // kMaskFlagPixelSample: of the taps whose hit lies in the texel, the one nearest its centre;
  // when there is none, the nearest of all (ties: the first).
  int nearest = -1;
  bool nearest_inside = false;
  float nearest_d2 = 0.0;
  vec3 nearest_hit = vec3(0.0), nearest_dir = vec3(0.0), nearest_normal = vec3(0.0);
  for (int k = 0; k < 4 && outcome == kMaskKept; ++k) {
    if (w[k] == 0.0) continue;
    ivec2 t = MapTexelOfPixel(tap[k].x, tap[k].y);
    vec4 m = InMap(t) ? texelFetch(camera_map, ivec3(t, 0), 0) : vec4(0.0);
    if (!(m.z > 0.5)) {
      outcome = kMaskEdgeSurface;  // the tap sees the background: silhouette
      break;
    }
    vec3 origin, dir;
    PixelRay(tap[k].x, tap[k].y, origin, dir);
    TapHit th = TapHitOf(origin, dir, t, m);
    if (!(abs(th.distance + dot(origin - p, dir)) <= tolerance)) {
      outcome = kMaskEdgeSurface;
      break;
    }
    if (!(m.y > 0.5)) outcome = kMaskEdgeShadow;
    vec3 hit = origin + th.distance * dir;
    vec3 to_hit = hit - p;
    float d2 = dot(to_hit, to_hit);
    bool in_texel = (params.flags & kMaskFlagPixelSample) != 0u &&
                    th.texel == float(push.first_texel + local);
    if (nearest < 0 || (in_texel && !nearest_inside) ||
        (in_texel == nearest_inside && d2 < nearest_d2)) {
      nearest = k;
      nearest_inside = in_texel;
      nearest_d2 = d2;
      nearest_hit = hit;
      nearest_dir = dir;
      nearest_normal = th.n_s;
    }
  }
  if (outcome != kMaskKept) {
    outcomes[local] = outcome;
    return;
  }
  if ((params.flags & kMaskFlagPixelSample) != 0u && !nearest_inside &&
      (params.flags & kMaskFlagPointPixels) != 0u &&
      tx.position.w * sqrt(cos_v) >= kMaskMinResolvedTexelPixels * footprint) {
    outcomes[local] = kMaskEdgeTexel;  // every tap's pixel measured another texel
    return;
  }
  if ((params.flags & kMaskFlagPixelSample) != 0u) {
    // The sample is the nearest tap's pixel at its hit's geometry (the CPU's SamplePoint::kPixel).
    n_s = nearest_normal;
    v = -nearest_dir;
    wi = ToLight(nearest_hit, dist);
    cos_i = dot(n_s, wi);
    // The hit's own normal may tip past min_cos: a rim or the terminator inside the footprint.
    if (!(dot(n_s, v) > min_cos)) {
      outcomes[local] = kMaskEdgeSurface;
      return;
    }
    if (!(cos_i > min_cos)) {
      outcomes[local] = kMaskEdgeShadow;
      return;
    }
    inv_d2 = (params.flags & kMaskFlagPointLight) != 0u ? 1.0 / (dist * dist) : 1.0;
    for (int k = 0; k < 4; ++k) w[k] = k == nearest ? 1.0 : 0.0;
  }
  // 7. Pixel values (MakeSample).
  for (int k = 0; k < 4; ++k) {
    if (w[k] == 0.0) continue;
    if (!AllFinite(PixelAt(tap[k].x, tap[k].y))) {
      outcomes[local] = kMaskInvalid;
      return;
    }
  }
  float saturation = params.tests.y;
  vec3 value = vec3(0.0);
  for (int k = 0; k < 4; ++k) {
    if (w[k] == 0.0) continue;
    vec3 q = PixelAt(tap[k].x, tap[k].y);
    if (saturation > 0.0 && (q.x >= saturation || q.y >= saturation || q.z >= saturation)) {
      outcomes[local] = kMaskClipped;
      return;
    }
    value += w[k] * q;
  }
  float max_channel = max(value.x, max(value.y, value.z));
  bool measured_noise = UseVarianceImage();
  vec3 measured = vec3(0.0);
  if (!measured_noise) {
    if (min(value.x, min(value.y, value.z)) < params.noise.w) {
      outcomes[local] = kMaskInvalid;
      return;
    }
    if (max_channel <= params.noise.z) {
      outcomes[local] = kMaskDark;
      return;
    }
  } else {
    measured = MeasuredVariance(tap, w);
    if (MeasuredInvalid(value, measured)) {
      outcomes[local] = kMaskInvalid;
      return;
    }
    if (MeasuredDark(value, measured)) {
      outcomes[local] = kMaskDark;
      return;
    }
  }
  // Tangent frame as the renderer builds it.
  vec3 tangent = tx.tangent.xyz;
  vec3 tt = tangent - n_s * dot(n_s, tangent);
  if (dot(tt, tt) < kTinyTangent2) tt = UnitOrthogonal(n_s);  // tangent parallel to the normal
  tt = normalize(tt);
  vec3 b = cross(n_s, tt);
  MaskSample s;
  vec3 wi_local = vec3(dot(tt, wi), dot(b, wi), dot(n_s, wi));
  vec3 wo_local = vec3(dot(tt, v), dot(b, v), dot(n_s, v));
  float floor_sigma = params.relative_sigma_floor.x * max_channel;
  for (int c = 0; c < 3; ++c) {
    s.wi[c] = wi_local[c];
    s.wo[c] = wo_local[c];
    float scale = params.intensity.w * params.intensity[c] * inv_d2 * cos_i;
    // A light with no output in a channel (or an unusable exposure) tells nothing about it.
    if (!(scale > 0.0) || isinf(scale)) {
      s.value[c] = 0.0;
      s.weight[c] = 0.0;
      continue;
    }
    // PixelVariance or MeasuredPixelVariance: > 0 because a sample that is not dark has
    // max_channel > 0, which makes the relative floor positive.
    float pixel_var = measured_noise
                          ? measured[c] + floor_sigma * floor_sigma
                          : params.noise.x * max(value[c], 0.0) + params.noise.y +
                                floor_sigma * floor_sigma;
    s.value[c] = value[c] / scale;
    // weight = scale² / pixel_var, clamped to float's range (the CPU's 1 / variance clamp).
    float weight = (scale / pixel_var) * scale;
    s.weight[c] = isinf(weight) || isnan(weight) || weight > kMaxWeight ? kMaxWeight : weight;
    if (isnan(s.value[c]) || isinf(s.value[c])) {
      outcomes[local] = kMaskInvalid;
      return;
    }
  }
  samples[local] = s;
  outcomes[local] = kMaskKept;
}
