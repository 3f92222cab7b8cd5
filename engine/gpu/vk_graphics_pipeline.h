#pragma once
// Rasterisation on top of the compute foundation: RenderTarget (a VkRenderPass of one subpass and
// one framebuffer per array layer over DeviceImages) and Pipeline (a graphics pipeline of a
// vertex + fragment shader pair, or a compute pipeline, over one DescriptorSetLayout).
//
// Conventions (Vulkan 1.0 core render passes; no dynamic rendering, no vertex input):
//   - Vertices are pulled from storage buffers with gl_VertexIndex, so pipelines declare no
//     vertex attributes; draws are non-indexed triangle lists (vkCmdDraw(3 * triangles)).
//   - Every attachment is cleared at the start of the pass and stored at its end, and ends in the
//     final layout given for its kind (RenderTarget::Create).
//     External subpass dependencies order the pass after earlier shader/transfer work (PassWait
//     says which) and make its attachment writes visible to later fragment/compute shaders and
//     transfers.
//   - Viewport and scissor are dynamic and set by RenderTarget::Begin to the whole target.
//   - Push constants (if any) are visible to every stage of the pipeline.
//   - Specialization constants apply to every stage.
#include <vulkan/vulkan.h>

#include <cstdint>
#include <vector>

#include "engine/core/status.h"
#include "engine/gpu/shader_blobs.h"
#include "engine/gpu/vk_context.h"
#include "engine/gpu/vk_image.h"
#include "engine/gpu/vk_pipeline.h"

namespace reflcap::gpu {

// What a render pass waits for before it writes its attachments (its external dependency from
// earlier commands). Every mode makes the pass's own writes visible to later fragment and compute
// shaders and transfers, and waits for earlier passes' attachment writes (which orders passes).
enum class PassWait {
  // Earlier fragment and compute shaders, transfers and passes: safe whatever read the
  // attachments before (a shared target that an earlier image's copy reads).
  kEverything,
  // Earlier fragment and compute shaders and passes, not transfers: for attachments that shaders
  // sample but no transfer reads or writes (shadow maps). A pass then need not wait for an
  // earlier image's copy to the host.
  kShaderReads,
  // Earlier passes only: for attachments that nothing recorded earlier in the same submission
  // touches (a target of the image's own), whose earlier uses a fence has already seen finish.
  kPasses,
};

class RenderTarget {
 public:
  // A render pass drawing into `colors` (in order: fragment output locations 0, 1, ...) and
  // `depth` (may be null), all of the same size and layer count; one framebuffer per layer. The
  // images must outlive the RenderTarget and must not be moved (it keeps their addresses to
  // update their tracked layouts in End). Colour attachments end in `color_final_layout`, depth
  // in `depth_final_layout` (SHADER_READ_ONLY_OPTIMAL for a depth image sampled afterwards, such
  // as a shadow map).
  static StatusOr<RenderTarget> Create(
      VkContext& ctx, const std::vector<DeviceImage*>& colors, DeviceImage* depth,
      VkImageLayout color_final_layout,
      VkImageLayout depth_final_layout = VK_IMAGE_LAYOUT_DEPTH_STENCIL_ATTACHMENT_OPTIMAL,
      PassWait wait = PassWait::kEverything);

  RenderTarget() = default;
  ~RenderTarget();
  RenderTarget(RenderTarget&& other) noexcept;
  RenderTarget& operator=(RenderTarget&& other) noexcept;
  RenderTarget(const RenderTarget&) = delete;
  RenderTarget& operator=(const RenderTarget&) = delete;

  VkRenderPass render_pass() const { return render_pass_; }
  uint32_t width() const { return width_; }
  uint32_t height() const { return height_; }
  uint32_t layers() const { return uint32_t(framebuffers_.size()); }
  uint32_t color_count() const { return uint32_t(colors_.size()); }

  // Records vkCmdBeginRenderPass on layer `layer`, clearing colour attachment i to color_clear[i]
  // (fewer values: the rest clear to 0) and depth to `depth_clear`, and sets viewport and scissor.
  void Begin(VkCommandBuffer cmd, uint32_t layer, const std::vector<VkClearColorValue>& color_clear,
             float depth_clear = 1.0f);
  // Records vkCmdEndRenderPass; the images' tracked layouts become the pass's final layouts.
  void End(VkCommandBuffer cmd);

