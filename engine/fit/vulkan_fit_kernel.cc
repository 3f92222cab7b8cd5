#include "engine/fit/vulkan_fit_kernel.h"

#include <algorithm>
#include <cstring>
#include <utility>
#include <vector>

#include "engine/gpu/vk_status.h"

namespace reflcap::fit::internal {

uint64_t MaxTexelBufferElements(const gpu::VkContext& ctx) {
  VkPhysicalDeviceProperties properties{};
  vkGetPhysicalDeviceProperties(ctx.physical_device(), &properties);
  return properties.limits.maxTexelBufferElements;
}

StatusOr<TexelBuffer> TexelBuffer::Create(gpu::VkContext& ctx, uint64_t elements, VkFormat format,
                                          uint32_t element_bytes, bool allow_mapping) {
  if (elements == 0) return InvalidArgumentError("TexelBuffer: no elements");
  const uint64_t bytes = elements * element_bytes;
  if (elements > MaxTexelBufferElements(ctx)) {
    return UnavailableError("Vulkan fitter: a texel buffer of ", elements,
                            " texels exceeds maxTexelBufferElements (", MaxTexelBufferElements(ctx),
                            ") of ", ctx.info().name);
  }
  if (bytes > ctx.max_allocation_bytes()) {
    return UnavailableError("Vulkan fitter: a texel buffer of ", bytes,
                            " bytes exceeds the allocation cap of ", ctx.max_allocation_bytes());
  }
  TexelBuffer t;
  t.device_ = ctx.device();
  t.elements_ = elements;
  t.bytes_ = bytes;
  VkBufferCreateInfo info{};
  info.sType = VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO;
  info.size = bytes;
  info.usage = VK_BUFFER_USAGE_UNIFORM_TEXEL_BUFFER_BIT | VK_BUFFER_USAGE_TRANSFER_DST_BIT;
  info.sharingMode = VK_SHARING_MODE_EXCLUSIVE;
  VK_RETURN_IF_ERROR(vkCreateBuffer(t.device_, &info, nullptr, &t.buffer_));
  VkMemoryRequirements requirements{};
  vkGetBufferMemoryRequirements(t.device_, t.buffer_, &requirements);
  REFLCAP_ASSIGN_OR_RETURN(
      uint32_t type,
      ctx.FindMemoryType(requirements.memoryTypeBits, VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT,
                         VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT | VK_MEMORY_PROPERTY_HOST_COHERENT_BIT));
  VkMemoryAllocateInfo allocate{};
  allocate.sType = VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO;
  allocate.allocationSize = requirements.size;
  allocate.memoryTypeIndex = type;
  VK_RETURN_IF_ERROR(vkAllocateMemory(t.device_, &allocate, nullptr, &t.memory_));
  VK_RETURN_IF_ERROR(vkBindBufferMemory(t.device_, t.buffer_, t.memory_, 0));
  const VkMemoryPropertyFlags flags = ctx.MemoryTypeFlags(type);
  if (allow_mapping && (flags & VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT) &&
      (flags & VK_MEMORY_PROPERTY_HOST_COHERENT_BIT)) {
    VK_RETURN_IF_ERROR(vkMapMemory(t.device_, t.memory_, 0, VK_WHOLE_SIZE, 0, &t.mapped_));
  }
  VkBufferViewCreateInfo view{};
  view.sType = VK_STRUCTURE_TYPE_BUFFER_VIEW_CREATE_INFO;
  view.buffer = t.buffer_;
  view.format = format;
  view.offset = 0;
  view.range = bytes;
  VK_RETURN_IF_ERROR(vkCreateBufferView(t.device_, &view, nullptr, &t.view_));
  return t;
}

Status TexelBuffer::Upload(gpu::VkContext& ctx, const void* data, uint64_t bytes,
                           uint64_t staging_bytes) {
  if (bytes > bytes_) {
    return InvalidArgumentError("TexelBuffer::Upload: ", bytes, " bytes into ", bytes_);
  }
  if (bytes == 0) return OkStatus();
  if (mapped_ != nullptr) {
    gpu::CopyBytes(mapped_, data, bytes);
    return OkStatus();
  }
  return gpu::UploadThroughStaging(
      ctx, data, bytes, staging_bytes,
      [this](gpu::CommandBuffer& cmd, const gpu::Buffer& staging, uint64_t staging_offset,
             uint64_t done, uint64_t n) {
        const VkBufferCopy region{staging_offset, done, n};
        vkCmdCopyBuffer(cmd.handle(), staging.handle(), buffer_, 1, &region);
        // The fit kernel reads the texels in later submissions of the same queue.
        VkMemoryBarrier barrier{};
        barrier.sType = VK_STRUCTURE_TYPE_MEMORY_BARRIER;
        barrier.srcAccessMask = VK_ACCESS_TRANSFER_WRITE_BIT;
        barrier.dstAccessMask = VK_ACCESS_SHADER_READ_BIT;
        vkCmdPipelineBarrier(cmd.handle(), VK_PIPELINE_STAGE_TRANSFER_BIT,
                             VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, 0, 1, &barrier, 0, nullptr, 0,
                             nullptr);
        return OkStatus();
      });
}

TexelBuffer::~TexelBuffer() { Release(); }

TexelBuffer::TexelBuffer(TexelBuffer&& other) noexcept { *this = std::move(other); }

TexelBuffer& TexelBuffer::operator=(TexelBuffer&& other) noexcept {
  if (this != &other) {
    Release();
    device_ = std::exchange(other.device_, VK_NULL_HANDLE);
    buffer_ = std::exchange(other.buffer_, VK_NULL_HANDLE);
    memory_ = std::exchange(other.memory_, VK_NULL_HANDLE);
    view_ = std::exchange(other.view_, VK_NULL_HANDLE);
    mapped_ = std::exchange(other.mapped_, nullptr);
    elements_ = std::exchange(other.elements_, 0);
    bytes_ = std::exchange(other.bytes_, 0);
  }
  return *this;
}

void TexelBuffer::Release() {
  if (device_ == VK_NULL_HANDLE) return;
  if (view_ != VK_NULL_HANDLE) vkDestroyBufferView(device_, view_, nullptr);
  if (buffer_ != VK_NULL_HANDLE) vkDestroyBuffer(device_, buffer_, nullptr);
  if (memory_ != VK_NULL_HANDLE) vkFreeMemory(device_, memory_, nullptr);  // unmaps too
  device_ = VK_NULL_HANDLE;
  view_ = VK_NULL_HANDLE;
  buffer_ = VK_NULL_HANDLE;
  memory_ = VK_NULL_HANDLE;
  mapped_ = nullptr;
}

namespace {

// Binding numbers and types of lm_fit.comp's set 0.
constexpr uint32_t kStorageBindings[] = {0, 1, 2, 4, 5, 6};
constexpr uint32_t kTexelBindings[] = {3};

}  // namespace

StatusOr<std::unique_ptr<LmKernels>> LmKernels::Create(gpu::VkContext& ctx, uint32_t local_size_x) {
  std::unique_ptr<LmKernels> k(new LmKernels());
  k->device_ = ctx.device();
  k->local_size_x_ = local_size_x;
  std::vector<VkDescriptorSetLayoutBinding> bindings;
  for (uint32_t b : kStorageBindings) {
    bindings.push_back({b, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, 1, VK_SHADER_STAGE_COMPUTE_BIT, nullptr});
  }
  for (uint32_t b : kTexelBindings) {
    bindings.push_back(
        {b, VK_DESCRIPTOR_TYPE_UNIFORM_TEXEL_BUFFER, 1, VK_SHADER_STAGE_COMPUTE_BIT, nullptr});
  }
  VkDescriptorSetLayoutCreateInfo set_info{};
  set_info.sType = VK_STRUCTURE_TYPE_DESCRIPTOR_SET_LAYOUT_CREATE_INFO;
  set_info.bindingCount = uint32_t(bindings.size());
  set_info.pBindings = bindings.data();
  VK_RETURN_IF_ERROR(vkCreateDescriptorSetLayout(k->device_, &set_info, nullptr, &k->set_layout_));

  const VkPushConstantRange push{VK_SHADER_STAGE_COMPUTE_BIT, 0,
                                 uint32_t(sizeof(gpu::shared::FitGpuPush))};
  VkPipelineLayoutCreateInfo layout_info{};
  layout_info.sType = VK_STRUCTURE_TYPE_PIPELINE_LAYOUT_CREATE_INFO;
  layout_info.setLayoutCount = 1;
  layout_info.pSetLayouts = &k->set_layout_;
  layout_info.pushConstantRangeCount = 1;
  layout_info.pPushConstantRanges = &push;
  VK_RETURN_IF_ERROR(vkCreatePipelineLayout(k->device_, &layout_info, nullptr, &k->layout_));

  const VkDescriptorPoolSize sizes[] = {
      {VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, uint32_t(std::size(kStorageBindings))},
      {VK_DESCRIPTOR_TYPE_UNIFORM_TEXEL_BUFFER, uint32_t(std::size(kTexelBindings))}};
  VkDescriptorPoolCreateInfo pool_info{};
  pool_info.sType = VK_STRUCTURE_TYPE_DESCRIPTOR_POOL_CREATE_INFO;
  pool_info.maxSets = 1;
  pool_info.poolSizeCount = 2;
  pool_info.pPoolSizes = sizes;
  VK_RETURN_IF_ERROR(vkCreateDescriptorPool(k->device_, &pool_info, nullptr, &k->pool_));
  VkDescriptorSetAllocateInfo allocate{};
  allocate.sType = VK_STRUCTURE_TYPE_DESCRIPTOR_SET_ALLOCATE_INFO;
  allocate.descriptorPool = k->pool_;
  allocate.descriptorSetCount = 1;
  allocate.pSetLayouts = &k->set_layout_;
  VK_RETURN_IF_ERROR(vkAllocateDescriptorSets(k->device_, &allocate, &k->set_));
  return k;
}

LmKernels::~LmKernels() {
  if (device_ == VK_NULL_HANDLE) return;
  for (auto& [key, pipeline] : pipelines_) vkDestroyPipeline(device_, pipeline, nullptr);
  if (pool_ != VK_NULL_HANDLE) vkDestroyDescriptorPool(device_, pool_, nullptr);  // frees set_
  if (layout_ != VK_NULL_HANDLE) vkDestroyPipelineLayout(device_, layout_, nullptr);
  if (set_layout_ != VK_NULL_HANDLE) vkDestroyDescriptorSetLayout(device_, set_layout_, nullptr);
}

StatusOr<VkPipeline> LmKernels::Pipeline(gpu::ShaderId shader, int loss, uint32_t cluster_size,
                                         bool native_math) {
  static_assert(sizeof(gpu::shared::FitGpuClusterPush) == sizeof(gpu::shared::FitGpuPush),
                "both kernels share the pipeline layout's push-constant range");
  const uint64_t key = ((uint64_t(shader) * 4 + uint64_t(loss)) * 64 + cluster_size) * 2 +
                       (native_math ? 1 : 0);
  auto it = pipelines_.find(key);
  if (it != pipelines_.end()) return it->second;
  const gpu::Span spirv = gpu::ShaderBlob(shader);
  VkShaderModuleCreateInfo module_info{};
  module_info.sType = VK_STRUCTURE_TYPE_SHADER_MODULE_CREATE_INFO;
  module_info.codeSize = spirv.size_bytes();
  module_info.pCode = spirv.data;
  VkShaderModule module = VK_NULL_HANDLE;
  VK_RETURN_IF_ERROR(vkCreateShaderModule(device_, &module_info, nullptr, &module));
  // Specialization constants: 0 = local_size_x, 1 = loss (lm_fit.comp's header), 2 = cluster
  // size, 3 = native exp/log (lm_fit_cluster.comp; entries a module does not use are ignored).
  const uint32_t data[4] = {local_size_x_, uint32_t(loss), cluster_size,
                            native_math ? VK_TRUE : VK_FALSE};
  const VkSpecializationMapEntry entries[4] = {
      {gpu::kLocalSizeXConstantId, 0, 4},
      {1, 4, 4},
      {uint32_t(gpu::shared::kFitClusterSizeConstantId), 8, 4},
      {uint32_t(gpu::shared::kFitNativeMathConstantId), 12, sizeof(VkBool32)}};
  VkSpecializationInfo spec{};
  spec.mapEntryCount = 4;
  spec.pMapEntries = entries;
  spec.dataSize = sizeof data;
  spec.pData = data;
  VkComputePipelineCreateInfo info{};
  info.sType = VK_STRUCTURE_TYPE_COMPUTE_PIPELINE_CREATE_INFO;
  info.stage.sType = VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO;
  info.stage.stage = VK_SHADER_STAGE_COMPUTE_BIT;
  info.stage.module = module;
  info.stage.pName = "main";
  info.stage.pSpecializationInfo = &spec;
  info.layout = layout_;
  VkPipeline pipeline = VK_NULL_HANDLE;
  const VkResult r = vkCreateComputePipelines(device_, VK_NULL_HANDLE, 1, &info, nullptr, &pipeline);
  vkDestroyShaderModule(device_, module, nullptr);
  if (r != VK_SUCCESS) {
    return gpu::VkResultToStatus(r, StrCat("vkCreateComputePipelines(", gpu::ShaderName(shader), ")").c_str(),
                                 __FILE__, __LINE__);
  }
  pipelines_[key] = pipeline;
  return pipeline;
}

void LmKernels::Write(const LmBindings& b) {
  const gpu::BufferBinding* buffers[] = {&b.settings, &b.desc, &b.queue, &b.lanes, &b.results, &b.control};
  VkDescriptorBufferInfo infos[std::size(kStorageBindings)];
  VkWriteDescriptorSet writes[std::size(kStorageBindings) + std::size(kTexelBindings)] = {};
  for (size_t i = 0; i < std::size(kStorageBindings); ++i) {
    infos[i] = {buffers[i]->buffer->handle(), buffers[i]->offset,
                buffers[i]->size == gpu::kWholeSize ? VK_WHOLE_SIZE : buffers[i]->size};
    writes[i].sType = VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET;
    writes[i].dstSet = set_;
    writes[i].dstBinding = kStorageBindings[i];
    writes[i].descriptorCount = 1;
    writes[i].descriptorType = VK_DESCRIPTOR_TYPE_STORAGE_BUFFER;
    writes[i].pBufferInfo = &infos[i];
  }
  const VkBufferView views[] = {b.records};
  for (size_t i = 0; i < std::size(kTexelBindings); ++i) {
    VkWriteDescriptorSet& w = writes[std::size(kStorageBindings) + i];
    w.sType = VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET;
    w.dstSet = set_;
    w.dstBinding = kTexelBindings[i];
    w.descriptorCount = 1;
    w.descriptorType = VK_DESCRIPTOR_TYPE_UNIFORM_TEXEL_BUFFER;
    w.pTexelBufferView = &views[i];
  }
  vkUpdateDescriptorSets(device_, uint32_t(std::size(writes)), writes, 0, nullptr);
}

void LmKernels::RecordDispatch(gpu::CommandBuffer& cmd, VkPipeline pipeline, const void* push,
                               uint32_t groups, bool barrier) const {
  const VkCommandBuffer c = cmd.handle();
  vkCmdBindPipeline(c, VK_PIPELINE_BIND_POINT_COMPUTE, pipeline);
  vkCmdBindDescriptorSets(c, VK_PIPELINE_BIND_POINT_COMPUTE, layout_, 0, 1, &set_, 0, nullptr);
  vkCmdPushConstants(c, layout_, VK_SHADER_STAGE_COMPUTE_BIT, 0,
                     uint32_t(sizeof(gpu::shared::FitGpuPush)), push);
  vkCmdDispatch(c, groups, 1, 1);
  if (!barrier) return;
  VkMemoryBarrier b{};
  b.sType = VK_STRUCTURE_TYPE_MEMORY_BARRIER;
  b.srcAccessMask = VK_ACCESS_SHADER_WRITE_BIT;
  b.dstAccessMask = VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_SHADER_WRITE_BIT |
                    VK_ACCESS_TRANSFER_READ_BIT | VK_ACCESS_TRANSFER_WRITE_BIT;
  vkCmdPipelineBarrier(c, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                       VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT | VK_PIPELINE_STAGE_TRANSFER_BIT, 0, 1,
                       &b, 0, nullptr, 0, nullptr);
}

}  // namespace reflcap::fit::internal
