#version 460
// Shading of a camera with lens distortion. The rasteriser can only sample the undistorted
// (pinhole) pixel grid, so the renderer first rasterises triangle indices at that grid over the
// undistorted footprint of the image (visibility.frag, the "visibility image"), then this pass
// takes, for each output pixel (and each N x N sub-sample), the exact ray of the distorted camera
// (PixelRay: undistortion as in Camera::PixelRay), looks up the visibility image around where that
// ray lands, intersects the ray with each triangle found there (3x3 texels) and shades the nearest
// hit with render/shading.glsl — the same function surface.frag calls. So distortion is
// "render undistorted, then remap", but what is remapped is visibility, not colour: the shaded
// value is evaluated at the exact ray hit, with no interpolation of the image.
//
// Hit choice (FindHit): the nearest triangle containing the ray's hit among the candidates and
// the triangles reached by walking over the mesh from them towards the hit (slivers that fell
// between the visibility samples, e.g. beside an occluding contour); failing that, inside the
// object's image only, the least-missed candidate's plane, or for a sample on a texel centre the
// plane of the triangle the rasteriser put there.
// Pinhole cameras without distortion take this path too with VulkanRenderOptions::camera_shading
// kResolve (what kAuto picks on GPUs).
//
// Bindings (set 0): 0 RenderParams, 1 RenderCorner[], 2 RenderTriangle[], 3 material, 4 frame,
//   5 shadow map (render/render_inputs.glsl); 6 visibility (usampler2DArray, R32_UINT: triangle
//   + 1, 0 = background); 7 out radiance vec4[width * height] (rgb exposure-weighted, a = mask);
//   8 out aux vec4[width * height] (cast_shadow, cos_theta_i, cos_theta_o, curvature).
// Push constants: none. Specialization: none (8 x 8 workgroups).
// C++ twin: RenderImage in render/reference/reference_renderer.cc (ray per sample, centre ray for
//   mask and aux).
#extension GL_GOOGLE_include_directive : require

#define REFLCAP_RENDER_CORNERS
#include "render/shading.glsl"
#include "render/surface_hit.glsl"

layout(local_size_x = 8, local_size_y = 8) in;

layout(set = 0, binding = 6) uniform usampler2DArray visibility;
layout(std430, set = 0, binding = 7) writeonly buffer OutRadiance { vec4 out_radiance[]; };
layout(std430, set = 0, binding = 8) writeonly buffer OutAux { vec4 out_aux[]; };

// Visibility texels searched around the ray's landing point, in each direction.
const int kSearchRadius = 1;
const int kMaxCandidates = (2 * kSearchRadius + 1) * (2 * kSearchRadius + 1);
// Triangles a walk crosses from a candidate before giving up: up to kMaxWalkSteps (8 stopped
// short of the hit on a 360 x 180 UV sphere at 96 px, whose pole fans are slivers: 0.2 % shading
// error there), fewer when many samples share an invocation, so that a pixel's walks stay inside
// lavapipe's 65,535 loop steps an invocation (engine/gpu/device_info.h) beside its other loops:
// kWalkStepBudget over the (N² + 1) samples' kMaxCandidates walks — 64 up to N = 5, 13 at
// N = 16. The same count on every device, so lavapipe and GPUs resolve alike.
const int kMaxWalkSteps = 64;
const uint kWalkStepBudget = 32000u;
int WalkSteps() {
  uint samples = params.supersampling * params.supersampling + 1u;
  return min(kMaxWalkSteps, int(kWalkStepBudget / (samples * uint(kMaxCandidates))));
}
// How far (texels) a sample may lie from a visibility texel's centre and still count as on it:
// the float rounding of the undistortion and the pixel -> texel mapping, far below a texel.
const float kTexelCentreSlack = 1e-3;

struct Hit {
  bool found;
  uint triangle;
  float b1, b2;  // barycentrics of corners 1 and 2
};

uint VisibilityAt(ivec2 q) {
  if (q.x < 0 || q.y < 0 || q.x >= int(params.vis_width) || q.y >= int(params.vis_height)) {
    return 0u;
  }
  return texelFetch(visibility, ivec3(q, 0), 0).r;
}

float MinComponent(vec3 b) { return min(b.x, min(b.y, b.z)); }

