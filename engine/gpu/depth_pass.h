#pragma once
// What the two rasterising users of the GPU — the Vulkan renderer (render/vulkan) and the Vulkan
// masks (acquire/resample) — share of their depth passes: the pass targets (colour attachments
// plus a D32 depth image, one framebuffer per layer), the camera's depth range around the
// object's bounding sphere, and the light map of a light: its views (a frustum fitted to the
// sphere, six cube faces, or an orthographic box), resolution, and the recording of its layers.
// The shaders' side is shaders/shared/light_map_view.h and shaders/common/light_map.glsl.
#include <vulkan/vulkan.h>

#include <cstdint>
#include <memory>
#include <vector>

#include "engine/core/status.h"
#include "engine/gpu/shader_blobs.h"
#include "engine/gpu/vk_buffer.h"
#include "engine/gpu/vk_context.h"
#include "engine/gpu/vk_descriptors.h"
#include "engine/gpu/vk_graphics_pipeline.h"
#include "engine/gpu/vk_image.h"
#include "engine/math/types.h"
#include "shaders/shared/light_map_view.h"

namespace reflcap::gpu {

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

// The depth range [*near, *far] of a bounding sphere (radius `radius`, centre at depth
// `centre_z` in the camera frame): pinhole, beyond a sliver in front of the centre; orthographic,
// from the plane z = 0 on (rays start there, as the CPU's do). An object behind the camera gets
// [1e-3, 1] (every pixel is background).
void CameraDepthRange(bool pinhole, double centre_z, double radius, double* near, double* far);

// The images of one pass and their render target, recreated when the size changes. Held by
// pointer: the RenderTarget keeps the images' addresses.
struct PassTarget {
  std::vector<std::unique_ptr<DeviceImage>> colors;  // COLOR_ATTACHMENT | SAMPLED
  std::unique_ptr<DeviceImage> depth;                // D32_SFLOAT
  RenderTarget target;
  uint32_t width = 0, height = 0, layers = 0;
};

// A pass target of `color_formats` attachments (ending in `color_final_layout`) and a D32 depth
// attachment — sampled and ending in SHADER_READ_ONLY_OPTIMAL when `sampled_depth` (light maps),
// else kept as an attachment. Six square layers are cube-compatible. `wait`: what its pass waits
// for (PassWait).
StatusOr<std::unique_ptr<PassTarget>> MakePassTarget(VkContext& ctx, uint32_t width,
                                                     uint32_t height, uint32_t layers,
                                                     const std::vector<VkFormat>& color_formats,
                                                     VkImageLayout color_final_layout,
                                                     bool sampled_depth,
                                                     PassWait wait = PassWait::kEverything);

// Unavailable (naming `purpose`) unless the device can render to and sample every format of
// `color_formats` and D32_SFLOAT.
Status CheckPassFormats(const VkContext& ctx, const std::vector<VkFormat>& color_formats,
                        const char* purpose);

// A perspective view from `origin` along unit `forward` ((right, up, forward) orthonormal) with
// tan(half-angle) `tan_half` and depth range [near, far].
shared::LightMapView PerspectiveLightView(const Vec3d& origin, const Vec3d& forward,
                                          const Vec3d& right, const Vec3d& up, double tan_half,
                                          double near, double far);
// An orthographic box from the near-plane centre `origin` along `forward`, half-width
// `half_width` and depth `depth`.
shared::LightMapView OrthographicLightView(const Vec3d& origin, const Vec3d& forward,
                                           const Vec3d& right, const Vec3d& up, double half_width,
                                           double depth);

// Which light map a point light gets (directional lights always get an orthographic box).
enum class LightMapShape {
  kAuto,    // kFitted when the light is farther than kFitMargin radii from the centre, else kCube
  kCube,    // six 90° faces around the light (+X, -X, +Y, -Y, +Z, -Z)
  kFitted,  // one perspective frustum around the bounding sphere (light outside it)
};

// The light map of one light for an object inside the sphere (centre, radius), object frame.
struct LightMapPlan {
  shared::LightMapView views[6] = {};
  uint32_t view_count = 0;
  int resolution = 0;      // texels per side of every view
  const char* kind = "";   // "fitted", "cube" or "orthographic"
};
// How a light map's side length is chosen: `texels_per_pixel` map texels per image pixel, an
// image pixel measuring `pixel_m` metres at the object's centre, clamped to [min_resolution,
// max_resolution] (cube faces: max_cube_resolution); `fixed` > 0 overrides all of that.
struct LightMapResolution {
  double texels_per_pixel = 2;
  double pixel_m = 1;
  int min_resolution = 256;
  int max_resolution = 4096;
  int max_cube_resolution = 2048;
  int fixed = 0;

