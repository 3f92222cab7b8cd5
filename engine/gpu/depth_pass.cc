#include "engine/gpu/depth_pass.h"

#include <algorithm>
#include <cmath>

#include "engine/gpu/vk_view.h"

namespace reflcap::gpu {

void CameraDepthRange(bool pinhole, double centre_z, double radius, double* near, double* far) {
  *near = pinhole ? std::max(centre_z - radius, (centre_z + radius) * kMinNearFraction)
                  : std::max(0.0, centre_z - radius);
  *far = centre_z + radius;
  if (!(*far > 0) || !(*far > *near)) {
    *near = 1e-3;
    *far = 1.0;
  }
}

StatusOr<std::unique_ptr<PassTarget>> MakePassTarget(VkContext& ctx, uint32_t width,
                                                     uint32_t height, uint32_t layers,
                                                     const std::vector<VkFormat>& color_formats,
                                                     VkImageLayout color_final_layout,
                                                     bool sampled_depth, PassWait wait) {
  auto t = std::make_unique<PassTarget>();
  t->width = width;
  t->height = height;
  t->layers = layers;
  const bool cube = layers == 6 && width == height;
  std::vector<DeviceImage*> colors;
  for (VkFormat f : color_formats) {
    ImageOptions o;
    o.width = width;
    o.height = height;
    o.layers = layers;
    o.format = f;
    o.usage = VK_IMAGE_USAGE_COLOR_ATTACHMENT_BIT | VK_IMAGE_USAGE_SAMPLED_BIT;
    o.cube_compatible = cube;
    REFLCAP_ASSIGN_OR_RETURN(DeviceImage img, DeviceImage::Create(ctx, o));
    t->colors.push_back(std::make_unique<DeviceImage>(std::move(img)));
    colors.push_back(t->colors.back().get());
  }
  ImageOptions d;
  d.width = width;
  d.height = height;
  d.layers = layers;
  d.format = VK_FORMAT_D32_SFLOAT;
  // A sampled depth image (a light map) may also be filled by a copy (the Vulkan renderer's
  // compute-drawn shadow maps).
  d.usage = VK_IMAGE_USAGE_DEPTH_STENCIL_ATTACHMENT_BIT |
            (sampled_depth ? VkImageUsageFlags{VK_IMAGE_USAGE_SAMPLED_BIT |
                                               VK_IMAGE_USAGE_TRANSFER_DST_BIT}
                           : VkImageUsageFlags{0});
  d.cube_compatible = cube;
  REFLCAP_ASSIGN_OR_RETURN(DeviceImage depth, DeviceImage::Create(ctx, d));
  t->depth = std::make_unique<DeviceImage>(std::move(depth));
  REFLCAP_ASSIGN_OR_RETURN(
      t->target,
      RenderTarget::Create(ctx, colors, t->depth.get(), color_final_layout,
                           sampled_depth ? VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL
                                         : VK_IMAGE_LAYOUT_DEPTH_STENCIL_ATTACHMENT_OPTIMAL,
                           wait));
  return t;
}

Status CheckPassFormats(const VkContext& ctx, const std::vector<VkFormat>& color_formats,
                        const char* purpose) {
  for (VkFormat f : color_formats) {
    if (!FormatSupports(ctx, f,
                        VK_FORMAT_FEATURE_COLOR_ATTACHMENT_BIT | VK_FORMAT_FEATURE_SAMPLED_IMAGE_BIT)) {
      return UnavailableError("Vulkan device ", ctx.info().name,
                              " cannot render to and sample format ", int(f), " (", purpose, ")");
    }
  }
  if (!FormatSupports(ctx, VK_FORMAT_D32_SFLOAT,
                      VK_FORMAT_FEATURE_DEPTH_STENCIL_ATTACHMENT_BIT |
                          VK_FORMAT_FEATURE_SAMPLED_IMAGE_BIT)) {
    return UnavailableError("Vulkan device ", ctx.info().name,
                            " cannot render to and sample a D32_SFLOAT depth image (", purpose,
                            ")");
  }
  return OkStatus();
}

shared::LightMapView PerspectiveLightView(const Vec3d& origin, const Vec3d& forward,
                                          const Vec3d& right, const Vec3d& up, double tan_half,
                                          double near, double far) {
  shared::LightMapView v{};
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

shared::LightMapView OrthographicLightView(const Vec3d& origin, const Vec3d& forward,
                                           const Vec3d& right, const Vec3d& up, double half_width,
                                           double depth) {
  shared::LightMapView v{};
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

int LightMapResolution::For(double extent_m, bool cube) const {
  if (fixed > 0) return fixed;
  const int max_res = cube ? max_cube_resolution : max_resolution;
  const double texels = std::ceil(texels_per_pixel * extent_m / pixel_m);
  return int(std::clamp(std::isfinite(texels) ? texels : double(max_res),
                        double(std::min(min_resolution, max_res)), double(max_res)));
}

Status ValidateLightMapResolution(const char* prefix, double texels_per_pixel, int min_resolution,
                                  int max_resolution, int max_cube_resolution) {
  if (!(texels_per_pixel > 0 && texels_per_pixel <= 64)) {
    return InvalidArgumentError(prefix, "_texels_per_pixel must be in (0, 64], got ",
                                texels_per_pixel);
  }
  for (int r : {min_resolution, max_resolution, max_cube_resolution}) {
    if (r < 16 || r > 16384) {
      return InvalidArgumentError(prefix, "-map resolution bounds must be in [16, 16384], got ", r);
    }
  }
  if (min_resolution > max_resolution) {
    return InvalidArgumentError("min_", prefix, "_resolution ", min_resolution, " exceeds max_",
                                prefix, "_resolution ", max_resolution);
  }
  return OkStatus();
}

StatusOr<LightMapPlan> PlanLightMap(bool point_light, const Vec3d& light_in_object,
                                    const Vec3d& light_dir_in_object, const Vec3d& centre,
                                    double radius, LightMapShape shape,
                                    const LightMapResolution& resolution) {
  LightMapPlan plan;
  if (!point_light) {
    const Vec3d forward = -light_dir_in_object;
    Vec3d right, up;
    Basis(forward, &right, &up);
    const double half = radius * kSphereInflation;
    const Vec3d origin = centre - forward * (half * kSphereInflation);
    plan.resolution = resolution.For(2 * half, false);
    plan.views[0] = OrthographicLightView(origin, forward, right, up, half,
                                          2 * half * kSphereInflation * kSphereInflation);
    plan.view_count = 1;
    plan.kind = "orthographic";
    return plan;
  }
  const Vec3d to_centre = centre - light_in_object;
  const double dist = to_centre.norm();
  const bool fitted = shape == LightMapShape::kFitted ||
                      (shape == LightMapShape::kAuto && dist > kFitMargin * radius);
  if (fitted) {
    if (!(dist > radius)) {
      return InvalidArgumentError(
          "a fitted light-map frustum needs the light outside the object's bounding sphere; use "
          "the cube map");
    }
    const Vec3d forward = to_centre / dist;
    Vec3d right, up;
    Basis(forward, &right, &up);
    const double tan_half = std::tan(std::asin(radius / dist)) * kSphereInflation;
    // Near plane at the sphere, but at least 1e-3 of the distance (float depth precision).
    const double f_near = std::max(dist - radius, dist * 1e-3) / kSphereInflation;
    const double f_far = (dist + radius) * kSphereInflation;
    plan.resolution = resolution.For(2 * dist * tan_half, false);
    plan.views[0] = PerspectiveLightView(light_in_object, forward, right, up, tan_half, f_near, f_far);
    plan.view_count = 1;
    plan.kind = "fitted";
    return plan;
  }
  const double c_far = (dist + radius) * kSphereInflation;
  const double c_near = radius * kCubeNearFraction;
  plan.resolution = resolution.For(2 * std::max(dist, radius), true);
  for (int face = 0; face < 6; ++face) {
    const int axis = face / 2;
    const double sign = face % 2 == 0 ? 1 : -1;
    Vec3d forward = Vec3d::Zero(), right = Vec3d::Zero(), up = Vec3d::Zero();
    forward[axis] = sign;
    right[(axis + 1) % 3] = 1;
    up[(axis + 2) % 3] = 1;
    plan.views[face] = PerspectiveLightView(light_in_object, forward, right, up, 1.0, c_near, c_far);
  }
  plan.view_count = 6;
  plan.kind = "cube";
  return plan;
}

StatusOr<LightMapPass> LightMapPass::Create(VkContext& ctx, const Options& options) {
  if (options.vertex == ShaderId::kCount || options.fragment == ShaderId::kCount ||
      options.params_binding == options.corners_binding) {
    return InvalidArgumentError("LightMapPass: a vertex and a fragment shader and two distinct "
                                "bindings are required");
  }
  LightMapPass pass;
  pass.options_ = options;
  REFLCAP_ASSIGN_OR_RETURN(
      pass.layout_, DescriptorSetLayout::Create(ctx, {{options.params_binding, kSsbo, kGfx},
                                                      {options.corners_binding, kSsbo, kGfx}}));
  REFLCAP_ASSIGN_OR_RETURN(pass.set_, DescriptorSet::Create(ctx, pass.layout_));
  return pass;
}

void LightMapPass::WriteBuffers(const Buffer& params, const Buffer& corners) {
  set_.WriteBuffer(options_.params_binding, params);
  set_.WriteBuffer(options_.corners_binding, corners);
}

Status LightMapPass::EnsureTarget(VkContext& ctx, uint32_t resolution, uint32_t layers) {
  if (target_ != nullptr && target_->width == resolution && target_->layers == layers) {
    return OkStatus();
  }
  target_.reset();
  REFLCAP_ASSIGN_OR_RETURN(target_, MakePassTarget(ctx, resolution, resolution, layers, {},
                                                   VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL,
                                                   /*sampled_depth=*/true));
  if (pipeline_.handle() == VK_NULL_HANDLE) {
    REFLCAP_ASSIGN_OR_RETURN(pipeline_, CreateLightMapPipeline(ctx, options_.vertex,
                                                               options_.fragment, layout_.handle(),
                                                               target_->target));
  }
  return OkStatus();
}

void LightMapPass::Record(VkCommandBuffer cmd, uint32_t view_count, uint32_t triangle_count) {
  RecordLightMapViews(cmd, pipeline_, set_.handle(), target_->target, view_count, triangle_count);
}

StatusOr<Pipeline> CreateLightMapPipeline(VkContext& ctx, ShaderId vertex, ShaderId fragment,
                                          VkDescriptorSetLayout set_layout,
                                          const RenderTarget& target) {
  GraphicsPipelineOptions o;
  o.vertex = vertex;
  o.fragment = fragment;
  o.set_layout = set_layout;
  o.push_constant_bytes = sizeof(shared::LightMapPush);
  o.color_writes = false;
  return Pipeline::CreateGraphics(ctx, o, target);
}

void RecordLightMapViews(VkCommandBuffer cmd, const Pipeline& pipeline, VkDescriptorSet set,
                         RenderTarget& target, uint32_t view_count, uint32_t triangle_count) {
  pipeline.Bind(cmd, set);
  for (uint32_t v = 0; v < view_count; ++v) {
    target.Begin(cmd, v, {}, 1.0f);
    const shared::LightMapPush push{v};
    pipeline.Push(cmd, &push, sizeof(push));
    vkCmdDraw(cmd, 3 * triangle_count, 1, 0, 0);
    target.End(cmd);
  }
}

}  // namespace reflcap::gpu
