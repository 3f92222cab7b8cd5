#include "engine/gpu/vk_commands.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <utility>

#include "engine/gpu/vk_status.h"

namespace reflcap::gpu {
namespace {

// Descriptor pools are created on demand, each for this many sets and storage-buffer
// descriptors; Begin() resets them all.
constexpr uint32_t kSetsPerPool = 64;
constexpr uint32_t kDescriptorsPerPool = 512;

}  // namespace

StatusOr<CommandBuffer> CommandBuffer::Create(VkContext& ctx) {
  CommandBuffer cmd;
  cmd.ctx_ = &ctx;
  VkCommandBufferAllocateInfo alloc{};
  alloc.sType = VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO;
  alloc.commandPool = ctx.command_pool();
  alloc.level = VK_COMMAND_BUFFER_LEVEL_PRIMARY;
  alloc.commandBufferCount = 1;
  VK_RETURN_IF_ERROR(vkAllocateCommandBuffers(ctx.device(), &alloc, &cmd.command_buffer_));
  VkFenceCreateInfo fence_info{};
  fence_info.sType = VK_STRUCTURE_TYPE_FENCE_CREATE_INFO;
  VK_RETURN_IF_ERROR(vkCreateFence(ctx.device(), &fence_info, nullptr, &cmd.fence_));
  return cmd;
}

CommandBuffer::~CommandBuffer() { Release(); }

CommandBuffer::CommandBuffer(CommandBuffer&& other) noexcept { *this = std::move(other); }

CommandBuffer& CommandBuffer::operator=(CommandBuffer&& other) noexcept {
  if (this != &other) {
    Release();
    ctx_ = std::exchange(other.ctx_, nullptr);
    command_buffer_ = std::exchange(other.command_buffer_, VK_NULL_HANDLE);
    fence_ = std::exchange(other.fence_, VK_NULL_HANDLE);
    pools_ = std::move(other.pools_);
    other.pools_.clear();
    pool_index_ = other.pool_index_;
    sets_in_pool_ = other.sets_in_pool_;
    descriptors_in_pool_ = other.descriptors_in_pool_;
    recording_ = std::exchange(other.recording_, false);
    pending_ = std::exchange(other.pending_, false);
    last_submit_wall_s_ = other.last_submit_wall_s_;
  }
  return *this;
}

void CommandBuffer::Release() {
  if (ctx_ == nullptr) return;
  const VkDevice device = ctx_->device();
  if (pending_) {
    // A submission that timed out may still run; its command buffer and descriptor sets must
    // outlive it. Device loss makes this wait return too.
    vkWaitForFences(device, 1, &fence_, VK_TRUE, UINT64_MAX);
    pending_ = false;
  }
  for (VkDescriptorPool pool : pools_) vkDestroyDescriptorPool(device, pool, nullptr);
  pools_.clear();
  if (fence_ != VK_NULL_HANDLE) vkDestroyFence(device, fence_, nullptr);
  if (command_buffer_ != VK_NULL_HANDLE) {
    vkFreeCommandBuffers(device, ctx_->command_pool(), 1, &command_buffer_);
  }
  fence_ = VK_NULL_HANDLE;
  command_buffer_ = VK_NULL_HANDLE;
  ctx_ = nullptr;
}

Status CommandBuffer::CheckRecording(const char* what) const {
  if (ctx_ == nullptr) return FailedPreconditionError(what, ": empty CommandBuffer");
  if (!recording_) return FailedPreconditionError(what, ": CommandBuffer is not recording (Begin)");
  return OkStatus();
}

Status CommandBuffer::Begin() {
  if (ctx_ == nullptr) return FailedPreconditionError("Begin: empty CommandBuffer");
  if (pending_) {
    const VkResult r = vkWaitForFences(ctx_->device(), 1, &fence_, VK_TRUE, 0);
    if (r == VK_TIMEOUT) {
      return FailedPreconditionError(
          "Begin: the previous submission, which timed out, is still "
          "running");
    }
    VK_RETURN_IF_ERROR(r);
    pending_ = false;
  }
  for (VkDescriptorPool pool : pools_) {
    VK_RETURN_IF_ERROR(vkResetDescriptorPool(ctx_->device(), pool, 0));
  }
  pool_index_ = 0;
  sets_in_pool_ = 0;
  descriptors_in_pool_ = 0;
  VK_RETURN_IF_ERROR(vkResetCommandBuffer(command_buffer_, 0));
  VkCommandBufferBeginInfo begin{};
  begin.sType = VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO;
  begin.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
  VK_RETURN_IF_ERROR(vkBeginCommandBuffer(command_buffer_, &begin));
  recording_ = true;
  return OkStatus();
}

StatusOr<VkDescriptorSet> CommandBuffer::AllocateSet(VkDescriptorSetLayout layout,
                                                     uint32_t num_descriptors) {
  if (num_descriptors > kDescriptorsPerPool) {
    return InvalidArgumentError("Dispatch: ", num_descriptors, " bindings (at most ",
                                kDescriptorsPerPool, ")");
  }
  const bool full = pool_index_ >= pools_.size() || sets_in_pool_ == kSetsPerPool ||
                    descriptors_in_pool_ + num_descriptors > kDescriptorsPerPool;
  if (full) {
    if (pool_index_ < pools_.size()) ++pool_index_;
    sets_in_pool_ = 0;
    descriptors_in_pool_ = 0;
    if (pool_index_ >= pools_.size()) {
      VkDescriptorPoolSize size{VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, kDescriptorsPerPool};
      VkDescriptorPoolCreateInfo info{};
      info.sType = VK_STRUCTURE_TYPE_DESCRIPTOR_POOL_CREATE_INFO;
      info.maxSets = kSetsPerPool;
      info.poolSizeCount = 1;
      info.pPoolSizes = &size;
      VkDescriptorPool pool = VK_NULL_HANDLE;
      VK_RETURN_IF_ERROR(vkCreateDescriptorPool(ctx_->device(), &info, nullptr, &pool));
      pools_.push_back(pool);
      pool_index_ = pools_.size() - 1;
    }
  }
  VkDescriptorSetAllocateInfo alloc{};
  alloc.sType = VK_STRUCTURE_TYPE_DESCRIPTOR_SET_ALLOCATE_INFO;
  alloc.descriptorPool = pools_[pool_index_];
  alloc.descriptorSetCount = 1;
  alloc.pSetLayouts = &layout;
  VkDescriptorSet set = VK_NULL_HANDLE;
  VK_RETURN_IF_ERROR(vkAllocateDescriptorSets(ctx_->device(), &alloc, &set));
  ++sets_in_pool_;
  descriptors_in_pool_ += num_descriptors;
  return set;
}

Status CommandBuffer::Dispatch(const ComputePipeline& pipeline,
                               const std::vector<BufferBinding>& bindings, PushConstants push,
                               uint32_t groups_x, uint32_t groups_y, uint32_t groups_z) {
  REFLCAP_RETURN_IF_ERROR(CheckRecording("Dispatch"));
  const DeviceInfo& d = ctx_->info();
  if (pipeline.pipeline() == VK_NULL_HANDLE)
    return InvalidArgumentError("Dispatch: empty pipeline");
  const char* name = ShaderName(pipeline.shader());
  if (bindings.size() != pipeline.num_buffers()) {
    return InvalidArgumentError("Dispatch ", name, ": ", bindings.size(), " bindings for ",
                                pipeline.num_buffers(), " storage buffers");
  }
  if (push.size != pipeline.push_constant_bytes() || (push.size > 0 && push.data == nullptr)) {
    return InvalidArgumentError("Dispatch ", name, ": ", push.size,
                                " bytes of push constants for a ", pipeline.push_constant_bytes(),
                                "-byte block");
  }
  const uint32_t groups[3] = {groups_x, groups_y, groups_z};
  for (int i = 0; i < 3; ++i) {
    if (groups[i] > d.max_compute_work_group_count[i]) {
      return InvalidArgumentError("Dispatch ", name, ": ", groups[i], " workgroups along axis ", i,
                                  " (device limit ", d.max_compute_work_group_count[i],
                                  "); split the work into chunks");
    }
  }

  std::vector<VkDescriptorBufferInfo> infos(bindings.size());
  for (size_t i = 0; i < bindings.size(); ++i) {
    const BufferBinding& b = bindings[i];
    if (b.buffer == nullptr || b.buffer->handle() == VK_NULL_HANDLE) {
      return InvalidArgumentError("Dispatch ", name, ": binding ", i, " has no buffer");
    }
    if (b.offset >= b.buffer->size() || b.offset % d.min_storage_buffer_offset_alignment != 0) {
      return InvalidArgumentError("Dispatch ", name, ": binding ", i, " offset ", b.offset,
                                  " is outside the ", b.buffer->size(),
                                  "-byte buffer or not a multiple of ",
                                  d.min_storage_buffer_offset_alignment);
    }
    const uint64_t size = b.size == kWholeSize ? b.buffer->size() - b.offset : b.size;
    if (size == 0 || size > b.buffer->size() - b.offset) {
      return InvalidArgumentError("Dispatch ", name, ": binding ", i, " range [", b.offset, ", ",
                                  b.offset + size, ") is empty or exceeds the ", b.buffer->size(),
                                  "-byte buffer");
    }
    if (size > d.max_storage_buffer_range) {
      return InvalidArgumentError("Dispatch ", name, ": binding ", i, " spans ", size,
                                  " bytes, more than maxStorageBufferRange ",
                                  d.max_storage_buffer_range,
                                  "; bind it in chunks (engine/gpu/chunking.h)");
    }
    infos[i] = {b.buffer->handle(), b.offset, size};
  }
  if (groups_x == 0 || groups_y == 0 || groups_z == 0) return OkStatus();

  REFLCAP_ASSIGN_OR_RETURN(VkDescriptorSet set,
                           AllocateSet(pipeline.set_layout(), pipeline.num_buffers()));
  std::vector<VkWriteDescriptorSet> writes(bindings.size());
  for (size_t i = 0; i < bindings.size(); ++i) {
    writes[i] = {};
    writes[i].sType = VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET;
    writes[i].dstSet = set;
    writes[i].dstBinding = static_cast<uint32_t>(i);
    writes[i].descriptorCount = 1;
    writes[i].descriptorType = VK_DESCRIPTOR_TYPE_STORAGE_BUFFER;
    writes[i].pBufferInfo = &infos[i];
  }
  vkUpdateDescriptorSets(ctx_->device(), static_cast<uint32_t>(writes.size()), writes.data(), 0,
                         nullptr);
  vkCmdBindPipeline(command_buffer_, VK_PIPELINE_BIND_POINT_COMPUTE, pipeline.pipeline());
  vkCmdBindDescriptorSets(command_buffer_, VK_PIPELINE_BIND_POINT_COMPUTE, pipeline.layout(), 0, 1,
                          &set, 0, nullptr);
  if (push.size > 0) {
    vkCmdPushConstants(command_buffer_, pipeline.layout(), VK_SHADER_STAGE_COMPUTE_BIT, 0,
                       push.size, push.data);
  }
  vkCmdDispatch(command_buffer_, groups_x, groups_y, groups_z);
  Barrier();
  return OkStatus();
}

Status CommandBuffer::CopyBuffer(const Buffer& src, uint64_t src_offset, const Buffer& dst,
                                 uint64_t dst_offset, uint64_t size) {
  REFLCAP_RETURN_IF_ERROR(CheckRecording("CopyBuffer"));
  if (src_offset > src.size() || size > src.size() - src_offset || dst_offset > dst.size() ||
      size > dst.size() - dst_offset) {
    return InvalidArgumentError("CopyBuffer: ", size, " bytes from offset ", src_offset, " of ",
                                src.size(), " to offset ", dst_offset, " of ", dst.size());
  }
  if (size == 0) return OkStatus();
  const VkBufferCopy region{src_offset, dst_offset, size};
  vkCmdCopyBuffer(command_buffer_, src.handle(), dst.handle(), 1, &region);
  Barrier();
  return OkStatus();
}

Status CommandBuffer::FillBuffer(const Buffer& dst, uint64_t offset, uint64_t size,
                                 uint32_t value) {
  REFLCAP_RETURN_IF_ERROR(CheckRecording("FillBuffer"));
  const uint64_t n = size == kWholeSize ? (dst.size() - offset) / 4 * 4 : size;
  if (offset % 4 != 0 || n % 4 != 0 || offset > dst.size() || n > dst.size() - offset) {
    return InvalidArgumentError("FillBuffer: ", n, " bytes at offset ", offset, " of ", dst.size(),
                                " (offset and size must be multiples of 4)");
  }
  if (n == 0) return OkStatus();
  vkCmdFillBuffer(command_buffer_, dst.handle(), offset, n, value);
  Barrier();
  return OkStatus();
}

void CommandBuffer::Barrier() {
  VkMemoryBarrier barrier{};
  barrier.sType = VK_STRUCTURE_TYPE_MEMORY_BARRIER;
  barrier.srcAccessMask = VK_ACCESS_SHADER_WRITE_BIT | VK_ACCESS_TRANSFER_WRITE_BIT;
  barrier.dstAccessMask = VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_SHADER_WRITE_BIT |
                          VK_ACCESS_TRANSFER_READ_BIT | VK_ACCESS_TRANSFER_WRITE_BIT;
  constexpr VkPipelineStageFlags kStages =
      VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT | VK_PIPELINE_STAGE_TRANSFER_BIT;
  vkCmdPipelineBarrier(command_buffer_, kStages, kStages, 0, 1, &barrier, 0, nullptr, 0, nullptr);
}

Status CommandBuffer::SubmitAndWait() {
  if (ctx_ == nullptr) return FailedPreconditionError("SubmitAndWait: empty CommandBuffer");
  return SubmitAndWait(ctx_->options().submit_timeout_s);
}

Status CommandBuffer::SubmitAndWait(double timeout_s) {
  REFLCAP_RETURN_IF_ERROR(Submit());
  return Wait(timeout_s);
}

Status CommandBuffer::Wait() {
  if (ctx_ == nullptr) return FailedPreconditionError("Wait: empty CommandBuffer");
  return Wait(ctx_->options().submit_timeout_s);
}

Status CommandBuffer::Submit() {
  REFLCAP_RETURN_IF_ERROR(CheckRecording("Submit"));
  recording_ = false;
  // Device writes become visible to host reads of mapped memory once the fence has signalled.
  VkMemoryBarrier to_host{};
  to_host.sType = VK_STRUCTURE_TYPE_MEMORY_BARRIER;
  to_host.srcAccessMask = VK_ACCESS_SHADER_WRITE_BIT | VK_ACCESS_TRANSFER_WRITE_BIT;
  to_host.dstAccessMask = VK_ACCESS_HOST_READ_BIT;
  vkCmdPipelineBarrier(command_buffer_,
                       VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT | VK_PIPELINE_STAGE_TRANSFER_BIT,
                       VK_PIPELINE_STAGE_HOST_BIT, 0, 1, &to_host, 0, nullptr, 0, nullptr);
  VK_RETURN_IF_ERROR(vkEndCommandBuffer(command_buffer_));
  VK_RETURN_IF_ERROR(vkResetFences(ctx_->device(), 1, &fence_));

  VkSubmitInfo submit{};

  submit.sType = VK_STRUCTURE_TYPE_SUBMIT_INFO;
  submit.commandBufferCount = 1;
  submit.pCommandBuffers = &command_buffer_;
  submit_start_ = std::chrono::steady_clock::now();
  VK_RETURN_IF_ERROR(vkQueueSubmit(ctx_->queue(), 1, &submit, fence_));
  pending_ = true;
  return OkStatus();
}

Status CommandBuffer::Wait(double timeout_s) {
  if (!pending_) return OkStatus();
  const double timeout_ns = std::max(0.0, timeout_s) * 1e9;
  const uint64_t timeout = timeout_ns >= 1.8e19 ? UINT64_MAX : static_cast<uint64_t>(timeout_ns);
  const VkResult r = vkWaitForFences(ctx_->device(), 1, &fence_, VK_TRUE, timeout);
  if (r == VK_TIMEOUT) {
    return UnavailableError("the Vulkan submission did not finish within ", timeout_s, " s on ",
                            ctx_->info().name, "; split the work into shorter submissions");
  }
  VK_RETURN_IF_ERROR(r);
  pending_ = false;
  last_submit_wall_s_ =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - submit_start_).count();
  return OkStatus();
}

}  // namespace reflcap::gpu
