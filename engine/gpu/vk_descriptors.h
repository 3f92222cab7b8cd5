#pragma once
// Descriptor sets with mixed binding types — storage buffers, combined image samplers, storage
// images — for pipelines beyond the compute foundation's all-storage-buffer layouts
// (vk_pipeline.h): the renderer's graphics pipelines and the compute passes that read its images.
//
//   DescriptorSetLayout layout = DescriptorSetLayout::Create(ctx, {
//       {0, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, VK_SHADER_STAGE_VERTEX_BIT},
//       {1, VK_DESCRIPTOR_TYPE_COMBINED_IMAGE_SAMPLER, VK_SHADER_STAGE_FRAGMENT_BIT}});
//   DescriptorSet set = DescriptorSet::Create(ctx, layout);   // its own small pool
//   set.WriteBuffer(0, buffer);  set.WriteImage(1, view, sampler, layout);
//
// A set must not be rewritten while a submission that uses it is running (Vulkan's rule); the
// renderer rewrites its sets only between SubmitAndWait calls.
#include <vulkan/vulkan.h>

#include <cstdint>
#include <vector>

#include "engine/core/status.h"
#include "engine/gpu/vk_buffer.h"
#include "engine/gpu/vk_context.h"

namespace reflcap::gpu {

// Short names for the binding lists of DescriptorSetLayout::Create.
constexpr VkDescriptorType kSsbo = VK_DESCRIPTOR_TYPE_STORAGE_BUFFER;
constexpr VkDescriptorType kTex = VK_DESCRIPTOR_TYPE_COMBINED_IMAGE_SAMPLER;
constexpr VkShaderStageFlags kGfx = VK_SHADER_STAGE_VERTEX_BIT | VK_SHADER_STAGE_FRAGMENT_BIT;
constexpr VkShaderStageFlags kComp = VK_SHADER_STAGE_COMPUTE_BIT;

struct DescriptorBinding {
  uint32_t binding = 0;
  VkDescriptorType type = VK_DESCRIPTOR_TYPE_STORAGE_BUFFER;
  VkShaderStageFlags stages = VK_SHADER_STAGE_ALL;
};

class DescriptorSetLayout {
 public:
  // InvalidArgument for an empty list or a binding number used twice.
  static StatusOr<DescriptorSetLayout> Create(VkContext& ctx,
                                              const std::vector<DescriptorBinding>& bindings);
  DescriptorSetLayout() = default;
  ~DescriptorSetLayout();
  DescriptorSetLayout(DescriptorSetLayout&& other) noexcept;
  DescriptorSetLayout& operator=(DescriptorSetLayout&& other) noexcept;
  DescriptorSetLayout(const DescriptorSetLayout&) = delete;
  DescriptorSetLayout& operator=(const DescriptorSetLayout&) = delete;

  VkDescriptorSetLayout handle() const { return layout_; }
  const std::vector<DescriptorBinding>& bindings() const { return bindings_; }

 private:
  VkDevice device_ = VK_NULL_HANDLE;
  VkDescriptorSetLayout layout_ = VK_NULL_HANDLE;
  std::vector<DescriptorBinding> bindings_;
};

// One descriptor set of `layout`, from a pool of its own sized for exactly that set.
class DescriptorSet {
 public:
  static StatusOr<DescriptorSet> Create(VkContext& ctx, const DescriptorSetLayout& layout);
  DescriptorSet() = default;
  ~DescriptorSet();
  DescriptorSet(DescriptorSet&& other) noexcept;
  DescriptorSet& operator=(DescriptorSet&& other) noexcept;
  DescriptorSet(const DescriptorSet&) = delete;
  DescriptorSet& operator=(const DescriptorSet&) = delete;

  VkDescriptorSet handle() const { return set_; }

  // Points storage-buffer binding `binding` at bytes [offset, offset + size) of `buffer` (size
  // VK_WHOLE_SIZE: to the end).
  void WriteBuffer(uint32_t binding, const Buffer& buffer, uint64_t offset = 0,
                   uint64_t size = VK_WHOLE_SIZE);
  // Points image binding `binding` (combined image sampler or storage image, as the layout says)
  // at `view`, read in `layout`; `sampler` is ignored for storage images.
  void WriteImage(uint32_t binding, VkImageView view, VkSampler sampler, VkImageLayout layout);

 private:
  VkDescriptorType TypeOf(uint32_t binding) const;

  VkDevice device_ = VK_NULL_HANDLE;
  VkDescriptorPool pool_ = VK_NULL_HANDLE;
  VkDescriptorSet set_ = VK_NULL_HANDLE;
  std::vector<DescriptorBinding> bindings_;
};

}  // namespace reflcap::gpu
