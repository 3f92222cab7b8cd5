#pragma once
// The CPU reference renderer: direct lighting of a textured mesh whose texels carry Lambert +
// Lafortune parameters, for one camera (pinhole with distortion, or orthographic) and one light
// (point or directional), with cast shadows from Embree occlusion rays, optional N×N stratified
// supersampling, background 0, and an object mask. It is deliberately simple — one ray per
// sample, no interreflection — because it is the reference that the fitter, the resampler and the
// Vulkan renderer are checked against.
//
// Radiometry (capture/1): pixel = exposure_s * L, L = f(wi, wo) * E, with E = I cos θi / d² for a
// point light and E = I cos θi for a directional one; f is evaluated in the texel's tangent frame
// (brdf/lafortune.h). A surface point is lit when cos θi > 0 at both the shading and the
// geometric normal and the segment to the light is free (origin offset along the geometric
// normal by RayScene::SurfaceOffset()).
#include "engine/camera/camera.h"
#include "engine/capture/capture.h"
#include "engine/core/status.h"
#include "engine/geometry/rigid3.h"
#include "engine/image/image.h"
#include "engine/mesh/ray_scene.h"
#include "engine/mesh/texel_atlas.h"
#include "engine/texel/brdf_maps.h"

namespace reflcap::render {

// What is drawn. The mesh and atlas are in the object frame; maps has one entry per atlas texel.
struct ShadedScene {
  const RayScene* scene = nullptr;
  const TexelAtlas* atlas = nullptr;
  const BrdfMaps* maps = nullptr;
};

struct RenderOptions {
  // N: N×N stratified samples per pixel (box filter over the pixel). 1 = one ray through the pixel
  // centre. Range [1, kMaxSupersampling].
  int supersampling = 1;
  // Trace shadow rays (off: every front-facing point sees the light).
  bool cast_shadows = true;
  Status Validate() const;
};

constexpr int kMaxSupersampling = 16;

struct RenderResult {
  Image pixels;  // 3 channels: exposure_s * radiance
  Image mask;    // 1 channel: 1 where the ray through the pixel centre hits the object, else 0
};

StatusOr<RenderResult> RenderImage(const ShadedScene& scene, const Camera& camera,
                                   const Light& light, const Rigid3& world_from_object,
                                   double exposure_s, const RenderOptions& options);

// The object mask alone (1 ray per pixel centre), as RenderResult::mask.
StatusOr<Image> RenderMask(const RayScene& scene, const Camera& camera,
                           const Rigid3& world_from_object);

}  // namespace reflcap::render
