#include "engine/gpu/chunking.h"

#include <algorithm>
#include <numeric>

namespace reflcap::gpu {

ChunkLimits ChunkLimits::FromDevice(const DeviceInfo& info, uint32_t local_size_x) {
  ChunkLimits limits;
  limits.max_binding_bytes = info.max_storage_buffer_range;
  limits.offset_alignment = std::max<uint64_t>(1, info.min_storage_buffer_offset_alignment);
  limits.max_elements =
      static_cast<uint64_t>(info.max_compute_work_group_count[0]) * std::max(1u, local_size_x);
  return limits;
}

StatusOr<uint64_t> MaxElementsPerChunk(const ChunkLimits& limits,
                                       const std::vector<uint64_t>& element_sizes,
                                       uint64_t granularity) {
  if (granularity == 0) return InvalidArgumentError("MaxElementsPerChunk: granularity is 0");
  if (element_sizes.empty()) return InvalidArgumentError("MaxElementsPerChunk: no arrays");
  if (limits.offset_alignment == 0) {
    return InvalidArgumentError("MaxElementsPerChunk: offset alignment is 0");
  }
  // count * size must be a multiple of the alignment a: count a multiple of a / gcd(a, size).
  uint64_t step = granularity;
  uint64_t max_count = limits.max_elements;
  for (uint64_t size : element_sizes) {
    if (size == 0) return InvalidArgumentError("MaxElementsPerChunk: an element size is 0");
    const uint64_t needed = limits.offset_alignment / std::gcd(limits.offset_alignment, size);
    step = std::lcm(step, needed);
    max_count = std::min(max_count, limits.max_binding_bytes / size);
  }
  const uint64_t count = max_count / step * step;
  if (count == 0) {
    return InvalidArgumentError("MaxElementsPerChunk: not even ", step,
                                " elements (one aligned group) fit in a binding of ",
                                limits.max_binding_bytes, " bytes / ", limits.max_elements,
                                " elements");
  }
  return count;
}

StatusOr<uint64_t> MaxElementsPerChunk(const ChunkLimits& limits,
                                       std::initializer_list<uint64_t> element_sizes,
                                       uint64_t granularity) {
  return MaxElementsPerChunk(limits, std::vector<uint64_t>(element_sizes), granularity);
}

std::vector<ElementRange> SplitIntoChunks(uint64_t element_count, uint64_t max_per_chunk) {
  REFLCAP_CHECK(max_per_chunk > 0) << "SplitIntoChunks: max_per_chunk is 0";
  std::vector<ElementRange> chunks;
  for (uint64_t first = 0; first < element_count; first += max_per_chunk) {
    chunks.push_back({first, std::min(max_per_chunk, element_count - first)});
  }
  return chunks;
}

uint64_t GroupCount(uint64_t count, uint32_t local_size) {
  REFLCAP_CHECK(local_size > 0) << "GroupCount: local_size is 0";
  return (count + local_size - 1) / local_size;
}

}  // namespace reflcap::gpu
