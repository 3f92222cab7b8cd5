// The Vulkan renderer (see vulkan_renderer.h): scene upload; per-image plans (camera and light in
// the object frame, shadow views, pass sizes), computed for every image before anything renders;
// batches of images recorded into one submission each — shadow, camera, visibility, resolve and
// box-filter passes per image, each with its own parameter blocks and output buffers — with
// several submissions in flight; and the parallel read-back into RenderResults.
#include "render/vulkan/vulkan_renderer.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstring>
#include <deque>
#include <utility>
#include <vector>

#include "engine/gpu/vk_buffer.h"
#include "engine/gpu/vk_commands.h"
#include "engine/gpu/depth_pass.h"
#include "engine/gpu/vk_context.h"
#include "engine/gpu/vk_descriptors.h"
#include "engine/gpu/vk_graphics_pipeline.h"
#include "engine/gpu/vk_image.h"
#include "engine/gpu/vk_timestamps.h"
#include "engine/gpu/vk_view.h"
#include "engine/core/parallel.h"
#include "engine/mesh/ray_scene.h"
#include "engine/core/worker_pool.h"
#include "shaders/shared/render_params.h"

namespace reflcap::render {
namespace {

namespace sh = gpu::shared;
using gpu::Buffer;
using gpu::DescriptorBinding;
using gpu::DescriptorSet;
using gpu::DescriptorSetLayout;
using gpu::DeviceImage;
using gpu::kComp;
using gpu::kGfx;
using gpu::kSsbo;
using gpu::kTex;
using gpu::MemoryKind;
using gpu::Pipeline;
using gpu::RenderTarget;

// Descriptor bindings (shaders/render/render_inputs.glsl and the passes).
constexpr uint32_t kBindParams = 0, kBindCorners = 1, kBindTriangles = 2, kBindMaterial = 3,
                   kBindFrame = 4, kBindShadowMap = 5, kBindSource = 6, kBindOutRadiance = 7,
                   kBindOutAux = 8, kBindNormalMapTexels = 9, kBindHeightField = 10,
                   kBindShadowRaster = 11;
// Workgroup sizes of the compute passes (the shaders' local_size).
constexpr uint32_t kTile = 8;         // distort_resolve.comp, downsample.comp: 8 x 8
constexpr uint32_t kTexelGroup = 64;  // normal_map_shade.comp
// Margin of the visibility image around the undistorted footprint, texels: the resolve's 3x3
// search reads one texel beyond the landing texel, which may itself be half a texel outside.
constexpr int kVisibilityMargin = 2;
// Largest visibility image side, texels, and largest ratio to the output image: beyond them the
// distortion is too strong for an undistorted pinhole render (fisheye lenses).
constexpr int kMaxVisibilitySide = 16384;
constexpr double kMaxVisibilityRatio = 8;
// Kept pass targets of other sizes than the current batch needs, per kind, before idle ones are
// released (captures have a few camera sizes; more means sizes vary image to image).
constexpr size_t kMaxIdleTargets = 8;
// Pass-target sizes a slot keeps (per_image_targets): captures mix at most a few camera sizes.
constexpr size_t kSlotTargets = 2;
// Parameter blocks are written by vkCmdUpdateBuffer: at most 65536 bytes, a multiple of 4.
static_assert(sizeof(gpu::shared::RenderParams) % 4 == 0 &&
              sizeof(gpu::shared::RenderParams) <= 65536);
// Margin of the read-back rectangle around the projected bounding box, px: covers float rounding
// of the projection (and the rasteriser's sub-pixel snapping) many times over.
constexpr double kRectMarginPx = 2;
// Read-back work per task: rows of this many pixels at least (a task should outweigh the
// hand-over to a worker, ~microseconds).
constexpr int kReadbackPixelsPerTask = 16384;
double SecondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

using gpu::Homogeneous;
using gpu::kSphereInflation;
using gpu::MakePassTarget;
using gpu::PassTarget;
using gpu::OrthoClipFromCam;
using gpu::PinholeClipFromCam;
using gpu::SetRows;
using gpu::V4;

// Parameter i of channel c in BrdfParams::Channel's layout ([rho_d, Cx_0, Cy_0, Cz_0, n_0, ...]).
float ParamAt(const brdf::BrdfParams& p, int c, int i) {
  if (i == 0) return p.rho_d[c];
  const int k = (i - 1) / 4;
  if (k >= p.num_lobes) return 0.0f;
  const brdf::LobeParams& lobe = p.lobes[k][c];
  switch ((i - 1) % 4) {
    case 0:
      return lobe.cx;
    case 1:
      return lobe.cy;
    case 2:
      return lobe.cz;
    default:
      return lobe.n;
  }
}

// For each triangle, the triangles across the edges opposite its corners 0, 1, 2 (-1: boundary
// or non-manifold edge), with vertices matched by exact position (RenderTriangle::neighbours).
std::vector<std::array<int32_t, 3>> TriangleNeighbours(const TriangleMesh& mesh) {
  // Weld: one id per distinct position (bitwise-equal floats), by sorting.
  const size_t nv = mesh.positions.size();
  std::vector<uint32_t> order(nv);
  for (size_t i = 0; i < nv; ++i) order[i] = uint32_t(i);
  auto key = [&](uint32_t i) {
    const Vec3f& p = mesh.positions[i];
    return std::array<float, 3>{p.x(), p.y(), p.z()};
  };
  std::sort(order.begin(), order.end(), [&](uint32_t a, uint32_t b) { return key(a) < key(b); });
  std::vector<uint32_t> welded(nv);
  for (size_t i = 0; i < nv; ++i) {
    welded[order[i]] =
        (i > 0 && key(order[i]) == key(order[i - 1])) ? welded[order[i - 1]] : uint32_t(i);
  }
  // Every (edge, triangle, opposite corner), sorted by edge: equal edges become neighbours.
  struct Side {
    uint64_t edge;
    int32_t triangle;
    int corner;
  };
  std::vector<Side> sides;
  sides.reserve(mesh.TriangleCount() * 3);
  for (size_t t = 0; t < mesh.TriangleCount(); ++t) {
    for (int k = 0; k < 3; ++k) {
      const uint64_t a = welded[mesh.triangles[t][(k + 1) % 3]];
      const uint64_t b = welded[mesh.triangles[t][(k + 2) % 3]];
      sides.push_back({std::min(a, b) << 32 | std::max(a, b), int32_t(t), k});
    }
  }
  std::sort(sides.begin(), sides.end(),
            [](const Side& a, const Side& b) { return a.edge < b.edge; });
  std::vector<std::array<int32_t, 3>> result(mesh.TriangleCount(), {-1, -1, -1});
  for (size_t i = 0; i < sides.size();) {
    size_t j = i;
    while (j < sides.size() && sides[j].edge == sides[i].edge) ++j;
    if (j - i == 2) {  // a manifold edge; boundary (1) and non-manifold (> 2) edges stay -1
      result[sides[i].triangle][sides[i].corner] = sides[i + 1].triangle;
      result[sides[i + 1].triangle][sides[i + 1].corner] = sides[i].triangle;
    }
    i = j;
  }
  return result;
}

}  // namespace

const char* ShadowMapKindName(ShadowMapKind kind) {
  switch (kind) {
    case ShadowMapKind::kCube:
      return "cube";
    case ShadowMapKind::kFitted:
      return "fitted";
    default:
      return "auto";
  }
}

Status VulkanRenderOptions::Validate() const {
  REFLCAP_RETURN_IF_ERROR(gpu::ValidateLightMapResolution(
      "shadow", shadow_texels_per_pixel, min_shadow_resolution, max_shadow_resolution,
      max_cube_resolution));
  if (shadow_resolution < 0 || shadow_resolution > 16384) {
    return InvalidArgumentError("shadow_resolution must be in [0, 16384], got ", shadow_resolution);
  }
  if (!(shadow_bias_texels >= 0 && shadow_bias_texels <= 16)) {
    return InvalidArgumentError("shadow_bias_texels must be in [0, 16], got ", shadow_bias_texels);
  }
  if (!(shadow_plane_limit_texels >= 0 && shadow_plane_limit_texels <= 1000)) {
    return InvalidArgumentError("shadow_plane_limit_texels must be in [0, 1000], got ",
                                shadow_plane_limit_texels);
  }
  if (visibility_scale != 1 && visibility_scale != 2) {
    return InvalidArgumentError("visibility_scale must be 1 or 2, got ", visibility_scale);
  }
  if (batch_images < 0 || batch_images > kMaxBatchImages) {
    return InvalidArgumentError("batch_images must be in [0, ", kMaxBatchImages, "], got ",
                                batch_images);
  }
  if (batch_readback_mib < 1 || batch_readback_mib > 4096) {
    return InvalidArgumentError("batch_readback_mib must be in [1, 4096], got ",
                                batch_readback_mib);
  }
  if (batches_in_flight < 1 || batches_in_flight > 8) {
    return InvalidArgumentError("batches_in_flight must be in [1, 8], got ", batches_in_flight);
  }
  if (shadow_cache_mib < 0 || shadow_cache_mib > 16384) {
    return InvalidArgumentError("shadow_cache_mib must be in [0, 16384], got ", shadow_cache_mib);
  }
  return OkStatus();
}

std::string VulkanBatchStats::ToString() const {
  return StrCat(images, " images in ", submissions, " submissions, ", seconds, " s (record ",
                record_s, " s, wait ", wait_s, " s, read-back ", readback_s, " s, sink ", sink_s,
                " s); shadow maps drawn ", shadow_maps_drawn, ", reused ", shadow_maps_reused,
                "; ", shadow_edge_pixels, " shadow-edge pixels shaded on the host in ",
                shadow_edge_s, " s",
                device_timed ? StrCat("; device ", device_s, " s (shadow maps ", device_shadow_s,
                                      " s, passes ", device_pass_s, " s, outputs ",
                                      device_outputs_s, " s)")
                             : std::string());
}

// ---- Impl -----------------------------------------------------------------------------------

namespace {

// Everything one image needs, computed on the host before anything is recorded.
struct ImagePlan {
  bool normal_map = false;
  int width = 0, height = 0, supersampling = 1;
  bool distorted = false;
  bool aux = false;  // RenderOptions::aux_buffers
  uint32_t shadow_views = 0;
  int shadow_resolution = 0;
  int vis_width = 0, vis_height = 0;
  // Pixels the 1x camera pass can cover (the projected bounding box of the mesh, with a margin):
  // only they are read back; every other pixel is background (0) without looking.
  int rect_x0 = 0, rect_y0 = 0, rect_w = 0, rect_h = 0;
  sh::RenderParams params{};        // shadow, 1x camera (or visibility + resolve), normal map
  sh::RenderParams hires_params{};  // the supersampled camera pass (Supersampled())
  sh::HeightFieldMarch march{};     // normal maps: the height-field shadow march (steps 0: none)
  VulkanRenderStats stats;          // shadow map and visibility of this image
  // Mesh images: what the host needs to shade shadow-edge pixels (RenderPixels).
  const Camera* camera = nullptr;
  const Light* light = nullptr;
  Rigid3 world_from_object;
  double exposure_s = 1;
  RenderOptions options;