  // Texels per side of a view covering `extent_m` metres at the object. A non-finite ratio (a
  // degenerate camera) takes the largest map.
  int For(double extent_m, bool cube) const;
};
// The options behind a LightMapResolution, as the renderer's and the masks' options name them
// (`<prefix>_texels_per_pixel`, `min_<prefix>_resolution`, `max_<prefix>_resolution`,
// `max_cube_resolution`): texels per pixel in (0, 64], bounds in [16, 16384], min <= max.
Status ValidateLightMapResolution(const char* prefix, double texels_per_pixel, int min_resolution,
                                  int max_resolution, int max_cube_resolution);

// InvalidArgument when `shape` is kFitted and the light is not outside the sphere.
StatusOr<LightMapPlan> PlanLightMap(bool point_light, const Vec3d& light_in_object,
                                    const Vec3d& light_dir_in_object, const Vec3d& centre,
                                    double radius, LightMapShape shape,
                                    const LightMapResolution& resolution);

// The light-map pass's pipeline: depth-only, `vertex` and `fragment` (which writes the distance
// as depth), set 0 of `set_layout` (the parameter block and the corners), push constant
// LightMapPush. Created for one light-map target, it serves any other (their render passes differ
// only in size and layer count, which do not break compatibility).
StatusOr<Pipeline> CreateLightMapPipeline(VkContext& ctx, ShaderId vertex, ShaderId fragment,
                                          VkDescriptorSetLayout set_layout,
                                          const RenderTarget& target);
// Records the views 0 .. view_count - 1 of a light map, each into its layer of `target` cleared
// to depth 1 (the map stores distance / scale: 1 = nothing before the scale), drawing
// 3 x triangle_count non-indexed vertices with `pipeline` and `set`.
void RecordLightMapViews(VkCommandBuffer cmd, const Pipeline& pipeline, VkDescriptorSet set,
                         RenderTarget& target, uint32_t view_count, uint32_t triangle_count);

// The light-map pass: a depth-only draw of every triangle into each view's layer of a D32 map,
// sampled afterwards (SHADER_READ_ONLY_OPTIMAL). Its descriptor set 0 holds two storage buffers
// read by the vertex and fragment stages — the pass's parameter block (whose views the vertex
// stage projects with) and the de-indexed triangle corners; its push constant is the view (one
// uint, shared/light_map_view.h LightMapPush).
class LightMapPass {
 public:
  struct Options {
    ShaderId vertex = ShaderId::kCount;    // required
    ShaderId fragment = ShaderId::kCount;  // required: writes the distance as depth
    uint32_t params_binding = 0;
    uint32_t corners_binding = 1;
  };
  static StatusOr<LightMapPass> Create(VkContext& ctx, const Options& options);

  // The set layout and set (other passes that read the same two buffers may share them).
  const DescriptorSetLayout& layout() const { return layout_; }
  const DescriptorSet& set() const { return set_; }
  // Points the set at the parameter block and the corners. No submission using it may run.
  void WriteBuffers(const Buffer& params, const Buffer& corners);
  // A map of `layers` views of resolution x resolution texels (recreated when either changes;
  // the pipeline is created with the first).
  Status EnsureTarget(VkContext& ctx, uint32_t resolution, uint32_t layers);
  // The map's depth image (after EnsureTarget).
  const DeviceImage& depth() const { return *target_->depth; }
  // Records the views 0 .. view_count - 1, each into its layer cleared to depth 1 (the map
  // stores distance / scale: 1 = nothing before the scale), drawing 3 x triangle_count
  // non-indexed vertices.
  void Record(VkCommandBuffer cmd, uint32_t view_count, uint32_t triangle_count);

 private:
  Options options_;
  DescriptorSetLayout layout_;
  DescriptorSet set_;
  Pipeline pipeline_;
  std::unique_ptr<PassTarget> target_;
};

}  // namespace reflcap::gpu
