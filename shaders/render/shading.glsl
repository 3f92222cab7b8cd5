// Per-point shading of the Vulkan renderer: the GLSL twin of the `shade` lambda of
// render/reference/reference_renderer.cc (RenderImage), with the same tests in the same order —
// back face black; lit iff cos θi > 0 at the shading and the geometric normal and not in shadow;
// material = the atlas texel under the UV (TexelOfHit: PixelOfUv, then the 3x3 neighbourhood);
// tangent frame = the texel's tangent re-orthogonalised against the shading normal; radiance =
// f(wi, wo) E, E = I cos θi / d² (point) or I cos θi (directional) — with one difference: "in
// shadow" is the shadow-map test InShadow below instead of an occlusion ray.
//
// Shadow test (InShadow). The map stores, per texel, the distance from the view's origin along the
// texel's ray to the nearest surface (shared/light_map_view.h). A point p with geometric
// normal n_g is compared not with its own distance but with t_plane, where the texel's ray meets
// the plane through p with normal n_g ("receiver-plane" depth): for a planar receiver that is
// exactly the distance the map holds where the receiver itself is nearest, so a lit plane cannot
// shadow itself at any slope; on a convex receiver the surface falls away behind that plane, so
// it cannot either. t_plane may lie far in front of p when the light grazes the surface (which
// only lets light through, never adds shadow); it is limited to shadow_bias.z texel footprints
// behind p (which would add shadow). p is in shadow when stored < t_plane - bias, with
//   bias = shadow_bias.x + shadow_bias.y * footprint * (1 + min(tan θ, kMaxLightMapSlope)):
//   shadow_bias.x  the CPU renderer's surface offset (1e-5 of the object's size): float rounding;
//   shadow_bias.y  texel footprints (the texel's width across the light at p's distance) for what
//                  the plane does not model: a concave receiver — neighbouring facets tilted
//                  towards the light, met by a texel ray up to half a texel beside p — comes
//                  closer to the light by about that offset times the change of tan θ, so the
//                  term grows with the slope tan θ of the light at n_g (θ its angle to n_g).
// Tradeoff: an occluder closer than the bias to the receiver plane casts no shadow, so contact
// shadows start a few footprints late (further at grazing light, where the lit radiance, ∝ cos θ,
// is small anyway); the default resolution puts several shadow texels in an image pixel, so this
// stays within a pixel of the shadow edge. Shadow edges are quantised to shadow texels (one
// sample, no filtering, so the result stays binary like the CPU's occlusion ray); a point within a
// texel of an edge (LightMapShadowEdge) is marked (Shade::shadow_edge), and the host shades its
// pixel with rays, so the render's shadow edges are the CPU's. The test itself is
// common/light_map.glsl's LightMapShadowed, which the Vulkan masks call too.
#ifndef REFLCAP_SHADERS_RENDER_SHADING_GLSL_
#define REFLCAP_SHADERS_RENDER_SHADING_GLSL_

#define REFLCAP_RENDER_SHADING
#include "render/material.glsl"
#include "render/render_inputs.glsl"
#include "common/light_map.glsl"
#include "common/texel_atlas.glsl"

// Eigen's unitOrthogonal() for a 3-vector (float: isMuchSmallerThan at 1e-5), which the CPU
// renderer uses when a texel's tangent is parallel to the shading normal.
vec3 UnitOrthogonal(vec3 v) {
  const float kPrecision = 1e-5;
  if (!(abs(v.x) <= abs(v.z) * kPrecision) || !(abs(v.y) <= abs(v.z) * kPrecision)) {
    return vec3(-v.y, v.x, 0.0) / length(v.xy);
  }
  return vec3(0.0, -v.z, v.y) / length(v.yz);
}

bool IsTexel(ivec2 px) {
  if (px.x < 0 || px.y < 0 || px.x >= int(params.atlas_width) || px.y >= int(params.atlas_height)) {
    return false;
  }
  return texelFetch(frame_map, ivec3(px, 0), 0).w > 0.5;
}

