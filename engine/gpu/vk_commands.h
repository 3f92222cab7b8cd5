#pragma once
// CommandBuffer: records compute dispatches and buffer copies into one primary command buffer,
// submits it to the context's compute queue and waits on a fence with a timeout. Reusable:
// Begin, record, SubmitAndWait, Begin again. After uVkCompute's vulkan/command_buffer.h.
//
// Dispatch binds storage buffers (whole buffers or byte ranges, e.g. one chunk of a larger
// array; see engine/gpu/chunking.h) through a descriptor set that the CommandBuffer allocates
// from its own pools, pushes the push constants and checks everything Vulkan would otherwise
// leave undefined: binding count, range alignment and size against maxStorageBufferRange, push
// size, group counts against maxComputeWorkGroupCount. Every Dispatch, CopyBuffer and FillBuffer
// is followed by a global memory barrier, so each command sees the results of the ones before it;
// SubmitAndWait also makes all writes visible to the host before it returns.
//
// Keep each submission short: a real GPU should finish one in well under a second (desktop
// drivers reset the GPU after ~2 s), so long work is split into several submissions.
#include <vulkan/vulkan.h>

#include <chrono>

#include <cstdint>
#include <type_traits>
#include <vector>

#include "engine/core/status.h"
#include "engine/gpu/chunking.h"
#include "engine/gpu/vk_buffer.h"
#include "engine/gpu/vk_context.h"
#include "engine/gpu/vk_pipeline.h"

namespace reflcap::gpu {

// BufferBinding::size meaning "from offset to the end of the buffer".
inline constexpr uint64_t kWholeSize = ~uint64_t{0};

// A byte range of a buffer bound to one storage-buffer binding.
struct BufferBinding {
  const Buffer* buffer = nullptr;
  uint64_t offset = 0;         // bytes; a multiple of minStorageBufferOffsetAlignment
  uint64_t size = kWholeSize;  // bytes; at most maxStorageBufferRange
};
inline BufferBinding Bind(const Buffer& buffer, uint64_t offset = 0, uint64_t size = kWholeSize) {
  return {&buffer, offset, size};
}
// Elements `range` of an array of `element_size`-byte elements stored in `buffer`.
inline BufferBinding BindElements(const Buffer& buffer, const ElementRange& range,
                                  uint64_t element_size) {
  return {&buffer, range.OffsetBytes(element_size), range.SizeBytes(element_size)};
}

// The bytes of a push-constant block: PushConstants::Of(my_push) or PushConstants{} for none.
struct PushConstants {
  const void* data = nullptr;
  uint32_t size = 0;
  template <typename T>
  static PushConstants Of(const T& value) {
    static_assert(std::is_trivially_copyable_v<T> && !std::is_pointer_v<T>,
                  "push constants are copied bytewise");
    return {&value, static_cast<uint32_t>(sizeof(T))};
  }
};

class CommandBuffer {
 public:
  static StatusOr<CommandBuffer> Create(VkContext& ctx);

  CommandBuffer() = default;
  ~CommandBuffer();
  CommandBuffer(CommandBuffer&& other) noexcept;
  CommandBuffer& operator=(CommandBuffer&& other) noexcept;
  CommandBuffer(const CommandBuffer&) = delete;
  CommandBuffer& operator=(const CommandBuffer&) = delete;

  // Starts recording, discarding what was recorded before. FailedPrecondition while an earlier
  // submission that timed out is still running.
  Status Begin();

  // Binds `bindings` to bindings 0..n-1 of the pipeline's set 0 and dispatches
  // groups_x x groups_y x groups_z workgroups (0 records nothing). InvalidArgument for a binding,
  // push or group count the pipeline or device does not accept.
  Status Dispatch(const ComputePipeline& pipeline, const std::vector<BufferBinding>& bindings,
                  PushConstants push, uint32_t groups_x, uint32_t groups_y = 1,
                  uint32_t groups_z = 1);
  // vkCmdCopyBuffer of `size` bytes.
  Status CopyBuffer(const Buffer& src, uint64_t src_offset, const Buffer& dst, uint64_t dst_offset,
                    uint64_t size);
  // vkCmdFillBuffer: `size` bytes (a multiple of 4, or kWholeSize) at `offset` (a multiple of 4)
  // set to the 32-bit pattern `value`.
  Status FillBuffer(const Buffer& dst, uint64_t offset, uint64_t size, uint32_t value);

  // Ends recording, submits, and waits until the device has finished (and its writes are
  // visible to the host) or `timeout_s` has passed (default ContextOptions::submit_timeout_s):
  // Unavailable then, and the CommandBuffer cannot Begin again until the work has finished.
  Status SubmitAndWait();
  Status SubmitAndWait(double timeout_s);
  // The two halves of SubmitAndWait, for overlapping host work with the device's: Submit ends
  // recording and submits; Wait waits for that submission (as SubmitAndWait; OkStatus when
  // nothing is pending). Begin may follow only after Wait.
  Status Submit();
  Status Wait();
  Status Wait(double timeout_s);
  // Host wall-clock seconds from vkQueueSubmit to the fence wait's return, for the last
  // successful SubmitAndWait.
  double last_submit_wall_s() const { return last_submit_wall_s_; }

  bool recording() const { return recording_; }
  // A submission was made and not yet seen finished by Wait (or Begin).
  bool pending() const { return pending_; }
  VkCommandBuffer handle() const { return command_buffer_; }
  VkContext& context() const { return *ctx_; }

 private:
  void Release();
  void Barrier();
  StatusOr<VkDescriptorSet> AllocateSet(VkDescriptorSetLayout layout, uint32_t num_descriptors);
  Status CheckRecording(const char* what) const;

  VkContext* ctx_ = nullptr;
  VkCommandBuffer command_buffer_ = VK_NULL_HANDLE;
  VkFence fence_ = VK_NULL_HANDLE;
  std::vector<VkDescriptorPool> pools_;
  size_t pool_index_ = 0;
  uint32_t sets_in_pool_ = 0;
  uint32_t descriptors_in_pool_ = 0;
  bool recording_ = false;
  bool pending_ = false;
  double last_submit_wall_s_ = 0;
  std::chrono::steady_clock::time_point submit_start_;
};

}  // namespace reflcap::gpu
