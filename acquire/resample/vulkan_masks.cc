// The Vulkan masks (see vulkan_masks.h): scene upload, per-photograph parameters (camera and light
// in the object frame, light views, camera-map grid), the recording of the light, camera and
// per-texel passes into one submission, and the read-back into ImageOutput.
#include "acquire/resample/vulkan_masks.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <limits>
#include <map>
#include <utility>
#include <vector>

#include "engine/gpu/vk_buffer.h"
#include "engine/gpu/vk_commands.h"
#include "engine/gpu/depth_pass.h"
#include "engine/gpu/vk_context.h"
#include "engine/gpu/vk_descriptors.h"
#include "engine/gpu/vk_graphics_pipeline.h"
#include "engine/gpu/vk_image.h"
#include "engine/gpu/vk_view.h"
#include "shaders/shared/resample_masks.h"

namespace reflcap::resample {
namespace {

namespace sh = gpu::shared;
using gpu::Buffer;
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

static_assert(sh::kMaskKept == uint32_t(Outcome::kKept) &&
              sh::kMaskGrazingView == uint32_t(Outcome::kGrazingView) &&
              sh::kMaskEdgeOutside == uint32_t(Outcome::kEdgeOutside) &&
              sh::kMaskOccluded == uint32_t(Outcome::kOccluded) &&
              sh::kMaskGrazingLight == uint32_t(Outcome::kGrazingLight) &&
              sh::kMaskShadowed == uint32_t(Outcome::kShadowed) &&
              sh::kMaskEdgeSurface == uint32_t(Outcome::kEdgeSurface) &&
              sh::kMaskEdgeShadow == uint32_t(Outcome::kEdgeShadow) &&
              sh::kMaskInvalid == uint32_t(Outcome::kInvalid) &&
              sh::kMaskClipped == uint32_t(Outcome::kClipped) &&
              sh::kMaskDark == uint32_t(Outcome::kDark) &&
              sh::kMaskEdgeTexel == uint32_t(Outcome::kEdgeTexel) && kOutcomeCount == 12,
              "shaders/shared/resample_masks.h outcome codes must equal resample::Outcome");

static_assert(sh::kMaskMinResolvedTexelPixels == kMinResolvedTexelPixels,
              "shaders/shared/resample_masks.h must hold resample::kMinResolvedTexelPixels");

// The light pass (gpu::LightMapPass) pushes a LightMapPush; mask_light.frag reads a MaskDrawPush.
static_assert(sizeof(sh::MaskDrawPush) == sizeof(sh::LightMapPush),
              "MaskDrawPush must have LightMapPush's layout (a single uint view)");

// Descriptor bindings (shaders/resample/masks_common.glsl).
constexpr uint32_t kBindParams = 0, kBindCorners = 1, kBindTriangles = 2, kBindLightMap = 3,
                   kBindCameraMap = 4, kBindTexels = 5, kBindRays = 6, kBindPixels = 7,
                   kBindOutcomes = 8, kBindSamples = 9, kBindVariance = 10,
                   kBindCameraNormal = 11, kBindTexelOfPixel = 12;
// MaskParams::relative_sigma_floor.y: 1 when binding 10 holds the photograph's variance image
// (images[].variance) and masks.comp takes each sample's noise from it (z, w: kDarkSigmas and
// kInvalidSigmas), 0 when the noise model (MaskParams::noise) applies.
constexpr float kUseVarianceImage = 1.0f;
// Camera-map texels around the undistorted footprint of a distorted photograph: nearest-texel
// rounding reaches half a texel beyond the outermost pixel ray.
constexpr int kMapMargin = 2;
// Largest camera map per side relative to the photograph: beyond it the distortion is too strong
// for one pinhole rasterisation (fisheye lenses).
constexpr double kMaxMapRatio = 4;
// Texel chunks are multiples of this many texels, so every chunk's byte offset is a multiple of
// any minStorageBufferOffsetAlignment (<= 256 bytes by the Vulkan spec; 1024 x 4 bytes).
constexpr uint64_t kChunkAlignTexels = 1024;

using gpu::Homogeneous;
using gpu::kSphereInflation;
using gpu::MakePassTarget;
using gpu::PassTarget;
using gpu::SetRows;
using gpu::V4;

void SetRigidRows(const Rigid3& t, sh::vec4 rows[3]) {
  for (int r = 0; r < 3; ++r) {
    rows[r] = {float(t.rotation(r, 0)), float(t.rotation(r, 1)), float(t.rotation(r, 2)),
               float(t.translation(r))};
  }
}

// The camera-map grid of one camera and, for a pinhole camera, the undistorted normalised
// coordinates of every pixel's ray (Camera::PixelRay), uploaded once.
struct CameraGrid {
  int width = 0, height = 0;
  double fx = 1, fy = 1, skew = 0, cx = 0, cy = 0;
  std::unique_ptr<Buffer> rays;
};

// Bytes of one of a camera's photographs as Process binds it (RGB floats, one storage-buffer
// binding): Process refuses, and VulkanMasksOnGpu reports, cameras above the device's range.
uint64_t PhotographBytes(const Camera& camera) {
  return uint64_t(std::max(camera.width, 0)) * uint64_t(std::max(camera.height, 0)) * 3 *
         sizeof(float);
}

}  // namespace

Status VulkanMaskOptions::Validate() const {
  REFLCAP_RETURN_IF_ERROR(gpu::ValidateLightMapResolution(
      "light", light_texels_per_pixel, min_light_resolution, max_light_resolution,
      max_cube_resolution));
  if (!(light_bias_texels >= 0 && light_bias_texels <= 16)) {
    return InvalidArgumentError("light_bias_texels must be in [0, 16], got ", light_bias_texels);
  }
  if (!(camera_bias_pixels >= 0 && camera_bias_pixels <= 16)) {
    return InvalidArgumentError("camera_bias_pixels must be in [0, 16], got ", camera_bias_pixels);
  }
  if (!(plane_limit_footprints >= 0 && plane_limit_footprints <= 1000)) {
    return InvalidArgumentError("plane_limit_footprints must be in [0, 1000], got ",
                                plane_limit_footprints);
  }
  return OkStatus();
}

struct VulkanMasks::Impl {
  const Capture* capture = nullptr;
  const TexelAtlas* atlas = nullptr;
  NoiseModel noise;
  double min_cos = 0;
  double surface_offset = 0;
  VulkanMaskOptions options;
  VulkanMaskStats stats;

