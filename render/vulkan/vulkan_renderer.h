#pragma once
// The Vulkan renderer: headless rasterisation of a textured mesh whose atlas texels carry Lambert +
// Lafortune parameters — the GPU twin of the CPU reference renderer
// (render/reference/reference_renderer.h), with the same inputs, outputs and radiometry, so that
// `reflcap render --backend vulkan` writes the same files as `--backend cpu`.
//
// Per image:
//   1. Shadow map (cast_shadows, mesh captures): the object's distance from the light rendered
//      into an R32F map — a cube map (six 90° faces) for a point light inside or near the object's
//      bounding sphere, one perspective frustum fitted to that sphere for a point light outside it
//      (the turntable rigs: ~10x the texels on the object that a cube face would give), an
//      orthographic box fitted to the sphere for a directional light. Shadow test with
//      receiver-plane depth and a one-texel bias (shaders/render/shading.glsl explains both).
//   2. Camera pass: the mesh rasterised with the camera's projection (pinhole K, or orthographic
//      with pixel_size_m) so that each pixel centre is sampled exactly where the CPU renderer
//      casts its ray; every fragment is shaded in the texel's tangent frame with the GLSL twins of
//      brdf/lafortune.h (surface.frag). Supersampling N renders at N x N the resolution (the
//      CPU's stratum centres) and box-filters; mask and aux buffers come from a 1x pass (the CPU
//      takes them from the centre ray).
//   3. Lens distortion: the undistorted grid is rasterised as triangle ids (a visibility image
//      covering the undistorted footprint of the image), and a compute pass follows each output
//      pixel's exact distorted ray: it intersects the triangles seen around where the ray lands
//      and shades the nearest hit with the same shading code (distort_resolve.comp). Colour is
//      never interpolated, so distortion costs no accuracy away from silhouettes.
//   Normal-map captures have no mesh to rasterise: a compute pass shades each texel (= masked
//   pixel) as RenderNormalMapImage does (normal_map_shade.comp).
//
// Material: parameter maps in atlas layout as an RGBA32F texture array (read with texelFetch at
// the atlas pixel under the interpolated UV, with the CPU's 3x3 fallback), per-texel tangents as
// a second texture, per-triangle geometric normals and curvature in a storage buffer.
//
// Agreement with the CPU renderer (tests/render/vulkan, render_agreement.h): away from
// silhouettes and cast-shadow edges the two differ by float rounding — ~1e-6 relative on smooth
// Lambertian surfaces; up to ~1e-4 under sharp lobes, where b^n amplifies the rasteriser's
// sub-pixel vertex snapping n-fold — plus rare shadow-map misses at grazing light (the bias
// tradeoff in shaders/render/shading.glsl); at silhouettes the rasteriser's coverage rule and at
// shadow edges the shadow map's texels decide pixels that the CPU's rays decide differently. On
// the synthetic relief object that is 75-90 dB PSNR with 2 px around those edges excluded.
//
// Batches (RenderImages; RenderImage is a batch of one). Many images are recorded into one
// submission, each with its own parameter blocks, descriptor sets and host-visible output
// buffers; several submissions are in flight (one fence each), so the device renders the next
// batches while the host copies a finished one into RenderResults (in parallel) and hands them
// to the caller. Scene and parameter maps stay resident (SetScene). Pass targets (camera,
// supersampled, visibility images) are shared by all images of one size: the queue orders their
// reuse (each render pass waits for earlier reads of its attachments). Shadow maps are kept in a
// small cache keyed by their exact views and resolution, so an image whose light map equals one
// already drawn (turntable captures: every camera of one turntable step and light) samples that
// map instead of drawing it again — the same bits it would draw. Only the pixels inside the
// projection of the mesh's bounding box (plus a margin) are copied back; the rest is background,
// 0 as the passes clear it. Results are bit-identical to rendering the images one by one,
// whatever the batch sizes.
//
// Errors: Unavailable when there is no Vulkan device with a graphics queue, when the device lacks
// a needed format, or when the scene exceeds a device limit (say which); InvalidArgument for bad
// options or a camera/light the CPU renderer would also refuse. Not thread-safe: one renderer per
// thread (it owns or borrows one VkContext; its submissions go to that context's queue).
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "engine/camera/camera.h"
#include "engine/capture/capture.h"
#include "engine/core/status.h"
#include "engine/geometry/rigid3.h"
#include "engine/gpu/device_info.h"
#include "engine/mesh/texel_atlas.h"
#include "engine/texel/brdf_maps.h"
#include "render/reference/reference_renderer.h"

