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
              sh::kMaskDark == uint32_t(Outcome::kDark) && kOutcomeCount == 11,
              "shaders/shared/resample_masks.h outcome codes must equal resample::Outcome");

// Descriptor bindings (shaders/resample/masks_common.glsl).
constexpr uint32_t kBindParams = 0, kBindCorners = 1, kBindTriangles = 2, kBindLightMap = 3,
                   kBindCameraMap = 4, kBindTexels = 5, kBindRays = 6, kBindPixels = 7,
                   kBindOutcomes = 8, kBindSamples = 9;
// Bounding-sphere inflation: geometry exactly on the sphere stays inside every frustum.
constexpr double kSphereInflation = 1.01;
// A point light farther than this many bounding radii from the centre gets one fitted frustum
// (~10x the texels on the object that a cube face gives); nearer, a cube map.
constexpr double kFitMargin = 1.05;
// Cube-map near plane relative to the bounding radius: occluders closer to a point light than
// this are clipped (a light that close to a surface is outside any real rig).
constexpr double kCubeNearFraction = 1e-3;
// Camera near plane as a fraction of the far plane when the camera is inside the bounding
// sphere: keeps float depth usable (geometry nearer than that is clipped).
constexpr double kMinNearFraction = 1e-4;
// Camera-map texels around the undistorted footprint of a distorted photograph: nearest-texel
// rounding reaches half a texel beyond the outermost pixel ray.
constexpr int kMapMargin = 2;
// Largest camera map per side relative to the photograph: beyond it the distortion is too strong
// for one pinhole rasterisation (fisheye lenses).
constexpr double kMaxMapRatio = 4;
// Texel chunks are multiples of this many texels, so every chunk's byte offset is a multiple of
// any minStorageBufferOffsetAlignment (<= 256 bytes by the Vulkan spec; 1024 x 4 bytes).
constexpr uint64_t kChunkAlignTexels = 1024;

using gpu::Basis;
using gpu::Homogeneous;
using gpu::SetRows;
using gpu::V4;
using gpu::ViewMatrix;

void SetRigidRows(const Rigid3& t, sh::vec4 rows[3]) {
  for (int r = 0; r < 3; ++r) {
    rows[r] = {float(t.rotation(r, 0)), float(t.rotation(r, 1)), float(t.rotation(r, 2)),
               float(t.translation(r))};
  }
}

sh::MaskView PerspectiveView(const Vec3d& origin, const Vec3d& forward, const Vec3d& right,
                             const Vec3d& up, double tan_half, double near, double far) {
  sh::MaskView v{};
  Mat4d proj = Mat4d::Zero();
  proj(0, 0) = 1 / tan_half;
  proj(1, 1) = 1 / tan_half;
  proj(2, 2) = far / (far - near);
  proj(2, 3) = -far * near / (far - near);
  proj(3, 2) = 1;
  SetRows(proj * ViewMatrix(origin, forward, right, up), v.clip_from_object);
  v.origin = V4(origin, 1);
  // Distance scale: the longest ray inside the frustum (to a far corner).
  v.forward = V4(forward, far * std::sqrt(1 + 2 * tan_half * tan_half));
  v.right = V4(right, tan_half);
  v.up = V4(up, tan_half);
  return v;
}

sh::MaskView OrthographicView(const Vec3d& origin, const Vec3d& forward, const Vec3d& right,
                              const Vec3d& up, double half_width, double depth) {
  sh::MaskView v{};
  Mat4d proj = Mat4d::Zero();
  proj(0, 0) = 1 / half_width;
  proj(1, 1) = 1 / half_width;
  proj(2, 2) = 1 / depth;
  proj(3, 3) = 1;
  SetRows(proj * ViewMatrix(origin, forward, right, up), v.clip_from_object);
  v.origin = V4(origin, 0);
  v.forward = V4(forward, depth);  // distance scale: the box's depth
  v.right = V4(right, half_width);
  v.up = V4(up, half_width);
  return v;
}

// Images of one pass and their render target (held by pointer: the target keeps their addresses).
struct PassTarget {
  std::unique_ptr<DeviceImage> color;  // null for the depth-only light pass
  std::unique_ptr<DeviceImage> depth;
  RenderTarget target;
  uint32_t width = 0, height = 0, layers = 0;
};