  std::unique_ptr<gpu::VkContext> ctx;
  gpu::CommandBuffer cmd;
  gpu::Sampler sampler;
  gpu::LightMapPass light_pass;
  DescriptorSetLayout camera_layout, texel_layout;
  DescriptorSet camera_set;
  std::vector<DescriptorSet> texel_sets;  // one per texel chunk
  Pipeline camera_pipeline, texel_pipeline;

  std::unique_ptr<Buffer> params, corners, triangle_normals, texels, pixels, outcomes, samples,
      map_readback, no_rays, variances, texel_of_pixel;
  std::map<int, CameraGrid> grids;  // by camera index
  std::unique_ptr<PassTarget> camera_target;
  uint32_t triangle_count = 0;
  uint32_t texel_count = 0;
  uint32_t chunk_texels = 0;
  Vec3d centre = Vec3d::Zero();
  double radius = 0;

  Status Init(const TriangleMesh& mesh);
  StatusOr<CameraGrid*> Grid(int camera_index);
  Status EnsureCameraTarget(uint32_t w, uint32_t h);
  void Draw(const Pipeline& pipeline, const DescriptorSet& set, uint32_t view) {
    pipeline.Bind(cmd.handle(), set.handle());
    const sh::MaskDrawPush push{view};
    pipeline.Push(cmd.handle(), &push, sizeof(push));
    vkCmdDraw(cmd.handle(), 3 * triangle_count, 1, 0, 0);
  }
};

Status VulkanMasks::Impl::Init(const TriangleMesh& mesh) {
  gpu::VkContext& c = *ctx;
  REFLCAP_RETURN_IF_ERROR(gpu::CheckPassFormats(c, {VK_FORMAT_R32G32B32A32_SFLOAT}, "masks"));
  REFLCAP_ASSIGN_OR_RETURN(cmd, gpu::CommandBuffer::Create(c));
  REFLCAP_ASSIGN_OR_RETURN(sampler, gpu::Sampler::Create(c));
  REFLCAP_ASSIGN_OR_RETURN(
      light_pass, gpu::LightMapPass::Create(c, {gpu::ShaderId::kResampleMaskDrawVert,
                                                gpu::ShaderId::kResampleMaskLightFrag, kBindParams,
                                                kBindCorners}));
  REFLCAP_ASSIGN_OR_RETURN(camera_layout,
                           DescriptorSetLayout::Create(c, {{kBindParams, kSsbo, kGfx},
                                                           {kBindCorners, kSsbo, kGfx},
                                                           {kBindTriangles, kSsbo, kGfx},
                                                           {kBindLightMap, kTex, kGfx},
                                                           {kBindTexelOfPixel, kSsbo, kGfx}}));
  REFLCAP_ASSIGN_OR_RETURN(texel_layout,
                           DescriptorSetLayout::Create(c, {{kBindParams, kSsbo, kComp},
                                                           {kBindCorners, kSsbo, kComp},
                                                           {kBindLightMap, kTex, kComp},
                                                           {kBindCameraMap, kTex, kComp},
                                                           {kBindTexels, kSsbo, kComp},
                                                           {kBindRays, kSsbo, kComp},
                                                           {kBindPixels, kSsbo, kComp},
                                                           {kBindOutcomes, kSsbo, kComp},
                                                           {kBindSamples, kSsbo, kComp},
                                                           {kBindVariance, kSsbo, kComp},
                                                           {kBindCameraNormal, kTex, kComp},
                                                           {kBindTexelOfPixel, kSsbo, kComp}}));
  REFLCAP_ASSIGN_OR_RETURN(camera_set, DescriptorSet::Create(c, camera_layout));
  REFLCAP_ASSIGN_OR_RETURN(
      texel_pipeline,
      Pipeline::CreateCompute(c, {gpu::ShaderId::kResampleMasks, texel_layout.handle(),
                                  uint32_t(sizeof(sh::MaskTexelPush)),
                                  {gpu::SpecConstant::Uint(gpu::kLocalSizeXConstantId,
                                                           sh::kMaskWorkgroupSize)}}));
  REFLCAP_RETURN_IF_ERROR(EnsureHostBuffer(c, &params, sizeof(sh::MaskParams)));
  REFLCAP_RETURN_IF_ERROR(EnsureHostBuffer(c, &no_rays, 16));

  // Scene: de-indexed corners, triangle normals (the CPU's float GeometricNormal), texels.
  triangle_count = uint32_t(mesh.TriangleCount());
  if (triangle_count == 0) return InvalidArgumentError("the mesh has no triangles");
  // The camera pass writes the triangle index as a float (exact below 2^24).
  if (mesh.TriangleCount() >= (size_t(1) << 24)) {
    return UnavailableError("Vulkan masks: the mesh's ", mesh.TriangleCount(),
                            " triangles exceed the camera map's 2^24");
  }
  std::vector<sh::MaskCorner> corner_data(size_t(triangle_count) * 3);
  std::vector<sh::vec4> normal_data(triangle_count);
  Eigen::AlignedBox3d box;
  for (uint32_t t = 0; t < triangle_count; ++t) {
    const Vec3f n_g = mesh.GeometricNormal(t);
    normal_data[t] = {n_g.x(), n_g.y(), n_g.z(), 0};
    for (int k = 0; k < 3; ++k) {
      const Vec3f& p = mesh.positions[mesh.triangles[t][k]];
      const Vec3f n = mesh.corner_normals.empty() ? n_g : mesh.corner_normals[t][k];
      // The UV rides in the w components for the camera pass's texel lookup (resample_masks.h).
      const Vec2f uv = mesh.corner_uvs.empty() ? Vec2f::Zero() : mesh.corner_uvs[t][k];
      corner_data[3 * t + k] = {{p.x(), p.y(), p.z(), uv.x()}, {n.x(), n.y(), n.z(), uv.y()}};
      box.extend(p.cast<double>());
    }
  }
  centre = box.center();
  radius = 0;
  for (const Vec3f& p : mesh.positions) radius = std::max(radius, (p.cast<double>() - centre).norm());
  radius = std::max(radius * kSphereInflation, 1e-9);  // a single point still gets a sphere
  const uint64_t max_range = c.info().max_storage_buffer_range;
  if (corner_data.size() * sizeof(sh::MaskCorner) > max_range) {
    return UnavailableError("Vulkan masks: the mesh's ", triangle_count, " triangles exceed the ",
                            "device's storage-buffer range of ", max_range, " bytes");
  }
  {
    REFLCAP_ASSIGN_OR_RETURN(Buffer b, gpu::CreateBufferFrom(c, corner_data));
    corners = std::make_unique<Buffer>(std::move(b));
  }
  {
    REFLCAP_ASSIGN_OR_RETURN(Buffer b, gpu::CreateBufferFrom(c, normal_data));
    triangle_normals = std::make_unique<Buffer>(std::move(b));
  }
  const TexelAtlas& a = *atlas;
  texel_count = uint32_t(a.TexelCount());
  std::vector<sh::MaskTexel> texel_data(texel_count);
  const std::vector<float> sides = TexelSidesM(mesh, a);
  for (uint32_t t = 0; t < texel_count; ++t) {
    const Vec3f& p = a.position[t];
    const Vec3f& n = a.shading_normal[t];
    const Vec3f& g = a.geometric_normal[t];
    const Vec3f& tg = a.tangent[t];
    texel_data[t] = {{p.x(), p.y(), p.z(), sides[t]},
                     {n.x(), n.y(), n.z(), 0},
                     {g.x(), g.y(), g.z(), 0},
                     {tg.x(), tg.y(), tg.z(), 0}};
  }
  {
    REFLCAP_ASSIGN_OR_RETURN(Buffer b, gpu::CreateBufferFrom(c, texel_data));
    texels = std::make_unique<Buffer>(std::move(b));
  }
  // The camera pass writes the hit's texel index as a float (exact below 2^24).
  if (texel_count >= (1u << 24)) {
    return UnavailableError("Vulkan masks: ", texel_count, " texels exceed the camera map's 2^24");
  }
  if (uint64_t(a.texel_of_pixel.size()) * sizeof(int32_t) > max_range) {
    return UnavailableError("Vulkan masks: the ", a.width, "x", a.height, " atlas exceeds the ",
                            "device's storage-buffer range of ", max_range, " bytes");
  }
  {
    REFLCAP_ASSIGN_OR_RETURN(Buffer b, gpu::CreateBufferFrom(c, a.texel_of_pixel));
    texel_of_pixel = std::make_unique<Buffer>(std::move(b));
  }
  REFLCAP_RETURN_IF_ERROR(EnsureHostBuffer(c, &outcomes, uint64_t(texel_count) * sizeof(uint32_t)));
  REFLCAP_RETURN_IF_ERROR(
      EnsureHostBuffer(c, &samples, uint64_t(texel_count) * sizeof(sh::MaskSample)));
  // Chunks: the largest multiple of kChunkAlignTexels whose texel records fit one binding.
  uint64_t fit = max_range / sizeof(sh::MaskTexel) / kChunkAlignTexels * kChunkAlignTexels;
  if (fit == 0) return UnavailableError("Vulkan masks: storage-buffer range too small");
  if (options.max_chunk_texels > 0) {
    fit = std::min<uint64_t>(
        fit, std::max<uint64_t>(options.max_chunk_texels / kChunkAlignTexels, 1) * kChunkAlignTexels);
  }
  chunk_texels = uint32_t(std::min<uint64_t>(fit, texel_count));
  const uint32_t chunks = (texel_count + chunk_texels - 1) / chunk_texels;
  for (uint32_t i = 0; i < chunks; ++i) {
    REFLCAP_ASSIGN_OR_RETURN(DescriptorSet set, DescriptorSet::Create(c, texel_layout));
    texel_sets.push_back(std::move(set));
  }
  return OkStatus();
}

StatusOr<CameraGrid*> VulkanMasks::Impl::Grid(int camera_index) {
  auto it = grids.find(camera_index);
  if (it != grids.end()) return &it->second;
  const Camera& camera = capture->cameras[camera_index];
  CameraGrid g;
  g.width = camera.width;
  g.height = camera.height;
  if (camera.model == CameraModel::kPinhole) {
    g.fx = camera.K(0, 0);
    g.fy = camera.K(1, 1);
    g.skew = camera.K(0, 1);
    g.cx = camera.K(0, 2);
    g.cy = camera.K(1, 2);
    const size_t n = size_t(camera.width) * camera.height;
    std::vector<sh::vec2> rays(n);
    double umin = 1e300, umax = -1e300, vmin = 1e300, vmax = -1e300;
    for (int y = 0; y < camera.height; ++y) {
      for (int x = 0; x < camera.width; ++x) {
        Vec3d o, d;
        camera.PixelRay({double(x), double(y)}, &o, &d);
        const double xn = d.x() / d.z(), yn = d.y() / d.z();
        rays[size_t(y) * camera.width + x] = {float(xn), float(yn)};
        const double u = g.fx * xn + g.skew * yn, v = g.fy * yn;
        umin = std::min(umin, u);
        umax = std::max(umax, u);
        vmin = std::min(vmin, v);
        vmax = std::max(vmax, v);
      }
    }
    if (camera.HasDistortion()) {
      // The undistorted grid covering every pixel's ray, with a margin.
      g.cx = kMapMargin - umin;
      g.cy = kMapMargin - vmin;
      const double w = std::ceil(umax - umin) + 2 * kMapMargin + 1;
      const double h = std::ceil(vmax - vmin) + 2 * kMapMargin + 1;
      if (!(w <= kMaxMapRatio * camera.width + 64 && h <= kMaxMapRatio * camera.height + 64)) {
        return InvalidArgumentError("camera \"", camera.id, "\": its distortion spreads the image "
                                    "over an undistorted footprint of ", w, "x", h,
                                    " px, too wide for one pinhole camera map");
      }
      g.width = int(w);
      g.height = int(h);
    }
    if (rays.size() * sizeof(sh::vec2) > ctx->info().max_storage_buffer_range) {
      return UnavailableError("Vulkan masks: camera \"", camera.id, "\" has too many pixels for "
                              "one storage-buffer binding");
    }
    REFLCAP_ASSIGN_OR_RETURN(Buffer b, gpu::CreateBufferFrom(*ctx, rays));
    g.rays = std::make_unique<Buffer>(std::move(b));
  }
  return &grids.emplace(camera_index, std::move(g)).first->second;
}

Status VulkanMasks::Impl::EnsureCameraTarget(uint32_t w, uint32_t h) {
  if (camera_target != nullptr && camera_target->width == w && camera_target->height == h) {
    return OkStatus();
  }
  camera_target.reset();
  REFLCAP_ASSIGN_OR_RETURN(camera_target,
                           MakePassTarget(*ctx, w, h, 1,
                                          {VK_FORMAT_R32G32B32A32_SFLOAT,
                                           VK_FORMAT_R32G32B32A32_SFLOAT},
                                          VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL, false));
  if (camera_pipeline.handle() == VK_NULL_HANDLE) {
    gpu::GraphicsPipelineOptions o;
    o.vertex = gpu::ShaderId::kResampleMaskDrawVert;
    o.fragment = gpu::ShaderId::kResampleMaskCameraFrag;
    o.set_layout = camera_layout.handle();
    o.push_constant_bytes = sizeof(sh::MaskDrawPush);
    REFLCAP_ASSIGN_OR_RETURN(camera_pipeline,
                             Pipeline::CreateGraphics(*ctx, o, camera_target->target));
  }
  return OkStatus();
}

VulkanMasks::VulkanMasks() : impl_(new Impl()) {}
VulkanMasks::~VulkanMasks() {
  if (impl_ != nullptr && impl_->ctx != nullptr) (void)impl_->ctx->WaitIdle();
  // Everything created from the context goes before it.
  if (impl_ != nullptr) {
    std::unique_ptr<gpu::VkContext> ctx = std::move(impl_->ctx);
    impl_.reset();
  }
}

const std::string& VulkanMasks::device_name() const { return impl_->ctx->info().name; }
bool VulkanMasks::software_device() const { return impl_->ctx->info().IsSoftware(); }
const VulkanMaskStats& VulkanMasks::last_stats() const { return impl_->stats; }

StatusOr<std::unique_ptr<VulkanMasks>> VulkanMasks::Create(const Capture& capture,
                                                           const TexelAtlas& atlas,
                                                           const TriangleMesh& mesh,
                                                           float surface_offset,
                                                           const NoiseModel& noise, double min_cos,
                                                           const VulkanMaskOptions& options) {
  REFLCAP_RETURN_IF_ERROR(options.Validate());
  const std::string file = capture.json_path.string();
  if (capture.normal_map.has_value()) {
    return InvalidArgumentError(file, ": a normal-map capture has no mesh to rasterise (its "
                                "texels are visible and unshadowed by construction)");
  }
  if (!(min_cos >= 0 && min_cos < 1)) {
    return InvalidArgumentError("min_cos must be in [0, 1), got ", min_cos);
  }
  if (!(noise.photon_sigma_at_1 >= 0) || !(noise.read_sigma >= 0) ||
      !std::isfinite(noise.photon_sigma_at_1) || !std::isfinite(noise.read_sigma)) {
    return InvalidArgumentError("noise model sigmas must be finite and >= 0");
  }
  if (!(surface_offset >= 0) || !std::isfinite(surface_offset)) {
    return InvalidArgumentError("surface_offset must be finite and >= 0");
  }
  for (size_t i = 0; i < capture.cameras.size(); ++i) {
    const Camera& cam = capture.cameras[i];
    if (cam.model == CameraModel::kOrthographic && !(cam.pixel_size_m > 0)) {
      return FailedPreconditionError(file, ": cameras[", i, "].pixel_size_m: an orthographic "
                                     "camera needs it to project a mesh");
    }
  }
  if (atlas.TexelCount() == 0) return InvalidArgumentError("the atlas has no texels");
  std::unique_ptr<VulkanMasks> m(new VulkanMasks());
  Impl& impl = *m->impl_;
  impl.capture = &capture;
  impl.atlas = &atlas;
  impl.noise = noise;
  impl.min_cos = min_cos;
  impl.surface_offset = surface_offset;
  impl.options = options;
  gpu::ContextOptions co;
  co.device = options.device;
  co.require_graphics = true;
  auto ctx = gpu::VkContext::Create(co);
  if (!ctx.ok()) {
    return Status(ctx.status().code(),
                  StrCat("--backend vulkan: ", ctx.status().message()));
  }
  impl.ctx = std::move(*ctx);
  REFLCAP_RETURN_IF_ERROR(impl.Init(mesh));
  return m;
}

Status VulkanMasks::Process(uint32_t image_index, const Image& pixels, ImageOutput* out,
                            CameraMapView* map, const Image* variance) {
  Impl& m = *impl_;
  const Capture& capture = *m.capture;
  REFLCAP_RETURN_IF_ERROR(CheckPhotograph(capture, image_index, pixels, variance));
  const CaptureImage& image = capture.images[image_index];
  const Camera& camera = capture.cameras[image.camera];
  const std::string field = StrCat(capture.json_path.string(), ": images[", image_index, "].file");
  gpu::VkContext& ctx = *m.ctx;
  m.stats = VulkanMaskStats{};
  const int w = camera.width, h = camera.height;
  const bool pinhole = camera.model == CameraModel::kPinhole;
  REFLCAP_ASSIGN_OR_RETURN(CameraGrid * grid, m.Grid(image.camera));

  // Camera and light in the object frame (as ImageResampler's Frame).
  const Rigid3 world_from_object = capture.WorldFromObject(image);
  const Rigid3 object_from_world = world_from_object.Inverse();
  const Rigid3 cam_from_object = camera.cam_from_world * world_from_object;
  const Rigid3 object_from_cam = cam_from_object.Inverse();
  const Light& light = capture.lights[image.light];
  const bool point_light = light.type == LightType::kPoint;
  const Vec3d light_in_object = object_from_world * light.position;
  const Vec3d light_dir_in_object = (object_from_world.rotation * light.direction).normalized();

  const double centre_z = (cam_from_object * m.centre).z();
  double near = 0, far = 0;
  gpu::CameraDepthRange(pinhole, centre_z, m.radius, &near, &far);

  sh::MaskParams p{};
  const Mat4d object_to_cam = Homogeneous(cam_from_object);
  if (pinhole) {
    SetRows(gpu::PinholeClipFromCam(grid->fx, grid->fy, grid->skew, grid->cx, grid->cy,
                                    grid->width, grid->height, near, far) *
                object_to_cam,
            p.camera_clip_from_object);
  } else {
    SetRows(gpu::OrthoClipFromCam(camera.pixel_size_m, w, h, near, far) * object_to_cam,
            p.camera_clip_from_object);
  }
  SetRigidRows(cam_from_object, p.cam_from_object);
  SetRigidRows(object_from_cam, p.object_from_cam);
  p.camera_centre = V4(object_from_cam.translation, 1);
  p.toward_cam = V4((-object_from_cam.rotation.col(2)).normalized(), 0);
  const double footprint_scale =
      pinhole ? 1.0 / std::min(std::abs(camera.K(0, 0)), std::abs(camera.K(1, 1)))
              : camera.pixel_size_m;
  p.intrinsics = {float(camera.K(0, 0)), float(camera.K(1, 1)), float(camera.K(0, 2)),
                  float(camera.K(1, 2))};
  p.intrinsics_extra = {float(camera.K(0, 1)), float(camera.pixel_size_m), float(footprint_scale),
                        0};
  p.distortion = {float(camera.dist[0]), float(camera.dist[1]), float(camera.dist[2]),
                  float(camera.dist[3])};
  p.distortion_extra = {float(camera.dist[4]), 0, 0, 0};
  p.map_intrinsics = {float(grid->fx), float(grid->fy), float(grid->cx), float(grid->cy)};
  p.map_intrinsics_extra = {float(grid->skew), float(m.atlas->width), float(m.atlas->height), 0};
  p.light = point_light ? V4(light_in_object, 1) : V4(light_dir_in_object, 0);
  p.intensity = V4(light.intensity, image.exposure_s);
  const double photon = m.noise.photon_sigma_at_1, read = m.noise.read_sigma;
  p.noise = {float(photon * photon), float(read * read), float(m.noise.DarkFloor()),
             float(m.noise.InvalidFloor())};
  p.tests = {float(m.min_cos), float(image.saturation), float(kEdgeDepthSlack),
             float(m.surface_offset)};
  p.bias = {float(m.options.light_bias_texels), float(m.options.plane_limit_footprints),
            float(m.options.camera_bias_pixels), float(m.options.plane_limit_footprints)};
  p.relative_sigma_floor = {float(kRelativeSigmaFloor), variance != nullptr ? kUseVarianceImage : 0,
                            float(kDarkSigmas), float(kInvalidSigmas)};
  p.flags = (pinhole ? sh::kMaskFlagPinhole : 0u) | (point_light ? sh::kMaskFlagPointLight : 0u) |
            (pinhole && camera.HasDistortion() ? sh::kMaskFlagDistortion : 0u) |
            (m.options.sample_point == SamplePoint::kPixel ? sh::kMaskFlagPixelSample : 0u) |
            (m.options.pixel_filter.value_or(camera.pixel_filter) == PixelFilter::kPoint
                 ? sh::kMaskFlagPointPixels
                 : 0u);
  p.width = uint32_t(w);
  p.height = uint32_t(h);
  p.map_width = uint32_t(pinhole ? grid->width : w);
  p.map_height = uint32_t(pinhole ? grid->height : h);
  p.image_index = image_index;

  // Light views and resolution: light_texels_per_pixel light-map texels per photograph pixel at
  // the object's centre, within the bounds.
  const VulkanMaskOptions& vo = m.options;
  // Pixel size at the object's centre; at least one radius away (a camera inside the sphere).
  const double pixel_m =
      pinhole ? std::max(centre_z, m.radius) / camera.K(0, 0) : camera.pixel_size_m;
  gpu::LightMapResolution resolution;
  resolution.texels_per_pixel = vo.light_texels_per_pixel;
  resolution.pixel_m = pixel_m;
  resolution.min_resolution = vo.min_light_resolution;
  resolution.max_resolution = vo.max_light_resolution;
  resolution.max_cube_resolution = vo.max_cube_resolution;
  REFLCAP_ASSIGN_OR_RETURN(
      const gpu::LightMapPlan plan,
      gpu::PlanLightMap(point_light, light_in_object, light_dir_in_object, m.centre, m.radius,
                        gpu::LightMapShape::kAuto, resolution));
  std::copy(plan.views, plan.views + plan.view_count, p.views);
  const uint32_t views = plan.view_count;
  const int res = plan.resolution;
  m.stats.light_map = plan.kind;
  p.num_light_views = views;
  p.light_resolution = uint32_t(res);
  m.stats.light_resolution = res;
  m.stats.map_width = int(p.map_width);
  m.stats.map_height = int(p.map_height);

  // Buffers, targets and descriptor sets (rewritten only here, between submissions).
  const uint64_t pixel_bytes = PhotographBytes(camera);
  if (pixel_bytes > ctx.info().max_storage_buffer_range) {
    return UnavailableError("Vulkan masks: ", field, " has ", uint64_t(w) * h,
                            " pixels, more than one storage-buffer binding holds (",
                            ctx.info().max_storage_buffer_range, " bytes)");
  }
  REFLCAP_RETURN_IF_ERROR(EnsureHostBuffer(ctx, &m.pixels, pixel_bytes));
  std::memcpy(m.pixels->mapped(), pixels.data.data(), pixel_bytes);
  if (variance != nullptr) {
    REFLCAP_RETURN_IF_ERROR(EnsureHostBuffer(ctx, &m.variances, pixel_bytes));
    std::memcpy(m.variances->mapped(), variance->data.data(), pixel_bytes);
  }
  // Without a variance image binding 10 must still hold a buffer; the shader does not read it.
  const Buffer& variance_buffer = variance != nullptr ? *m.variances : *m.pixels;
  std::memcpy(m.params->mapped(), &p, sizeof(p));
  REFLCAP_RETURN_IF_ERROR(m.light_pass.EnsureTarget(ctx, uint32_t(res), views));
  REFLCAP_RETURN_IF_ERROR(m.EnsureCameraTarget(p.map_width, p.map_height));
  constexpr VkImageLayout kRead = VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL;
  m.light_pass.WriteBuffers(*m.params, *m.corners);
  m.camera_set.WriteBuffer(kBindParams, *m.params);
  m.camera_set.WriteBuffer(kBindCorners, *m.corners);
  m.camera_set.WriteBuffer(kBindTriangles, *m.triangle_normals);
  m.camera_set.WriteBuffer(kBindTexelOfPixel, *m.texel_of_pixel);
  m.camera_set.WriteImage(kBindLightMap, m.light_pass.depth().array_view(), m.sampler.handle(),
                          kRead);
  const Buffer& rays = pinhole ? *grid->rays : *m.no_rays;
  for (size_t c = 0; c < m.texel_sets.size(); ++c) {
    const uint64_t first = uint64_t(c) * m.chunk_texels;
    const uint64_t count = std::min<uint64_t>(m.chunk_texels, m.texel_count - first);
    DescriptorSet& set = m.texel_sets[c];
    set.WriteBuffer(kBindParams, *m.params);
    set.WriteBuffer(kBindCorners, *m.corners);
    set.WriteBuffer(kBindTexelOfPixel, *m.texel_of_pixel);
    set.WriteImage(kBindLightMap, m.light_pass.depth().array_view(), m.sampler.handle(), kRead);
    set.WriteImage(kBindCameraMap, m.camera_target->colors[0]->array_view(), m.sampler.handle(),
                   kRead);
    set.WriteImage(kBindCameraNormal, m.camera_target->colors[1]->array_view(),
                   m.sampler.handle(), kRead);
    set.WriteBuffer(kBindTexels, *m.texels, first * sizeof(sh::MaskTexel),
                    count * sizeof(sh::MaskTexel));
    set.WriteBuffer(kBindRays, rays);
    set.WriteBuffer(kBindPixels, *m.pixels, 0, pixel_bytes);
    set.WriteBuffer(kBindVariance, variance_buffer, 0, pixel_bytes);
    set.WriteBuffer(kBindOutcomes, *m.outcomes, first * sizeof(uint32_t), count * sizeof(uint32_t));
    set.WriteBuffer(kBindSamples, *m.samples, first * sizeof(sh::MaskSample),
                    count * sizeof(sh::MaskSample));
  }
  const uint64_t map_bytes = uint64_t(p.map_width) * p.map_height * 16;
  if (map != nullptr) REFLCAP_RETURN_IF_ERROR(EnsureHostBuffer(ctx, &m.map_readback, map_bytes));

  // Record: light views, camera map, texels, (camera map read-back).
  REFLCAP_RETURN_IF_ERROR(m.cmd.Begin());
  VkCommandBuffer cb = m.cmd.handle();
  m.light_pass.Record(cb, views, m.triangle_count);
  m.camera_target->target.Begin(cb, 0, {});  // colour 0: background (no hit)
  m.Draw(m.camera_pipeline, m.camera_set, sh::kMaskCameraView);
  m.camera_target->target.End(cb);
  for (size_t c = 0; c < m.texel_sets.size(); ++c) {
    const uint32_t first = uint32_t(c) * m.chunk_texels;
    const sh::MaskTexelPush push{first, std::min(m.chunk_texels, m.texel_count - first)};
    m.texel_pipeline.Bind(cb, m.texel_sets[c].handle());
    m.texel_pipeline.Push(cb, &push, sizeof(push));
    vkCmdDispatch(cb, (push.count + sh::kMaskWorkgroupSize - 1) / sh::kMaskWorkgroupSize, 1, 1);
  }
  if (map != nullptr) {
    REFLCAP_RETURN_IF_ERROR(
        gpu::RecordCopyImageToBuffer(m.cmd, *m.camera_target->colors[0], 0, *m.map_readback, 0));
  }
  REFLCAP_RETURN_IF_ERROR(m.cmd.SubmitAndWait());
  m.stats.gpu_seconds = m.cmd.last_submit_wall_s();

  // Read back.
  const size_t texels = m.texel_count;
  const auto* outcome = static_cast<const uint32_t*>(m.outcomes->mapped());
  const auto* sample = static_cast<const sh::MaskSample*>(m.samples->mapped());
  out->outcome.resize(texels);
  out->kept.clear();
  out->primary_rays = out->tap_shadow_rays = out->visibility_rays = out->shadow_rays = 0;
  for (size_t t = 0; t < texels; ++t) {
    const uint32_t o = outcome[t];
    if (o >= uint32_t(kOutcomeCount)) {
      return InternalError("Vulkan masks: texel ", t, " got outcome code ", o);
    }
    out->outcome[t] = uint8_t(o);
    if (o != sh::kMaskKept) continue;
    TexelSample s;
    s.texel = uint32_t(t);
    std::memcpy(s.sample.wi, sample[t].wi, sizeof(s.sample.wi));
    std::memcpy(s.sample.wo, sample[t].wo, sizeof(s.sample.wo));
    std::memcpy(s.sample.value, sample[t].value, sizeof(s.sample.value));
    std::memcpy(s.sample.weight, sample[t].weight, sizeof(s.sample.weight));
    s.sample.image = image_index;
    out->kept.push_back(s);
  }
  if (map != nullptr) {
    map->width = int(p.map_width);
    map->height = int(p.map_height);
    const size_t n = size_t(map->width) * map->height;
    const auto* texel = static_cast<const float*>(m.map_readback->mapped());
    map->distance.resize(n);
    map->hit.resize(n);
    map->lit.resize(n);
    for (size_t i = 0; i < n; ++i) {
      map->distance[i] = texel[4 * i];
      map->lit[i] = texel[4 * i + 1] > 0.5f;
      map->hit[i] = texel[4 * i + 2] > 0.5f;
    }
    map->pinhole = pinhole;
    map->cam_from_object = cam_from_object;
    map->fx = grid->fx;
    map->fy = grid->fy;
    map->skew = grid->skew;
    map->cx = grid->cx;
    map->cy = grid->cy;
    map->pixel_size_m = camera.pixel_size_m;
    map->footprint_scale = footprint_scale;
  }
  return OkStatus();
}

Status VulkanMasksAvailable(const std::string& device) {
  return VulkanMasksOnGpu(device).status();
}

StatusOr<bool> VulkanMasksOnGpu(const std::string& device, const Capture* capture) {
  gpu::ContextOptions co;
  co.device = device;
  co.require_graphics = true;
  auto ctx = gpu::VkContext::Create(co);
  if (!ctx.ok()) {
    return Status(ctx.status().code(), StrCat("--backend vulkan: ", ctx.status().message()));
  }
  const gpu::DeviceInfo& info = (*ctx)->info();
  for (size_t i = 0; capture != nullptr && i < capture->cameras.size(); ++i) {
    const Camera& camera = capture->cameras[i];
    if (PhotographBytes(camera) > info.max_storage_buffer_range) {
      return UnavailableError(capture->json_path.string(), ": cameras[", i, "]: ", camera.width,
                              "x", camera.height, " photographs are more than one storage-buffer "
                              "binding of ", info.name, " holds (", info.max_storage_buffer_range,
                              " bytes)");
    }
  }
  return !info.IsSoftware();
}

}  // namespace reflcap::resample
