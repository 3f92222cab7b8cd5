// engine/gpu/chunking.h: chunk sizes that respect binding range, offset alignment and dispatch
// limits for every array of a structure-of-arrays batch.
#include "engine/gpu/chunking.h"

#include <gtest/gtest.h>

#include <numeric>

namespace reflcap::gpu {
namespace {

constexpr uint64_t kMiB = uint64_t{1} << 20;

ChunkLimits Lavapipe() {
  ChunkLimits limits;
  limits.max_binding_bytes = 128 * kMiB;
  limits.offset_alignment = 16;
  return limits;
}

TEST(MaxElementsPerChunk, FillsTheBindingRangeForOneArray) {
  EXPECT_EQ(*MaxElementsPerChunk(Lavapipe(), {4}), 32 * kMiB);
  EXPECT_EQ(*MaxElementsPerChunk(Lavapipe(), {4}, 64), 32 * kMiB);
  // 12-byte elements: count * 12 must be a multiple of 16, so count a multiple of 4.
  EXPECT_EQ(*MaxElementsPerChunk(Lavapipe(), {12}), 11184808u);
}

TEST(MaxElementsPerChunk, KeepsEveryArrayOfASoaBatchAlignedAndInRange) {
  const std::vector<uint64_t> sizes = {4, 12, 2, 52};
  for (uint64_t granularity : {1, 7, 64, 256}) {
    const StatusOr<uint64_t> count = MaxElementsPerChunk(Lavapipe(), sizes, granularity);
    ASSERT_TRUE(count.ok()) << count.status().ToString();
    EXPECT_EQ(*count % granularity, 0u);
    for (uint64_t size : sizes) {
      EXPECT_LE(*count * size, Lavapipe().max_binding_bytes) << size;
      EXPECT_EQ(*count * size % Lavapipe().offset_alignment, 0u) << size;
    }
    // As large as possible: one more step would overflow the 52-byte array's binding. The step
    // keeps all arrays aligned: 16 / gcd(16, 2) = 8 elements of the 2-byte array.
    const uint64_t step = std::lcm(granularity, uint64_t{8});
    EXPECT_GT((*count + step) * 52, Lavapipe().max_binding_bytes);
  }
}

TEST(MaxElementsPerChunk, RespectsTheDispatchLimit) {
  DeviceInfo info;
  info.max_storage_buffer_range = 128 * kMiB;
  info.min_storage_buffer_offset_alignment = 16;
  info.max_compute_work_group_count = {65535, 65535, 65535};
  const ChunkLimits limits = ChunkLimits::FromDevice(info, 64);
  EXPECT_EQ(limits.max_elements, 65535u * 64);
  EXPECT_EQ(*MaxElementsPerChunk(limits, {4}, 64), 65535u * 64);
}

TEST(MaxElementsPerChunk, RejectsImpossibleRequests) {
  EXPECT_EQ(MaxElementsPerChunk(Lavapipe(), {0}).status().code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(MaxElementsPerChunk(Lavapipe(), {4}, 0).status().code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(MaxElementsPerChunk(Lavapipe(), std::vector<uint64_t>{}).status().code(),
            StatusCode::kInvalidArgument);
  ChunkLimits tiny = Lavapipe();
  tiny.max_binding_bytes = 8;
  EXPECT_EQ(MaxElementsPerChunk(tiny, {16}).status().code(), StatusCode::kInvalidArgument);
}

TEST(SplitIntoChunks, CoversTheRangeContiguously) {
  EXPECT_TRUE(SplitIntoChunks(0, 10).empty());
  const std::vector<ElementRange> chunks = SplitIntoChunks(25, 10);
  ASSERT_EQ(chunks.size(), 3u);
  EXPECT_EQ(chunks[0].first, 0u);
  EXPECT_EQ(chunks[0].count, 10u);
  EXPECT_EQ(chunks[1].first, 10u);
  EXPECT_EQ(chunks[2].first, 20u);
  EXPECT_EQ(chunks[2].count, 5u);
  EXPECT_EQ(chunks[2].OffsetBytes(12), 240u);
  EXPECT_EQ(chunks[2].SizeBytes(12), 60u);
  EXPECT_EQ(SplitIntoChunks(30, 10).size(), 3u);
}

TEST(GroupCount, RoundsUp) {
  EXPECT_EQ(GroupCount(0, 64), 0u);
  EXPECT_EQ(GroupCount(1, 64), 1u);
  EXPECT_EQ(GroupCount(64, 64), 1u);
  EXPECT_EQ(GroupCount(65, 64), 2u);
}

}  // namespace
}  // namespace reflcap::gpu