 private:
  void Release();

  VkDevice device_ = VK_NULL_HANDLE;
  VkRenderPass render_pass_ = VK_NULL_HANDLE;
  std::vector<VkFramebuffer> framebuffers_;
  std::vector<DeviceImage*> colors_;
  DeviceImage* depth_ = nullptr;
  VkImageLayout color_final_layout_ = VK_IMAGE_LAYOUT_UNDEFINED;
  VkImageLayout depth_final_layout_ = VK_IMAGE_LAYOUT_DEPTH_STENCIL_ATTACHMENT_OPTIMAL;
  uint32_t width_ = 0, height_ = 0;
};

struct GraphicsPipelineOptions {
  ShaderId vertex = ShaderId::kCount;  // required
  // kCount = no fragment stage (a depth-only pass; set color_writes false).
  ShaderId fragment = ShaderId::kCount;
  VkDescriptorSetLayout set_layout = VK_NULL_HANDLE;  // set 0; required
  uint32_t push_constant_bytes = 0;  // multiple of 4, <= maxPushConstantsSize; 0 = none
  VkCullModeFlags cull_mode = VK_CULL_MODE_NONE;
  // Depth test with `depth_compare`, writing depth when `depth_write`, when the target has a
  // depth attachment. A depth pre-pass writes with LESS; the shading pass after it in the same
  // render pass tests EQUAL without writing, so each pixel is shaded once (the vertex stage must
  // then compute gl_Position identically in both: declare it `invariant`).
  bool depth_test = true;
  VkCompareOp depth_compare = VK_COMPARE_OP_LESS;
  bool depth_write = true;
  // Write the colour attachments (off: a depth-only pass).
  bool color_writes = true;
  std::vector<SpecConstant> spec_constants;
};

struct ComputeLayoutPipelineOptions {
  ShaderId shader = ShaderId::kCount;                 // required; local size fixed by the shader
  VkDescriptorSetLayout set_layout = VK_NULL_HANDLE;  // set 0; required
  uint32_t push_constant_bytes = 0;
  std::vector<SpecConstant> spec_constants;
};

// A VkPipeline with its layout and bind point.
class Pipeline {
 public:
  // A graphics pipeline for `target`'s render pass (its colour attachment count and depth).
  static StatusOr<Pipeline> CreateGraphics(VkContext& ctx, const GraphicsPipelineOptions& options,
                                           const RenderTarget& target);
  // A compute pipeline whose set 0 is `options.set_layout` (any binding types).
  static StatusOr<Pipeline> CreateCompute(VkContext& ctx,
                                          const ComputeLayoutPipelineOptions& options);

  Pipeline() = default;
  ~Pipeline();
  Pipeline(Pipeline&& other) noexcept;
  Pipeline& operator=(Pipeline&& other) noexcept;
  Pipeline(const Pipeline&) = delete;
  Pipeline& operator=(const Pipeline&) = delete;

  VkPipeline handle() const { return pipeline_; }
  VkPipelineLayout layout() const { return layout_; }
  VkPipelineBindPoint bind_point() const { return bind_point_; }
  uint32_t push_constant_bytes() const { return push_constant_bytes_; }

  // Records binding the pipeline and `set` as set 0.
  void Bind(VkCommandBuffer cmd, VkDescriptorSet set) const;
  // Records vkCmdPushConstants of `size` bytes (must equal push_constant_bytes()).
  void Push(VkCommandBuffer cmd, const void* data, uint32_t size) const;

 private:
  void Release();

  VkDevice device_ = VK_NULL_HANDLE;
  VkPipelineLayout layout_ = VK_NULL_HANDLE;
  VkPipeline pipeline_ = VK_NULL_HANDLE;
  VkPipelineBindPoint bind_point_ = VK_PIPELINE_BIND_POINT_GRAPHICS;
  VkShaderStageFlags push_stages_ = 0;
  uint32_t push_constant_bytes_ = 0;
};

}  // namespace reflcap::gpu
