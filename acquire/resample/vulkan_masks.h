#pragma once
// VulkanMasks: the Vulkan twin of ImageResampler (image_resampler.h) for mesh captures — the same
// tests in the same order, the same Outcome codes and the same BRDF samples, with visibility from
// the camera and cast shadow from the light decided by depth maps that Vulkan rasterises instead
// of Embree's occlusion rays (`reflcap resample --backend vulkan`).
//
// Per photograph, one submission:
//   1. Light map: the object's distance from the light in a D32 depth map — a cube map (six 90°
//      faces) for a point light inside or near the object's bounding sphere, one perspective
//      frustum fitted to the sphere for a point light outside it (the turntable rigs), an
//      orthographic box fitted to the sphere for a directional light (as the Vulkan renderer's
//      shadow maps, render/vulkan/vulkan_renderer.h).
//   2. Camera map: the mesh rasterised with the camera's projection (pinhole K, or orthographic
//      with pixel_size_m) so that each texel centre is sampled exactly where the CPU casts a
//      pixel's camera ray; per texel the distance along that ray, whether the hit is lit (normals
//      facing the light, no occluder in the light map) and whether anything is hit — the CPU's
//      pixel map, for every pixel at once; a second attachment holds the hit's interpolated
//      shading normal (SamplePoint::kPixel measures the sample with it). With lens distortion the
//      map is the undistorted grid covering the photograph's footprint, and a pixel's ray reads
//      the nearest map texel (its distance and normal then belong to a point up to half a map
//      texel from the pixel's own hit).
//   3. masks.comp, one invocation per texel: view grazing, projection, occlusion (camera map,
//      receiver-plane depth), light grazing, cast shadow (light map), footprint (every bilinear
//      tap's camera-map texel a hit within the edge depth tolerance, and lit), the sample point
//      (kPixel: the tap whose hit — its ray at the map's distance — lies nearest the texel
//      centre, at that hit's geometry), pixel tests, and the sample (value, weight, wi/wo in the
//      tangent frame). With the photograph's variance
//      image (images[].variance) bound, the pixel tests and weights take their noise from it
//      exactly as the CPU does (MeasuredVariance and its neighbours in image_resampler.h).
//
// Depth bias (shaders/resample/masks_common.glsl): a point is hidden when the map's distance is
// below the receiver-plane distance minus bias = surface offset (RayScene::SurfaceOffset, the
// CPU's ray offset) + k footprints x (1 + min(tan θ, 10)); k = light_bias_texels of the light map
// texel, camera_bias_pixels of the photograph's pixel. Disagreements with Embree are confined to
// where a map texel straddles an edge: occluding contours and depth discontinuities (the texel
// centre's ray sees the occluder, the CPU's exact ray to the camera does not, or vice versa) and
// shadow boundaries (quantised to light-map texels); contact shadows start up to the bias late.
//
// Errors: Unavailable when there is no Vulkan device with a graphics queue or a needed format,
// or when a buffer exceeds a device limit (say which); InvalidArgument for bad options or inputs
// (as ImageResampler). Not thread-safe: one object per thread.
#include <cstdint>
#include <memory>
#include <optional>
#include <string>

#include "acquire/resample/image_resampler.h"
#include "acquire/resample/mask_agreement.h"
#include "engine/capture/capture.h"
#include "engine/core/status.h"
#include "engine/image/image.h"
#include "engine/mesh/mesh.h"
#include "engine/mesh/texel_atlas.h"