StatusOr<std::unique_ptr<PassTarget>> MakePassTarget(gpu::VkContext& ctx, uint32_t w, uint32_t h,
                                                     uint32_t layers, bool with_color) {
  auto t = std::make_unique<PassTarget>();
  t->width = w;
  t->height = h;
  t->layers = layers;
  std::vector<DeviceImage*> colors;
  if (with_color) {
    gpu::ImageOptions o;
    o.width = w;
    o.height = h;
    o.format = VK_FORMAT_R32G32B32A32_SFLOAT;
    o.usage = VK_IMAGE_USAGE_COLOR_ATTACHMENT_BIT | VK_IMAGE_USAGE_SAMPLED_BIT;
    REFLCAP_ASSIGN_OR_RETURN(DeviceImage img, DeviceImage::Create(ctx, o));
    t->color = std::make_unique<DeviceImage>(std::move(img));
    colors.push_back(t->color.get());
  }
  gpu::ImageOptions d;
  d.width = w;
  d.height = h;
  d.layers = layers;
  d.format = VK_FORMAT_D32_SFLOAT;
  d.usage = VK_IMAGE_USAGE_DEPTH_STENCIL_ATTACHMENT_BIT |
            (with_color ? VkImageUsageFlags{0} : VkImageUsageFlags{VK_IMAGE_USAGE_SAMPLED_BIT});
  REFLCAP_ASSIGN_OR_RETURN(DeviceImage depth, DeviceImage::Create(ctx, d));
  t->depth = std::make_unique<DeviceImage>(std::move(depth));
  REFLCAP_ASSIGN_OR_RETURN(
      t->target,
      RenderTarget::Create(ctx, colors, t->depth.get(), VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL,
                           with_color ? VK_IMAGE_LAYOUT_DEPTH_STENCIL_ATTACHMENT_OPTIMAL
                                      : VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL));
  return t;
}

// The camera-map grid of one camera and, for a pinhole camera, the undistorted normalised
// coordinates of every pixel's ray (Camera::PixelRay), uploaded once.
struct CameraGrid {
  int width = 0, height = 0;
  double fx = 1, fy = 1, skew = 0, cx = 0, cy = 0;
  std::unique_ptr<Buffer> rays;
};

}  // namespace

