#include "engine/gpu/vk_buffer.h"

#include <algorithm>
#include <cstring>
#include <utility>

#include "engine/core/parallel.h"
#include "engine/core/worker_pool.h"
#include "engine/gpu/vk_commands.h"
#include "engine/gpu/vk_status.h"

namespace reflcap::gpu {
namespace {

std::string Bytes(uint64_t n) {
  if (n >= (uint64_t{1} << 30)) return StrCat(n / double(uint64_t{1} << 30), " GiB (", n, " B)");
  if (n >= (uint64_t{1} << 20)) return StrCat(n / double(uint64_t{1} << 20), " MiB (", n, " B)");
  return StrCat(n, " B");
}

Status CheckRange(const Buffer& buffer, uint64_t offset, uint64_t size, const char* what) {
  if (buffer.handle() == VK_NULL_HANDLE) return InvalidArgumentError(what, ": empty Buffer");
  if (offset > buffer.size() || size > buffer.size() - offset) {
    return InvalidArgumentError(what, ": bytes [", offset, ", ", offset + size,
                                ") exceed the buffer's ", buffer.size());
  }
  return OkStatus();
}

}  // namespace

StatusOr<Buffer> Buffer::Create(VkContext& ctx, uint64_t size_bytes, MemoryKind kind) {
  if (size_bytes == 0) return InvalidArgumentError("Buffer::Create: size is 0");
  const uint64_t cap = ctx.max_allocation_bytes();
  if (size_bytes > cap) {
    return UnavailableError(
        "a ", Bytes(size_bytes), " buffer exceeds the single-allocation cap of ", Bytes(cap),
        " on ", ctx.info().name, " (min of reflcap's 1 GiB, maxMemoryAllocationSize ",
        Bytes(ctx.info().max_memory_allocation_size), " and the device-local heap ",
        Bytes(ctx.info().device_local_heap_size), "); process the data in chunks");
  }

  Buffer b;
  b.device_ = ctx.device();
  b.size_ = size_bytes;
  b.kind_ = kind;
  VkBufferCreateInfo info{};
  info.sType = VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO;
  info.size = size_bytes;
  info.usage = VK_BUFFER_USAGE_STORAGE_BUFFER_BIT | VK_BUFFER_USAGE_TRANSFER_SRC_BIT |
               VK_BUFFER_USAGE_TRANSFER_DST_BIT;
  info.sharingMode = VK_SHARING_MODE_EXCLUSIVE;
  VK_RETURN_IF_ERROR(vkCreateBuffer(b.device_, &info, nullptr, &b.buffer_));

  VkMemoryRequirements req{};
  vkGetBufferMemoryRequirements(b.device_, b.buffer_, &req);
  constexpr VkMemoryPropertyFlags kHostCoherent =
      VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT | VK_MEMORY_PROPERTY_HOST_COHERENT_BIT;
  StatusOr<uint32_t> type =
      kind == MemoryKind::kDevice
          ? ctx.FindMemoryType(req.memoryTypeBits, VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT)
          : ctx.FindMemoryType(req.memoryTypeBits, kHostCoherent,
                               VK_MEMORY_PROPERTY_HOST_CACHED_BIT);
  if (!type.ok() && kind == MemoryKind::kDevice) {
    // Some devices (software or exotic) expose no DEVICE_LOCAL type for buffers; any type works.
    type = ctx.FindMemoryType(req.memoryTypeBits, 0);
  }
  if (!type.ok()) return type.status();

  VkMemoryAllocateInfo alloc{};

  alloc.sType = VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO;
  alloc.allocationSize = req.size;
  alloc.memoryTypeIndex = *type;
  VK_RETURN_IF_ERROR(vkAllocateMemory(b.device_, &alloc, nullptr, &b.memory_));
  VK_RETURN_IF_ERROR(vkBindBufferMemory(b.device_, b.buffer_, b.memory_, 0));
  if ((ctx.MemoryTypeFlags(*type) & kHostCoherent) == kHostCoherent) {
    VK_RETURN_IF_ERROR(vkMapMemory(b.device_, b.memory_, 0, VK_WHOLE_SIZE, 0, &b.mapped_));
  }
  return b;
}

Buffer::~Buffer() { Release(); }

Buffer::Buffer(Buffer&& other) noexcept { *this = std::move(other); }

Buffer& Buffer::operator=(Buffer&& other) noexcept {
  if (this != &other) {
    Release();
    device_ = std::exchange(other.device_, VK_NULL_HANDLE);
    buffer_ = std::exchange(other.buffer_, VK_NULL_HANDLE);
    memory_ = std::exchange(other.memory_, VK_NULL_HANDLE);
    size_ = std::exchange(other.size_, 0);
    kind_ = other.kind_;
    mapped_ = std::exchange(other.mapped_, nullptr);
  }
  return *this;
}

void Buffer::Release() {
  if (device_ == VK_NULL_HANDLE) return;
  if (buffer_ != VK_NULL_HANDLE) vkDestroyBuffer(device_, buffer_, nullptr);
  if (memory_ != VK_NULL_HANDLE) vkFreeMemory(device_, memory_, nullptr);  // also unmaps
  device_ = VK_NULL_HANDLE;
  buffer_ = VK_NULL_HANDLE;
  memory_ = VK_NULL_HANDLE;
  mapped_ = nullptr;
  size_ = 0;
}

namespace {

// The threads of CopyBytes: started on first use and kept for the process's life, apart from
// ParallelFor's (also kept, engine/core/parallel.cc) so that a transfer is never queued behind
// other work: the fit uploads one batch's records while all cores prepare the next. Threads
// started per piece (the tenth session's ParallelFor) had made the ring of 8 MiB pieces 9.3 GB/s
// up on an H200, where two 32 MiB pieces had measured 15.7. Never destroyed: its idle workers end
// with the process, and no static destructor can find it gone.
WorkerPool& CopyPool() {
  static WorkerPool* const pool =
      new WorkerPool(std::max(1, std::min(HardwareThreads(), kMaxCopyThreads) - 1));
  return *pool;
}

}  // namespace

void CopyBytes(void* dst, const void* src, uint64_t size) {
  if (size < kParallelCopyBytes || HardwareThreads() < 2) {
    std::memcpy(dst, src, size);
    return;
  }
  const int64_t blocks = int64_t((size + kCopyBlockBytes - 1) / kCopyBlockBytes);
  CopyPool().ParallelFor(blocks, [&](int64_t b) {
    const uint64_t begin = uint64_t(b) * kCopyBlockBytes;
    const uint64_t end = std::min(size, begin + kCopyBlockBytes);
    std::memcpy(static_cast<char*>(dst) + begin, static_cast<const char*>(src) + begin,
                end - begin);
  });
}

Status Upload(VkContext& ctx, const void* src, uint64_t size, Buffer& dst, uint64_t dst_offset) {
  REFLCAP_RETURN_IF_ERROR(CheckRange(dst, dst_offset, size, "Upload"));
  if (size == 0) return OkStatus();
  if (!dst.host_visible()) {
    return UploadStaged(ctx, src, size, dst, dst_offset, kStagingChunkBytes);
  }
  CopyBytes(static_cast<char*>(dst.mapped()) + dst_offset, src, size);
  return OkStatus();
}

Status Download(VkContext& ctx, const Buffer& src, uint64_t src_offset, uint64_t size, void* dst) {
  REFLCAP_RETURN_IF_ERROR(CheckRange(src, src_offset, size, "Download"));
  if (size == 0) return OkStatus();
  if (!src.host_visible()) {
    return DownloadStaged(ctx, src, src_offset, size, dst, kStagingChunkBytes);
  }
  CopyBytes(dst, static_cast<const char*>(src.mapped()) + src_offset, size);
  return OkStatus();
}

namespace {

// The staging ring of a transfer of `size` bytes (> 0): piece k of `piece` bytes goes through
// slot k % slots of the context's staging buffer, each slot with its command buffer, so the host
// copies into or out of one slot while the device copies the others.
struct StagingRing {
  uint64_t piece = 0, pieces = 0, slots = 0;
  Buffer* staging = nullptr;
  std::vector<CommandBuffer> cmd;

