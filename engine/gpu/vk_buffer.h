#pragma once
// Buffer: one VkBuffer with its own VkDeviceMemory (reflcap makes few, large allocations, so no
// sub-allocator), plus host<->device copy helpers.
//
//   MemoryKind::kDevice   storage buffer in DEVICE_LOCAL memory (usage: storage, transfer
//                         src/dst). On unified-memory devices (lavapipe, integrated GPUs,
//                         resizable BAR) the chosen type may also be host-visible and coherent;
//                         then it is mapped and Upload/Download copy directly.
//   MemoryKind::kHost     HOST_VISIBLE | HOST_COHERENT (HOST_CACHED preferred, for read-back),
//                         always mapped; staging, or small buffers the host reads often.
//
// Sizes are bytes. Create refuses a size above VkContext::max_allocation_bytes() (1 GiB, or less
// where the device's maxMemoryAllocationSize or heap is smaller) with Unavailable before calling
// Vulkan: lavapipe crashes on allocations above 2 GiB rather than failing. Larger data sets are
// split into several buffers or processed in chunks (engine/gpu/chunking.h).
#include <vulkan/vulkan.h>

#include <cstdint>
#include <functional>
#include <memory>
#include <vector>

#include "engine/core/status.h"
#include "engine/gpu/vk_context.h"

namespace reflcap::gpu {

enum class MemoryKind { kDevice, kHost };

class Buffer {
 public:
  // A buffer of size_bytes (> 0) bytes, contents undefined.
  static StatusOr<Buffer> Create(VkContext& ctx, uint64_t size_bytes, MemoryKind kind);

  Buffer() = default;
  ~Buffer();
  Buffer(Buffer&& other) noexcept;
  Buffer& operator=(Buffer&& other) noexcept;
  Buffer(const Buffer&) = delete;
  Buffer& operator=(const Buffer&) = delete;

  VkBuffer handle() const { return buffer_; }
  uint64_t size() const { return size_; }
  MemoryKind kind() const { return kind_; }
  // Host pointer to the whole buffer when it is host-visible and coherent, else nullptr.
  void* mapped() const { return mapped_; }
  bool host_visible() const { return mapped_ != nullptr; }

 private:
  void Release();

  VkDevice device_ = VK_NULL_HANDLE;
  VkBuffer buffer_ = VK_NULL_HANDLE;
  VkDeviceMemory memory_ = VK_NULL_HANDLE;
  uint64_t size_ = 0;
  MemoryKind kind_ = MemoryKind::kDevice;
  void* mapped_ = nullptr;
};

// Bytes per staging copy when a buffer is not host-visible: uploads and downloads go through a
// ring of kStagingSlots pieces of this size in a host buffer, the host copying some while the
// device copies the others (PCIe DMA and host memcpy overlap). Each piece costs a submission and
// a wake-up of the copy threads, so larger pieces won on a GPU: a 64 MiB transfer on an H200
// (reflcap_gpu_bench, 2026-11-28, copy threads kept in a pool) moved 8.0 / 12.6 / 11.6 / 16.6
// GB/s up and 9.1 / 13.4 / 12.6 / 14.7 down in pieces of 4 / 8 / 16 / 32 MiB. Up to 128 MiB of
// pinned host memory, allocated on the first staged transfer (a device whose memory the host maps,
// such as lavapipe, never stages).
inline constexpr uint64_t kStagingChunkBytes = uint64_t{32} << 20;  // 32 MiB
inline constexpr int kStagingSlots = 4;
// Host copies of at least kParallelCopyBytes are split into kCopyBlockBytes blocks over up to
// kMaxCopyThreads threads (the caller and a pool kept for the process): one core's memcpy
// (~10 GB/s) is below a PCIe 4/5 link's DMA rate; eight cores saturate a socket's memory
// bandwidth, more only contend.
inline constexpr uint64_t kParallelCopyBytes = uint64_t{4} << 20;
inline constexpr uint64_t kCopyBlockBytes = uint64_t{1} << 20;
inline constexpr int kMaxCopyThreads = 8;

// memcpy, split over threads for large copies (see kParallelCopyBytes).
void CopyBytes(void* dst, const void* src, uint64_t size);

// Copies `size` bytes from `src` into `dst` at `dst_offset` and waits until they are there (a
// direct memcpy when dst is host-visible, else through staging). InvalidArgument when the range
// does not fit in dst.
Status Upload(VkContext& ctx, const void* src, uint64_t size, Buffer& dst, uint64_t dst_offset = 0);
// Copies `size` bytes of `src` from `src_offset` into host memory `dst`, after all work submitted
// so far has finished.
Status Download(VkContext& ctx, const Buffer& src, uint64_t src_offset, uint64_t size, void* dst);

// The staging paths of Upload and Download, for any buffer: through pieces of
// min(size, staging_bytes) bytes (> 0) in up to kStagingSlots slots of the context's reusable
// staging buffer (VkContext::StagingBuffer), one submission per piece, the host's copies of some
// pieces overlapping the device's of others. Upload/Download use them with
// kStagingChunkBytes when the buffer is not host-visible; tests call them directly because on
// unified-memory devices (lavapipe) every buffer is.
Status UploadStaged(VkContext& ctx, const void* src, uint64_t size, Buffer& dst,
                    uint64_t dst_offset, uint64_t staging_bytes);
Status DownloadStaged(VkContext& ctx, const Buffer& src, uint64_t src_offset, uint64_t size,
                      void* dst, uint64_t staging_bytes);
// UploadStaged's ring for a destination that is not a Buffer (a texel buffer): `record` records,
// into a command buffer being recorded, the device's copy of `n` bytes from `staging` at
// `staging_offset` to the destination at byte `done` of the upload (and any barrier its readers
// need). Returns when every piece is there.
class CommandBuffer;
using RecordStagedCopy = std::function<Status(CommandBuffer& cmd, const Buffer& staging,
                                              uint64_t staging_offset, uint64_t done, uint64_t n)>;
Status UploadThroughStaging(VkContext& ctx, const void* src, uint64_t size, uint64_t staging_bytes,
                            const RecordStagedCopy& record);

// Makes *buffer a host-visible buffer of at least `bytes` (16 when bytes is 0: a binding needs a
// buffer even when it is empty), reusing the current one when it is large enough.
Status EnsureHostBuffer(VkContext& ctx, std::unique_ptr<Buffer>* buffer, uint64_t bytes);

// A device buffer holding `values` (at least one element).
template <typename T>
StatusOr<Buffer> CreateBufferFrom(VkContext& ctx, const std::vector<T>& values,
                                  MemoryKind kind = MemoryKind::kDevice) {
  REFLCAP_ASSIGN_OR_RETURN(Buffer buffer, Buffer::Create(ctx, values.size() * sizeof(T), kind));
  REFLCAP_RETURN_IF_ERROR(Upload(ctx, values.data(), values.size() * sizeof(T), buffer));
  return buffer;
}

// The first `count` elements of `buffer` as T.
template <typename T>
StatusOr<std::vector<T>> DownloadVector(VkContext& ctx, const Buffer& buffer, size_t count) {
  std::vector<T> values(count);
  REFLCAP_RETURN_IF_ERROR(Download(ctx, buffer, 0, count * sizeof(T), values.data()));
  return values;
}

}  // namespace reflcap::gpu