namespace reflcap::resample {

struct VulkanMaskOptions {
  // Vulkan device: "" = automatic (a discrete GPU, else integrated/virtual, else lavapipe), an
  // index, or a piece of its name (the CLI's --device NAME|INDEX).
  std::string device;
  // Automatic light-map resolution: this many light-map texels per photograph pixel, measured at
  // the object's centre. Higher = shadow edges closer to Embree's exact ones. Range (0, 64].
  double light_texels_per_pixel = 2;
  // Bounds of the automatic resolution, texels per side: [min, max] for single maps, max_cube for
  // each cube face. Each in [16, 16384]; min <= max. The minimum is in units of the object (small
  // concave features shadow themselves wrongly below ~1000 texels across it).
  int min_light_resolution = 1024;
  int max_light_resolution = 4096;
  int max_cube_resolution = 2048;
  // Light-map bias beyond the surface offset, in light-map texel footprints, times
  // (1 + min(tan θ, 10)). [0, 16].
  double light_bias_texels = 1.0;
  // Camera-map bias beyond the surface offset, in photograph pixel footprints at the texel, times
  // (1 + min(tan θo, 10)). [0, 16].
  double camera_bias_pixels = 1.0;
  // Largest receiver-plane correction behind the point, in footprints (both maps). [0, 1000].
  double plane_limit_footprints = 8;
  // Texels per dispatch (per bound chunk of the texel buffers): 0 = as many as one
  // storage-buffer binding holds (2,097,152 on lavapipe's 128 MiB); else rounded down to a
  // multiple of 1024 (>= 1024). Tests set it small to exercise the chunked path.
  uint32_t max_chunk_texels = 0;
  // Where each texel's sample is measured, as ImageResampler::SetSamplePoint (image_resampler.h).
  SamplePoint sample_point = SamplePoint::kPixel;
  // What the cameras' pixels measure, as ImageResampler::SetPixelFilter (nullopt: each camera's).
  std::optional<PixelFilter> pixel_filter;

  Status Validate() const;
};

// What the last Process did (for the report and benchmarks).
struct VulkanMaskStats {
  std::string light_map = "none";  // "cube", "fitted", "orthographic"
  int light_resolution = 0;        // texels per side (per face for a cube map)
  int map_width = 0, map_height = 0;
  double gpu_seconds = 0;  // submit + fence wait
};

class VulkanMasks {
 public:
  // The capture, atlas and mesh must outlive the object. surface_offset: RayScene::SurfaceOffset
  // of the mesh (m). min_cos in [0, 1). FailedPrecondition as ImageResampler::Create (orthographic
  // camera without pixel_size_m); InvalidArgument for a normal-map capture (no mesh to rasterise:
  // ImageResampler casts no ray there anyway).
  static StatusOr<std::unique_ptr<VulkanMasks>> Create(const Capture& capture,
                                                       const TexelAtlas& atlas,
                                                       const TriangleMesh& mesh,
                                                       float surface_offset,
                                                       const NoiseModel& noise, double min_cos,
                                                       const VulkanMaskOptions& options = {});
  ~VulkanMasks();
  VulkanMasks(const VulkanMasks&) = delete;
  VulkanMasks& operator=(const VulkanMasks&) = delete;

  // ImageResampler::Process on the GPU (ray counts stay 0). When `map` is not null it receives
  // the photograph's camera map (for MaskAgreement). `variance`: the photograph's variance image
  // (as ImageResampler::Process), nullptr = the noise model.
  Status Process(uint32_t image_index, const Image& pixels, ImageOutput* out,
                 CameraMapView* map = nullptr, const Image* variance = nullptr);

  // The Vulkan device's name ("llvmpipe (LLVM 15.0.6, 256 bits)").
  const std::string& device_name() const;
  // Whether that device is the CPU (lavapipe): the host's cores then do the masks' work too.
  bool software_device() const;
  const VulkanMaskStats& last_stats() const;

 private:
  VulkanMasks();
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// OK when a Vulkan device matching `device` ("" = any) with a graphics queue can be opened;
// Unavailable with the reason otherwise (no driver, no device, or a build without Vulkan).
Status VulkanMasksAvailable(const std::string& device);

// Whether the device VulkanMasks would open for `device` is a GPU (true) or a CPU implementation
// such as lavapipe (false, whose "GPU" work competes with Embree for the same cores);
// Unavailable as VulkanMasksAvailable, and, when `capture` is given, Unavailable naming the
// camera when its photographs are larger than one storage-buffer binding of the device holds
// (Process would refuse them). `reflcap run` resamples on the fit's device only when this is
// true.
StatusOr<bool> VulkanMasksOnGpu(const std::string& device, const Capture* capture = nullptr);

}  // namespace reflcap::resample