// The reference renderer's TexelOfHit: the atlas pixel under `uv`, else the first texel of its
// 3x3 neighbourhood (rows, then columns, as the CPU searches). False when there is none.
bool TexelOfHit(vec2 uv, out ivec2 texel) {
  ivec2 px = AtlasPixelOfUv(uv, uvec2(params.atlas_width, params.atlas_height));
  texel = px;
  if (IsTexel(px)) return true;
  for (int dy = -1; dy <= 1; ++dy) {
    for (int dx = -1; dx <= 1; ++dx) {
      ivec2 q = px + ivec2(dx, dy);
      if (IsTexel(q)) {
        texel = q;
        return true;
      }
    }
  }
  return false;
}

// Whether p (geometric normal n_g, facing the light) is in shadow; see the file comment. `edge`:
// the map cannot tell to within a texel (LightMapShadowEdge).
bool InShadow(vec3 p, vec3 n_g, out bool edge) {
  int v = LightMapViewOf(p, params.light.xyz, params.num_shadow_views);
  LightMapView view = params.views[v];
  vec4 clip = TransformRows(view.clip_from_object, p);
  bool shadowed = LightMapShadowed(shadow_map, v, clip, view.origin, view.forward, view.right,
                                   view.up, params.shadow_resolution, p, n_g,
                                   params.shadow_bias.xyz);
  edge = LightMapShadowEdge(shadow_map, v, clip, view.origin, view.forward, view.right, view.up,
                            params.shadow_resolution, p, n_g, params.shadow_bias.xyz, shadowed);
  return shadowed;
}

struct Shade {
  vec3 radiance;  // f E (before the pixel weight)
  vec4 aux;       // cast_shadow, cos_theta_i, cos_theta_o, curvature (AuxChannel order)
  bool shadow_edge;  // the shadow map cannot tell this point's shadow (InShadow's `edge`)
};

// A pass's radiance alpha: 1 where a surface was hit, + 2 where its shadow is a shadow edge
// (kShadowEdgeAlpha; the host shades those pixels with rays). Hosts read the mask as bit 0.
const float kShadowEdgeAlpha = 2.0;

// Shades surface point p (object frame) with unit shading normal n_s, unit geometric normal n_g,
// texture coordinates uv and unit direction to the viewer wo; `curvature` is copied to aux.
Shade ShadeSurface(vec3 p, vec3 n_s, vec3 n_g, vec2 uv, vec3 wo, float curvature) {
  Shade s;
  s.radiance = vec3(0.0);
  s.shadow_edge = false;
  vec3 wi;
  vec3 irradiance_per_cos = params.intensity.rgb;
  if ((params.flags & kRenderFlagPointLight) != 0u) {
    vec3 to_light = params.light.xyz - p;
    float dist = length(to_light);
    wi = to_light / dist;
    irradiance_per_cos /= dist * dist;
  } else {
    wi = params.light.xyz;
  }
  float cos_i = dot(n_s, wi);
  s.aux = vec4(0.0, cos_i, dot(n_s, wo), curvature);
  if (dot(n_g, wo) <= 0.0) return s;  // back face of an open mesh: black
  if (cos_i <= 0.0 || dot(n_g, wi) <= 0.0) return s;
  if ((params.flags & kRenderFlagCastShadows) != 0u && InShadow(p, n_g, s.shadow_edge)) {
    s.aux.x = 1.0;
    return s;
  }
  ivec2 texel;
  if (!TexelOfHit(uv, texel)) return s;
  vec3 tangent = texelFetch(frame_map, ivec3(texel, 0), 0).xyz;
  vec3 t = tangent - n_s * dot(n_s, tangent);
  if (dot(t, t) < 1e-12) t = UnitOrthogonal(n_s);  // tangent parallel to the normal: any
  t = normalize(t);
  vec3 b = cross(n_s, t);
  vec3 wi_local = vec3(dot(t, wi), dot(b, wi), cos_i);
  vec3 wo_local = vec3(dot(t, wo), dot(b, wo), dot(n_s, wo));
  if (wo_local.z <= 0.0) return s;  // shading normal turned away from the viewer
  vec3 f = EvalRgbAt(texel, wi_local, wo_local);
  s.radiance = f * irradiance_per_cos * cos_i;
  return s;
}

#endif  // REFLCAP_SHADERS_RENDER_SHADING_GLSL_
