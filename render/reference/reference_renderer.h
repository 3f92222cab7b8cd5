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
//
// Validation buffers (RenderOptions::aux_buffers): per pixel, on the ray through the pixel centre
// only (never supersampled), what `reflcap validate` needs to break errors down by region — the
// object mask, a cast-shadow flag, cos θi and cos θo at the shading normal, and a scale-free
// curvature (see AuxChannel and SurfaceCurvature below).
//
// Normal-map captures (RenderNormalMapImage): one texel per masked pixel, shaded from its own
// normal with directional lights; no rays are cast and there is no supersampling (the texel is
// the pixel). Cast shadows come from the height field integrated from the normal map
// (engine/mesh/height_field.h) when one is given: a pixel whose march towards the light passes
// below it gets no direct light.
#include <string>
#include <vector>

#include "engine/camera/camera.h"
#include "engine/capture/capture.h"
#include "engine/core/status.h"
#include "engine/geometry/rigid3.h"
#include "engine/image/image.h"
#include "engine/mesh/height_field.h"
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
  // Also fill RenderResult::aux (costs about one more shading sample per pixel when
  // supersampling > 1; nothing extra at 1).
  bool aux_buffers = false;
  // Side of the square the N×N samples cover, in pixels, centred on the pixel: 1 = the pixel's own
  // area; wider = the pixel also integrates light from beside it, as a camera's optics and a path
  // tracer's reconstruction filter make it (suzanne's Cycles photographs: 1.5). Range [1,
  // kMaxPixelFootprint]; with N = 1 the one sample stays at the centre whatever the footprint.
  double pixel_footprint = 1;
  Status Validate() const;
};

constexpr int kMaxSupersampling = 16;
// A footprint beyond 4 px is a blurred image, not a pixel model.
constexpr double kMaxPixelFootprint = 4;

// Offset from the pixel centre of sample i of n along one axis: the centre of stratum i of the
// footprint, ((i + 0.5) / n − 0.5) · footprint (0 for n = 1). Every backend samples here
// (distort_resolve.comp, indirect_light.cc).
inline double SampleOffset(int i, int n, double footprint) {
  return ((i + 0.5) / n - 0.5) * footprint;
}

// Channels of RenderResult::aux, evaluated at the pixel centre; 0 on the background. The order is
// alphabetical by name, which is the order OpenEXR stores (and ReadExrChannels returns) them.
enum AuxChannel : int {
  // 1 where the point faces the light (cos θi > 0 at the shading and the geometric normal) but the
  // segment to the light is blocked; 0 elsewhere, and everywhere when cast_shadows is off.
  kAuxCastShadow = 0,
  kAuxCosThetaI,  // shading normal · direction to the light (signed)
  kAuxCosThetaO,  // shading normal · direction to the camera (signed)
  kAuxCurvature,  // scale-free curvature of the surface under the pixel (SurfaceCurvature)
  kAuxMask,       // 1 where the centre ray hits the object (= RenderResult::mask)
  kAuxChannelCount
};
// "cast_shadow", "cos_theta_i", "cos_theta_o", "curvature", "mask": the EXR channel names.
const std::vector<std::string>& AuxChannelNames();

struct RenderResult {
  Image pixels;  // 3 channels: exposure_s * radiance
  Image mask;    // 1 channel: 1 where the ray through the pixel centre hits the object, else 0
  Image aux;     // kAuxChannelCount channels when RenderOptions::aux_buffers, else empty
};

// Curvature, made scale-free by the object's size, so one threshold serves every object:
//   κ_t = max over the triangle's edges (i, j) of angle(n_i, n_j) / |p_i - p_j|,
// the largest rate at which the corner shading normals turn along an edge (≈ the larger principal
// curvature |κ1|; 1/R on a sphere of radius R), times the object size
//   S = sqrt(Σ_t A_t |c_t - c|² / Σ_t A_t)   (area-weighted RMS distance of the triangle
// centroids c_t from the surface centroid c; R for a sphere), so a sphere gives ≈ 1 and a plane 0.
// It is seen through the shading normals: a crease of a flat-shaded mesh (split normals, equal
// within each triangle) reads 0, as the fit, which uses the same normals, sees no curvature there.
// Returns one value per triangle.
std::vector<float> SurfaceCurvature(const TriangleMesh& mesh);

// The same measure on a normal-map atlas (texel = pixel of `camera`), per texel: for each image
// axis, the angle between the normals of the two neighbours along it over their distance on the
// surface — 2 px (1 px, one-sided, at the mask border) times sqrt(1 + slope²), slope = n_axis / n_z
// of the height field seen along the camera's viewing axis, |n_z| clamped to kMinNormalMapCos —
// the larger of the two, times S = sqrt(texels / π) px (the radius of the disc of the same area;
// R for an orthographic sphere). So it is in units of the object size, as SurfaceCurvature, and
// needs no pixel size. A texel without neighbours reads 0.
std::vector<float> NormalMapCurvature(const TexelAtlas& atlas, const Camera& camera);
// Height-field slopes steeper than 1/0.1 (84° from the view axis) are clamped: the limb of an
// orthographic normal map, where a pixel spans an unbounded stretch of surface.
constexpr double kMinNormalMapCos = 0.1;

StatusOr<RenderResult> RenderImage(const ShadedScene& scene, const Camera& camera,
                                   const Light& light, const Rigid3& world_from_object,
                                   double exposure_s, const RenderOptions& options);

// Shades pixels `pixels` (row-major indices) of `result`, a camera.width x camera.height render
// with options' layout (aux when aux_buffers), exactly as RenderImage would — same rays,
// supersampling and aux — overwriting their radiance, mask and aux. The Vulkan renderer has the
// pixels its shadow map could not decide shaded so. `curvature`: SurfaceCurvature of the scene's
// mesh when the caller has it (else computed here when aux_buffers). InvalidArgument for a result
// of another size or a pixel outside it.
Status RenderPixels(const ShadedScene& scene, const Camera& camera, const Light& light,
                    const Rigid3& world_from_object, double exposure_s,
                    const RenderOptions& options, const std::vector<float>* curvature,
                    const std::vector<uint32_t>& pixels, RenderResult* result);

// Renders one photograph of a normal-map capture: atlas from BuildNormalMapAtlas (texel = pixel of
// `camera`, normals in the world frame), maps one entry per texel. pixel = exposure_s * f(wi, wo) *
// I * max(0, cos θi) with wi = light.direction (InvalidArgument for a point light: the surface
// positions are unknown) and wo = -camera axis (orthographic) or -pixel ray (pinhole). Cast
// shadows when options.cast_shadows and `heights` (IntegrateNormalMap of this normal map) is
// given: a pixel facing the light (cos θi > 0) for which HeightFieldShadowed holds is black and
// has aux cast_shadow = 1. No supersampling (options.supersampling is ignored); mask = 1 on
// texels. The atlas (and `heights`) must have the camera's size (InvalidArgument otherwise).
StatusOr<RenderResult> RenderNormalMapImage(const TexelAtlas& atlas, const BrdfMaps& maps,
                                            const Camera& camera, const Light& light,
                                            double exposure_s, const RenderOptions& options,
                                            const HeightField* heights = nullptr);

// The object mask alone (1 ray per pixel centre), as RenderResult::mask.
StatusOr<Image> RenderMask(const RayScene& scene, const Camera& camera,
                           const Rigid3& world_from_object);

}  // namespace reflcap::render
