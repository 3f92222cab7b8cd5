#version 460
// Compute rasteriser of the Vulkan renderer's shadow maps (VulkanRenderOptions::shadow_raster):
// the map the shadow pass (shadow.vert + shadow.frag) draws — per texel, the distance from the
// view's origin along the texel's ray to the nearest surface, divided by forward.w and clamped
// to [0, 1] — found by intersecting each texel's ray (shared/light_map_view.h, as
// common/light_map.glsl's LightMapTexelShadowed builds it) with the triangles. One workgroup per
// triangle; its invocations share the texels of the triangle's bounding box; the nearest surface
// wins through atomicMin on the distance's bits (non-negative floats order as their bit
// patterns). On GPUs whose rasteriser is a small part of the chip this is several times faster
// than the pass; on any device the map is the pass's up to float rounding of the distance and the
// coverage of texel centres within rounding of a triangle's edge (where the map is within a texel
// of a silhouette, which LightMapShadowEdge leaves to the host's rays).
//
// Bindings (set 0): 0 RenderParams (views), 1 RenderCorner[], 11 uint raster[] (view v's
// texel (x, y) at v resolution² + y resolution + x; filled with the bits of 1.0 beforehand).
// Push constants: ShadowRasterPush.
#extension GL_GOOGLE_include_directive : require

#define REFLCAP_RENDER_CORNERS
#include "render/render_inputs.glsl"

layout(local_size_x = 32) in;  // kRasterWorkgroup in vulkan_renderer.cc

layout(std430, set = 0, binding = 11) buffer RasterBlock { uint raster[]; };
layout(push_constant) uniform Push { ShadowRasterPush push; };

// Barycentric slack of the coverage test: a texel centre on an edge shared by two triangles is
// covered by both despite their different rounding (no cracks), while a silhouette grows by
// 1e-6 of its triangle, far below a texel.
const float kCoverageSlack = 1e-6;

// Widens the NDC box [lo, hi] by point q (clip coordinates) when it lies in front of the view.
void Extend(vec4 q, inout vec2 lo, inout vec2 hi) {
  if (!(q.w > 0.0)) return;  // behind a perspective view's origin: only clipped points count
  vec2 ndc = q.xy / q.w;
  lo = min(lo, ndc);
  hi = max(hi, ndc);
}

void main() {
  uint tri = gl_WorkGroupID.y * push.groups_x + gl_WorkGroupID.x;
  if (tri >= push.triangles) return;
  LightMapView view = params.views[push.view];
  vec3 p[3] = vec3[3](corners[3u * tri].position_u.xyz, corners[3u * tri + 1u].position_u.xyz,
                      corners[3u * tri + 2u].position_u.xyz);
  // The bounding box of the triangle's part in front of the near plane (clip z >= 0, Vulkan
  // depth), in NDC: its corners there and where its edges cross the plane.
  vec4 c[3] = vec4[3](TransformRows(view.clip_from_object, p[0]),
                      TransformRows(view.clip_from_object, p[1]),
                      TransformRows(view.clip_from_object, p[2]));
  vec2 lo = vec2(1e30), hi = vec2(-1e30);
  for (int i = 0; i < 3; ++i) {
    vec4 a = c[i], b = c[(i + 1) % 3];
    if (a.z >= 0.0) Extend(a, lo, hi);
    if ((a.z >= 0.0) != (b.z >= 0.0)) Extend(mix(a, b, a.z / (a.z - b.z)), lo, hi);
  }
  if (!(lo.x <= hi.x && lo.y <= hi.y)) return;  // wholly behind the near plane (or NaN)
  // Texels whose centres ((i + 0.5) / res * 2 - 1) may lie inside, one more on each side for the
  // rounding of the projection (the ray test decides), clamped to the map. C++ twin of this range
  // (the loop-limit check on lavapipe): MostRasterTexelsPerInvocation, vulkan_renderer.cc.
  float res = float(push.resolution);
  vec2 first = clamp(floor((lo * 0.5 + 0.5) * res - 0.5), vec2(0.0), vec2(res - 1.0));
  vec2 last = clamp(ceil((hi * 0.5 + 0.5) * res - 0.5), vec2(0.0), vec2(res - 1.0));
  uvec2 origin_texel = uvec2(first);
  uvec2 size = uvec2(last - first) + 1u;
  uint count = size.x * size.y;

  vec3 e1 = p[1] - p[0], e2 = p[2] - p[0];
  bool perspective = view.origin.w > 0.5;
  uint layer = push.view * push.resolution * push.resolution;
  for (uint i = gl_LocalInvocationID.x; i < count; i += gl_WorkGroupSize.x) {
    uvec2 texel = origin_texel + uvec2(i % size.x, i / size.x);
    vec2 centre = (vec2(texel) + 0.5) / res * 2.0 - 1.0;
    vec3 o = view.origin.xyz;
    vec3 d = view.forward.xyz;
    vec3 across = centre.x * view.right.w * view.right.xyz + centre.y * view.up.w * view.up.xyz;
    if (perspective) {
      d = normalize(d + across);
    } else {
      o += across;
    }
    // Möller–Trumbore, both faces (the pass draws them all). An edge-on triangle (det 0) covers
    // no texel centre, as the rasteriser's zero-area triangle; NaN fails every comparison.
    vec3 pv = cross(d, e2);
    float det = dot(e1, pv);
    if (!(abs(det) > 0.0)) continue;
    float inv = 1.0 / det;
    vec3 tv = o - p[0];
    float u = dot(tv, pv) * inv;
    vec3 qv = cross(tv, e1);
    float v = dot(d, qv) * inv;
    float t = dot(e2, qv) * inv;
    if (!(u >= -kCoverageSlack && v >= -kCoverageSlack && u + v <= 1.0 + kCoverageSlack)) {
      continue;
    }
    // In front of the near plane, as the pass clips (and t > 0 along the texel's ray).
    vec3 hit = o + t * d;
    if (!(TransformRows(view.clip_from_object, hit).z >= 0.0) || !(t > 0.0)) continue;
    // Perspective: t = |hit - origin| (d is unit); orthographic: t = (hit - origin) . forward
    // (o moved across the view, orthogonal to forward). Clamped as gl_FragDepth is.
    float stored = clamp(t / view.forward.w, 0.0, 1.0);
    atomicMin(raster[layer + texel.y * push.resolution + texel.x], floatBitsToUint(stored));
  }
}
