#include "engine/gpu/vk_descriptors.h"

#include <map>
#include <set>
#include <utility>

#include "engine/core/check.h"
#include "engine/gpu/vk_status.h"

namespace reflcap::gpu {

StatusOr<DescriptorSetLayout> DescriptorSetLayout::Create(
    VkContext& ctx, const std::vector<DescriptorBinding>& bindings) {
  if (bindings.empty()) return InvalidArgumentError("DescriptorSetLayout: no bindings");
  std::set<uint32_t> seen;
  std::vector<VkDescriptorSetLayoutBinding> vk_bindings;
  for (const DescriptorBinding& b : bindings) {
    if (!seen.insert(b.binding).second) {
      return InvalidArgumentError("DescriptorSetLayout: binding ", b.binding, " is used twice");
    }
    VkDescriptorSetLayoutBinding vb{};
    vb.binding = b.binding;
    vb.descriptorType = b.type;
    vb.descriptorCount = 1;
    vb.stageFlags = b.stages;
    vk_bindings.push_back(vb);
  }
  DescriptorSetLayout l;
  l.device_ = ctx.device();
  l.bindings_ = bindings;
  VkDescriptorSetLayoutCreateInfo info{};
  info.sType = VK_STRUCTURE_TYPE_DESCRIPTOR_SET_LAYOUT_CREATE_INFO;
  info.bindingCount = uint32_t(vk_bindings.size());
  info.pBindings = vk_bindings.data();
  VK_RETURN_IF_ERROR(vkCreateDescriptorSetLayout(l.device_, &info, nullptr, &l.layout_));
  return l;
}

DescriptorSetLayout::~DescriptorSetLayout() {
  if (device_ != VK_NULL_HANDLE && layout_ != VK_NULL_HANDLE) {
    vkDestroyDescriptorSetLayout(device_, layout_, nullptr);
  }
}

DescriptorSetLayout::DescriptorSetLayout(DescriptorSetLayout&& other) noexcept {
  *this = std::move(other);
}

DescriptorSetLayout& DescriptorSetLayout::operator=(DescriptorSetLayout&& other) noexcept {
  if (this != &other) {
    if (device_ != VK_NULL_HANDLE && layout_ != VK_NULL_HANDLE) {
      vkDestroyDescriptorSetLayout(device_, layout_, nullptr);
    }
    device_ = std::exchange(other.device_, VK_NULL_HANDLE);
    layout_ = std::exchange(other.layout_, VK_NULL_HANDLE);
    bindings_ = std::move(other.bindings_);
  }
  return *this;
}

StatusOr<DescriptorSet> DescriptorSet::Create(VkContext& ctx, const DescriptorSetLayout& layout) {
  std::map<VkDescriptorType, uint32_t> counts;
  for (const DescriptorBinding& b : layout.bindings()) ++counts[b.type];
  std::vector<VkDescriptorPoolSize> sizes;
  for (const auto& [type, count] : counts) sizes.push_back({type, count});
  DescriptorSet s;
  s.device_ = ctx.device();
  s.bindings_ = layout.bindings();
  VkDescriptorPoolCreateInfo pool_info{};
  pool_info.sType = VK_STRUCTURE_TYPE_DESCRIPTOR_POOL_CREATE_INFO;
  pool_info.maxSets = 1;
  pool_info.poolSizeCount = uint32_t(sizes.size());
  pool_info.pPoolSizes = sizes.data();
  VK_RETURN_IF_ERROR(vkCreateDescriptorPool(s.device_, &pool_info, nullptr, &s.pool_));
  const VkDescriptorSetLayout set_layout = layout.handle();
  VkDescriptorSetAllocateInfo alloc{};
  alloc.sType = VK_STRUCTURE_TYPE_DESCRIPTOR_SET_ALLOCATE_INFO;
  alloc.descriptorPool = s.pool_;
  alloc.descriptorSetCount = 1;
  alloc.pSetLayouts = &set_layout;
  VK_RETURN_IF_ERROR(vkAllocateDescriptorSets(s.device_, &alloc, &s.set_));
  return s;
}

DescriptorSet::~DescriptorSet() {
  if (device_ != VK_NULL_HANDLE && pool_ != VK_NULL_HANDLE) {
    vkDestroyDescriptorPool(device_, pool_, nullptr);  // frees the set
  }
}

DescriptorSet::DescriptorSet(DescriptorSet&& other) noexcept { *this = std::move(other); }

DescriptorSet& DescriptorSet::operator=(DescriptorSet&& other) noexcept {
  if (this != &other) {
    if (device_ != VK_NULL_HANDLE && pool_ != VK_NULL_HANDLE) {
      vkDestroyDescriptorPool(device_, pool_, nullptr);
    }
    device_ = std::exchange(other.device_, VK_NULL_HANDLE);
    pool_ = std::exchange(other.pool_, VK_NULL_HANDLE);
    set_ = std::exchange(other.set_, VK_NULL_HANDLE);
    bindings_ = std::move(other.bindings_);
  }
  return *this;
}

VkDescriptorType DescriptorSet::TypeOf(uint32_t binding) const {
  for (const DescriptorBinding& b : bindings_) {
    if (b.binding == binding) return b.type;
  }
  REFLCAP_CHECK(false) << "descriptor binding " << binding << " is not in the set's layout";
  return VK_DESCRIPTOR_TYPE_MAX_ENUM;
}

void DescriptorSet::WriteBuffer(uint32_t binding, const Buffer& buffer, uint64_t offset,
                                uint64_t size) {
  VkDescriptorBufferInfo info{buffer.handle(), offset, size};
  VkWriteDescriptorSet write{};
  write.sType = VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET;
  write.dstSet = set_;
  write.dstBinding = binding;
  write.descriptorCount = 1;
  write.descriptorType = TypeOf(binding);
  REFLCAP_CHECK(write.descriptorType == VK_DESCRIPTOR_TYPE_STORAGE_BUFFER)
      << "binding " << binding << " is not a storage buffer";
  write.pBufferInfo = &info;
  vkUpdateDescriptorSets(device_, 1, &write, 0, nullptr);
}

void DescriptorSet::WriteImage(uint32_t binding, VkImageView view, VkSampler sampler,
                               VkImageLayout layout) {
  VkDescriptorImageInfo info{sampler, view, layout};
  VkWriteDescriptorSet write{};
  write.sType = VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET;
  write.dstSet = set_;
  write.dstBinding = binding;
  write.descriptorCount = 1;
  write.descriptorType = TypeOf(binding);
  REFLCAP_CHECK(write.descriptorType == VK_DESCRIPTOR_TYPE_COMBINED_IMAGE_SAMPLER ||
                write.descriptorType == VK_DESCRIPTOR_TYPE_STORAGE_IMAGE)
      << "binding " << binding << " is not an image";
  if (write.descriptorType == VK_DESCRIPTOR_TYPE_STORAGE_IMAGE) info.sampler = VK_NULL_HANDLE;
  write.pImageInfo = &info;
  vkUpdateDescriptorSets(device_, 1, &write, 0, nullptr);
}

}  // namespace reflcap::gpu