namespace reflcap::gpu {
class VkContext;
}

namespace reflcap::render {

// Which shadow map a point light gets.
enum class ShadowMapKind {
  kAuto,    // kFitted when the light is outside the object's bounding sphere (by
            // gpu::kFitMargin, engine/gpu/depth_pass.h), else kCube
  kCube,    // six 90° faces around the light
  kFitted,  // one perspective frustum around the bounding sphere (light must be outside it)
};
const char* ShadowMapKindName(ShadowMapKind kind);

// How shadow maps are drawn. Measured on an NVIDIA H200 (a compute GPU whose rasteriser is a
// small part of the chip), a 1143² map of 19,200 triangles: 0.25 ms by the pass, 0.10 ms by
// compute.
enum class ShadowRaster {
  kAuto,      // kCompute on GPUs; kGraphics on CPU devices (lavapipe)
  kGraphics,  // the depth pass (shadow.vert + shadow.frag)
  kCompute,   // a compute pass intersecting every texel's ray with the triangles
              // (shadow_raster.comp): the same map up to rounding at triangle edges
};

// How pinhole cameras without lens distortion are shaded. On the H200 at 512 px (19,200
// triangles): the camera pass with per-fragment shading and its copy to the host 0.61 ms, the
// visibility pass and the resolve 0.28 ms (BM_RenderBatch/vulkan/512/64: 1,221 against 1,743
// images/s). Both agree with the CPU reference to the same tests (the resolve's visibility image
// is aligned with the pixel grid, so a pixel centre's texel is the rasteriser's own answer).
enum class CameraShading {
  kAuto,      // kResolve on GPUs; kFragment on CPU devices (lavapipe, where the pass is faster)
  kFragment,  // the camera pass shades every fragment (surface.frag); images are copied out
  kResolve,   // as distorted cameras: a visibility pass (triangle ids), then a compute pass
              // shades each pixel by its exact camera ray (distort_resolve.comp)
};

struct VulkanRenderOptions {
  // Point lights' shadow map (directional lights always get an orthographic map).
  ShadowMapKind shadow_map = ShadowMapKind::kAuto;
  // Automatic shadow-map resolution: this many shadow texels per image pixel, measured along a
  // line at the object's centre (a receiver facing the light). Higher = shadow edges closer to
  // the CPU's exact ones, at the cost of memory and rasterisation time. Range (0, 64].
  double shadow_texels_per_pixel = 2;
  // Bounds of the automatic resolution (texels per side): [min, max] for single maps, max_cube for
  // each cube face. Each in [16, 16384]; min <= max. The minimum is in units of the object, not
  // of the image: small concave features (a groove a few mm wide on a 0.1 m object) shadow
  // themselves wrongly below ~1000 texels across the object, whatever the image size.
  int min_shadow_resolution = 1024;
  int max_shadow_resolution = 4096;
  int max_cube_resolution = 2048;
  // A fixed resolution instead (0 = automatic). [0, 16384].
  int shadow_resolution = 0;
  // Shadow bias beyond the surface offset, in texel footprints, times (1 + the light's slope
  // tan θ, at most 10) (shading.glsl). [0, 16].
  double shadow_bias_texels = 1.0;
  // Largest receiver-plane correction behind the point, in texel footprints (shading.glsl).
  // [0, 1000].
  double shadow_plane_limit_texels = 8;
  // Distorted cameras: visibility-image texels per output pixel along each axis (1 or 2; 2 finds
  // sub-pixel triangles more often, at 4x the visibility pass).
  int visibility_scale = 1;
  // Pinhole cameras without distortion: per-fragment shading or the distortion path's visibility
  // image + exact rays (CameraShading).
  CameraShading camera_shading = CameraShading::kAuto;
  // Shadow maps by the rasteriser or by compute (ShadowRaster).
  ShadowRaster shadow_raster = ShadowRaster::kAuto;
  // Batching. Images recorded per submission: 0 = automatic — 1 on a CPU device (lavapipe: a
  // submission costs nothing there next to the rendering, and small steps overlap the host's
  // read-back and file writing best), else as many as fit batch_readback_mib, at most
  // kMaxBatchImages. [0, kMaxBatchImages].
  int batch_images = 0;
  // Host-visible read-back memory of one batch (radiance, aux, mask buffers), MiB; bounds every
  // batch (an image larger than this still renders, alone). [1, 4096].
  int batch_readback_mib = 128;
  // Submissions in flight: while the host reads back batch k, the device renders k + 1 .. k + n - 1.
  // [1, 8].
  int batches_in_flight = 3;
  // Images of a batch of several each get camera (or visibility) pass targets of their own, whose
  // passes then need not wait for the earlier images' copies to the host: copies overlap later
  // images' passes. Costs device memory of about 1.1x the batch's read-back memory per flight.
  // Off (or a batch of one image): one target per size, shared by every image.
  bool per_image_targets = true;
  // Device timestamps around every image's phases (shadow map, camera pass, outputs), summed in
  // VulkanBatchStats::device_*; for benchmarks (the timestamps can serialise the phases).
  bool profile_device = false;
  // Device memory for kept shadow maps, MiB: an image whose light map (views and resolution: the
  // light and the object's pose in it) equals a kept one samples it instead of drawing it again.
  // 0 = keep none beyond the one being drawn (every image draws its own map). [0, 16384].
  int shadow_cache_mib = 256;
  // Mesh scenes with cast shadows: the pixels whose shadow the map cannot decide to within a
  // shadow texel (an occluder's silhouette passes within a texel of the point, seen from the
  // light) are shaded on the host with the CPU reference renderer's rays (RenderPixels), so shadow
  // edges are the CPU's. Off: the map decides every pixel (on the million preset at 1024 px,
  // ~100 pixels an image then flip between lit and shadow, -5.8 dB PSNR-L at shadow edges).
  bool exact_shadow_edges = true;

