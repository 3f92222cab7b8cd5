// Buffers: host <-> device round trips (direct and staged), the allocation cap, and processing
// a buffer larger than maxStorageBufferRange in bound chunks.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdint>
#include <numeric>
#include <thread>
#include <vector>

#include "engine/gpu/chunking.h"
#include "engine/gpu/vk_buffer.h"
#include "engine/gpu/vk_commands.h"
#include "engine/gpu/vk_pipeline.h"
#include "shaders/shared/chunk_probe.h"
#include "tests/engine/gpu/gpu_test_util.h"

namespace reflcap::gpu {
namespace {

using ::testing::HasSubstr;

constexpr uint64_t kMiB = uint64_t{1} << 20;

std::vector<uint8_t> Pattern(size_t n, uint32_t seed) {
  std::vector<uint8_t> bytes(n);
  uint32_t h = seed;
  for (uint8_t& b : bytes) {
    h = h * 1664525u + 1013904223u;
    b = static_cast<uint8_t>(h >> 24);
  }
  return bytes;
}

class BufferTest : public testing::VulkanTest {};

TEST_F(BufferTest, RoundTripsHostDataThroughEveryPath) {
  for (MemoryKind kind : {MemoryKind::kDevice, MemoryKind::kHost}) {
    for (size_t size : {size_t{4}, size_t{1001}, size_t{3 * kMiB + 5}}) {
      StatusOr<Buffer> buffer = Buffer::Create(ctx(), size + 16, kind);
      ASSERT_TRUE(buffer.ok()) << buffer.status().ToString();
      EXPECT_EQ(buffer->size(), size + 16);
      if (kind == MemoryKind::kHost) {
        EXPECT_TRUE(buffer->host_visible());
      }

      const std::vector<uint8_t> data = Pattern(size, static_cast<uint32_t>(size));
      std::vector<uint8_t> back(size);
      // Direct (or staged, on a device whose device memory the host cannot map).
      ASSERT_TRUE(Upload(ctx(), data.data(), size, *buffer, 16).ok());
      ASSERT_TRUE(Download(ctx(), *buffer, 16, size, back.data()).ok());
      EXPECT_EQ(back, data) << "size " << size;
      // Staged through a 64 KiB host buffer: several submissions for the larger sizes.
      const std::vector<uint8_t> data2 = Pattern(size, static_cast<uint32_t>(size) + 1);
      ASSERT_TRUE(UploadStaged(ctx(), data2.data(), size, *buffer, 16, 64 << 10).ok());
      std::fill(back.begin(), back.end(), 0);
      ASSERT_TRUE(DownloadStaged(ctx(), *buffer, 16, size, back.data(), 64 << 10).ok());
      EXPECT_EQ(back, data2) << "size " << size;
    }
  }
}

// Copies of at least kParallelCopyBytes go through the process's copy pool in kCopyBlockBytes
// blocks: sizes that end inside a block, and four threads copying at once (the pool is shared by
// every caller), must each get exactly their bytes.
TEST(CopyBytesTest, LargeCopiesFromSeveralThreadsAtOnceAreExact) {
  const std::vector<size_t> sizes = {size_t(kParallelCopyBytes), size_t(kParallelCopyBytes) + 1,
                                     size_t(9 * kCopyBlockBytes) - 3};
  std::vector<std::thread> callers;
  std::vector<int> mismatches(4, -1);
  for (int c = 0; c < 4; ++c) {
    callers.emplace_back([&, c] {
      int bad = 0;
      for (int repeat = 0; repeat < 3; ++repeat) {
        for (size_t size : sizes) {
          const std::vector<uint8_t> from =
              Pattern(size, uint32_t(size) + 7u * uint32_t(c) + uint32_t(repeat));
          std::vector<uint8_t> to(size + 2, 0xEE);
          CopyBytes(to.data() + 1, from.data(), size);
          bad += !std::equal(from.begin(), from.end(), to.begin() + 1);
          bad += to.front() != 0xEE || to.back() != 0xEE;  // nothing written outside
        }
      }
      mismatches[size_t(c)] = bad;
    });
  }
  for (std::thread& t : callers) t.join();
  EXPECT_EQ(mismatches, std::vector<int>(4, 0));
}

// Staged transfers whose pieces are large enough for the parallel host copy.
TEST_F(BufferTest, RoundTripsThroughStagingPiecesCopiedInParallel) {
  const uint64_t piece = kParallelCopyBytes + kCopyBlockBytes / 2;  // ends inside a block
  const size_t size = size_t(3 * piece + 12345);  // four pieces, the last one short
  StatusOr<Buffer> buffer = Buffer::Create(ctx(), size, MemoryKind::kDevice);
  ASSERT_TRUE(buffer.ok()) << buffer.status().ToString();
  const std::vector<uint8_t> data = Pattern(size, 99);
  ASSERT_TRUE(UploadStaged(ctx(), data.data(), size, *buffer, 0, piece).ok());
  std::vector<uint8_t> back(size, 0);
  ASSERT_TRUE(DownloadStaged(ctx(), *buffer, 0, size, back.data(), piece).ok());
  EXPECT_TRUE(back == data);
}

TEST_F(BufferTest, CopiesAndFillsOnTheDevice) {
  const std::vector<uint32_t> values = {1, 2, 3, 4, 5, 6, 7, 8};
  StatusOr<Buffer> a = CreateBufferFrom(ctx(), values);
  StatusOr<Buffer> b = Buffer::Create(ctx(), 8 * sizeof(uint32_t), MemoryKind::kDevice);
  StatusOr<CommandBuffer> cmd = CommandBuffer::Create(ctx());
  ASSERT_TRUE(a.ok() && b.ok() && cmd.ok());
  ASSERT_TRUE(cmd->Begin().ok());
  ASSERT_TRUE(cmd->FillBuffer(*b, 0, kWholeSize, 0xABCDu).ok());
  ASSERT_TRUE(cmd->CopyBuffer(*a, 8, *b, 16, 12).ok());  // values 3, 4, 5 -> b[4..6]
  ASSERT_TRUE(cmd->SubmitAndWait().ok());
  StatusOr<std::vector<uint32_t>> got = DownloadVector<uint32_t>(ctx(), *b, 8);
  ASSERT_TRUE(got.ok());
  EXPECT_EQ(*got, (std::vector<uint32_t>{0xABCD, 0xABCD, 0xABCD, 0xABCD, 3, 4, 5, 0xABCD}));

  ASSERT_TRUE(cmd->Begin().ok());
  EXPECT_EQ(cmd->CopyBuffer(*a, 0, *b, 16, 32).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(cmd->FillBuffer(*b, 2, 4, 0).code(), StatusCode::kInvalidArgument);
  std::vector<uint8_t> sink(64);
  EXPECT_EQ(Download(ctx(), *b, 16, 32, sink.data()).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(Upload(ctx(), sink.data(), 40, *b).code(), StatusCode::kInvalidArgument);
}

// lavapipe crashes on allocations above 2 GiB instead of failing; Buffer::Create must refuse
// anything above the cap with a Status before Vulkan sees it.
TEST_F(BufferTest, RefusesAllocationsAboveTheCapWithStatus) {
  const uint64_t cap = ctx().max_allocation_bytes();
  for (uint64_t size : {cap + 1, uint64_t{3} << 30, uint64_t{1} << 40}) {
    StatusOr<Buffer> buffer = Buffer::Create(ctx(), size, MemoryKind::kDevice);
    ASSERT_FALSE(buffer.ok()) << size;
    EXPECT_EQ(buffer.status().code(), StatusCode::kUnavailable);
    EXPECT_THAT(buffer.status().message(), HasSubstr("single-allocation cap"));
    EXPECT_THAT(buffer.status().message(), HasSubstr("chunks"));
  }
  EXPECT_EQ(Buffer::Create(ctx(), 0, MemoryKind::kHost).status().code(),
            StatusCode::kInvalidArgument);
}

// A 160 MiB array — more than lavapipe's 128 MiB maxStorageBufferRange — transformed in place by
// shaders/probe/chunk_probe.comp, one bound chunk per dispatch. The probe adds each element's
// global index, so a chunk bound at the wrong offset or given the wrong first_element shows.
TEST_F(BufferTest, ProcessesAnArrayLargerThanMaxStorageBufferRangeInBoundChunks) {
  constexpr uint64_t kBytes = 160 * kMiB;
  constexpr uint32_t kLocalSize = 1024;  // so that group counts do not bound the chunks first
  const uint64_t count = kBytes / sizeof(uint32_t);
  const DeviceInfo& d = ctx().info();

  std::vector<uint32_t> host(count);
  for (uint64_t i = 0; i < count; ++i) host[i] = static_cast<uint32_t>(i * 7 + 3);
  StatusOr<Buffer> data = CreateBufferFrom(ctx(), host);
  ASSERT_TRUE(data.ok()) << data.status().ToString();

  ComputePipelineOptions options;
  options.shader = ShaderId::kChunkProbe;
  options.num_buffers = 1;
  options.push_constant_bytes = sizeof(shared::ChunkProbePush);
  options.local_size_x = std::min(kLocalSize, d.max_compute_work_group_size[0]);
  StatusOr<ComputePipeline> pipeline = ComputePipeline::Create(ctx(), options);
  ASSERT_TRUE(pipeline.ok()) << pipeline.status().ToString();
  StatusOr<CommandBuffer> cmd = CommandBuffer::Create(ctx());
  ASSERT_TRUE(cmd.ok());

  // Binding the whole array at once is refused where it exceeds the device's range.
  ASSERT_TRUE(cmd->Begin().ok());
  if (kBytes > d.max_storage_buffer_range) {
    const shared::ChunkProbePush whole{0, static_cast<uint32_t>(count)};
    const Status refused = cmd->Dispatch(*pipeline, {Bind(*data)}, PushConstants::Of(whole), 1);
    EXPECT_EQ(refused.code(), StatusCode::kInvalidArgument);
    EXPECT_THAT(refused.message(), HasSubstr("maxStorageBufferRange"));
  }

  // Chunks of at most 128 MiB (the device's range, or less on devices that allow more, so that
  // every device runs more than one chunk).
  ChunkLimits limits = ChunkLimits::FromDevice(d, options.local_size_x);
  limits.max_binding_bytes = std::min<uint64_t>(limits.max_binding_bytes, 128 * kMiB);
  StatusOr<uint64_t> per_chunk =
      MaxElementsPerChunk(limits, {sizeof(uint32_t)}, options.local_size_x);
  ASSERT_TRUE(per_chunk.ok()) << per_chunk.status().ToString();
  const std::vector<ElementRange> chunks = SplitIntoChunks(count, *per_chunk);
  ASSERT_GE(chunks.size(), 2u);
  RecordProperty("chunks", static_cast<int>(chunks.size()));
  for (const ElementRange& chunk : chunks) {
    const shared::ChunkProbePush push{static_cast<uint32_t>(chunk.first),
                                      static_cast<uint32_t>(chunk.count)};
    const Status s = cmd->Dispatch(
        *pipeline, {BindElements(*data, chunk, sizeof(uint32_t))}, PushConstants::Of(push),
        static_cast<uint32_t>(GroupCount(chunk.count, options.local_size_x)));
    ASSERT_TRUE(s.ok()) << s.ToString();
  }
  const Status submitted = cmd->SubmitAndWait();
  ASSERT_TRUE(submitted.ok()) << submitted.ToString();

  std::vector<uint32_t> back(count);
  ASSERT_TRUE(Download(ctx(), *data, 0, kBytes, back.data()).ok());
  uint64_t mismatches = 0, first_bad = 0;
  for (uint64_t i = 0; i < count; ++i) {
    const uint32_t want = host[i] * shared::kChunkProbeMultiplier + static_cast<uint32_t>(i);
    if (back[i] != want && mismatches++ == 0) first_bad = i;
  }
  EXPECT_EQ(mismatches, 0u) << "first at element " << first_bad;
}

}  // namespace
}  // namespace reflcap::gpu