// The triangle the ray (o, d) hits, found from the triangles the visibility image shows around
// `vis_pixel` (see the file comment): from each candidate, a walk across the edge the ray's plane
// hit lies beyond (RenderTriangle::neighbours), up to WalkSteps() triangles, until a triangle
// contains the hit — which finds sub-texel triangles on connected surfaces, such as the sliver of
// a bump's flank seen at grazing angle in front of the surface the texels show. The nearest hit
// found wins. If none is found — only deep inside the object's image (every searched texel
// covered), for unconnected meshes — the candidate the ray misses least, extrapolated over its
// plane.
Hit FindHit(vec3 o, vec3 d, vec2 vis_pixel) {
  ivec2 c = ivec2(floor(vis_pixel + 0.5));  // nearest texel (centres at integer coordinates)
  uint ids[kMaxCandidates];
  int count = 0;
  bool covered = true;
  for (int dy = -kSearchRadius; dy <= kSearchRadius; ++dy) {
    for (int dx = -kSearchRadius; dx <= kSearchRadius; ++dx) {
      uint id = VisibilityAt(c + ivec2(dx, dy));
      if (id == 0u) {
        covered = false;
        continue;
      }
      bool seen = false;
      for (int i = 0; i < count; ++i) seen = seen || ids[i] == id;
      if (!seen) ids[count++] = id;
    }
  }
  const int walk_steps = WalkSteps();
  Hit best;
  best.found = false;
  float best_t = 3.0e38;
  Hit outside;
  outside.found = false;
  float outside_score = -3.0e38;
  for (int i = 0; i < count; ++i) {
    uint tri = ids[i] - 1u;
    for (int step = 0; step < walk_steps; ++step) {
      float t;
      vec3 b;
      if (!IntersectPlane(o, d, tri, t, b) || !(t > 0.0)) break;
      float score = MinComponent(b);
      if (score >= 0.0) {
        if (t < best_t) {
          best_t = t;
          best = Hit(true, tri, b.y, b.z);
        }
        break;
      }
      if (step == 0 && score > outside_score) {
        outside_score = score;
        outside = Hit(true, tri, b.y, b.z);
      }
      int k = b.x <= b.y && b.x <= b.z ? 0 : (b.y <= b.z ? 1 : 2);
      int next = triangles[tri].neighbours[k];
      if (next < 0) break;
      tri = uint(next);
    }
  }
  if (best.found) return best;
  if (covered) return outside;
  // A sample on a visibility texel's centre (an undistorted pinhole camera's pixel centre: the
  // visibility grid is the output grid shifted by whole texels) has the rasteriser's own answer:
  // the triangle covering that centre, extrapolated over its plane — what the per-fragment path
  // (surface.frag) shades there. Elsewhere a texel's coverage says nothing exact about the ray.
  if (all(lessThan(abs(vis_pixel - vec2(c)), vec2(kTexelCentreSlack)))) {
    uint id = VisibilityAt(c);
    float t;
    vec3 b;
    if (id != 0u && IntersectPlane(o, d, id - 1u, t, b) && t > 0.0) {
      return Hit(true, id - 1u, b.y, b.z);
    }
  }
  outside.found = false;
  return outside;
}

struct Sample {
  bool hit;
  vec3 radiance;
  vec4 aux;
  bool shadow_edge;
};

Sample TraceSample(vec2 pixel) {
  Sample s;
  s.hit = false;
  s.radiance = vec3(0.0);
  s.aux = vec4(0.0);
  s.shadow_edge = false;
  float yd = (pixel.y - params.intrinsics.w) / params.intrinsics.y;
  float xd = (pixel.x - params.intrinsics.z - params.intrinsics_extra.x * yd) / params.intrinsics.x;
  vec2 xy = Undistort(vec2(xd, yd), params.distortion, params.distortion_extra.x);
  vec3 d_cam = normalize(vec3(xy, 1.0));
  vec3 d = normalize(vec3(dot(params.object_from_cam[0].xyz, d_cam),
                          dot(params.object_from_cam[1].xyz, d_cam),
                          dot(params.object_from_cam[2].xyz, d_cam)));
  vec3 o = params.camera_origin.xyz;
  vec2 vis_pixel = vec2(params.vis_intrinsics.x * xy.x + params.vis_intrinsics_extra.x * xy.y +
                            params.vis_intrinsics.z,
                        params.vis_intrinsics.y * xy.y + params.vis_intrinsics.w);
  Hit h = FindHit(o, d, vis_pixel);
  if (!h.found) return s;
  s.hit = true;
  SurfacePoint sp = SurfaceAt(h.triangle, h.b1, h.b2);
  vec4 tri = triangles[h.triangle].normal_curvature;
  Shade sh = ShadeSurface(sp.p, sp.n_s, tri.xyz, sp.uv, -d, tri.w);
  s.radiance = sh.radiance;
  s.aux = sh.aux;
  s.shadow_edge = sh.shadow_edge;
  return s;
}

void main() {
  uvec2 px = gl_GlobalInvocationID.xy;
  if (px.x >= params.width || px.y >= params.height) return;
  uint index = px.y * params.width + px.x;
  Sample centre = TraceSample(vec2(px));
  uint n = params.supersampling;
  vec3 sum = centre.radiance;
  bool edge = centre.shadow_edge;
  if (n > 1u) {
    sum = vec3(0.0);
    for (uint sy = 0u; sy < n; ++sy) {
      for (uint sx = 0u; sx < n; ++sx) {
        // Stratum centres of the pixel's footprint (intrinsics_extra.w px square, 1 = the pixel):
        // ((i + 0.5) / n - 0.5) x footprint, as the CPU renderer (SampleOffset).
        vec2 offset = ((vec2(sx, sy) + 0.5) / float(n) - 0.5) * params.intrinsics_extra.w;
        Sample s = TraceSample(vec2(px) + offset);
        sum += s.radiance;
        edge = edge || s.shadow_edge;
      }
    }
  }
  out_radiance[index] = vec4(sum * params.intensity.w,
                             (centre.hit ? 1.0 : 0.0) + (edge ? kShadowEdgeAlpha : 0.0));
  out_aux[index] = centre.aux;
}