  Status Validate() const;
};

// Largest VulkanRenderOptions::batch_images.
constexpr int kMaxBatchImages = 256;

// What the last RenderImage did (for reports and benchmarks); after RenderImages, the last image
// of the call, with the whole call's times.
struct VulkanRenderStats {
  std::string shadow_map = "none";  // "none", "cube", "fitted", "orthographic"
  int shadow_resolution = 0;        // texels per side (per face for a cube map)
  bool shadow_map_reused = false;   // RenderImage: sampled a kept map instead of drawing one
  bool shadow_map_computed = false; // drawn by compute (ShadowRaster), not the depth pass
  bool distortion_resolve = false;  // distorted camera: visibility image + exact rays
  int visibility_width = 0, visibility_height = 0;
  double seconds = 0;      // host wall clock of the whole call
  // Submit to fence signalled, summed over the call's submissions (which overlap when several
  // are in flight: then an upper bound on the device's time).
  double gpu_seconds = 0;
};

// What the last RenderImages (or RenderImage) call did.
struct VulkanBatchStats {
  size_t images = 0;
  size_t submissions = 0;
  size_t shadow_maps_drawn = 0;   // shadow passes recorded
  size_t shadow_maps_reused = 0;  // images that sampled a kept map instead
  double seconds = 0;             // host wall clock of the whole call
  double record_s = 0;            // host: planning, descriptor updates, recording, submitting
  double wait_s = 0;              // host blocked on fences (the device was behind)
  double readback_s = 0;          // host: output buffers -> RenderResults (parallel)
  double sink_s = 0;              // host: in the caller's sink
  size_t shadow_edge_pixels = 0;  // pixels shaded on the host at shadow-map edges
  double shadow_edge_s = 0;       // host: shading them (part of readback_s)
  // VulkanRenderOptions::profile_device on a device with timestamps: the device's time over the
  // submissions (first to last timestamp, summed) and its parts — each phase from the end of the
  // one before it: shadow maps drawn (and the batch's start), camera or visibility passes,
  // outputs (copies to the host, resolves, supersampled passes, normal-map dispatches).
  bool device_timed = false;
  double device_s = 0, device_shadow_s = 0, device_pass_s = 0, device_outputs_s = 0;
  std::string ToString() const;
};

// One image of RenderImages: the arguments of RenderImage (or RenderNormalMapImage).
struct RenderRequest {
  const Camera* camera = nullptr;  // required; must outlive the call
  const Light* light = nullptr;    // required; must outlive the call
  Rigid3 world_from_object;        // mesh scenes (normal-map scenes ignore it)
  double exposure_s = 1;
  std::string label;  // names the image in errors; "" = "requests[i]"
};

// Receives image `index` (into the requests) of RenderImages. A non-OK status stops the call.
using RenderSink = std::function<Status(size_t index, RenderResult&& result)>;

class VulkanRenderer {
 public:
  // A renderer on its own VkContext, on device `device` (ContextOptions::device: "" automatic,
  // an index, or a name substring) with a graphics queue.
  static StatusOr<std::unique_ptr<VulkanRenderer>> Create(const std::string& device,
                                                          const VulkanRenderOptions& options = {});
  // A renderer on the caller's context, which must outlive it and have been created with
  // ContextOptions::require_graphics.
  static StatusOr<std::unique_ptr<VulkanRenderer>> Create(gpu::VkContext* ctx,
                                                          const VulkanRenderOptions& options = {});
  ~VulkanRenderer();
  VulkanRenderer(const VulkanRenderer&) = delete;
  VulkanRenderer& operator=(const VulkanRenderer&) = delete;