  bool Supersampled() const { return !normal_map && !distorted && supersampling > 1; }
  uint64_t OutBytes() const { return uint64_t(width) * uint64_t(height) * 16; }
  // Host-visible output memory: radiance, aux, and the 1x pass when supersampled.
  uint64_t ReadbackBytes() const { return OutBytes() * (Supersampled() ? 3 : 2); }
  // What a shadow map drawn for this image holds: its views and resolution, as bytes.
  std::vector<uint8_t> ShadowContent() const {
    std::vector<uint8_t> key(sizeof(sh::LightMapView) * shadow_views + 2 * sizeof(uint32_t));
    const uint32_t shape[2] = {shadow_views, uint32_t(shadow_resolution)};
    std::memcpy(key.data(), shape, sizeof(shape));
    std::memcpy(key.data() + sizeof(shape), params.views, sizeof(sh::LightMapView) * shadow_views);
    return key;
  }
};

// A pass target kept between images (and batches) with what it holds.
struct CachedTarget {
  std::unique_ptr<PassTarget> target;
  uint32_t width = 0, height = 0, layers = 0;
  std::vector<uint8_t> content;  // shadow maps: ShadowContent of the last map drawn; empty: none
  uint64_t last_use = 0;         // Impl::use_counter at the last use (LRU)
  uint64_t batch = 0;            // the last batch (Impl::batch_counter) recorded with it
  // Camera, supersampled and visibility targets: every image and batch uses it, so a pass on it
  // first waits for earlier reads (BeginPass). Their render passes wait only for earlier passes
  // (PassWait::kPasses), as a slot's own do: one render pass kind, one pipeline each.
  bool shared = false;
  uint64_t Bytes() const { return uint64_t(width) * height * layers * 4; }
};

// Image k of a Flight: its descriptor sets (created on first use) and output buffers.
struct Slot {
  std::unique_ptr<DescriptorSet> light, camera, hires, resolve, downsample, normal_map, raster;
  std::unique_ptr<Buffer> out_radiance, out_aux, out_mask;
  // Camera and visibility pass targets of this slot's own (VulkanRenderOptions::
  // per_image_targets), at most kSlotTargets sizes, least recently used first out.
  std::vector<std::unique_ptr<CachedTarget>> targets;
};

// One submission: command buffer and fence, the images' parameter blocks (two per image,
// Impl::params_stride apart: the 1x and the supersampled pass; in device memory, written by the
// submission itself, so a discrete GPU's shaders never read them across the bus), and its slots.
struct Flight {
  gpu::CommandBuffer cmd;  // submitted without waiting (Submit / Wait): batches in flight
  std::unique_ptr<Buffer> params;
  uint64_t params_capacity = 0;  // bytes
  std::vector<Slot> slots;
  std::vector<size_t> images;  // plan indices, in slot order; empty when idle
  uint64_t batch = 0;
  bool per_image_targets = false;  // this batch's images use their slots' own targets
  // VulkanRenderOptions::profile_device: query 0 at the start, 1 + 3k + {0, 1, 2} after image
  // k's shadow map, pass and outputs.
  std::unique_ptr<gpu::TimestampQueryPool> timestamps;
};

Status EnsureSet(gpu::VkContext& ctx, std::unique_ptr<DescriptorSet>* set,
                 const DescriptorSetLayout& layout) {
  if (*set != nullptr) return OkStatus();
  REFLCAP_ASSIGN_OR_RETURN(DescriptorSet s, DescriptorSet::Create(ctx, layout));
  *set = std::make_unique<DescriptorSet>(std::move(s));
  return OkStatus();
}

// Records a copy of the rectangle (x0, y0, w, h) of `image` (one layer, RGBA32F) into `dst` laid
// out as the whole image (rows of image.width() texels from offset 0); the rest of dst is left
// as it was.
void RecordCopyToBuffer(VkCommandBuffer cb, DeviceImage& image, const Buffer& dst, int x0, int y0,
                        int w, int h) {
  image.TransitionTo(cb, VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL);
  if (w <= 0 || h <= 0) return;
  VkBufferImageCopy region{};
  region.bufferOffset = (uint64_t(y0) * image.width() + uint64_t(x0)) * 16;
  region.bufferRowLength = image.width();
  region.imageSubresource = {image.aspect(), 0, 0, 1};
  region.imageOffset = {x0, y0, 0};
  region.imageExtent = {uint32_t(w), uint32_t(h), 1};
  vkCmdCopyImageToBuffer(cb, image.handle(), VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, dst.handle(), 1,
                         &region);
}

// `src_access` of earlier work in `src_stages` finishes and is visible to `dst_access` of later
// work in `dst_stages`.
void RecordMemoryBarrier(VkCommandBuffer cb, VkPipelineStageFlags src_stages,
                         VkAccessFlags src_access, VkPipelineStageFlags dst_stages,
                         VkAccessFlags dst_access) {
  VkMemoryBarrier barrier{};
  barrier.sType = VK_STRUCTURE_TYPE_MEMORY_BARRIER;
  barrier.srcAccessMask = src_access;
  barrier.dstAccessMask = dst_access;
  vkCmdPipelineBarrier(cb, src_stages, dst_stages, 0, 1, &barrier, 0, nullptr, 0, nullptr);
}

// Transfer writes (fills) finish and are visible before later compute shaders write or read.
void RecordTransferToCompute(VkCommandBuffer cb) {
  RecordMemoryBarrier(cb, VK_PIPELINE_STAGE_TRANSFER_BIT, VK_ACCESS_TRANSFER_WRITE_BIT,
                      VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                      VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_SHADER_WRITE_BIT);
}

// Begins `target`'s pass on layer 0; a shared target first waits for earlier shaders and
// copies that read it (an execution dependency suffices for reads; the render pass orders the
// writes of earlier passes).
void BeginPass(VkCommandBuffer cb, CachedTarget& target) {
  if (target.shared) {
    vkCmdPipelineBarrier(cb,
                         VK_PIPELINE_STAGE_FRAGMENT_SHADER_BIT |
                             VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT | VK_PIPELINE_STAGE_TRANSFER_BIT,
                         VK_PIPELINE_STAGE_EARLY_FRAGMENT_TESTS_BIT |
                             VK_PIPELINE_STAGE_LATE_FRAGMENT_TESTS_BIT |
                             VK_PIPELINE_STAGE_COLOR_ATTACHMENT_OUTPUT_BIT,
                         0, 0, nullptr, 0, nullptr, 0, nullptr);
  }
  target.target->target.Begin(cb, 0, {});
}

}  // namespace

struct VulkanRenderer::Impl {
  std::unique_ptr<gpu::VkContext> owned_ctx;
  gpu::VkContext* ctx = nullptr;
  VulkanRenderOptions options;
  VulkanRenderStats stats;
  VulkanBatchStats batch_stats;
  gpu::CommandBuffer cmd;  // scene uploads
  gpu::Sampler sampler;

  // Descriptor set layouts, one per pass (the light layout — params + corners — serves the
  // shadow and the visibility pass), and the pipelines.
  DescriptorSetLayout light_layout, camera_layout, resolve_layout, downsample_layout,
      normal_map_layout, raster_layout;
  Pipeline shadow_pipeline, depth_pipeline, camera_pipeline, visibility_pipeline,
      resolve_pipeline, downsample_pipeline, normal_map_pipeline, raster_pipeline;
  // Compute-drawn shadow maps (ShadowRaster::kCompute): the raster buffer every map is drawn into
  // before its copy into the map, and the smaller ones it replaced while submissions that use
  // them may still run (freed once none is in flight).
  std::unique_ptr<Buffer> raster_buffer;
  std::vector<std::unique_ptr<Buffer>> retired_raster_buffers;

  // Scene.
  enum class SceneKind { kNone, kMesh, kNormalMap } scene_kind = SceneKind::kNone;
  // Mesh scenes: the caller's scene (shadow-edge pixels are shaded with its rays) and its
  // SurfaceCurvature.
  ShadedScene mesh_scene;
  std::vector<float> mesh_curvature;
  std::unique_ptr<Buffer> corners, triangles, normal_map_texels;
  // Normal-map scenes: the height field (heights_px uploaded; one float when there is none), and
  // the host copy its marches are planned from.
  std::unique_ptr<Buffer> height_field_buffer;
  std::unique_ptr<HeightField> height_field;
  std::unique_ptr<DeviceImage> material, frame, dummy_shadow;
  uint32_t triangle_count = 0;
  uint32_t texel_count = 0;
  int num_lobes = 0;
  int atlas_width = 0, atlas_height = 0;
  Vec3d sphere_centre = Vec3d::Zero();  // object frame
  Eigen::AlignedBox3d bounds;           // the mesh's bounding box, object frame
  double sphere_radius = 0;
  double surface_offset = 0;

  // Pass targets, shared by every image and batch: the queue orders their reuse.
  std::vector<std::unique_ptr<CachedTarget>> shadow_maps, camera_targets, hires_targets,
      visibility_targets;
  uint64_t use_counter = 0, batch_counter = 0;

  // Submissions: a ring of Flights, those in flight oldest first.
  std::vector<std::unique_ptr<Flight>> flights;
  size_t next_flight = 0;
  std::deque<Flight*> in_flight;
  uint64_t params_stride = 0;
  std::unique_ptr<WorkerPool> readback_pool;
  // The plans and sink of the RenderPlans call in progress (Drain delivers their images).
  const std::vector<ImagePlan>* plans = nullptr;
  const RenderSink* sink = nullptr;