Status VulkanMaskOptions::Validate() const {
  if (!(light_texels_per_pixel > 0 && light_texels_per_pixel <= 64)) {
    return InvalidArgumentError("light_texels_per_pixel must be in (0, 64], got ",
                                light_texels_per_pixel);
  }
  for (int r : {min_light_resolution, max_light_resolution, max_cube_resolution}) {
    if (r < 16 || r > 16384) {
      return InvalidArgumentError("light-map resolution bounds must be in [16, 16384], got ", r);
    }
  }
  if (min_light_resolution > max_light_resolution) {
    return InvalidArgumentError("min_light_resolution ", min_light_resolution,
                                " exceeds max_light_resolution ", max_light_resolution);
  }
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
  DescriptorSetLayout light_layout, camera_layout, texel_layout;
  DescriptorSet light_set, camera_set;
  std::vector<DescriptorSet> texel_sets;  // one per texel chunk
  Pipeline light_pipeline, camera_pipeline, texel_pipeline;

  std::unique_ptr<Buffer> params, corners, triangle_normals, texels, pixels, outcomes, samples,
      map_readback, no_rays;
  std::map<int, CameraGrid> grids;  // by camera index
  std::unique_ptr<PassTarget> light_target, camera_target;
  uint32_t triangle_count = 0;
  uint32_t texel_count = 0;
  uint32_t chunk_texels = 0;
  Vec3d centre = Vec3d::Zero();
  double radius = 0;

  Status Init(const TriangleMesh& mesh);
  StatusOr<CameraGrid*> Grid(int camera_index);
  Status EnsureLightTarget(uint32_t res, uint32_t layers);
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
  if (!gpu::FormatSupports(
          c, VK_FORMAT_R32G32B32A32_SFLOAT,
          VK_FORMAT_FEATURE_COLOR_ATTACHMENT_BIT | VK_FORMAT_FEATURE_SAMPLED_IMAGE_BIT) ||
      !gpu::FormatSupports(
          c, VK_FORMAT_D32_SFLOAT,
          VK_FORMAT_FEATURE_DEPTH_STENCIL_ATTACHMENT_BIT | VK_FORMAT_FEATURE_SAMPLED_IMAGE_BIT)) {
    return UnavailableError("Vulkan device ", c.info().name,
                            " cannot render to and sample RGBA32F and D32 images (masks)");
  }
  REFLCAP_ASSIGN_OR_RETURN(cmd, gpu::CommandBuffer::Create(c));
  REFLCAP_ASSIGN_OR_RETURN(sampler, gpu::Sampler::Create(c));
  constexpr VkDescriptorType kSsbo = VK_DESCRIPTOR_TYPE_STORAGE_BUFFER;
  constexpr VkDescriptorType kTex = VK_DESCRIPTOR_TYPE_COMBINED_IMAGE_SAMPLER;
  constexpr VkShaderStageFlags kGfx = VK_SHADER_STAGE_VERTEX_BIT | VK_SHADER_STAGE_FRAGMENT_BIT;
  constexpr VkShaderStageFlags kComp = VK_SHADER_STAGE_COMPUTE_BIT;
  REFLCAP_ASSIGN_OR_RETURN(
      light_layout,
      DescriptorSetLayout::Create(c, {{kBindParams, kSsbo, kGfx}, {kBindCorners, kSsbo, kGfx}}));
  REFLCAP_ASSIGN_OR_RETURN(camera_layout,
                           DescriptorSetLayout::Create(c, {{kBindParams, kSsbo, kGfx},
                                                           {kBindCorners, kSsbo, kGfx},
                                                           {kBindTriangles, kSsbo, kGfx},
                                                           {kBindLightMap, kTex, kGfx}}));
  REFLCAP_ASSIGN_OR_RETURN(texel_layout,
                           DescriptorSetLayout::Create(c, {{kBindParams, kSsbo, kComp},
                                                           {kBindLightMap, kTex, kComp},
                                                           {kBindCameraMap, kTex, kComp},
                                                           {kBindTexels, kSsbo, kComp},
                                                           {kBindRays, kSsbo, kComp},
                                                           {kBindPixels, kSsbo, kComp},
                                                           {kBindOutcomes, kSsbo, kComp},
                                                           {kBindSamples, kSsbo, kComp}}));
  REFLCAP_ASSIGN_OR_RETURN(light_set, DescriptorSet::Create(c, light_layout));
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
  std::vector<sh::MaskCorner> corner_data(size_t(triangle_count) * 3);
  std::vector<sh::vec4> normal_data(triangle_count);
  Eigen::AlignedBox3d box;
  for (uint32_t t = 0; t < triangle_count; ++t) {
    const Vec3f n_g = mesh.GeometricNormal(t);
    normal_data[t] = {n_g.x(), n_g.y(), n_g.z(), 0};
    for (int k = 0; k < 3; ++k) {
      const Vec3f& p = mesh.positions[mesh.triangles[t][k]];
      const Vec3f n = mesh.corner_normals.empty() ? n_g : mesh.corner_normals[t][k];
      corner_data[3 * t + k] = {{p.x(), p.y(), p.z(), 0}, {n.x(), n.y(), n.z(), 0}};
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
  for (uint32_t t = 0; t < texel_count; ++t) {
    const Vec3f& p = a.position[t];
    const Vec3f& n = a.shading_normal[t];
    const Vec3f& g = a.geometric_normal[t];
    const Vec3f& tg = a.tangent[t];
    texel_data[t] = {{p.x(), p.y(), p.z(), 0}, {n.x(), n.y(), n.z(), 0}, {g.x(), g.y(), g.z(), 0},
                     {tg.x(), tg.y(), tg.z(), 0}};
  }
  {
    REFLCAP_ASSIGN_OR_RETURN(Buffer b, gpu::CreateBufferFrom(c, texel_data));
    texels = std::make_unique<Buffer>(std::move(b));
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

Status VulkanMasks::Impl::EnsureLightTarget(uint32_t res, uint32_t layers) {
  if (light_target != nullptr && light_target->width == res && light_target->layers == layers) {
    return OkStatus();
  }
  light_target.reset();
  REFLCAP_ASSIGN_OR_RETURN(light_target, MakePassTarget(*ctx, res, res, layers, false));
  if (light_pipeline.handle() == VK_NULL_HANDLE) {
    gpu::GraphicsPipelineOptions o;
    o.vertex = gpu::ShaderId::kResampleMaskDrawVert;
    o.fragment = gpu::ShaderId::kResampleMaskLightFrag;
    o.set_layout = light_layout.handle();
    o.push_constant_bytes = sizeof(sh::MaskDrawPush);
    o.color_writes = false;
    REFLCAP_ASSIGN_OR_RETURN(light_pipeline,
                             Pipeline::CreateGraphics(*ctx, o, light_target->target));
  }
  return OkStatus();
}

Status VulkanMasks::Impl::EnsureCameraTarget(uint32_t w, uint32_t h) {
  if (camera_target != nullptr && camera_target->width == w && camera_target->height == h) {
    return OkStatus();
  }
  camera_target.reset();
  REFLCAP_ASSIGN_OR_RETURN(camera_target, MakePassTarget(*ctx, w, h, 1, true));
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
                            CameraMapView* map) {
  Impl& m = *impl_;
  const Capture& capture = *m.capture;
  REFLCAP_RETURN_IF_ERROR(CheckPhotograph(capture, image_index, pixels));
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
  double near = pinhole ? std::max(centre_z - m.radius, (centre_z + m.radius) * kMinNearFraction)
                        : std::max(0.0, centre_z - m.radius);
  double far = centre_z + m.radius;
  if (!(far > 0) || !(far > near)) {
    near = 1e-3;
    far = 1.0;  // the object is behind the camera: every texel projects outside anyway
  }

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
  p.map_intrinsics_extra = {float(grid->skew), 0, 0, 0};
  p.light = point_light ? V4(light_in_object, 1) : V4(light_dir_in_object, 0);
  p.intensity = V4(light.intensity, image.exposure_s);
  const double photon = m.noise.photon_sigma_at_1, read = m.noise.read_sigma;
  p.noise = {float(photon * photon), float(read * read), float(m.noise.DarkFloor()),
             float(m.noise.InvalidFloor())};
  p.tests = {float(m.min_cos), float(image.saturation), float(kEdgeDepthSlack),
             float(m.surface_offset)};
  p.bias = {float(m.options.light_bias_texels), float(m.options.plane_limit_footprints),
            float(m.options.camera_bias_pixels), float(m.options.plane_limit_footprints)};
  p.relative_sigma_floor = {float(kRelativeSigmaFloor), 0, 0, 0};
  p.flags = (pinhole ? sh::kMaskFlagPinhole : 0u) | (point_light ? sh::kMaskFlagPointLight : 0u) |
            (pinhole && camera.HasDistortion() ? sh::kMaskFlagDistortion : 0u);
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
  auto resolution_for = [&](double extent_m, int max_res) {
    // A non-finite ratio (degenerate camera) takes the largest map.
    const double texels = std::ceil(vo.light_texels_per_pixel * extent_m / pixel_m);
    return int(std::clamp(std::isfinite(texels) ? texels : double(max_res),
                          double(std::min(vo.min_light_resolution, max_res)), double(max_res)));
  };
  uint32_t views = 0;
  int res = 0;
  if (point_light) {
    const Vec3d to_centre = m.centre - light_in_object;
    const double dist = to_centre.norm();
    if (dist > kFitMargin * m.radius) {
      const Vec3d forward = to_centre / dist;
      Vec3d right, up;
      Basis(forward, &right, &up);
      const double tan_half = std::tan(std::asin(m.radius / dist)) * kSphereInflation;
      // Near plane at the sphere, but at least 1e-3 of the distance (float depth precision).
      const double f_near = std::max(dist - m.radius, dist * 1e-3) / kSphereInflation;
      const double f_far = (dist + m.radius) * kSphereInflation;
      res = resolution_for(2 * dist * tan_half, vo.max_light_resolution);
      p.views[0] = PerspectiveView(light_in_object, forward, right, up, tan_half, f_near, f_far);
      views = 1;
      m.stats.light_map = "fitted";
    } else {
      const double c_far = (dist + m.radius) * kSphereInflation;
      const double c_near = m.radius * kCubeNearFraction;
      res = resolution_for(2 * std::max(dist, m.radius), vo.max_cube_resolution);
      for (int face = 0; face < 6; ++face) {
        const int axis = face / 2;
        const double sign = face % 2 == 0 ? 1 : -1;
        Vec3d forward = Vec3d::Zero(), right = Vec3d::Zero(), up = Vec3d::Zero();
        forward[axis] = sign;
        right[(axis + 1) % 3] = 1;
        up[(axis + 2) % 3] = 1;
        p.views[face] = PerspectiveView(light_in_object, forward, right, up, 1.0, c_near, c_far);
      }
      views = 6;
      m.stats.light_map = "cube";
    }
  } else {
    const Vec3d forward = -light_dir_in_object;
    Vec3d right, up;
    Basis(forward, &right, &up);
    const double half = m.radius * kSphereInflation;
    const Vec3d origin = m.centre - forward * (half * kSphereInflation);
    res = resolution_for(2 * half, vo.max_light_resolution);
    p.views[0] = OrthographicView(origin, forward, right, up, half,
                                  2 * half * kSphereInflation * kSphereInflation);
    views = 1;
    m.stats.light_map = "orthographic";
  }
  p.num_light_views = views;
  p.light_resolution = uint32_t(res);
  m.stats.light_resolution = res;
  m.stats.map_width = int(p.map_width);
  m.stats.map_height = int(p.map_height);

  // Buffers, targets and descriptor sets (rewritten only here, between submissions).
  const uint64_t pixel_bytes = uint64_t(w) * h * 3 * sizeof(float);
  if (pixel_bytes > ctx.info().max_storage_buffer_range) {
    return UnavailableError("Vulkan masks: ", field, " has ", uint64_t(w) * h,
                            " pixels, more than one storage-buffer binding holds (",
                            ctx.info().max_storage_buffer_range, " bytes)");
  }
  REFLCAP_RETURN_IF_ERROR(EnsureHostBuffer(ctx, &m.pixels, pixel_bytes));
  std::memcpy(m.pixels->mapped(), pixels.data.data(), pixel_bytes);
  std::memcpy(m.params->mapped(), &p, sizeof(p));
  REFLCAP_RETURN_IF_ERROR(m.EnsureLightTarget(uint32_t(res), views));
  REFLCAP_RETURN_IF_ERROR(m.EnsureCameraTarget(p.map_width, p.map_height));
  constexpr VkImageLayout kRead = VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL;
  m.light_set.WriteBuffer(kBindParams, *m.params);
  m.light_set.WriteBuffer(kBindCorners, *m.corners);
  m.camera_set.WriteBuffer(kBindParams, *m.params);
  m.camera_set.WriteBuffer(kBindCorners, *m.corners);
  m.camera_set.WriteBuffer(kBindTriangles, *m.triangle_normals);
  m.camera_set.WriteImage(kBindLightMap, m.light_target->depth->array_view(), m.sampler.handle(),
                          kRead);
  const Buffer& rays = pinhole ? *grid->rays : *m.no_rays;
  for (size_t c = 0; c < m.texel_sets.size(); ++c) {
    const uint64_t first = uint64_t(c) * m.chunk_texels;
    const uint64_t count = std::min<uint64_t>(m.chunk_texels, m.texel_count - first);
    DescriptorSet& set = m.texel_sets[c];
    set.WriteBuffer(kBindParams, *m.params);
    set.WriteImage(kBindLightMap, m.light_target->depth->array_view(), m.sampler.handle(), kRead);
    set.WriteImage(kBindCameraMap, m.camera_target->color->array_view(), m.sampler.handle(),
                   kRead);
    set.WriteBuffer(kBindTexels, *m.texels, first * sizeof(sh::MaskTexel),
                    count * sizeof(sh::MaskTexel));
    set.WriteBuffer(kBindRays, rays);
    set.WriteBuffer(kBindPixels, *m.pixels, 0, pixel_bytes);
    set.WriteBuffer(kBindOutcomes, *m.outcomes, first * sizeof(uint32_t), count * sizeof(uint32_t));
    set.WriteBuffer(kBindSamples, *m.samples, first * sizeof(sh::MaskSample),
                    count * sizeof(sh::MaskSample));
  }
  const uint64_t map_bytes = uint64_t(p.map_width) * p.map_height * 16;
  if (map != nullptr) REFLCAP_RETURN_IF_ERROR(EnsureHostBuffer(ctx, &m.map_readback, map_bytes));

  // Record: light views, camera map, texels, (camera map read-back).
  REFLCAP_RETURN_IF_ERROR(m.cmd.Begin());
  VkCommandBuffer cb = m.cmd.handle();
  for (uint32_t v = 0; v < views; ++v) {
    m.light_target->target.Begin(cb, v, {}, 1.0f);  // 1: nothing before the distance scale
    m.Draw(m.light_pipeline, m.light_set, v);
    m.light_target->target.End(cb);
  }
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
        gpu::RecordCopyImageToBuffer(m.cmd, *m.camera_target->color, 0, *m.map_readback, 0));
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
  gpu::ContextOptions co;
  co.device = device;
  co.require_graphics = true;
  auto ctx = gpu::VkContext::Create(co);
  if (!ctx.ok()) {
    return Status(ctx.status().code(), StrCat("--backend vulkan: ", ctx.status().message()));
  }
  return OkStatus();
}

}  // namespace reflcap::resample
