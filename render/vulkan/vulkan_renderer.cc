// The Vulkan renderer (see vulkan_renderer.h): scene upload, per-image parameters (camera and
// light in the object frame, shadow views), and the recording of the shadow, camera, visibility,
// resolve and box-filter passes into one submission per image.
#include "render/vulkan/vulkan_renderer.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstring>
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
#include "engine/mesh/ray_scene.h"
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
                   kBindOutAux = 8, kBindNormalMapTexels = 9;
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
  return OkStatus();
}

// ---- Impl -----------------------------------------------------------------------------------

struct VulkanRenderer::Impl {
  std::unique_ptr<gpu::VkContext> owned_ctx;
  gpu::VkContext* ctx = nullptr;
  VulkanRenderOptions options;
  VulkanRenderStats stats;
  gpu::CommandBuffer cmd;
  gpu::Sampler sampler;

  // Descriptor set layouts and sets, one per pass.
  gpu::LightMapPass shadow_pass;  // shadow maps; its set (params, corners) also serves visibility
  DescriptorSetLayout camera_layout, resolve_layout, downsample_layout,
      normal_map_layout;
  DescriptorSet camera_set, resolve_set, downsample_set, normal_map_set;
  Pipeline depth_pipeline, camera_pipeline, visibility_pipeline, resolve_pipeline,
      downsample_pipeline, normal_map_pipeline;

  // Per-image parameters (host-visible).
  std::unique_ptr<Buffer> params;
  // Scene.
  enum class SceneKind { kNone, kMesh, kNormalMap } scene_kind = SceneKind::kNone;
  std::unique_ptr<Buffer> corners, triangles, normal_map_texels;
  std::unique_ptr<DeviceImage> material, frame, dummy_shadow;
  uint32_t triangle_count = 0;
  uint32_t texel_count = 0;
  int num_lobes = 0;
  int atlas_width = 0, atlas_height = 0;
  Vec3d sphere_centre = Vec3d::Zero();  // object frame
  double sphere_radius = 0;
  double surface_offset = 0;
  // Pass targets.
  std::unique_ptr<PassTarget> camera, camera_hires, visibility;
  // Outputs (host-visible): radiance (rgb, a = mask), aux, and the 1x pass radiance+mask when the
  // main pass is supersampled.
  std::unique_ptr<Buffer> out_radiance, out_aux, out_mask;

  Status Init(const VulkanRenderOptions& o);
  Status EnsureCameraPipelines();
  Status EnsureTarget(std::unique_ptr<PassTarget>* target, uint32_t w, uint32_t h,
                      const std::vector<VkFormat>& formats, VkImageLayout final_layout);
  Status UploadMaterial(const TexelAtlas& atlas, const BrdfMaps& maps);
  Status WriteParams(const sh::RenderParams& p) {
    std::memcpy(params->mapped(), &p, sizeof(p));
    return OkStatus();
  }
  void Draw(const Pipeline& pipeline, const DescriptorSet& set, const void* push,
            uint32_t push_bytes) {
    pipeline.Bind(cmd.handle(), set.handle());
    if (push_bytes > 0) pipeline.Push(cmd.handle(), push, push_bytes);
    vkCmdDraw(cmd.handle(), 3 * triangle_count, 1, 0, 0);
  }
  StatusOr<RenderResult> Assemble(int w, int h, bool aux_buffers, const Buffer& radiance,
                                  const Buffer& aux, const Buffer* mask_source);
};

Status VulkanRenderer::Impl::Init(const VulkanRenderOptions& o) {
  REFLCAP_RETURN_IF_ERROR(o.Validate());
  options = o;
  gpu::VkContext& c = *ctx;
  REFLCAP_ASSIGN_OR_RETURN(cmd, gpu::CommandBuffer::Create(c));
  REFLCAP_ASSIGN_OR_RETURN(sampler, gpu::Sampler::Create(c));
  REFLCAP_RETURN_IF_ERROR(gpu::CheckPassFormats(
      c, {VK_FORMAT_R32G32B32A32_SFLOAT, VK_FORMAT_R32_UINT}, "camera passes and shadow maps"));

  REFLCAP_ASSIGN_OR_RETURN(
      shadow_pass, gpu::LightMapPass::Create(c, {gpu::ShaderId::kRenderShadowVert,
                                                 gpu::ShaderId::kRenderShadowFrag, kBindParams,
                                                 kBindCorners}));
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
                                                           {kBindNormalMapTexels, kSsbo, kComp}}));
  REFLCAP_ASSIGN_OR_RETURN(camera_set, DescriptorSet::Create(c, camera_layout));
  REFLCAP_ASSIGN_OR_RETURN(resolve_set, DescriptorSet::Create(c, resolve_layout));
  REFLCAP_ASSIGN_OR_RETURN(downsample_set, DescriptorSet::Create(c, downsample_layout));
  REFLCAP_ASSIGN_OR_RETURN(normal_map_set, DescriptorSet::Create(c, normal_map_layout));

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

  REFLCAP_RETURN_IF_ERROR(EnsureHostBuffer(c, &params, sizeof(sh::RenderParams)));
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

