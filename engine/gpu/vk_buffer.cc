#include "engine/gpu/vk_buffer.h"

#include <algorithm>
#include <cstring>
#include <utility>

#include "engine/core/parallel.h"
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

void CopyBytes(void* dst, const void* src, uint64_t size) {
  if (size < kParallelCopyBytes) {
    std::memcpy(dst, src, size);
    return;
  }
  const int64_t blocks = int64_t((size + kCopyBlockBytes - 1) / kCopyBlockBytes);
  ParallelFor(
      0, blocks, 1,
      [&](int64_t b0, int64_t b1, int) {
        const uint64_t begin = uint64_t(b0) * kCopyBlockBytes;
        const uint64_t end = std::min(size, uint64_t(b1) * kCopyBlockBytes);
        std::memcpy(static_cast<char*>(dst) + begin, static_cast<const char*>(src) + begin,
                    end - begin);
      },
      std::min(HardwareThreads(), kMaxCopyThreads));
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

Status UploadStaged(VkContext& ctx, const void* src, uint64_t size, Buffer& dst,
                    uint64_t dst_offset, uint64_t staging_bytes) {
  REFLCAP_RETURN_IF_ERROR(CheckRange(dst, dst_offset, size, "UploadStaged"));
  if (staging_bytes == 0) return InvalidArgumentError("UploadStaged: staging_bytes is 0");
  if (size == 0) return OkStatus();
  // Two halves of the staging buffer, each with its command buffer: the host fills one while the
  // device copies the other.
  const uint64_t piece = std::min(size, staging_bytes);
  const int halves = size > piece ? 2 : 1;
  REFLCAP_ASSIGN_OR_RETURN(Buffer * staging, ctx.StagingBuffer(piece * halves));
  CommandBuffer cmd[2];
  for (int h = 0; h < halves; ++h) {
    REFLCAP_ASSIGN_OR_RETURN(cmd[h], CommandBuffer::Create(ctx));
  }
  int h = 0;
  for (uint64_t done = 0; done < size; h = (h + 1) % halves) {
    const uint64_t n = std::min(size - done, piece);
    REFLCAP_RETURN_IF_ERROR(cmd[h].Wait());  // its previous copy has left the staging half
    CopyBytes(static_cast<char*>(staging->mapped()) + h * piece,
              static_cast<const char*>(src) + done, n);
    REFLCAP_RETURN_IF_ERROR(cmd[h].Begin());
    REFLCAP_RETURN_IF_ERROR(cmd[h].CopyBuffer(*staging, h * piece, dst, dst_offset + done, n));
    REFLCAP_RETURN_IF_ERROR(cmd[h].Submit());
    done += n;
  }
  for (int k = 0; k < halves; ++k) REFLCAP_RETURN_IF_ERROR(cmd[k].Wait());
  return OkStatus();
}

Status DownloadStaged(VkContext& ctx, const Buffer& src, uint64_t src_offset, uint64_t size,
                      void* dst, uint64_t staging_bytes) {
  REFLCAP_RETURN_IF_ERROR(CheckRange(src, src_offset, size, "DownloadStaged"));
  if (staging_bytes == 0) return InvalidArgumentError("DownloadStaged: staging_bytes is 0");
  if (size == 0) return OkStatus();
  // The device copies piece k + 1 into one half of the staging buffer while the host copies
  // piece k out of the other.
  const uint64_t piece = std::min(size, staging_bytes);
  const uint64_t pieces = (size + piece - 1) / piece;
  const int halves = pieces > 1 ? 2 : 1;
  REFLCAP_ASSIGN_OR_RETURN(Buffer * staging, ctx.StagingBuffer(piece * halves));
  CommandBuffer cmd[2];
  for (int h = 0; h < halves; ++h) {
    REFLCAP_ASSIGN_OR_RETURN(cmd[h], CommandBuffer::Create(ctx));
  }
  auto start_copy = [&](uint64_t k) -> Status {
    const int h = int(k % halves);
    const uint64_t offset = k * piece;
    REFLCAP_RETURN_IF_ERROR(cmd[h].Begin());
    REFLCAP_RETURN_IF_ERROR(
        cmd[h].CopyBuffer(src, src_offset + offset, *staging, h * piece, std::min(piece, size - offset)));
    return cmd[h].Submit();
  };
  REFLCAP_RETURN_IF_ERROR(start_copy(0));
  for (uint64_t k = 0; k < pieces; ++k) {
    if (k + 1 < pieces) REFLCAP_RETURN_IF_ERROR(start_copy(k + 1));
    const int h = int(k % halves);
    REFLCAP_RETURN_IF_ERROR(cmd[h].Wait());
    const uint64_t offset = k * piece;
    CopyBytes(static_cast<char*>(dst) + offset,
              static_cast<const char*>(staging->mapped()) + h * piece,
              std::min(piece, size - offset));
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
