#pragma once
// Splitting large structure-of-arrays batches into pieces a single dispatch can bind and run.
//
// A storage-buffer binding may span at most maxStorageBufferRange bytes (128 MiB on lavapipe, 4 GiB
// or less elsewhere) and must start at a multiple of minStorageBufferOffsetAlignment; a dispatch
// has at most maxComputeWorkGroupCount[0] workgroups along x. A batch of N elements stored as
// several arrays (SoA: one array per attribute, each with its own element size) is therefore run
// as chunks of consecutive elements [first, first + count): every array of the batch is bound at
// byte offset first * element_size with size count * element_size, and the shader receives
// `first` and `count` as push constants. MaxElementsPerChunk picks the largest count that keeps
// every array's binding within the range limit and every chunk's offset aligned; SplitIntoChunks
// cuts [0, N) into such chunks. Vulkan-free; DeviceInfo supplies the limits.
//
//   ComputePipelineOptions o{ShaderId::kMyKernel, /*num_buffers=*/2, sizeof(MyPush)};
//   REFLCAP_ASSIGN_OR_RETURN(ComputePipeline pipe, ComputePipeline::Create(ctx, o));
//   REFLCAP_ASSIGN_OR_RETURN(uint64_t per_chunk, MaxElementsPerChunk(
//       ChunkLimits::FromDevice(ctx.info(), o.local_size_x), {sizeof(float), 12}, o.local_size_x));
//   REFLCAP_RETURN_IF_ERROR(cmd.Begin());
//   for (const ElementRange& r : SplitIntoChunks(n, per_chunk)) {
//     const MyPush push{uint32_t(r.first), uint32_t(r.count)};
//     REFLCAP_RETURN_IF_ERROR(cmd.Dispatch(pipe, {BindElements(a, r, sizeof(float)),
//                                                 BindElements(b, r, 12)},
//                                          PushConstants::Of(push),
//                                          uint32_t(GroupCount(r.count, o.local_size_x))));
//   }
//   REFLCAP_RETURN_IF_ERROR(cmd.SubmitAndWait());  // or submit every few chunks: keep each short
#include <cstdint>
#include <initializer_list>
#include <vector>

#include "engine/core/status.h"
#include "engine/gpu/device_info.h"

namespace reflcap::gpu {

// Elements [first, first + count) of a batch.
struct ElementRange {
  uint64_t first = 0;
  uint64_t count = 0;
  // Byte offset and size of this range in an array of `element_size`-byte elements.
  uint64_t OffsetBytes(uint64_t element_size) const { return first * element_size; }
  uint64_t SizeBytes(uint64_t element_size) const { return count * element_size; }
};

// Limits that bound one chunk; FromDevice fills them from a device.
struct ChunkLimits {
  uint64_t max_binding_bytes = 0;      // maxStorageBufferRange
  uint64_t offset_alignment = 1;       // minStorageBufferOffsetAlignment (a power of two)
  uint64_t max_elements = UINT64_MAX;  // e.g. maxComputeWorkGroupCount[0] * local_size_x

  // The device's range and alignment, and max_elements = maxComputeWorkGroupCount[0] *
  // local_size_x for a 1-D dispatch of one invocation per element (local_size_x > 0).
  static ChunkLimits FromDevice(const DeviceInfo& info, uint32_t local_size_x);
};

// The largest element count per chunk such that, for each element size in `element_sizes` (bytes,
// > 0): count * size <= max_binding_bytes and count * size is a multiple of offset_alignment (so
// the next chunk's offset is aligned); count <= max_elements and count is a multiple of
// `granularity` (> 0; e.g. the workgroup size, so that only the last chunk has a partial group).
// InvalidArgument for a zero size or granularity, or when not even one aligned group fits.
StatusOr<uint64_t> MaxElementsPerChunk(const ChunkLimits& limits,
                                       std::initializer_list<uint64_t> element_sizes,
                                       uint64_t granularity = 1);
StatusOr<uint64_t> MaxElementsPerChunk(const ChunkLimits& limits,
                                       const std::vector<uint64_t>& element_sizes,
                                       uint64_t granularity = 1);

// [0, element_count) cut into consecutive ranges of max_per_chunk (> 0) elements, the last one
// shorter; empty for element_count = 0.
std::vector<ElementRange> SplitIntoChunks(uint64_t element_count, uint64_t max_per_chunk);

// Workgroups needed for `count` invocations at `local_size` (> 0) per group: ceil(count / local).
uint64_t GroupCount(uint64_t count, uint32_t local_size);

}  // namespace reflcap::gpu