  static StatusOr<StagingRing> Open(VkContext& ctx, uint64_t size, uint64_t staging_bytes) {
    StagingRing r;
    r.piece = std::min(size, staging_bytes);
    r.pieces = (size + r.piece - 1) / r.piece;
    r.slots = std::min<uint64_t>(r.pieces, kStagingSlots);
    REFLCAP_ASSIGN_OR_RETURN(r.staging, ctx.StagingBuffer(r.piece * r.slots));
    r.cmd.resize(size_t(r.slots));
    for (CommandBuffer& c : r.cmd) {
      REFLCAP_ASSIGN_OR_RETURN(c, CommandBuffer::Create(ctx));
    }
    return r;
  }
  CommandBuffer& CommandOf(uint64_t k) { return cmd[size_t(k % slots)]; }
  uint64_t SlotOffset(uint64_t k) const { return (k % slots) * piece; }
  char* SlotMemory(uint64_t k) const { return static_cast<char*>(staging->mapped()) + SlotOffset(k); }
};

}  // namespace

Status UploadThroughStaging(VkContext& ctx, const void* src, uint64_t size, uint64_t staging_bytes,
                            const RecordStagedCopy& record) {
  if (staging_bytes == 0) return InvalidArgumentError("UploadThroughStaging: staging_bytes is 0");
  if (size == 0) return OkStatus();
  REFLCAP_ASSIGN_OR_RETURN(StagingRing ring, StagingRing::Open(ctx, size, staging_bytes));
  for (uint64_t k = 0; k < ring.pieces; ++k) {
    CommandBuffer& c = ring.CommandOf(k);
    const uint64_t done = k * ring.piece, n = std::min(ring.piece, size - done);
    REFLCAP_RETURN_IF_ERROR(c.Wait());  // its previous copy has left the slot
    CopyBytes(ring.SlotMemory(k), static_cast<const char*>(src) + done, n);
    REFLCAP_RETURN_IF_ERROR(c.Begin());
    REFLCAP_RETURN_IF_ERROR(record(c, *ring.staging, ring.SlotOffset(k), done, n));
    REFLCAP_RETURN_IF_ERROR(c.Submit());
  }
  for (CommandBuffer& c : ring.cmd) REFLCAP_RETURN_IF_ERROR(c.Wait());
  return OkStatus();
}

Status UploadStaged(VkContext& ctx, const void* src, uint64_t size, Buffer& dst,
                    uint64_t dst_offset, uint64_t staging_bytes) {
  REFLCAP_RETURN_IF_ERROR(CheckRange(dst, dst_offset, size, "UploadStaged"));
  return UploadThroughStaging(
      ctx, src, size, staging_bytes,
      [&](CommandBuffer& cmd, const Buffer& staging, uint64_t staging_offset, uint64_t done,
          uint64_t n) { return cmd.CopyBuffer(staging, staging_offset, dst, dst_offset + done, n); });
}

Status DownloadStaged(VkContext& ctx, const Buffer& src, uint64_t src_offset, uint64_t size,
                      void* dst, uint64_t staging_bytes) {
  REFLCAP_RETURN_IF_ERROR(CheckRange(src, src_offset, size, "DownloadStaged"));
  if (staging_bytes == 0) return InvalidArgumentError("DownloadStaged: staging_bytes is 0");
  if (size == 0) return OkStatus();
  // The device copies the next pieces into the other slots while the host copies piece k out.
  REFLCAP_ASSIGN_OR_RETURN(StagingRing ring, StagingRing::Open(ctx, size, staging_bytes));
  auto start_copy = [&](uint64_t k) -> Status {
    CommandBuffer& c = ring.CommandOf(k);
    const uint64_t offset = k * ring.piece;
    REFLCAP_RETURN_IF_ERROR(c.Begin());
    REFLCAP_RETURN_IF_ERROR(c.CopyBuffer(src, src_offset + offset, *ring.staging,
                                         ring.SlotOffset(k), std::min(ring.piece, size - offset)));
    return c.Submit();
  };
  for (uint64_t k = 0; k < ring.slots; ++k) REFLCAP_RETURN_IF_ERROR(start_copy(k));
  for (uint64_t k = 0; k < ring.pieces; ++k) {
    REFLCAP_RETURN_IF_ERROR(ring.CommandOf(k).Wait());
    const uint64_t offset = k * ring.piece;
    CopyBytes(static_cast<char*>(dst) + offset, ring.SlotMemory(k),
              std::min(ring.piece, size - offset));
    if (k + ring.slots < ring.pieces) REFLCAP_RETURN_IF_ERROR(start_copy(k + ring.slots));
  }
  return OkStatus();
}

Status EnsureHostBuffer(VkContext& ctx, std::unique_ptr<Buffer>* buffer, uint64_t bytes) {
  if (*buffer != nullptr && (*buffer)->size() >= bytes) return OkStatus();
  buffer->reset();
  REFLCAP_ASSIGN_OR_RETURN(Buffer b, Buffer::Create(ctx, std::max<uint64_t>(bytes, 16),
                                                    MemoryKind::kHost));
  *buffer = std::make_unique<Buffer>(std::move(b));
  return OkStatus();
}

}  // namespace reflcap::gpu