  const gpu::DeviceInfo& device() const;
  const VulkanRenderOptions& options() const;
  // What kAuto chose on this device: shadow maps drawn by compute (ShadowRaster), pinhole cameras
  // shaded by the resolve pass (CameraShading).
  bool computes_shadow_maps() const;
  bool resolves_pinhole_cameras() const;
  const VulkanRenderStats& last_stats() const;

  // Uploads a mesh scene (geometry, atlas tangents, parameter maps); replaces any earlier scene.
  // maps must have one entry per atlas texel (checked). Unavailable when the mesh or the atlas
  // exceeds a device limit. With exact_shadow_edges the scene's ray scene, atlas and maps must
  // outlive the renders: the pixels at shadow-map edges are shaded with them on the host.
  Status SetScene(const ShadedScene& scene);
  // Uploads a normal-map scene: atlas from BuildNormalMapAtlas, maps one entry per texel, and
  // optionally its height field (IntegrateNormalMap, the atlas's size; else InvalidArgument),
  // which casts shadows as in RenderNormalMapImage (options.cast_shadows); nullptr = none.
  Status SetNormalMapScene(const TexelAtlas& atlas, const BrdfMaps& maps, const Camera& camera,
                           const HeightField* heights = nullptr);

  // RenderImage of reference_renderer.h on the GPU, for the scene of SetScene.
  StatusOr<RenderResult> RenderImage(const Camera& camera, const Light& light,
                                     const Rigid3& world_from_object, double exposure_s,
                                     const RenderOptions& options);
  // RenderNormalMapImage of reference_renderer.h, for the scene of SetNormalMapScene (whose
  // camera must be `camera`'s size).
  StatusOr<RenderResult> RenderNormalMapImage(const Camera& camera, const Light& light,
                                              double exposure_s, const RenderOptions& options);

  // Renders every request as RenderImage (mesh scene) or RenderNormalMapImage (normal-map scene)
  // would, bit for bit, in batches of several images per submission with several submissions in
  // flight (see the file comment), and calls sink(i, result) for i = 0, 1, ... in order, on the
  // calling thread. Every request is checked before anything renders: a bad one fails the call,
  // naming its label, before the sink sees any image. After a device error or a sink error the
  // call returns it once the device has finished what was submitted; images already handed over
  // stay handed over, no other one is.
  Status RenderImages(const std::vector<RenderRequest>& requests, const RenderOptions& options,
                      const RenderSink& sink);
  // The same, collecting the results.
  StatusOr<std::vector<RenderResult>> RenderImages(const std::vector<RenderRequest>& requests,
                                                   const RenderOptions& options);
  const VulkanBatchStats& last_batch_stats() const;

 private:
  VulkanRenderer();
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace reflcap::render
