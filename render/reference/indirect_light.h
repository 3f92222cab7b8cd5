#pragma once
// Interreflection for re-renders of mesh captures: light that reaches a point only by way of
// other parts of the object. A direct-light render is black wherever the light does not reach —
// the far side of the object, cast shadows — while a photograph shows the light bounced there
// from the lit parts (on the Blender suzanne capture those pixels hold 60 % of the held-out LDR
// error). The object's own fitted reflectance predicts it:
//
//   1. Gather table (once per mesh, image-independent: the object is rigid, only the light moves
//      in its frame). From every texel's centre, `rays` directions, cosine-distributed about its
//      shading normal (stratified: a √rays × √rays grid of the unit square, jittered by a hash of
//      texel and ray, mapped by Malley's method), origin offset along the geometric normal; the
//      texel under each ray's first hit is stored (-1: the ray leaves the object, or hits a back
//      face, or starts below the geometric horizon).
//   2. Per photograph, in the object frame: direct irradiance of every texel, E(t) = I cos θi / d²
//      (point light) or I cos θi (directional) when cos θi > 0 at the shading and geometric
//      normals and the segment to the light is free, else 0. Each texel leaves radiance
//      L0(t) = ρ(t)/π · E(t) (the diffuse part: lobes are narrow and what they send is left out).
//   3. Bounces. With the cosine-distributed estimator E_ind(x) = π/M Σ_j L(y_j) over the M rays of
//      x that hit texels y_j, the indirect radiance leaving x is
//        L_ind,1(x) = ρ(x)/M Σ_j L0(y_j),   L_ind,k+1(x) = ρ(x)/M Σ_j L_ind,k(y_j),
//      summed over `bounces` bounces (the series converges: ρ < 1).
//   4. The re-render adds exposure · L_ind(texel under the pixel) to each pixel (AddTexelRadiance),
//      with the pixel sampling of RenderImage, after whichever backend drew the direct light —
//      the CPU computes it for every backend, so backends agree by construction.
//
// Cost: texels × rays closest-hit rays once (≈ 1 s for 114k texels × 64 on 2 cores), then per
// image texels occlusion rays, texels × rays × bounces gathers and one ray per pixel sample.
// Memory: 4 bytes per texel and ray. Deterministic: the same table for any thread count.
#include <cstdint>
#include <vector>

#include "engine/camera/camera.h"
#include "engine/capture/capture.h"
#include "engine/core/status.h"
#include "engine/geometry/rigid3.h"
#include "engine/image/image.h"
#include "engine/mesh/ray_scene.h"
#include "engine/mesh/texel_atlas.h"
#include "engine/texel/brdf_maps.h"

namespace reflcap::render {

constexpr int kMaxIndirectRays = 1024;    // rays per texel (memory: 4 KB per texel)
constexpr int kMaxIndirectBounces = 8;    // beyond this, ρ^k of any real material is negligible

class IndirectLight {
 public:
  // Traces the gather table of `atlas` (a mesh atlas: every texel has a triangle) on `scene`,
  // `rays` per texel in [1, kMaxIndirectRays]. InvalidArgument for a normal-map atlas or a bad
  // ray count.
  static StatusOr<IndirectLight> Build(const RayScene& scene, const TexelAtlas& atlas, int rays);

  int rays() const { return rays_; }
  size_t texels() const { return texels_; }
  // The texel hit by ray r of texel t, -1 for none.
  int32_t HitTexel(size_t t, int r) const { return hit_[t * size_t(rays_) + size_t(r)]; }

  // Indirect radiance leaving every texel (RGB, before exposure) for one photograph's light,
  // `object_from_world` the object's pose inverse, summed over `bounces` in [1,
  // kMaxIndirectBounces]. Texels whose parameters are not finite neither send nor receive.
  // `cast_shadows` false: every texel facing the light is lit (as RenderOptions::cast_shadows).
  std::vector<Vec3f> TexelRadiance(const RayScene& scene, const TexelAtlas& atlas,
                                   const BrdfMaps& maps, const Light& light,
                                   const Rigid3& object_from_world, int bounces,
                                   bool cast_shadows) const;

 private:
  int rays_ = 0;
  size_t texels_ = 0;
  std::vector<int32_t> hit_;
};

// Adds exposure_s · radiance[texel under the ray] to `pixels` (3 channels, the camera's size) for
// the rays RenderImage traces with the same `supersampling` and `footprint`: the pixel centre at
// 1, the centres of N×N strata of the footprint averaged otherwise (SampleOffset). Pixels whose
// rays miss (or hit a back face) are unchanged.
void AddTexelRadiance(const RayScene& scene, const TexelAtlas& atlas, const Camera& camera,
                      const Rigid3& world_from_object, double exposure_s, int supersampling,
                      double footprint,
                      const std::vector<Vec3f>& radiance, Image* pixels);

}  // namespace reflcap::render