  Status Init(const VulkanRenderOptions& o);
  Status UploadMaterial(const TexelAtlas& atlas, const BrdfMaps& maps);
  StatusOr<ImagePlan> PlanMeshImage(const Camera& camera, const Light& light,
                                    const Rigid3& world_from_object, double exposure_s,
                                    const RenderOptions& options) const;
  StatusOr<ImagePlan> PlanNormalMapImage(const Camera& camera, const Light& light,
                                         double exposure_s, const RenderOptions& options) const;
  // Renders `plans` in batches and hands each result to `sink`, in order.
  Status RenderPlans(const std::vector<ImagePlan>& plans, const RenderSink& sink);
  Status RecordImage(Flight& flight, size_t k, const ImagePlan& plan);
  Status RecordMeshImage(Flight& flight, size_t k, const ImagePlan& plan);
  Status RecordNormalMapImage(Flight& flight, size_t k, const ImagePlan& plan);
  // Waits for the oldest submission, reads its images back and hands them to the sink.
  Status CompleteOldest();
  Status Drain();
  // After an error: waits for whatever was submitted, forgets it and every kept shadow map's
  // content (a map recorded but never submitted was not drawn).
  void Abandon();
  StatusOr<CachedTarget*> AcquireTarget(std::vector<std::unique_ptr<CachedTarget>>* cache,
                                        uint32_t w, uint32_t h,
                                        const std::vector<VkFormat>& formats,
                                        VkImageLayout final_layout);
  // A target of `slot`'s own (its flight is idle: no submission uses the slot's targets), whose
  // pass waits only for earlier passes (PassWait::kPasses) and needs no barrier before it.
  StatusOr<CachedTarget*> AcquireSlotTarget(Slot& slot, uint32_t w, uint32_t h,
                                            const std::vector<VkFormat>& formats,
                                            VkImageLayout final_layout);
  // Records timestamp `index` of the flight's pool (profile_device).
  void Stamp(Flight& flight, uint32_t index) {
    if (flight.timestamps != nullptr) (void)flight.timestamps->Write(flight.cmd, index);
  }
  // Adds a completed flight's timestamps to batch_stats.
  void AddDeviceTimes(const Flight& flight);
  bool IsCpuDevice() const { return ctx->info().IsSoftware(); }
  bool ComputeShadowMaps() const {
    return options.shadow_raster == ShadowRaster::kCompute ||
           (options.shadow_raster == ShadowRaster::kAuto && !IsCpuDevice());
  }
  bool ResolvePinhole() const {
    return options.camera_shading == CameraShading::kResolve ||
           (options.camera_shading == CameraShading::kAuto && !IsCpuDevice());
  }
  // Records drawing image k's shadow map `shadow` by compute (shadow_raster.comp).
  Status RecordComputeShadowMap(Flight& flight, size_t k, const ImagePlan& plan,
                                CachedTarget& shadow);
  // The shadow map of `plan`: a kept one holding exactly its views (*reused), else one to draw.
  StatusOr<CachedTarget*> AcquireShadowMap(const ImagePlan& plan, bool* reused);
  // Releases kept targets that the batch being recorded does not use, once nothing submitted
  // can still use them (drains the submissions first).
  Status ReleaseIdle(std::vector<std::unique_ptr<CachedTarget>>* cache);
  // The pipelines not made yet whose pass targets (of any size) are given (null: not needed).
  Status EnsurePipelines(const CachedTarget* camera, const CachedTarget* visibility,
                         const CachedTarget* shadow);
  void Draw(VkCommandBuffer cb, const Pipeline& pipeline, const DescriptorSet& set) {
    pipeline.Bind(cb, set.handle());
    vkCmdDraw(cb, 3 * triangle_count, 1, 0, 0);
  }
  void ReadBack(const Flight& flight, std::vector<RenderResult>* results);
};

Status VulkanRenderer::Impl::Init(const VulkanRenderOptions& o) {
  REFLCAP_RETURN_IF_ERROR(o.Validate());
  options = o;
  gpu::VkContext& c = *ctx;
  REFLCAP_ASSIGN_OR_RETURN(cmd, gpu::CommandBuffer::Create(c));
  REFLCAP_ASSIGN_OR_RETURN(sampler, gpu::Sampler::Create(c));
  REFLCAP_RETURN_IF_ERROR(gpu::CheckPassFormats(
      c, {VK_FORMAT_R32G32B32A32_SFLOAT, VK_FORMAT_R32_UINT}, "camera passes and shadow maps"));

  REFLCAP_ASSIGN_OR_RETURN(light_layout, DescriptorSetLayout::Create(
                                             c, {{kBindParams, kSsbo, kGfx},
                                                 {kBindCorners, kSsbo, kGfx}}));
  REFLCAP_ASSIGN_OR_RETURN(camera_layout,
                           DescriptorSetLayout::Create(c, {{kBindParams, kSsbo, kGfx},
                                                           {kBindCorners, kSsbo, kGfx},
                                                           {kBindTriangles, kSsbo, kGfx},
                                                           {kBindMaterial, kTex, kGfx},
                                                           {kBindFrame, kTex, kGfx},
                                                           {kBindShadowMap, kTex, kGfx}}));
  REFLCAP_ASSIGN_OR_RETURN(resolve_layout,
                           DescriptorSetLayout::Create(c, {{kBindParams, kSsbo, kComp},
                                                           {kBindCorners, kSsbo, kComp},
                                                           {kBindTriangles, kSsbo, kComp},
                                                           {kBindMaterial, kTex, kComp},
                                                           {kBindFrame, kTex, kComp},
                                                           {kBindShadowMap, kTex, kComp},
                                                           {kBindSource, kTex, kComp},
                                                           {kBindOutRadiance, kSsbo, kComp},
                                                           {kBindOutAux, kSsbo, kComp}}));
  REFLCAP_ASSIGN_OR_RETURN(downsample_layout,
                           DescriptorSetLayout::Create(
                               c, {{kBindSource, kTex, kComp}, {kBindOutRadiance, kSsbo, kComp}}));
  REFLCAP_ASSIGN_OR_RETURN(normal_map_layout,
                           DescriptorSetLayout::Create(c, {{kBindParams, kSsbo, kComp},
                                                           {kBindMaterial, kTex, kComp},
                                                           {kBindOutRadiance, kSsbo, kComp},
                                                           {kBindOutAux, kSsbo, kComp},
                                                           {kBindNormalMapTexels, kSsbo, kComp},
                                                           {kBindHeightField, kSsbo, kComp}}));

  REFLCAP_ASSIGN_OR_RETURN(
      resolve_pipeline,
      Pipeline::CreateCompute(
          c, {gpu::ShaderId::kRenderDistortResolve, resolve_layout.handle(), 0, {}}));
  REFLCAP_ASSIGN_OR_RETURN(downsample_pipeline,
                           Pipeline::CreateCompute(c, {gpu::ShaderId::kRenderDownsample,
                                                       downsample_layout.handle(),
                                                       uint32_t(sizeof(sh::DownsamplePush)),
                                                       {}}));
  REFLCAP_ASSIGN_OR_RETURN(normal_map_pipeline,
                           Pipeline::CreateCompute(c, {gpu::ShaderId::kRenderNormalMapShade,
                                                       normal_map_layout.handle(),
                                                       uint32_t(sizeof(sh::NormalMapPush)),
                                                       {}}));

  // Parameter blocks of one flight sit at this stride (bindable offsets).
  const uint64_t align = std::max<uint64_t>(1, c.info().min_storage_buffer_offset_alignment);
  params_stride = (sizeof(sh::RenderParams) + align - 1) / align * align;
  // A 1x1 stand-in bound as the shadow map when a pass draws no shadows.
  gpu::ImageOptions o1;
  o1.width = o1.height = 1;
  o1.format = VK_FORMAT_R32_SFLOAT;
  o1.usage = VK_IMAGE_USAGE_SAMPLED_BIT;
  REFLCAP_ASSIGN_OR_RETURN(DeviceImage dummy, DeviceImage::Create(c, o1));
  dummy_shadow = std::make_unique<DeviceImage>(std::move(dummy));
  const float nothing = 1.0f;
  REFLCAP_RETURN_IF_ERROR(
      gpu::UploadImageLayer(c, cmd, *dummy_shadow, 0, &nothing, sizeof(nothing)));
  return OkStatus();
}

Status VulkanRenderer::Impl::EnsurePipelines(const CachedTarget* camera,
                                             const CachedTarget* visibility,
                                             const CachedTarget* shadow) {
  // Each pipeline is made with the first target of its kind: render passes of other sizes (and
  // layer counts, and external dependencies) with the same formats are compatible with it.
  if (depth_pipeline.handle() == VK_NULL_HANDLE && camera != nullptr) {
    // Depth pre-pass, then shading with depth EQUAL: every pixel is shaded once, by its nearest
    // surface (the full shading is what costs, on lavapipe above all).
    gpu::GraphicsPipelineOptions o;
    o.vertex = gpu::ShaderId::kRenderSurfaceVert;
    o.set_layout = camera_layout.handle();
    o.color_writes = false;
    const gpu::RenderTarget& target = camera->target->target;
    REFLCAP_ASSIGN_OR_RETURN(depth_pipeline, Pipeline::CreateGraphics(*ctx, o, target));
    o.fragment = gpu::ShaderId::kRenderSurfaceFrag;
    o.color_writes = true;
    o.depth_compare = VK_COMPARE_OP_EQUAL;
    o.depth_write = false;
    REFLCAP_ASSIGN_OR_RETURN(camera_pipeline, Pipeline::CreateGraphics(*ctx, o, target));
  }
  if (visibility_pipeline.handle() == VK_NULL_HANDLE && visibility != nullptr) {
    gpu::GraphicsPipelineOptions o;
    o.vertex = gpu::ShaderId::kRenderSurfaceVert;
    o.fragment = gpu::ShaderId::kRenderVisibilityFrag;
    o.set_layout = light_layout.handle();  // params + corners
    REFLCAP_ASSIGN_OR_RETURN(
        visibility_pipeline,
        Pipeline::CreateGraphics(*ctx, o, visibility->target->target));
  }
  if (shadow_pipeline.handle() == VK_NULL_HANDLE && shadow != nullptr) {
    REFLCAP_ASSIGN_OR_RETURN(
        shadow_pipeline,
        gpu::CreateLightMapPipeline(*ctx, gpu::ShaderId::kRenderShadowVert,
                                    gpu::ShaderId::kRenderShadowFrag, light_layout.handle(),
                                    shadow->target->target));
  }
  return OkStatus();
}
Status VulkanRenderer::Impl::UploadMaterial(const TexelAtlas& atlas, const BrdfMaps& maps) {
  if (maps.texels.size() != atlas.TexelCount()) {
    return InvalidArgumentError("parameter maps have ", maps.texels.size(), " texels, the atlas ",
                                atlas.TexelCount());
  }
  if (maps.num_lobes < 0 || maps.num_lobes > brdf::kMaxLobes) {
    return InvalidArgumentError("num_lobes ", maps.num_lobes, " outside [0, ", brdf::kMaxLobes,
                                "]");
  }
  const int per_channel = brdf::ParamsPerChannel(maps.num_lobes);
  const int layers = (3 * per_channel + 3) / 4;
  const size_t pixels = size_t(atlas.width) * atlas.height;
  gpu::ImageOptions o;
  o.width = uint32_t(atlas.width);
  o.height = uint32_t(atlas.height);
  o.layers = uint32_t(layers);
  o.format = VK_FORMAT_R32G32B32A32_SFLOAT;
  o.usage = VK_IMAGE_USAGE_SAMPLED_BIT;
  material.reset();
  frame.reset();
  REFLCAP_ASSIGN_OR_RETURN(DeviceImage m, DeviceImage::Create(*ctx, o));
  material = std::make_unique<DeviceImage>(std::move(m));
  o.layers = 1;
  REFLCAP_ASSIGN_OR_RETURN(DeviceImage f, DeviceImage::Create(*ctx, o));
  frame = std::make_unique<DeviceImage>(std::move(f));

  std::vector<float> layer(pixels * 4);
  for (int l = 0; l < layers; ++l) {
    std::fill(layer.begin(), layer.end(), 0.0f);
    for (size_t t = 0; t < atlas.TexelCount(); ++t) {
      const size_t px = atlas.pixel_of_texel[t];
      for (int lane = 0; lane < 4; ++lane) {
        const int k = 4 * l + lane;
        if (k >= 3 * per_channel) break;
        const int c = k / per_channel, i = k % per_channel;
        layer[px * 4 + lane] = ParamAt(maps.texels[t], c, i);
      }
    }
    REFLCAP_RETURN_IF_ERROR(gpu::UploadImageLayer(*ctx, cmd, *material, uint32_t(l), layer.data(),
                                                  layer.size() * sizeof(float)));
  }
  std::fill(layer.begin(), layer.end(), 0.0f);
  for (size_t t = 0; t < atlas.TexelCount(); ++t) {
    const size_t px = atlas.pixel_of_texel[t];
    const Vec3f& tangent = atlas.tangent[t];
    layer[px * 4 + 0] = tangent.x();
    layer[px * 4 + 1] = tangent.y();
    layer[px * 4 + 2] = tangent.z();
    layer[px * 4 + 3] = 1.0f;
  }
  REFLCAP_RETURN_IF_ERROR(
      gpu::UploadImageLayer(*ctx, cmd, *frame, 0, layer.data(), layer.size() * sizeof(float)));
  num_lobes = maps.num_lobes;
  atlas_width = atlas.width;
  atlas_height = atlas.height;
  return OkStatus();
}

StatusOr<ImagePlan> VulkanRenderer::Impl::PlanMeshImage(const Camera& camera, const Light& light,
                                                        const Rigid3& world_from_object,
                                                        double exposure_s,
                                                        const RenderOptions& options) const {
  const bool pinhole = camera.model == CameraModel::kPinhole;
  if (!pinhole && !(camera.pixel_size_m > 0)) {
    return InvalidArgumentError("camera \"", camera.id,
                                "\": orthographic rendering needs pixel_size_m");
  }
  if (camera.width <= 0 || camera.height <= 0) {
    return InvalidArgumentError("camera \"", camera.id, "\" has no pixels");
  }
  ImagePlan plan;
  plan.camera = &camera;
  plan.light = &light;
  plan.world_from_object = world_from_object;
  plan.exposure_s = exposure_s;
  plan.options = options;
  const int w = camera.width, h = camera.height, n = options.supersampling;
  REFLCAP_RETURN_IF_ERROR(options.Validate());
  // Samples spread over more than the pixel (RenderOptions::pixel_footprint) sit off the
  // supersampled pass's grid: only the resolve takes them, by their exact rays.
  const bool wide_footprint = n > 1 && options.pixel_footprint != 1;
  if (wide_footprint && !pinhole) {
    return InvalidArgumentError("camera \"", camera.id, "\": a pixel footprint of ",
                                options.pixel_footprint,
                                " px needs a pinhole camera on the Vulkan renderer (orthographic "
                                "cameras are rasterised on the pixel grid)");
  }
  if (wide_footprint && this->options.camera_shading == CameraShading::kFragment) {
    return InvalidArgumentError("camera_shading fragment samples the pixel grid only; a pixel "
                                "footprint of ", options.pixel_footprint,
                                " px needs the resolve (camera_shading auto or resolve)");
  }
  const bool distorted =
      pinhole && (camera.HasDistortion() || ResolvePinhole() || wide_footprint);
  const bool point_light = light.type == LightType::kPoint;
  plan.width = w;
  plan.height = h;
  plan.supersampling = n;
  plan.distorted = distorted;
  plan.aux = options.aux_buffers;

  // Camera and light in the object frame.
  const Rigid3 cam_from_object = camera.cam_from_world * world_from_object;
  const Rigid3 object_from_cam = cam_from_object.Inverse();
  const Rigid3 object_from_world = world_from_object.Inverse();
  const Vec3d light_in_object = object_from_world * light.position;
  const Vec3d light_dir_in_object = (object_from_world.rotation * light.direction).normalized();
  const Vec3d centre = sphere_centre;
  const double radius = sphere_radius;
  const double centre_z = (cam_from_object * centre).z();
  // Depth range of the object in front of the camera (pinhole: beyond a sliver in front of the
  // centre; orthographic: rays start on the plane z = 0, as the CPU's do).
  double near = 0, far = 0;
  gpu::CameraDepthRange(pinhole, centre_z, radius, &near, &far);

  sh::RenderParams& p = plan.params;
  const double fx = camera.K(0, 0), fy = camera.K(1, 1), s = camera.K(0, 1), cx = camera.K(0, 2),
               cy = camera.K(1, 2);
  const Mat4d object_to_cam = Homogeneous(cam_from_object);
  auto clip_for_scale = [&](int scale) -> Mat4d {
    if (!pinhole) {
      return OrthoClipFromCam(camera.pixel_size_m / scale, w * scale, h * scale, near, far) *
             object_to_cam;
    }
    return PinholeClipFromCam(fx * scale, fy * scale, s * scale, scale * (cx + 0.5) - 0.5,
                              scale * (cy + 0.5) - 0.5, w * scale, h * scale, near, far) *
           object_to_cam;
  };
  SetRows(clip_for_scale(1), p.clip_from_object);
  p.camera_origin = V4(object_from_cam.translation, 1);
  p.camera_axis = V4(object_from_cam.rotation.col(2), 0);
  for (int r = 0; r < 3; ++r)
    p.object_from_cam[r] = V4(object_from_cam.rotation.row(r).transpose(), 0);
  p.light = point_light ? V4(light_in_object, 1) : V4(light_dir_in_object, 0);
  p.intensity = V4(light.intensity, exposure_s);
  p.intrinsics = {float(fx), float(fy), float(cx), float(cy)};
  // z: 1 sample per side; w: the footprint the resolve spreads its N x N samples over.
  p.intrinsics_extra = {float(s), float(camera.pixel_size_m), 1,
                        float(n > 1 ? options.pixel_footprint : 1.0)};
  p.distortion = {float(camera.dist[0]), float(camera.dist[1]), float(camera.dist[2]),
                  float(camera.dist[3])};
  p.distortion_extra = {float(camera.dist[4]), 0, 0, 0};
  p.flags = (pinhole ? sh::kRenderFlagPinhole : 0u) |
            (point_light ? sh::kRenderFlagPointLight : 0u) |
            (distorted ? sh::kRenderFlagDistortion : 0u);
  p.num_lobes = uint32_t(num_lobes);
  p.params_per_channel = uint32_t(brdf::ParamsPerChannel(num_lobes));
  p.atlas_width = uint32_t(atlas_width);
  p.atlas_height = uint32_t(atlas_height);
  p.width = uint32_t(w);
  p.height = uint32_t(h);
  p.supersampling = uint32_t(n);

  // Shadow views.
  const VulkanRenderOptions& vo = this->options;
  const double pixel_m = pinhole ? std::max(centre_z, radius) / fx : camera.pixel_size_m;
  gpu::LightMapResolution resolution;
  resolution.texels_per_pixel = vo.shadow_texels_per_pixel;
  resolution.pixel_m = pixel_m;
  resolution.min_resolution = vo.min_shadow_resolution;
  resolution.max_resolution = vo.max_shadow_resolution;
  resolution.max_cube_resolution = vo.max_cube_resolution;
  resolution.fixed = vo.shadow_resolution;
  uint32_t views = 0;
  int res = 0;
  if (options.cast_shadows) {
    gpu::LightMapShape shape = gpu::LightMapShape::kAuto;
    if (vo.shadow_map == ShadowMapKind::kCube) shape = gpu::LightMapShape::kCube;
    if (vo.shadow_map == ShadowMapKind::kFitted) shape = gpu::LightMapShape::kFitted;
    REFLCAP_ASSIGN_OR_RETURN(
        const gpu::LightMapPlan light_map,
        gpu::PlanLightMap(point_light, light_in_object, light_dir_in_object, centre, radius, shape,
                          resolution));
    std::copy(light_map.views, light_map.views + light_map.view_count, p.views);
    views = light_map.view_count;
    res = light_map.resolution;
    plan.stats.shadow_map = light_map.kind;
    plan.stats.shadow_map_computed = ComputeShadowMaps();
    p.flags |= sh::kRenderFlagCastShadows;
    plan.stats.shadow_resolution = res;
  }
  p.num_shadow_views = views;
  p.shadow_resolution = uint32_t(res);
  p.shadow_bias = {float(surface_offset), float(vo.shadow_bias_texels),
                   float(vo.shadow_plane_limit_texels), 0};
  plan.shadow_views = views;
  plan.shadow_resolution = res;

  if (distorted) {
    // Visibility image of a distorted camera: the undistorted footprint of the image's border
    // (pixel edges, ±0.5 px), in normalised coordinates, at visibility_scale texels per pixel.
    double xmin = 1e300, xmax = -1e300, ymin = 1e300, ymax = -1e300;
    bool finite = true;  // a border point without an undistortion (beyond the lens model's fold)
    auto extend = [&](double u, double v) {
      const double yd = (v - cy) / fy;
      const double xd = (u - cx - s * yd) / fx;
      const Vec2d xy = camera.Undistort({xd, yd});
      finite = finite && std::isfinite(xy.x()) && std::isfinite(xy.y());
      xmin = std::min(xmin, xy.x());
      xmax = std::max(xmax, xy.x());
      ymin = std::min(ymin, xy.y());
      ymax = std::max(ymax, xy.y());
    };
    // The border of what the samples reach: the pixels' edges, or their footprints' (wider).
    const double half = 0.5 * (n > 1 ? std::max(1.0, options.pixel_footprint) : 1.0);
    for (int x = 0; x <= w; ++x) {
      const double u = std::min(x - half, w - 1 + half);
      extend(u, -half);
      extend(u, h - 1 + half);
    }
    extend(w - 1 + half, -half);
    extend(w - 1 + half, h - 1 + half);
    for (int y = 0; y <= h; ++y) {
      const double v = std::min(y - half, h - 1 + half);
      extend(-half, v);
      extend(w - 1 + half, v);
    }
    const int scale = vo.visibility_scale;
    const double vfx = fx * scale, vfy = fy * scale, vs = s * scale;
    const double u0 = std::min({vfx * xmin + vs * ymin, vfx * xmin + vs * ymax});
    const double u1 = std::max({vfx * xmax + vs * ymin, vfx * xmax + vs * ymax});
    double vcx = kVisibilityMargin - u0;
    double vcy = kVisibilityMargin - vfy * ymin;
    double width_d = std::ceil(u1 - u0) + 2 * kVisibilityMargin + 1;
    double height_d = std::ceil(vfy * (ymax - ymin)) + 2 * kVisibilityMargin + 1;
    if (!camera.HasDistortion()) {
      // A pinhole camera shaded by the resolve (CameraShading::kResolve): pixel x lands at
      // visibility x scale - cx scale + vcx, so whole texels beside its centre when vcx - cx scale
      // is whole; then the texel under a pixel centre holds the rasteriser's own answer for that
      // ray (distort_resolve.comp falls back on it). Up to a texel more of margin on each axis.
      vcx = scale * cx + std::ceil(vcx - scale * cx);
      vcy = scale * cy + std::ceil(vcy - scale * cy);
      width_d += 1;
      height_d += 1;
    }
    if (!(finite && width_d >= 1 && height_d >= 1 && width_d <= kMaxVisibilitySide &&
          height_d <= kMaxVisibilitySide &&
          width_d <= kMaxVisibilityRatio * scale * w + 64 &&
          height_d <= kMaxVisibilityRatio * scale * h + 64)) {
      return InvalidArgumentError("camera \"", camera.id,
                                  "\": its distortion spreads the image "
                                  "over an undistorted footprint of ",
                                  width_d, "x", height_d,
                                  " px, too wide for the Vulkan renderer's pinhole rasterisation");
    }
    const int vis_w = int(width_d), vis_h = int(height_d);
    p.vis_intrinsics = {float(vfx), float(vfy), float(vcx), float(vcy)};
    p.vis_intrinsics_extra = {float(vs), 0, 0, 0};
    p.vis_width = uint32_t(vis_w);
    p.vis_height = uint32_t(vis_h);
    plan.vis_width = vis_w;
    plan.vis_height = vis_h;
    plan.stats.distortion_resolve = true;
    plan.stats.visibility_width = vis_w;
    plan.stats.visibility_height = vis_h;
    // The visibility pass uses clip_from_object of the visibility image; the resolve reads the
    // output camera's intrinsics. One params block serves both: the vertex stage reads
    // clip_from_object, which for a distorted camera is the visibility projection.
    SetRows(PinholeClipFromCam(vfx, vfy, vs, vcx, vcy, vis_w, vis_h, near, far) * object_to_cam,
            p.clip_from_object);
  }
  // Pixel weight: the camera pass shades one sample per pixel (the supersampled pass below sets
  // its own); the resolve sums N x N samples.
  p.intensity.w = float(distorted ? exposure_s / (double(n) * n) : exposure_s);
  plan.rect_w = w;
  plan.rect_h = h;
  if (!distorted && n == 1) {
    // A fragment covers a pixel centre inside the projection of its triangle, which lies inside
    // the projection of the mesh's bounding box (convex; all of it in front of the camera, else
    // the whole image is kept).
    double u0 = 1e300, u1 = -1e300, v0 = 1e300, v1 = -1e300;
    bool bounded = true;
    for (int corner = 0; corner < 8; ++corner) {
      const Vec3d q = cam_from_object * bounds.corner(Eigen::AlignedBox3d::CornerType(corner));
      double u, v;
      if (pinhole) {
        if (!(q.z() > 1e-9 * radius)) {
          bounded = false;
          break;
        }
        u = fx * q.x() / q.z() + s * q.y() / q.z() + cx;
        v = fy * q.y() / q.z() + cy;
      } else {
        u = q.x() / camera.pixel_size_m + 0.5 * (w - 1);
        v = q.y() / camera.pixel_size_m + 0.5 * (h - 1);
      }
      u0 = std::min(u0, u), u1 = std::max(u1, u), v0 = std::min(v0, v), v1 = std::max(v1, v);
    }
    if (bounded && std::isfinite(u0) && std::isfinite(u1) && std::isfinite(v0) &&
        std::isfinite(v1)) {
      const double x0 = std::clamp(std::floor(u0) - kRectMarginPx, 0.0, double(w));
      const double x1 = std::clamp(std::ceil(u1) + kRectMarginPx + 1, 0.0, double(w));
      const double y0 = std::clamp(std::floor(v0) - kRectMarginPx, 0.0, double(h));
      const double y1 = std::clamp(std::ceil(v1) + kRectMarginPx + 1, 0.0, double(h));
      plan.rect_x0 = int(x0);
      plan.rect_y0 = int(y0);
      plan.rect_w = int(x1) - int(x0);
      plan.rect_h = int(y1) - int(y0);
    }
  }
  if (plan.Supersampled()) {
    // Supersampled pass: N x N the resolution (stratum centres), each fragment weighted
    // exposure / N², box-filtered into the radiance output; mask and aux come from the 1x pass.
    sh::RenderParams& q = plan.hires_params;
    q = p;
    SetRows(clip_for_scale(n), q.clip_from_object);
    q.intrinsics_extra.z = float(n);  // surface.frag: fragment -> stratum centre
    q.intensity.w = float(exposure_s / (double(n) * n));
  }
  return plan;
}

StatusOr<ImagePlan> VulkanRenderer::Impl::PlanNormalMapImage(const Camera& camera,
                                                             const Light& light, double exposure_s,
                                                             const RenderOptions& options) const {
  if (atlas_width != camera.width || atlas_height != camera.height) {
    return InvalidArgumentError("camera \"", camera.id, "\" is ", camera.width, "x", camera.height,
                                " but the normal map is ", atlas_width, "x", atlas_height);
  }
  if (light.type != LightType::kDirectional) {
    return InvalidArgumentError("light \"", light.id,
                                "\": normal-map captures are rendered with directional lights "
                                "only (the surface positions are unknown)");
  }
  ImagePlan plan;
  plan.normal_map = true;
  const int w = camera.width, h = camera.height;
  plan.width = w;
  plan.height = h;
  plan.rect_w = w;
  plan.rect_h = h;
  plan.aux = options.aux_buffers;
  const bool pinhole = camera.model == CameraModel::kPinhole;
  const Rigid3 world_from_cam = camera.cam_from_world.Inverse();
  sh::RenderParams& p = plan.params;
  p.camera_axis = V4(camera.AxisInWorld(), 0);
  for (int r = 0; r < 3; ++r)
    p.object_from_cam[r] = V4(world_from_cam.rotation.row(r).transpose(), 0);
  p.light = V4(light.direction.normalized(), 0);
  p.intensity = V4(light.intensity, exposure_s);
  p.intrinsics = {float(camera.K(0, 0)), float(camera.K(1, 1)), float(camera.K(0, 2)),
                  float(camera.K(1, 2))};
  p.intrinsics_extra = {float(camera.K(0, 1)), float(camera.pixel_size_m), 1, 0};
  p.distortion = {float(camera.dist[0]), float(camera.dist[1]), float(camera.dist[2]),
                  float(camera.dist[3])};
  p.distortion_extra = {float(camera.dist[4]), 0, 0, 0};
  p.flags = (pinhole ? sh::kRenderFlagPinhole : 0u) |
            (pinhole && camera.HasDistortion() ? sh::kRenderFlagDistortion : 0u);
  p.num_lobes = uint32_t(num_lobes);
  p.params_per_channel = uint32_t(brdf::ParamsPerChannel(num_lobes));
  p.atlas_width = uint32_t(atlas_width);
  p.atlas_height = uint32_t(atlas_height);
  p.width = uint32_t(w);
  p.height = uint32_t(h);
  p.supersampling = 1;
  if (options.cast_shadows && height_field != nullptr) {
    plan.march = MakeHeightFieldMarch(*height_field, light.direction);
  }
  return plan;
}

// ---- Pass targets ---------------------------------------------------------------------------

Status VulkanRenderer::Impl::ReleaseIdle(std::vector<std::unique_ptr<CachedTarget>>* cache) {
  if (cache->size() < kMaxIdleTargets) return OkStatus();
  // Destroying a target needs every submission that may use it finished.
  REFLCAP_RETURN_IF_ERROR(Drain());
  cache->erase(std::remove_if(cache->begin(), cache->end(),
                              [&](const std::unique_ptr<CachedTarget>& t) {
                                return t->batch != batch_counter;
                              }),
               cache->end());
  return OkStatus();
}

StatusOr<CachedTarget*> VulkanRenderer::Impl::AcquireTarget(
    std::vector<std::unique_ptr<CachedTarget>>* cache, uint32_t w, uint32_t h,
    const std::vector<VkFormat>& formats, VkImageLayout final_layout) {
  for (const std::unique_ptr<CachedTarget>& t : *cache) {
    if (t->width == w && t->height == h) {
      t->batch = batch_counter;
      return t.get();
    }
  }
  REFLCAP_RETURN_IF_ERROR(ReleaseIdle(cache));
  auto t = std::make_unique<CachedTarget>();
  REFLCAP_ASSIGN_OR_RETURN(t->target,
                           MakePassTarget(*ctx, w, h, 1, formats, final_layout, false,
                                          gpu::PassWait::kPasses));
  t->shared = true;
  t->width = w;
  t->height = h;
  t->layers = 1;
  t->batch = batch_counter;
  cache->push_back(std::move(t));
  return cache->back().get();
}

StatusOr<CachedTarget*> VulkanRenderer::Impl::AcquireSlotTarget(
    Slot& slot, uint32_t w, uint32_t h, const std::vector<VkFormat>& formats,
    VkImageLayout final_layout) {
  ++use_counter;
  for (const std::unique_ptr<CachedTarget>& t : slot.targets) {
    if (t->width == w && t->height == h && t->target->colors.size() == formats.size() &&
        t->target->colors[0]->format() == formats[0]) {
      t->last_use = use_counter;
      return t.get();
    }
  }
  if (slot.targets.size() >= kSlotTargets) {
    slot.targets.erase(std::min_element(
        slot.targets.begin(), slot.targets.end(),
        [](const auto& a, const auto& b) { return a->last_use < b->last_use; }));
  }
  auto t = std::make_unique<CachedTarget>();
  REFLCAP_ASSIGN_OR_RETURN(t->target, MakePassTarget(*ctx, w, h, 1, formats, final_layout, false,
                                                     gpu::PassWait::kPasses));
  t->width = w;
  t->height = h;
  t->layers = 1;
  t->last_use = use_counter;
  slot.targets.push_back(std::move(t));
  return slot.targets.back().get();
}

void VulkanRenderer::Impl::AddDeviceTimes(const Flight& flight) {
  if (flight.timestamps == nullptr) return;
  const uint32_t last = uint32_t(3 * flight.images.size());
  auto elapsed = [&](uint32_t a, uint32_t b) {
    StatusOr<double> s = flight.timestamps->ElapsedSeconds(a, b);
    return s.ok() ? *s : 0.0;
  };
  batch_stats.device_timed = true;
  batch_stats.device_s += elapsed(0, last);
  for (uint32_t k = 0; k < flight.images.size(); ++k) {
    batch_stats.device_shadow_s += elapsed(3 * k, 3 * k + 1);
    batch_stats.device_pass_s += elapsed(3 * k + 1, 3 * k + 2);
    batch_stats.device_outputs_s += elapsed(3 * k + 2, 3 * k + 3);
  }
}

StatusOr<CachedTarget*> VulkanRenderer::Impl::AcquireShadowMap(const ImagePlan& plan,
                                                               bool* reused) {
  const uint32_t res = uint32_t(plan.shadow_resolution), layers = plan.shadow_views;
  const std::vector<uint8_t> content = plan.ShadowContent();
  const uint64_t cache_bytes = uint64_t(options.shadow_cache_mib) << 20;
  *reused = false;
  CachedTarget* lru = nullptr;
  size_t same_shape = 0;
  uint64_t kept_bytes = 0;
  for (const std::unique_ptr<CachedTarget>& t : shadow_maps) {
    kept_bytes += t->Bytes();
    if (t->width != res || t->layers != layers) continue;
    if (cache_bytes > 0 && t->content == content) {
      // The same views at the same resolution: the map holds exactly what this image would draw
      // (the queue has drawn it before anything recorded after it runs).
      *reused = true;
      t->last_use = ++use_counter;
      t->batch = batch_counter;
      return t.get();
    }
    ++same_shape;
    if (lru == nullptr || t->last_use < lru->last_use) lru = t.get();
  }
  const uint64_t map_bytes = uint64_t(res) * res * layers * 4;
  const uint64_t capacity = std::max<uint64_t>(1, cache_bytes / std::max<uint64_t>(1, map_bytes));
  CachedTarget* target = nullptr;
  if (lru != nullptr && (same_shape >= capacity || kept_bytes + map_bytes > cache_bytes)) {
    // Redraw the least recently used map of this shape. Safe even if an image recorded earlier
    // samples it: its render pass waits for every earlier shader read of its attachment.
    target = lru;
  } else {
    REFLCAP_RETURN_IF_ERROR(ReleaseIdle(&shadow_maps));
    auto t = std::make_unique<CachedTarget>();
    // No transfer reads or writes a shadow map: its pass waits for earlier shader reads of it
    // (images sampling the map it redraws), not for earlier images' copies to the host.
    REFLCAP_ASSIGN_OR_RETURN(t->target,
                             MakePassTarget(*ctx, res, res, layers, {},
                                            VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL,
                                            /*sampled_depth=*/true, gpu::PassWait::kShaderReads));
    t->width = t->height = res;
    t->layers = layers;
    shadow_maps.push_back(std::move(t));
    target = shadow_maps.back().get();
  }
  target->content = content;
  target->last_use = ++use_counter;
  target->batch = batch_counter;
  return target;
}

// ---- Recording ------------------------------------------------------------------------------

Status VulkanRenderer::Impl::RecordImage(Flight& flight, size_t k, const ImagePlan& plan) {
  Slot& slot = flight.slots[k];
  const uint64_t out_bytes = plan.OutBytes();
  REFLCAP_RETURN_IF_ERROR(EnsureHostBuffer(*ctx, &slot.out_radiance, out_bytes));
  REFLCAP_RETURN_IF_ERROR(EnsureHostBuffer(*ctx, &slot.out_aux, out_bytes));
  if (plan.Supersampled()) {
    REFLCAP_RETURN_IF_ERROR(EnsureHostBuffer(*ctx, &slot.out_mask, out_bytes));
  }
  return plan.normal_map ? RecordNormalMapImage(flight, k, plan)
                         : RecordMeshImage(flight, k, plan);
}

Status VulkanRenderer::Impl::RecordMeshImage(Flight& flight, size_t k, const ImagePlan& plan) {
  Slot& slot = flight.slots[k];
  gpu::VkContext& c = *ctx;
  const uint64_t params_offset = 2 * k * params_stride;
  const uint64_t out_bytes = plan.OutBytes();
  const uint32_t w = uint32_t(plan.width), h = uint32_t(plan.height);
  const uint32_t n = uint32_t(plan.supersampling);

  // Targets.
  CachedTarget* shadow = nullptr;
  bool shadow_reused = false;
  if (plan.shadow_views > 0) {
    REFLCAP_ASSIGN_OR_RETURN(shadow, AcquireShadowMap(plan, &shadow_reused));
  }
  CachedTarget *camera = nullptr, *hires = nullptr, *visibility = nullptr;
  const std::vector<VkFormat> kCameraFormats = {VK_FORMAT_R32G32B32A32_SFLOAT,
                                                VK_FORMAT_R32G32B32A32_SFLOAT};
  if (plan.distorted) {
    const uint32_t vw = uint32_t(plan.vis_width), vh = uint32_t(plan.vis_height);
    const std::vector<VkFormat> formats = {VK_FORMAT_R32_UINT};
    REFLCAP_ASSIGN_OR_RETURN(
        visibility,
        flight.per_image_targets
            ? AcquireSlotTarget(slot, vw, vh, formats, VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL)
            : AcquireTarget(&visibility_targets, vw, vh, formats,
                            VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL));
  } else {
    REFLCAP_ASSIGN_OR_RETURN(
        camera, flight.per_image_targets
                    ? AcquireSlotTarget(slot, w, h, kCameraFormats,
                                        VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL)
                    : AcquireTarget(&camera_targets, w, h, kCameraFormats,
                                    VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL));
    if (plan.Supersampled()) {
      REFLCAP_ASSIGN_OR_RETURN(hires,
                               AcquireTarget(&hires_targets, w * n, h * n, kCameraFormats,
                                             VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL));
    }
  }
  REFLCAP_RETURN_IF_ERROR(EnsurePipelines(camera != nullptr ? camera : hires, visibility,
                                          ComputeShadowMaps() ? nullptr : shadow));

  // Descriptor sets of this slot (no submission using them is pending: the flight is idle).
  constexpr VkImageLayout kRead = VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL;
  const DeviceImage& shadow_image = shadow != nullptr ? *shadow->target->depth : *dummy_shadow;
  const Buffer& params = *flight.params;
  REFLCAP_RETURN_IF_ERROR(EnsureSet(c, &slot.light, light_layout));
  slot.light->WriteBuffer(kBindParams, params, params_offset, sizeof(sh::RenderParams));
  slot.light->WriteBuffer(kBindCorners, *corners);
  auto write_shading = [&](DescriptorSet& set, uint64_t offset) {
    set.WriteBuffer(kBindParams, params, offset, sizeof(sh::RenderParams));
    set.WriteBuffer(kBindCorners, *corners);
    set.WriteBuffer(kBindTriangles, *triangles);
    set.WriteImage(kBindMaterial, material->array_view(), sampler.handle(), kRead);
    set.WriteImage(kBindFrame, frame->array_view(), sampler.handle(), kRead);
    set.WriteImage(kBindShadowMap, shadow_image.array_view(), sampler.handle(), kRead);
  };
  if (plan.distorted) {
    REFLCAP_RETURN_IF_ERROR(EnsureSet(c, &slot.resolve, resolve_layout));
    write_shading(*slot.resolve, params_offset);
    slot.resolve->WriteImage(kBindSource, visibility->target->colors[0]->array_view(),
                             sampler.handle(), kRead);
    slot.resolve->WriteBuffer(kBindOutRadiance, *slot.out_radiance, 0, out_bytes);
    slot.resolve->WriteBuffer(kBindOutAux, *slot.out_aux, 0, out_bytes);
  } else {
    REFLCAP_RETURN_IF_ERROR(EnsureSet(c, &slot.camera, camera_layout));
    write_shading(*slot.camera, params_offset);
    if (plan.Supersampled()) {
      REFLCAP_RETURN_IF_ERROR(EnsureSet(c, &slot.hires, camera_layout));
      write_shading(*slot.hires, params_offset + params_stride);
      REFLCAP_RETURN_IF_ERROR(EnsureSet(c, &slot.downsample, downsample_layout));
      slot.downsample->WriteImage(kBindSource, hires->target->colors[0]->array_view(),
                                  sampler.handle(), kRead);
      slot.downsample->WriteBuffer(kBindOutRadiance, *slot.out_radiance, 0, out_bytes);
    }
  }

  // Record. Attachments shared with earlier images are safe to overwrite: each pass on them waits
  // for earlier reads of them (shared targets: BeginPass's barrier; shadow maps: their render
  // pass, PassWait::kShaderReads); a slot's own targets were last read by a submission whose
  // fence the host has seen.
  const VkCommandBuffer cb = flight.cmd.handle();
  const uint32_t stamp = uint32_t(1 + 3 * k);
  if (shadow != nullptr && !shadow_reused) {
    if (ComputeShadowMaps()) {
      REFLCAP_RETURN_IF_ERROR(RecordComputeShadowMap(flight, k, plan, *shadow));
    } else {
      gpu::RecordLightMapViews(cb, shadow_pipeline, slot.light->handle(), shadow->target->target,
                               plan.shadow_views, triangle_count);
    }
    ++batch_stats.shadow_maps_drawn;
  } else if (shadow != nullptr) {
    ++batch_stats.shadow_maps_reused;
  }
  Stamp(flight, stamp);
  if (plan.distorted) {
    BeginPass(cb, *visibility);
    Draw(cb, visibility_pipeline, *slot.light);
    visibility->target->target.End(cb);
    Stamp(flight, stamp + 1);
    resolve_pipeline.Bind(cb, slot.resolve->handle());
    vkCmdDispatch(cb, (w + kTile - 1) / kTile, (h + kTile - 1) / kTile, 1);
  } else {
    BeginPass(cb, *camera);
    Draw(cb, depth_pipeline, *slot.camera);
    Draw(cb, camera_pipeline, *slot.camera);
    camera->target->target.End(cb);
    Stamp(flight, stamp + 1);
    RecordCopyToBuffer(cb, *camera->target->colors[0],
                       plan.Supersampled() ? *slot.out_mask : *slot.out_radiance, plan.rect_x0,
                       plan.rect_y0, plan.rect_w, plan.rect_h);
    if (plan.aux) {
      RecordCopyToBuffer(cb, *camera->target->colors[1], *slot.out_aux, plan.rect_x0,
                         plan.rect_y0, plan.rect_w, plan.rect_h);
    }
    if (plan.Supersampled()) {
      BeginPass(cb, *hires);
      Draw(cb, depth_pipeline, *slot.hires);
      Draw(cb, camera_pipeline, *slot.hires);
      hires->target->target.End(cb);
      const sh::DownsamplePush push{w, h, n, 0};
      downsample_pipeline.Bind(cb, slot.downsample->handle());
      downsample_pipeline.Push(cb, &push, sizeof(push));
      vkCmdDispatch(cb, (w + kTile - 1) / kTile, (h + kTile - 1) / kTile, 1);
    }
  }
  Stamp(flight, stamp + 2);
  return OkStatus();
}

namespace {

// shadow_raster.comp's local_size_x: the invocations that share a triangle's texels.
constexpr uint64_t kRasterWorkgroup = 32;

// The most map texels one invocation of shadow_raster.comp visits for `mesh` in the views of
// `params` (resolution `res`): a triangle's bounding box (the shader's texel range, computed the
// same way) over the workgroup's invocations; the whole map for a triangle reaching behind a
// view's near plane, where the shader clips and this bound does not (an over-estimate).
uint64_t MostRasterTexelsPerInvocation(const TriangleMesh& mesh, const sh::RenderParams& params,
                                       uint32_t views, uint32_t res) {
  uint64_t most = 0;
  for (uint32_t v = 0; v < views; ++v) {
    const sh::vec4* rows = params.views[v].clip_from_object;
    for (const auto& tri : mesh.triangles) {
      double lo[2] = {1e30, 1e30}, hi[2] = {-1e30, -1e30};
      bool whole = false;
      for (int c = 0; c < 3; ++c) {
        const Vec3f& p = mesh.positions[tri[c]];
        double q[4];
        for (int r = 0; r < 4; ++r) {
          const sh::vec4& m = rows[r];
          q[r] = double(m.x) * p.x() + double(m.y) * p.y() + double(m.z) * p.z() + double(m.w);
        }
        if (!(q[2] >= 0 && q[3] > 0)) {
          whole = true;
          break;
        }
        for (int a = 0; a < 2; ++a) {
          lo[a] = std::min(lo[a], q[a] / q[3]);
          hi[a] = std::max(hi[a], q[a] / q[3]);
        }
      }
      uint64_t texels = uint64_t(res) * res;
      if (!whole) {
        uint64_t side[2];
        for (int a = 0; a < 2; ++a) {
          const double first = std::clamp(std::floor((lo[a] * 0.5 + 0.5) * res - 0.5), 0.0,
                                          double(res) - 1);
          const double last = std::clamp(std::ceil((hi[a] * 0.5 + 0.5) * res - 0.5), 0.0,
                                         double(res) - 1);
          side[a] = last >= first ? uint64_t(last - first) + 1 : 0;
        }
        texels = side[0] * side[1];
      }
      most = std::max(most, (texels + kRasterWorkgroup - 1) / kRasterWorkgroup);
    }
  }
  return most;
}

}  // namespace

Status VulkanRenderer::Impl::RecordComputeShadowMap(Flight& flight, size_t k,
                                                   const ImagePlan& plan, CachedTarget& shadow) {
  Slot& slot = flight.slots[k];
  gpu::VkContext& c = *ctx;
  const uint32_t res = uint32_t(plan.shadow_resolution), layers = plan.shadow_views;
  // A device that stops long loops silently (lavapipe) would leave texels of a large triangle
  // undrawn: refuse instead.
  const uint32_t budget = gpu::MaxLoopIterationsPerInvocation(c.info());
  if (budget != gpu::kNoLoopIterationLimit) {
    const uint64_t most =
        MostRasterTexelsPerInvocation(mesh_scene.scene->mesh(), plan.params, layers, res);
    if (gpu::LoopSteps(most) > budget) {
      return UnavailableError("a triangle covers up to ", most * kRasterWorkgroup,
                              " texels of a ", res,
                              "² shadow map, more than compute-drawn maps can visit on ",
                              c.info().name, " (", budget,
                              " loop steps per invocation): use ShadowRaster::kGraphics");
    }
  }
  const uint64_t bytes = uint64_t(res) * res * layers * sizeof(uint32_t);
  if (bytes > c.info().max_storage_buffer_range) {
    return UnavailableError("a compute-drawn ", res, "² shadow map of ", layers,
                            " views needs a storage buffer of ", bytes, " bytes, more than ",
                            c.info().name, " binds (maxStorageBufferRange ",
                            c.info().max_storage_buffer_range,
                            "): use ShadowRaster::kGraphics or a lower resolution");
  }
  if (raster_buffer == nullptr || raster_buffer->size() < bytes) {
    if (raster_buffer != nullptr) retired_raster_buffers.push_back(std::move(raster_buffer));
    REFLCAP_ASSIGN_OR_RETURN(Buffer b, Buffer::Create(c, bytes, gpu::MemoryKind::kDevice));
    raster_buffer = std::make_unique<Buffer>(std::move(b));
  }
  if (raster_pipeline.handle() == VK_NULL_HANDLE) {
    REFLCAP_ASSIGN_OR_RETURN(raster_layout,
                             DescriptorSetLayout::Create(c, {{kBindParams, kSsbo, kComp},
                                                             {kBindCorners, kSsbo, kComp},
                                                             {kBindShadowRaster, kSsbo, kComp}}));
    gpu::ComputeLayoutPipelineOptions o;
    o.shader = gpu::ShaderId::kRenderShadowRaster;
    o.set_layout = raster_layout.handle();
    o.push_constant_bytes = sizeof(sh::ShadowRasterPush);
    REFLCAP_ASSIGN_OR_RETURN(raster_pipeline, Pipeline::CreateCompute(c, o));
  }
  REFLCAP_RETURN_IF_ERROR(EnsureSet(c, &slot.raster, raster_layout));
  slot.raster->WriteBuffer(kBindParams, *flight.params, 2 * k * params_stride,
                           sizeof(sh::RenderParams));
  slot.raster->WriteBuffer(kBindCorners, *corners);
  slot.raster->WriteBuffer(kBindShadowRaster, *raster_buffer, 0, bytes);

  const VkCommandBuffer cb = flight.cmd.handle();
  // Earlier work that reads the raster buffer (the last map's copy) or this map (images that
  // sampled it before it is redrawn) finishes first; then the map may be overwritten.
  RecordMemoryBarrier(cb, VK_PIPELINE_STAGE_ALL_COMMANDS_BIT, VK_ACCESS_MEMORY_WRITE_BIT,
                      VK_PIPELINE_STAGE_TRANSFER_BIT,
                      VK_ACCESS_MEMORY_READ_BIT | VK_ACCESS_MEMORY_WRITE_BIT);
  gpu::DeviceImage& map = *shadow.target->depth;
  // From UNDEFINED whatever the tracked layout says (every texel is rewritten; and a batch
  // abandoned after recording leaves the tracked layout unsubmitted).
  map.set_layout(VK_IMAGE_LAYOUT_UNDEFINED);
  map.TransitionTo(cb, VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL);
  // Every texel starts at 1.0 (the pass's depth clear: nothing before the distance scale).
  constexpr uint32_t kOneBits = 0x3F800000u;
  vkCmdFillBuffer(cb, raster_buffer->handle(), 0, bytes, kOneBits);
  RecordTransferToCompute(cb);
  // One workgroup per triangle, at most 65,535 along x (the limit every device allows).
  constexpr uint32_t kMaxGroupsX = 65535;
  const uint32_t groups_x = std::min(triangle_count, kMaxGroupsX);
  const uint32_t groups_y = (triangle_count + groups_x - 1) / groups_x;
  raster_pipeline.Bind(cb, slot.raster->handle());
  for (uint32_t v = 0; v < layers; ++v) {
    const sh::ShadowRasterPush push{v, res, triangle_count, groups_x};
    raster_pipeline.Push(cb, &push, sizeof(push));
    vkCmdDispatch(cb, groups_x, groups_y, 1);
  }
  RecordMemoryBarrier(cb, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, VK_ACCESS_SHADER_WRITE_BIT,
                      VK_PIPELINE_STAGE_TRANSFER_BIT, VK_ACCESS_TRANSFER_READ_BIT);
  VkBufferImageCopy region{};
  region.imageSubresource = {VK_IMAGE_ASPECT_DEPTH_BIT, 0, 0, layers};
  region.imageExtent = {res, res, 1};
  vkCmdCopyBufferToImage(cb, raster_buffer->handle(), map.handle(),
                         VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, 1, &region);
  map.TransitionTo(cb, VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL);
  return OkStatus();
}

Status VulkanRenderer::Impl::RecordNormalMapImage(Flight& flight, size_t k,
                                                  const ImagePlan& plan) {
  Slot& slot = flight.slots[k];
  const uint64_t out_bytes = plan.OutBytes();
  constexpr VkImageLayout kRead = VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL;
  REFLCAP_RETURN_IF_ERROR(EnsureSet(*ctx, &slot.normal_map, normal_map_layout));
  DescriptorSet& set = *slot.normal_map;
  set.WriteBuffer(kBindParams, *flight.params, 2 * k * params_stride, sizeof(sh::RenderParams));
  set.WriteImage(kBindMaterial, material->array_view(), sampler.handle(), kRead);
  set.WriteBuffer(kBindOutRadiance, *slot.out_radiance, 0, out_bytes);
  set.WriteBuffer(kBindOutAux, *slot.out_aux, 0, out_bytes);
  set.WriteBuffer(kBindNormalMapTexels, *normal_map_texels);
  set.WriteBuffer(kBindHeightField, *height_field_buffer);
  const VkCommandBuffer cb = flight.cmd.handle();
  // Pixels without a texel stay 0 (background).
  vkCmdFillBuffer(cb, slot.out_radiance->handle(), 0, out_bytes, 0);
  vkCmdFillBuffer(cb, slot.out_aux->handle(), 0, out_bytes, 0);
  RecordTransferToCompute(cb);
  sh::NormalMapPush push{};
  push.texels = texel_count;
  push.march = plan.march;
  normal_map_pipeline.Bind(cb, set.handle());
  normal_map_pipeline.Push(cb, &push, sizeof(push));
  vkCmdDispatch(cb, (texel_count + kTexelGroup - 1) / kTexelGroup, 1, 1);
  for (uint32_t i = 1; i <= 3; ++i) Stamp(flight, uint32_t(3 * k + i));
  return OkStatus();
}

// ---- Batches --------------------------------------------------------------------------------

void VulkanRenderer::Impl::ReadBack(const Flight& flight, std::vector<RenderResult>* results) {
  const std::vector<ImagePlan>& all = *plans;
  const size_t count = flight.images.size();
  results->clear();
  results->resize(count);
  // Tasks: rows of one image, kReadbackPixelsPerTask pixels or more each.
  struct Task {
    size_t k;
    int y0, y1;
  };
  // Every row of each image: rows outside the rectangle are background (0), written here, so
  // that the images need no zero fill before (a whole extra write of every image: 9 MB of
  // 512 px images with aux buffers).
  std::vector<Task> tasks;
  for (size_t k = 0; k < count; ++k) {
    const ImagePlan& plan = all[flight.images[k]];
    const int rows = std::max(1, kReadbackPixelsPerTask / std::max(1, plan.width));
    for (int y = 0; y < plan.height; y += rows) {
      tasks.push_back({k, y, std::min(plan.height, y + rows)});
    }
  }
  if (readback_pool == nullptr && HardwareThreads() > 1 && tasks.size() > 1) {
    readback_pool = std::make_unique<WorkerPool>(HardwareThreads() - 1);
  }
  auto parallel = [&](int64_t n, const std::function<void(int64_t)>& body) {
    if (readback_pool != nullptr) {
      readback_pool->ParallelFor(n, body);
    } else {
      for (int64_t i = 0; i < n; ++i) body(i);
    }
  };
  // Allocation without values: the row tasks below write every one.
  for (size_t k = 0; k < count; ++k) {
    const ImagePlan& plan = all[flight.images[k]];
    RenderResult& r = (*results)[k];
    r.pixels = Image::Uninitialized(plan.width, plan.height, 3);
    r.mask = Image::Uninitialized(plan.width, plan.height, 1);
    if (plan.aux) r.aux = Image::Uninitialized(plan.width, plan.height, kAuxChannelCount);
  }
  // Pixels at shadow-map edges, per task (row-major within each image, tasks in image order).
  std::vector<std::vector<uint32_t>> edges(tasks.size());
  parallel(int64_t(tasks.size()), [&](int64_t t) {
    const Task& task = tasks[size_t(t)];
    const ImagePlan& plan = all[flight.images[task.k]];
    const Slot& slot = flight.slots[task.k];
    RenderResult& result = (*results)[task.k];
    const float* rad = static_cast<const float*>(slot.out_radiance->mapped());
    const float* ax = static_cast<const float*>(slot.out_aux->mapped());
    const float* mask = plan.Supersampled() ? static_cast<const float*>(slot.out_mask->mapped())
                                            : rad;
    // The radiance alpha is 1 where a surface was hit + 2 at a shadow edge (shading.glsl
    // kShadowEdgeAlpha; the supersampled pass's downsample carries the edge alone, its mask
    // comes from the 1x pass): the mask is bit 0 of the mask's alpha, the edge bit 1 of the
    // radiance's.
    const bool edges_wanted = !plan.normal_map && options.exact_shadow_edges &&
                              plan.options.cast_shadows;
    // Pixels outside the rectangle are 0: background, as the passes clear it.
    const auto zero = [&](size_t begin, size_t end) {
      if (end <= begin) return;
      std::fill(result.pixels.data.begin() + std::ptrdiff_t(3 * begin),
                result.pixels.data.begin() + std::ptrdiff_t(3 * end), 0.0f);
      std::fill(result.mask.data.begin() + std::ptrdiff_t(begin),
                result.mask.data.begin() + std::ptrdiff_t(end), 0.0f);
      if (plan.aux) {
        std::fill(result.aux.data.begin() + std::ptrdiff_t(kAuxChannelCount * begin),
                  result.aux.data.begin() + std::ptrdiff_t(kAuxChannelCount * end), 0.0f);
      }
    };
    for (int y = task.y0; y < task.y1; ++y) {
      const size_t row = size_t(y) * plan.width;
      if (y < plan.rect_y0 || y >= plan.rect_y0 + plan.rect_h) {
        zero(row, row + size_t(plan.width));
        continue;
      }
      const size_t begin = row + size_t(plan.rect_x0);
      const size_t end = begin + size_t(plan.rect_w);
      zero(row, begin);
      zero(end, row + size_t(plan.width));
      for (size_t i = begin; i < end; ++i) {
        for (int c = 0; c < 3; ++c) result.pixels.data[i * 3 + c] = rad[i * 4 + c];
        const float m = (int(mask[i * 4 + 3] + 0.5f) & 1) != 0 ? 1.0f : 0.0f;
        result.mask.data[i] = m;
        if (edges_wanted && (int(rad[i * 4 + 3] + 0.5f) & 2) != 0) {
          edges[size_t(t)].push_back(uint32_t(i));
        }
        if (plan.aux) {
          float* a = &result.aux.data[i * kAuxChannelCount];
          a[kAuxCastShadow] = ax[i * 4 + 0];
          a[kAuxCosThetaI] = ax[i * 4 + 1];
          a[kAuxCosThetaO] = ax[i * 4 + 2];
          a[kAuxCurvature] = ax[i * 4 + 3];
          a[kAuxMask] = m;
        }
      }
    }
  });
  // Those pixels shaded as the CPU reference renderer shades them, the images in parallel (a
  // few dozen pixels an image: one after another they were a quarter of the read-back on the
  // H200's host).
  const auto edge_start = std::chrono::steady_clock::now();
  std::vector<std::vector<uint32_t>> image_edges(count);
  size_t task = 0;
  for (size_t k = 0; k < count; ++k) {
    for (; task < tasks.size() && tasks[task].k == k; ++task) {
      image_edges[k].insert(image_edges[k].end(), edges[task].begin(), edges[task].end());
    }
    batch_stats.shadow_edge_pixels += image_edges[k].size();
  }
  parallel(int64_t(count), [&](int64_t k) {
    const std::vector<uint32_t>& pixels = image_edges[size_t(k)];
    if (pixels.empty()) return;
    const ImagePlan& plan = all[flight.images[size_t(k)]];
    const Status s = RenderPixels(mesh_scene, *plan.camera, *plan.light, plan.world_from_object,
                                  plan.exposure_s, plan.options, &mesh_curvature, pixels,
                                  &(*results)[size_t(k)]);
    // The plan checked camera and options, and the result has the plan's size.
    REFLCAP_CHECK(s.ok()) << s.ToString();
  });
  batch_stats.shadow_edge_s += SecondsSince(edge_start);
}

Status VulkanRenderer::Impl::CompleteOldest() {
  REFLCAP_CHECK(!in_flight.empty());
  Flight& flight = *in_flight.front();
  auto t = std::chrono::steady_clock::now();
  REFLCAP_RETURN_IF_ERROR(flight.cmd.Wait(ctx->options().submit_timeout_s));
  batch_stats.wait_s += SecondsSince(t);
  stats.gpu_seconds += flight.cmd.last_submit_wall_s();
  AddDeviceTimes(flight);
  t = std::chrono::steady_clock::now();
  std::vector<RenderResult> results;
  ReadBack(flight, &results);
  batch_stats.readback_s += SecondsSince(t);
  t = std::chrono::steady_clock::now();
  const std::vector<size_t> images = std::move(flight.images);
  flight.images.clear();
  in_flight.pop_front();
  for (size_t k = 0; k < images.size(); ++k) {
    REFLCAP_RETURN_IF_ERROR((*sink)(images[k], std::move(results[k])));
  }
  batch_stats.sink_s += SecondsSince(t);
  return OkStatus();
}

Status VulkanRenderer::Impl::Drain() {
  while (!in_flight.empty()) REFLCAP_RETURN_IF_ERROR(CompleteOldest());
  retired_raster_buffers.clear();  // nothing submitted can use them any more
  return OkStatus();
}

void VulkanRenderer::Impl::Abandon() {
  for (Flight* f : in_flight) {
    // No timeout: the flight's buffers must not be reused or freed while the device runs it.
    (void)f->cmd.Wait(1e30);
    f->images.clear();
  }
  in_flight.clear();
  for (const std::unique_ptr<Flight>& f : flights) f->images.clear();
  for (const std::unique_ptr<CachedTarget>& t : shadow_maps) t->content.clear();
}

Status VulkanRenderer::Impl::RenderPlans(const std::vector<ImagePlan>& all,
                                         const RenderSink& image_sink) {
  plans = &all;
  sink = &image_sink;
  const bool software = ctx->info().IsSoftware();
  const size_t max_images =
      options.batch_images > 0 ? size_t(options.batch_images)
                               : (software ? size_t{1} : size_t(kMaxBatchImages));
  const uint64_t budget = uint64_t(options.batch_readback_mib) << 20;
  while (flights.size() < size_t(options.batches_in_flight)) {
    auto f = std::make_unique<Flight>();
    REFLCAP_ASSIGN_OR_RETURN(f->cmd, gpu::CommandBuffer::Create(*ctx));
    flights.push_back(std::move(f));
  }
  const size_t ring = size_t(options.batches_in_flight);
  Status status = OkStatus();
  size_t next = 0;
  while (status.ok() && next < all.size()) {
    // The batch: consecutive images up to the image cap and the read-back budget (at least one).
    size_t end = next + 1;
    uint64_t bytes = all[next].ReadbackBytes();
    while (end < all.size() && end - next < max_images &&
           bytes + all[end].ReadbackBytes() <= budget) {
      bytes += all[end].ReadbackBytes();
      ++end;
    }
    Flight& flight = *flights[next_flight % ring];
    ++next_flight;
    // When the ring is full its next flight is the oldest one in flight: read that one back
    // (the device meanwhile renders the others).
    while (status.ok() && !flight.images.empty()) status = CompleteOldest();
    if (!status.ok()) break;
    const auto record_start = std::chrono::steady_clock::now();
    flight.batch = ++batch_counter;
    const size_t count = end - next;
    if (flight.slots.size() < count) flight.slots.resize(count);
    if (flight.params_capacity < 2 * count * params_stride) {
      flight.params.reset();
      flight.params_capacity = 0;
      auto buffer = Buffer::Create(*ctx, 2 * count * params_stride, gpu::MemoryKind::kDevice);
      status = buffer.status();
      if (status.ok()) {
        flight.params = std::make_unique<Buffer>(std::move(buffer).value());
        flight.params_capacity = 2 * count * params_stride;
      }
    }
    // A slot's own targets pay off only when an image's passes could wait for another's copy.
    flight.per_image_targets = options.per_image_targets && count > 1;
    const uint32_t queries = uint32_t(1 + 3 * count);
    if (status.ok() && options.profile_device && ctx->info().timestamp_valid_bits > 0 &&
        (flight.timestamps == nullptr || flight.timestamps->count() < queries)) {
      flight.timestamps.reset();
      auto pool = gpu::TimestampQueryPool::Create(*ctx, queries);
      status = pool.status();
      if (status.ok()) {
        flight.timestamps = std::make_unique<gpu::TimestampQueryPool>(std::move(pool).value());
      }
    }
    if (status.ok()) status = flight.cmd.Begin();
    if (status.ok() && flight.timestamps != nullptr) {
      status = flight.timestamps->Reset(flight.cmd);
    }
    if (status.ok()) {
      // The parameter blocks travel in the command buffer (vkCmdUpdateBuffer), then every
      // shader stage waits for them.
      const VkCommandBuffer cb = flight.cmd.handle();
      for (size_t k = 0; k < count; ++k) {
        const ImagePlan& plan = all[next + k];
        vkCmdUpdateBuffer(cb, flight.params->handle(), 2 * k * params_stride,
                          sizeof(sh::RenderParams), &plan.params);
        if (plan.Supersampled()) {
          vkCmdUpdateBuffer(cb, flight.params->handle(), (2 * k + 1) * params_stride,
                            sizeof(sh::RenderParams), &plan.hires_params);
        }
      }
      RecordMemoryBarrier(cb, VK_PIPELINE_STAGE_TRANSFER_BIT, VK_ACCESS_TRANSFER_WRITE_BIT,
                          VK_PIPELINE_STAGE_VERTEX_SHADER_BIT |
                              VK_PIPELINE_STAGE_FRAGMENT_SHADER_BIT |
                              VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                          VK_ACCESS_SHADER_READ_BIT);
      Stamp(flight, 0);
    }
    for (size_t k = 0; status.ok() && k < count; ++k) {
      status = RecordImage(flight, k, all[next + k]);
      flight.images.push_back(next + k);
    }
    if (status.ok()) status = flight.cmd.Submit();
    batch_stats.record_s += SecondsSince(record_start);
    if (!status.ok()) break;
    ++batch_stats.submissions;
    in_flight.push_back(&flight);
    next = end;
  }
  if (status.ok()) status = Drain();
  if (!status.ok()) Abandon();
  plans = nullptr;
  sink = nullptr;
  return status;
}

// ---- VulkanRenderer -------------------------------------------------------------------------

VulkanRenderer::VulkanRenderer() : impl_(std::make_unique<Impl>()) {}
VulkanRenderer::~VulkanRenderer() {
  if (impl_ != nullptr && impl_->ctx != nullptr) (void)impl_->ctx->WaitIdle();
  // Members go in reverse order of declaration: flights (their fences waited for), targets,
  // scene, pipelines, layouts; the owned context last (Impl declares it first).
}

StatusOr<std::unique_ptr<VulkanRenderer>> VulkanRenderer::Create(
    const std::string& device, const VulkanRenderOptions& options) {
  REFLCAP_RETURN_IF_ERROR(options.Validate());
  gpu::ContextOptions co;
  co.device = device;
  co.require_graphics = true;
  REFLCAP_ASSIGN_OR_RETURN(std::unique_ptr<gpu::VkContext> ctx, gpu::VkContext::Create(co));
  std::unique_ptr<VulkanRenderer> r(new VulkanRenderer());
  r->impl_->owned_ctx = std::move(ctx);
  r->impl_->ctx = r->impl_->owned_ctx.get();
  REFLCAP_RETURN_IF_ERROR(r->impl_->Init(options));
  return r;
}

StatusOr<std::unique_ptr<VulkanRenderer>> VulkanRenderer::Create(
    gpu::VkContext* ctx, const VulkanRenderOptions& options) {
  REFLCAP_CHECK(ctx != nullptr);
  if (!ctx->options().require_graphics) {
    return FailedPreconditionError(
        "VulkanRenderer needs a VkContext created with ContextOptions::require_graphics");
  }
  std::unique_ptr<VulkanRenderer> r(new VulkanRenderer());
  r->impl_->ctx = ctx;
  REFLCAP_RETURN_IF_ERROR(r->impl_->Init(options));
  return r;
}

const gpu::DeviceInfo& VulkanRenderer::device() const { return impl_->ctx->info(); }
const VulkanRenderOptions& VulkanRenderer::options() const { return impl_->options; }
const VulkanRenderStats& VulkanRenderer::last_stats() const { return impl_->stats; }
bool VulkanRenderer::computes_shadow_maps() const { return impl_->ComputeShadowMaps(); }
bool VulkanRenderer::resolves_pinhole_cameras() const { return impl_->ResolvePinhole(); }
const VulkanBatchStats& VulkanRenderer::last_batch_stats() const { return impl_->batch_stats; }

Status VulkanRenderer::SetScene(const ShadedScene& scene) {
  REFLCAP_CHECK(scene.scene && scene.atlas && scene.maps);
  Impl& m = *impl_;
  const TriangleMesh& mesh = scene.scene->mesh();
  const gpu::DeviceInfo& info = m.ctx->info();
  const uint64_t corner_bytes = uint64_t(mesh.TriangleCount()) * 3 * sizeof(sh::RenderCorner);
  if (mesh.TriangleCount() == 0) return InvalidArgumentError("SetScene: the mesh has no triangles");
  if (corner_bytes > info.max_storage_buffer_range) {
    return UnavailableError("a mesh of ", mesh.TriangleCount(), " triangles needs ", corner_bytes,
                            " bytes of corners, more than one storage buffer may span on ",
                            info.name, " (maxStorageBufferRange ", info.max_storage_buffer_range,
                            ")");
  }
  m.scene_kind = Impl::SceneKind::kNone;
  // Kept shadow maps show the old geometry.
  for (const std::unique_ptr<CachedTarget>& t : m.shadow_maps) t->content.clear();
  std::vector<sh::RenderCorner> corners(mesh.TriangleCount() * 3);
  std::vector<sh::RenderTriangle> triangles(mesh.TriangleCount());
  std::vector<float> curvature = SurfaceCurvature(mesh);
  const std::vector<std::array<int32_t, 3>> neighbours = TriangleNeighbours(mesh);
  for (size_t t = 0; t < mesh.TriangleCount(); ++t) {
    for (int c = 0; c < 3; ++c) {
      const Vec3f& p = mesh.positions[mesh.triangles[t][c]];
      const Vec2f& uv = mesh.corner_uvs[t][c];
      const Vec3f& n = mesh.corner_normals[t][c];
      corners[3 * t + c] = {{p.x(), p.y(), p.z(), uv.x()}, {n.x(), n.y(), n.z(), uv.y()}};
    }
    const Vec3f ng = mesh.GeometricNormal(t);
    const std::array<int32_t, 3>& nb = neighbours[t];
    triangles[t] = {{ng.x(), ng.y(), ng.z(), curvature[t]}, {nb[0], nb[1], nb[2], -1}};
  }
  m.corners.reset();
  m.triangles.reset();
  REFLCAP_ASSIGN_OR_RETURN(Buffer cb, gpu::CreateBufferFrom(*m.ctx, corners));
  m.corners = std::make_unique<Buffer>(std::move(cb));
  REFLCAP_ASSIGN_OR_RETURN(Buffer tb, gpu::CreateBufferFrom(*m.ctx, triangles));
  m.triangles = std::make_unique<Buffer>(std::move(tb));
  m.triangle_count = uint32_t(mesh.TriangleCount());
  REFLCAP_RETURN_IF_ERROR(m.UploadMaterial(*scene.atlas, *scene.maps));

  const Eigen::AlignedBox3f box = mesh.Bounds();
  m.sphere_centre = box.center().cast<double>();
  m.bounds = box.cast<double>();
  m.sphere_radius = 0.5 * box.diagonal().cast<double>().norm() * kSphereInflation;
  m.surface_offset = scene.scene->SurfaceOffset();
  m.mesh_scene = scene;
  m.mesh_curvature = std::move(curvature);
  m.scene_kind = Impl::SceneKind::kMesh;
  return OkStatus();
}

Status VulkanRenderer::SetNormalMapScene(const TexelAtlas& atlas, const BrdfMaps& maps,
                                         const Camera& camera, const HeightField* heights) {
  Impl& m = *impl_;
  if (atlas.TexelCount() == 0) return InvalidArgumentError("SetNormalMapScene: no texels");
  if (heights != nullptr &&
      (heights->width != atlas.width || heights->height != atlas.height ||
       heights->heights_px.size() != size_t(atlas.width) * size_t(atlas.height))) {
    return InvalidArgumentError("SetNormalMapScene: the height field is ", heights->width, "x",
                                heights->height, " but the normal map is ", atlas.width, "x",
                                atlas.height);
  }
  m.scene_kind = Impl::SceneKind::kNone;
  const std::vector<float> curvature = NormalMapCurvature(atlas, camera);
  std::vector<sh::NormalMapTexel> texels(atlas.TexelCount());
  for (size_t t = 0; t < atlas.TexelCount(); ++t) {
    int x, y;
    atlas.PixelOf(t, &x, &y);
    const Vec3f& n = atlas.shading_normal[t];
    const Vec3f& ta = atlas.tangent[t];
    const Vec3f& b = atlas.bitangent[t];
    texels[t] = {{n.x(), n.y(), n.z(), curvature[t]},
                 {ta.x(), ta.y(), ta.z(), 0},
                 {b.x(), b.y(), b.z(), 0},
                 {uint32_t(x), uint32_t(y), 0, 0}};
  }
  const uint64_t bytes = texels.size() * sizeof(sh::NormalMapTexel);
  if (bytes > m.ctx->info().max_storage_buffer_range) {
    return UnavailableError("a normal map of ", texels.size(),
                            " texels exceeds one storage buffer on ", m.ctx->info().name);
  }
  m.normal_map_texels.reset();
  REFLCAP_ASSIGN_OR_RETURN(Buffer tb, gpu::CreateBufferFrom(*m.ctx, texels));
  m.normal_map_texels = std::make_unique<Buffer>(std::move(tb));
  m.texel_count = uint32_t(texels.size());
  const std::vector<float> none(1, kHeightFieldOutside);
  const std::vector<float>& field = heights != nullptr ? heights->heights_px : none;
  if (field.size() * sizeof(float) > m.ctx->info().max_storage_buffer_range) {
    return UnavailableError("a height field of ", field.size(),
                            " pixels exceeds one storage buffer on ", m.ctx->info().name);
  }
  m.height_field_buffer.reset();
  m.height_field.reset();
  REFLCAP_ASSIGN_OR_RETURN(Buffer hb, gpu::CreateBufferFrom(*m.ctx, field));
  m.height_field_buffer = std::make_unique<Buffer>(std::move(hb));
  if (heights != nullptr) m.height_field = std::make_unique<HeightField>(*heights);
  REFLCAP_RETURN_IF_ERROR(m.UploadMaterial(atlas, maps));
  m.scene_kind = Impl::SceneKind::kNormalMap;
  return OkStatus();
}

StatusOr<RenderResult> VulkanRenderer::RenderImage(const Camera& camera, const Light& light,
                                                   const Rigid3& world_from_object,
                                                   double exposure_s,
                                                   const RenderOptions& options) {
  const auto start = std::chrono::steady_clock::now();
  REFLCAP_RETURN_IF_ERROR(options.Validate());
  Impl& m = *impl_;
  if (m.scene_kind != Impl::SceneKind::kMesh) {
    return FailedPreconditionError("VulkanRenderer::RenderImage: no mesh scene (SetScene)");
  }
  m.stats = VulkanRenderStats{};
  m.batch_stats = VulkanBatchStats{};
  REFLCAP_ASSIGN_OR_RETURN(ImagePlan plan,
                           m.PlanMeshImage(camera, light, world_from_object, exposure_s, options));
  m.stats = plan.stats;
  std::vector<ImagePlan> plans;
  plans.push_back(std::move(plan));
  RenderResult result;
  REFLCAP_RETURN_IF_ERROR(m.RenderPlans(plans, [&](size_t, RenderResult&& r) {
    result = std::move(r);
    return OkStatus();
  }));
  m.stats.shadow_map_reused = m.batch_stats.shadow_maps_reused > 0;
  m.batch_stats.images = 1;
  m.stats.seconds = m.batch_stats.seconds = SecondsSince(start);
  return result;
}

StatusOr<RenderResult> VulkanRenderer::RenderNormalMapImage(const Camera& camera,
                                                            const Light& light, double exposure_s,
                                                            const RenderOptions& options) {
  const auto start = std::chrono::steady_clock::now();
  REFLCAP_RETURN_IF_ERROR(options.Validate());
  Impl& m = *impl_;
  if (m.scene_kind != Impl::SceneKind::kNormalMap) {
    return FailedPreconditionError(
        "VulkanRenderer::RenderNormalMapImage: no normal-map scene (SetNormalMapScene)");
  }
  m.stats = VulkanRenderStats{};
  m.batch_stats = VulkanBatchStats{};
  REFLCAP_ASSIGN_OR_RETURN(ImagePlan plan,
                           m.PlanNormalMapImage(camera, light, exposure_s, options));
  std::vector<ImagePlan> plans;
  plans.push_back(std::move(plan));
  RenderResult result;
  REFLCAP_RETURN_IF_ERROR(m.RenderPlans(plans, [&](size_t, RenderResult&& r) {
    result = std::move(r);
    return OkStatus();
  }));
  m.batch_stats.images = 1;
  m.stats.seconds = m.batch_stats.seconds = SecondsSince(start);
  return result;
}

Status VulkanRenderer::RenderImages(const std::vector<RenderRequest>& requests,
                                   const RenderOptions& options, const RenderSink& sink) {
  const auto start = std::chrono::steady_clock::now();
  REFLCAP_RETURN_IF_ERROR(options.Validate());
  Impl& m = *impl_;
  if (m.scene_kind == Impl::SceneKind::kNone) {
    return FailedPreconditionError(
        "VulkanRenderer::RenderImages: no scene (SetScene or SetNormalMapScene)");
  }
  m.stats = VulkanRenderStats{};
  m.batch_stats = VulkanBatchStats{};
  // Every image is planned (and checked) before the first one renders.
  std::vector<ImagePlan> plans;
  plans.reserve(requests.size());
  for (size_t i = 0; i < requests.size(); ++i) {
    const RenderRequest& q = requests[i];
    const std::string label = q.label.empty() ? StrCat("requests[", i, "]") : q.label;
    if (q.camera == nullptr || q.light == nullptr) {
      return InvalidArgumentError(label, ": no camera or no light");
    }
    StatusOr<ImagePlan> plan =
        m.scene_kind == Impl::SceneKind::kMesh
            ? m.PlanMeshImage(*q.camera, *q.light, q.world_from_object, q.exposure_s, options)
            : m.PlanNormalMapImage(*q.camera, *q.light, q.exposure_s, options);
    if (!plan.ok()) return plan.status().WithContext(label);
    plans.push_back(std::move(plan).value());
  }
  const double plan_s = SecondsSince(start);
  Status status = m.RenderPlans(plans, sink);
  m.batch_stats.record_s += plan_s;
  if (!plans.empty()) {
    const double gpu_seconds = m.stats.gpu_seconds;
    m.stats = plans.back().stats;
    m.stats.gpu_seconds = gpu_seconds;
  }
  m.batch_stats.images = status.ok() ? plans.size() : 0;
  m.stats.seconds = m.batch_stats.seconds = SecondsSince(start);
  return status;
}

StatusOr<std::vector<RenderResult>> VulkanRenderer::RenderImages(
    const std::vector<RenderRequest>& requests, const RenderOptions& options) {
  std::vector<RenderResult> results(requests.size());
  REFLCAP_RETURN_IF_ERROR(RenderImages(requests, options, [&](size_t i, RenderResult&& r) {
    results[i] = std::move(r);
    return OkStatus();
  }));
  return results;
}

}  // namespace reflcap::render