Status VulkanRenderer::Impl::EnsureTarget(std::unique_ptr<PassTarget>* target, uint32_t w,
                                          uint32_t h, const std::vector<VkFormat>& formats,
                                          VkImageLayout final_layout) {
  if (*target != nullptr && (*target)->width == w && (*target)->height == h) return OkStatus();
  target->reset();
  REFLCAP_ASSIGN_OR_RETURN(*target,
                           MakePassTarget(*ctx, w, h, 1, formats, final_layout, false));
  return OkStatus();
}

Status VulkanRenderer::Impl::EnsureCameraPipelines() {
  if (camera_pipeline.handle() == VK_NULL_HANDLE && camera != nullptr) {
    // Depth pre-pass, then shading with depth EQUAL: every pixel is shaded once, by its nearest
    // surface (the full shading is what costs, on lavapipe above all).
    gpu::GraphicsPipelineOptions o;
    o.vertex = gpu::ShaderId::kRenderSurfaceVert;
    o.set_layout = camera_layout.handle();
    o.color_writes = false;
    REFLCAP_ASSIGN_OR_RETURN(depth_pipeline, Pipeline::CreateGraphics(*ctx, o, camera->target));
    o.fragment = gpu::ShaderId::kRenderSurfaceFrag;
    o.color_writes = true;
    o.depth_compare = VK_COMPARE_OP_EQUAL;
    o.depth_write = false;
    REFLCAP_ASSIGN_OR_RETURN(camera_pipeline, Pipeline::CreateGraphics(*ctx, o, camera->target));
  }
  if (visibility_pipeline.handle() == VK_NULL_HANDLE && visibility != nullptr) {
    gpu::GraphicsPipelineOptions o;
    o.vertex = gpu::ShaderId::kRenderSurfaceVert;
    o.fragment = gpu::ShaderId::kRenderVisibilityFrag;
    o.set_layout = shadow_pass.layout().handle();  // params + corners
    REFLCAP_ASSIGN_OR_RETURN(visibility_pipeline,
                             Pipeline::CreateGraphics(*ctx, o, visibility->target));
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

StatusOr<RenderResult> VulkanRenderer::Impl::Assemble(int w, int h, bool aux_buffers,
                                                      const Buffer& radiance, const Buffer& aux,
                                                      const Buffer* mask_source) {
  RenderResult result{Image(w, h, 3, 0.0f), Image(w, h, 1, 0.0f), Image()};
  if (aux_buffers) result.aux = Image(w, h, kAuxChannelCount, 0.0f);
  const float* rad = static_cast<const float*>(radiance.mapped());
  const float* ax = static_cast<const float*>(aux.mapped());
  const float* mask =
      static_cast<const float*>(mask_source ? mask_source->mapped() : radiance.mapped());
  const size_t n = size_t(w) * h;
  for (size_t i = 0; i < n; ++i) {
    for (int c = 0; c < 3; ++c) result.pixels.data[i * 3 + c] = rad[i * 4 + c];
    const float m = mask[i * 4 + 3] > 0.5f ? 1.0f : 0.0f;
    result.mask.data[i] = m;
    if (aux_buffers) {
      float* a = &result.aux.data[i * kAuxChannelCount];
      a[kAuxCastShadow] = ax[i * 4 + 0];
      a[kAuxCosThetaI] = ax[i * 4 + 1];
      a[kAuxCosThetaO] = ax[i * 4 + 2];
      a[kAuxCurvature] = ax[i * 4 + 3];
      a[kAuxMask] = m;
    }
  }
  return result;
}

// ---- VulkanRenderer -------------------------------------------------------------------------

VulkanRenderer::VulkanRenderer() : impl_(std::make_unique<Impl>()) {}
VulkanRenderer::~VulkanRenderer() {
  if (impl_ != nullptr && impl_->ctx != nullptr) (void)impl_->ctx->WaitIdle();
  // Members go in reverse order of declaration; the owned context last (Impl declares it first).
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
  std::vector<sh::RenderCorner> corners(mesh.TriangleCount() * 3);
  std::vector<sh::RenderTriangle> triangles(mesh.TriangleCount());
  const std::vector<float> curvature = SurfaceCurvature(mesh);
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
  m.sphere_radius = 0.5 * box.diagonal().cast<double>().norm() * kSphereInflation;
  m.surface_offset = scene.scene->SurfaceOffset();
  m.scene_kind = Impl::SceneKind::kMesh;
  return OkStatus();
}

Status VulkanRenderer::SetNormalMapScene(const TexelAtlas& atlas, const BrdfMaps& maps,
                                         const Camera& camera) {
  Impl& m = *impl_;
  if (atlas.TexelCount() == 0) return InvalidArgumentError("SetNormalMapScene: no texels");
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
  const bool pinhole = camera.model == CameraModel::kPinhole;
  if (!pinhole && !(camera.pixel_size_m > 0)) {
    return InvalidArgumentError("camera \"", camera.id,
                                "\": orthographic rendering needs pixel_size_m");
  }
  if (camera.width <= 0 || camera.height <= 0) {
    return InvalidArgumentError("camera \"", camera.id, "\" has no pixels");
  }
  gpu::VkContext& ctx = *m.ctx;
  m.stats = VulkanRenderStats{};
  const int w = camera.width, h = camera.height, n = options.supersampling;
  const bool distorted = pinhole && (camera.HasDistortion() || m.options.always_resolve);
  const bool point_light = light.type == LightType::kPoint;

  // Camera and light in the object frame.
  const Rigid3 cam_from_object = camera.cam_from_world * world_from_object;
  const Rigid3 object_from_cam = cam_from_object.Inverse();
  const Rigid3 object_from_world = world_from_object.Inverse();
  const Vec3d light_in_object = object_from_world * light.position;
  const Vec3d light_dir_in_object = (object_from_world.rotation * light.direction).normalized();
  const Vec3d centre = m.sphere_centre;
  const double radius = m.sphere_radius;
  const double centre_z = (cam_from_object * centre).z();
  // Depth range of the object in front of the camera (pinhole: beyond a sliver in front of the
  // centre; orthographic: rays start on the plane z = 0, as the CPU's do).
  double near = 0, far = 0;
  gpu::CameraDepthRange(pinhole, centre_z, radius, &near, &far);

  sh::RenderParams p{};
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
  p.intrinsics_extra = {float(s), float(camera.pixel_size_m), 1, 0};  // z: 1 sample per side
  p.distortion = {float(camera.dist[0]), float(camera.dist[1]), float(camera.dist[2]),
                  float(camera.dist[3])};
  p.distortion_extra = {float(camera.dist[4]), 0, 0, 0};
  p.flags = (pinhole ? sh::kRenderFlagPinhole : 0u) |
            (point_light ? sh::kRenderFlagPointLight : 0u) |
            (distorted ? sh::kRenderFlagDistortion : 0u);
  p.num_lobes = uint32_t(m.num_lobes);
  p.params_per_channel = uint32_t(brdf::ParamsPerChannel(m.num_lobes));
  p.atlas_width = uint32_t(m.atlas_width);
  p.atlas_height = uint32_t(m.atlas_height);
  p.width = uint32_t(w);
  p.height = uint32_t(h);
  p.supersampling = uint32_t(n);

  // Shadow views.
  const VulkanRenderOptions& vo = m.options;
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
        const gpu::LightMapPlan plan,
        gpu::PlanLightMap(point_light, light_in_object, light_dir_in_object, centre, radius, shape,
                          resolution));
    std::copy(plan.views, plan.views + plan.view_count, p.views);
    views = plan.view_count;
    res = plan.resolution;
    m.stats.shadow_map = plan.kind;
    p.flags |= sh::kRenderFlagCastShadows;
    m.stats.shadow_resolution = res;
  }
  p.num_shadow_views = views;
  p.shadow_resolution = uint32_t(res);
  p.shadow_bias = {float(m.surface_offset), float(vo.shadow_bias_texels),
                   float(vo.shadow_plane_limit_texels), 0};

  // Visibility image of a distorted camera: the undistorted footprint of the image's border
  // (pixel edges, ±0.5 px), in normalised coordinates, at visibility_scale texels per pixel.
  int vis_w = 0, vis_h = 0;
  double vfx = 0, vfy = 0, vs = 0, vcx = 0, vcy = 0;
  if (distorted) {
    double xmin = 1e300, xmax = -1e300, ymin = 1e300, ymax = -1e300;
    auto extend = [&](double u, double v) {
      const double yd = (v - cy) / fy;
      const double xd = (u - cx - s * yd) / fx;
      const Vec2d xy = camera.Undistort({xd, yd});
      xmin = std::min(xmin, xy.x());
      xmax = std::max(xmax, xy.x());
      ymin = std::min(ymin, xy.y());
      ymax = std::max(ymax, xy.y());
    };
    for (int x = 0; x <= w; ++x) {
      extend(x - 0.5, -0.5);
      extend(x - 0.5, h - 0.5);
    }
    for (int y = 0; y <= h; ++y) {
      extend(-0.5, y - 0.5);
      extend(w - 0.5, y - 0.5);
    }
    const int scale = vo.visibility_scale;
    vfx = fx * scale;
    vfy = fy * scale;
    vs = s * scale;
    const double u0 = std::min({vfx * xmin + vs * ymin, vfx * xmin + vs * ymax});
    const double u1 = std::max({vfx * xmax + vs * ymin, vfx * xmax + vs * ymax});
    vcx = kVisibilityMargin - u0;
    vcy = kVisibilityMargin - vfy * ymin;
    const double width_d = std::ceil(u1 - u0) + 2 * kVisibilityMargin + 1;
    const double height_d = std::ceil(vfy * (ymax - ymin)) + 2 * kVisibilityMargin + 1;
    if (!(width_d <= kMaxVisibilitySide && height_d <= kMaxVisibilitySide &&
          width_d <= kMaxVisibilityRatio * scale * w + 64 &&
          height_d <= kMaxVisibilityRatio * scale * h + 64)) {
      return InvalidArgumentError("camera \"", camera.id,
                                  "\": its distortion spreads the image "
                                  "over an undistorted footprint of ",
                                  width_d, "x", height_d,
                                  " px, too wide for the Vulkan renderer's pinhole rasterisation");
    }
    vis_w = int(width_d);
    vis_h = int(height_d);
    p.vis_intrinsics = {float(vfx), float(vfy), float(vcx), float(vcy)};
    p.vis_intrinsics_extra = {float(vs), 0, 0, 0};
    p.vis_width = uint32_t(vis_w);
    p.vis_height = uint32_t(vis_h);
    m.stats.distortion_resolve = true;
    m.stats.visibility_width = vis_w;
    m.stats.visibility_height = vis_h;
  }

  // Targets, outputs and descriptor sets (rewritten only here, between submissions).
  if (views > 0) REFLCAP_RETURN_IF_ERROR(m.shadow_pass.EnsureTarget(ctx, uint32_t(res), views));
  const uint64_t out_bytes = uint64_t(w) * h * 16;
  REFLCAP_RETURN_IF_ERROR(EnsureHostBuffer(ctx, &m.out_radiance, out_bytes));
  REFLCAP_RETURN_IF_ERROR(EnsureHostBuffer(ctx, &m.out_aux, out_bytes));
  if (distorted) {
    // The visibility pass uses clip_from_object of the visibility image; the resolve reads the
    // output camera's intrinsics. One params block serves both: the vertex stage reads
    // clip_from_object, which for a distorted camera is the visibility projection.
    SetRows(PinholeClipFromCam(vfx, vfy, vs, vcx, vcy, vis_w, vis_h, near, far) * object_to_cam,
            p.clip_from_object);
    REFLCAP_RETURN_IF_ERROR(m.EnsureTarget(&m.visibility, uint32_t(vis_w), uint32_t(vis_h),
                                           {VK_FORMAT_R32_UINT},
                                           VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL));
  } else {
    REFLCAP_RETURN_IF_ERROR(
        m.EnsureTarget(&m.camera, uint32_t(w), uint32_t(h),
                       {VK_FORMAT_R32G32B32A32_SFLOAT, VK_FORMAT_R32G32B32A32_SFLOAT},
                       VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL));
    if (n > 1) {
      REFLCAP_RETURN_IF_ERROR(
          m.EnsureTarget(&m.camera_hires, uint32_t(w * n), uint32_t(h * n),
                         {VK_FORMAT_R32G32B32A32_SFLOAT, VK_FORMAT_R32G32B32A32_SFLOAT},
                         VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL));
      REFLCAP_RETURN_IF_ERROR(EnsureHostBuffer(ctx, &m.out_mask, out_bytes));
    }
  }
  REFLCAP_RETURN_IF_ERROR(m.EnsureCameraPipelines());
  const DeviceImage& shadow_image = views > 0 ? m.shadow_pass.depth() : *m.dummy_shadow;
  constexpr VkImageLayout kRead = VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL;
  m.shadow_pass.WriteBuffers(*m.params, *m.corners);
  for (DescriptorSet* set : {&m.camera_set, &m.resolve_set}) {
    set->WriteBuffer(kBindParams, *m.params);
    set->WriteBuffer(kBindCorners, *m.corners);
    set->WriteBuffer(kBindTriangles, *m.triangles);
    set->WriteImage(kBindMaterial, m.material->array_view(), m.sampler.handle(), kRead);
    set->WriteImage(kBindFrame, m.frame->array_view(), m.sampler.handle(), kRead);
    set->WriteImage(kBindShadowMap, shadow_image.array_view(), m.sampler.handle(), kRead);
  }
  if (distorted) {
    m.resolve_set.WriteImage(kBindSource, m.visibility->colors[0]->array_view(), m.sampler.handle(),
                             kRead);
    m.resolve_set.WriteBuffer(kBindOutRadiance, *m.out_radiance, 0, out_bytes);
    m.resolve_set.WriteBuffer(kBindOutAux, *m.out_aux, 0, out_bytes);
  }
  if (!distorted && n > 1) {
    m.downsample_set.WriteImage(kBindSource, m.camera_hires->colors[0]->array_view(),
                                m.sampler.handle(), kRead);
    m.downsample_set.WriteBuffer(kBindOutRadiance, *m.out_radiance, 0, out_bytes);
  }
  // Pixel weight: the camera pass shades one sample per pixel (the supersampled pass below sets
  // its own); the resolve sums N x N samples.
  p.intensity.w = float(distorted ? exposure_s / (double(n) * n) : exposure_s);
  REFLCAP_RETURN_IF_ERROR(m.WriteParams(p));

  // Record. The params block is host-visible and read by every pass of this submission, so
  // everything that differs between passes goes through push constants or is fixed above; the
  // supersampled pass needs its own projection and weight, so it runs in a second submission.
  REFLCAP_RETURN_IF_ERROR(m.cmd.Begin());
  VkCommandBuffer cb = m.cmd.handle();
  if (views > 0) m.shadow_pass.Record(cb, views, m.triangle_count);
  if (distorted) {
    m.visibility->target.Begin(cb, 0, {});
    m.Draw(m.visibility_pipeline, m.shadow_pass.set(), nullptr, 0);
    m.visibility->target.End(cb);
    m.resolve_pipeline.Bind(cb, m.resolve_set.handle());
    vkCmdDispatch(cb, (uint32_t(w) + kTile - 1) / kTile, (uint32_t(h) + kTile - 1) / kTile, 1);
  } else {
    m.camera->target.Begin(cb, 0, {});
    m.Draw(m.depth_pipeline, m.camera_set, nullptr, 0);
    m.Draw(m.camera_pipeline, m.camera_set, nullptr, 0);
    m.camera->target.End(cb);
    REFLCAP_RETURN_IF_ERROR(gpu::RecordCopyImageToBuffer(m.cmd, *m.camera->colors[0], 0,
                                                         n > 1 ? *m.out_mask : *m.out_radiance, 0));
    REFLCAP_RETURN_IF_ERROR(
        gpu::RecordCopyImageToBuffer(m.cmd, *m.camera->colors[1], 0, *m.out_aux, 0));
  }
  REFLCAP_RETURN_IF_ERROR(m.cmd.SubmitAndWait());
  m.stats.gpu_seconds += m.cmd.last_submit_wall_s();

  if (!distorted && n > 1) {
    // Supersampled pass: N x N the resolution (stratum centres), each fragment weighted
    // exposure / N², box-filtered into out_radiance. No shadow map redraw: it is still there.
    SetRows(clip_for_scale(n), p.clip_from_object);
    p.intrinsics_extra.z = float(n);  // surface.frag: fragment -> stratum centre
    p.intensity.w = float(exposure_s / (double(n) * n));
    REFLCAP_RETURN_IF_ERROR(m.WriteParams(p));
    REFLCAP_RETURN_IF_ERROR(m.cmd.Begin());
    cb = m.cmd.handle();
    m.camera_hires->target.Begin(cb, 0, {});
    m.Draw(m.depth_pipeline, m.camera_set, nullptr, 0);
    m.Draw(m.camera_pipeline, m.camera_set, nullptr, 0);
    m.camera_hires->target.End(cb);
    const sh::DownsamplePush push{uint32_t(w), uint32_t(h), uint32_t(n), 0};
    m.downsample_pipeline.Bind(cb, m.downsample_set.handle());
    m.downsample_pipeline.Push(cb, &push, sizeof(push));
    vkCmdDispatch(cb, (uint32_t(w) + kTile - 1) / kTile, (uint32_t(h) + kTile - 1) / kTile, 1);
    REFLCAP_RETURN_IF_ERROR(m.cmd.SubmitAndWait());
    m.stats.gpu_seconds += m.cmd.last_submit_wall_s();
  }

  StatusOr<RenderResult> result = m.Assemble(w, h, options.aux_buffers, *m.out_radiance, *m.out_aux,
                                             (!distorted && n > 1) ? m.out_mask.get() : nullptr);
  m.stats.seconds = SecondsSince(start);
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
  if (m.atlas_width != camera.width || m.atlas_height != camera.height) {
    return InvalidArgumentError("camera \"", camera.id, "\" is ", camera.width, "x", camera.height,
                                " but the normal map is ", m.atlas_width, "x", m.atlas_height);
  }
  if (light.type != LightType::kDirectional) {
    return InvalidArgumentError("light \"", light.id,
                                "\": normal-map captures are rendered with directional lights "
                                "only (the surface positions are unknown)");
  }
  gpu::VkContext& ctx = *m.ctx;
  m.stats = VulkanRenderStats{};
  const int w = camera.width, h = camera.height;
  const bool pinhole = camera.model == CameraModel::kPinhole;
  const Rigid3 world_from_cam = camera.cam_from_world.Inverse();
  sh::RenderParams p{};
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
  p.num_lobes = uint32_t(m.num_lobes);
  p.params_per_channel = uint32_t(brdf::ParamsPerChannel(m.num_lobes));
  p.atlas_width = uint32_t(m.atlas_width);
  p.atlas_height = uint32_t(m.atlas_height);
  p.width = uint32_t(w);
  p.height = uint32_t(h);
  p.supersampling = 1;
  REFLCAP_RETURN_IF_ERROR(m.WriteParams(p));
  const uint64_t out_bytes = uint64_t(w) * h * 16;
  REFLCAP_RETURN_IF_ERROR(EnsureHostBuffer(ctx, &m.out_radiance, out_bytes));
  REFLCAP_RETURN_IF_ERROR(EnsureHostBuffer(ctx, &m.out_aux, out_bytes));
  constexpr VkImageLayout kRead = VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL;
  m.normal_map_set.WriteBuffer(kBindParams, *m.params);
  m.normal_map_set.WriteImage(kBindMaterial, m.material->array_view(), m.sampler.handle(), kRead);
  m.normal_map_set.WriteBuffer(kBindOutRadiance, *m.out_radiance, 0, out_bytes);
  m.normal_map_set.WriteBuffer(kBindOutAux, *m.out_aux, 0, out_bytes);
  m.normal_map_set.WriteBuffer(kBindNormalMapTexels, *m.normal_map_texels);

  REFLCAP_RETURN_IF_ERROR(m.cmd.Begin());
  REFLCAP_RETURN_IF_ERROR(m.cmd.FillBuffer(*m.out_radiance, 0, out_bytes, 0));
  REFLCAP_RETURN_IF_ERROR(m.cmd.FillBuffer(*m.out_aux, 0, out_bytes, 0));
  VkCommandBuffer cb = m.cmd.handle();
  const sh::NormalMapPush push{m.texel_count};
  m.normal_map_pipeline.Bind(cb, m.normal_map_set.handle());
  m.normal_map_pipeline.Push(cb, &push, sizeof(push));
  vkCmdDispatch(cb, (m.texel_count + kTexelGroup - 1) / kTexelGroup, 1, 1);
  REFLCAP_RETURN_IF_ERROR(m.cmd.SubmitAndWait());
  m.stats.gpu_seconds = m.cmd.last_submit_wall_s();
  StatusOr<RenderResult> result =
      m.Assemble(w, h, options.aux_buffers, *m.out_radiance, *m.out_aux, nullptr);
  m.stats.seconds = SecondsSince(start);
  return result;
}

}  // namespace reflcap::render
