// Pipelines, command recording and submission: argument checks, submit timeouts, timing.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <chrono>
#include <thread>
#include <vector>

#include "engine/gpu/chunking.h"
#include "engine/gpu/device_info.h"
#include "engine/gpu/vk_buffer.h"
#include "engine/gpu/vk_commands.h"
#include "engine/gpu/vk_pipeline.h"
#include "engine/gpu/vk_timestamps.h"
#include "shaders/shared/chunk_probe.h"
#include "shaders/shared/loop_probe.h"
#include "tests/engine/gpu/gpu_test_util.h"

namespace reflcap::gpu {
namespace {

using ::testing::HasSubstr;

class CommandsTest : public testing::VulkanTest {
 protected:
  StatusOr<ComputePipeline> ChunkProbe() {
    ComputePipelineOptions options;
    options.shader = ShaderId::kChunkProbe;
    options.push_constant_bytes = sizeof(shared::ChunkProbePush);
    return ComputePipeline::Create(ctx(), options);
  }
};

TEST_F(CommandsTest, PipelineRejectsInvalidOptions) {
  ComputePipelineOptions options;
  EXPECT_EQ(ComputePipeline::Create(ctx(), options).status().code(),
            StatusCode::kInvalidArgument);  // no shader
  options.shader = ShaderId::kChunkProbe;
  options.num_buffers = 0;
  EXPECT_EQ(ComputePipeline::Create(ctx(), options).status().code(), StatusCode::kInvalidArgument);
  options.num_buffers = 1;
  options.push_constant_bytes = 6;
  EXPECT_EQ(ComputePipeline::Create(ctx(), options).status().code(), StatusCode::kInvalidArgument);
  options.push_constant_bytes = 8;
  options.local_size_x = ctx().info().max_compute_work_group_size[0] + 1;
  EXPECT_EQ(ComputePipeline::Create(ctx(), options).status().code(), StatusCode::kInvalidArgument);
  options.local_size_x = 64;
  options.spec_constants = {SpecConstant::Uint(kLocalSizeXConstantId, 32)};
  EXPECT_EQ(ComputePipeline::Create(ctx(), options).status().code(), StatusCode::kInvalidArgument);
  options.spec_constants.clear();
  EXPECT_TRUE(ComputePipeline::Create(ctx(), options).ok());
}

TEST_F(CommandsTest, DispatchRejectsWhatVulkanWouldLeaveUndefined) {
  StatusOr<ComputePipeline> pipeline = ChunkProbe();
  StatusOr<Buffer> buffer = Buffer::Create(ctx(), 4096, MemoryKind::kDevice);
  StatusOr<CommandBuffer> cmd = CommandBuffer::Create(ctx());
  ASSERT_TRUE(pipeline.ok() && buffer.ok() && cmd.ok());
  const shared::ChunkProbePush push{0, 16};
  const PushConstants pc = PushConstants::Of(push);

  // Not recording yet.
  EXPECT_EQ(cmd->Dispatch(*pipeline, {Bind(*buffer)}, pc, 1).code(),
            StatusCode::kFailedPrecondition);
  ASSERT_TRUE(cmd->Begin().ok());
  EXPECT_EQ(cmd->Dispatch(*pipeline, {}, pc, 1).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(cmd->Dispatch(*pipeline, {Bind(*buffer), Bind(*buffer)}, pc, 1).code(),
            StatusCode::kInvalidArgument);
  EXPECT_EQ(cmd->Dispatch(*pipeline, {Bind(*buffer)}, PushConstants{}, 1).code(),
            StatusCode::kInvalidArgument);
  const uint32_t too_small = 7;
  EXPECT_EQ(cmd->Dispatch(*pipeline, {Bind(*buffer)}, PushConstants::Of(too_small), 1).code(),
            StatusCode::kInvalidArgument);
  EXPECT_EQ(cmd->Dispatch(*pipeline, {Bind(*buffer, 4096)}, pc, 1).code(),
            StatusCode::kInvalidArgument);
  EXPECT_EQ(cmd->Dispatch(*pipeline, {Bind(*buffer, 0, 8192)}, pc, 1).code(),
            StatusCode::kInvalidArgument);
  const uint64_t alignment = ctx().info().min_storage_buffer_offset_alignment;
  if (alignment > 1) {
    EXPECT_EQ(cmd->Dispatch(*pipeline, {Bind(*buffer, alignment / 2)}, pc, 1).code(),
              StatusCode::kInvalidArgument);
  }
  const Status too_many = cmd->Dispatch(*pipeline, {Bind(*buffer)}, pc,
                                        ctx().info().max_compute_work_group_count[0] + 1u);
  if (ctx().info().max_compute_work_group_count[0] < UINT32_MAX) {
    EXPECT_EQ(too_many.code(), StatusCode::kInvalidArgument);
    EXPECT_THAT(too_many.message(), HasSubstr("workgroups"));
  }
  EXPECT_TRUE(cmd->Dispatch(*pipeline, {Bind(*buffer)}, pc, 0).ok());  // records nothing
  EXPECT_TRUE(cmd->Dispatch(*pipeline, {Bind(*buffer, alignment, 64)}, pc, 1).ok());
  EXPECT_TRUE(cmd->SubmitAndWait().ok());
  EXPECT_EQ(cmd->SubmitAndWait().code(), StatusCode::kFailedPrecondition);  // not recording
}

TEST_F(CommandsTest, ManyDispatchesInOneSubmissionSeeEachOthersResults) {
  // 200 dispatches (several descriptor pools) each add the global index to every element:
  // the auto barriers make each dispatch read the previous one's writes.
  constexpr uint32_t kCount = 256;
  constexpr int kDispatches = 200;
  StatusOr<ComputePipeline> pipeline = ChunkProbe();
  StatusOr<Buffer> buffer = CreateBufferFrom(ctx(), std::vector<uint32_t>(kCount, 0));
  StatusOr<CommandBuffer> cmd = CommandBuffer::Create(ctx());
  ASSERT_TRUE(pipeline.ok() && buffer.ok() && cmd.ok());
  for (int round = 0; round < 2; ++round) {  // the second round reuses the reset pools
    ASSERT_TRUE(cmd->Begin().ok());
    const shared::ChunkProbePush push{0, kCount};
    for (int i = 0; i < kDispatches; ++i) {
      ASSERT_TRUE(cmd->Dispatch(*pipeline, {Bind(*buffer)}, PushConstants::Of(push), 4).ok());
    }
    ASSERT_TRUE(cmd->SubmitAndWait().ok());
  }
  StatusOr<std::vector<uint32_t>> got = DownloadVector<uint32_t>(ctx(), *buffer, kCount);
  ASSERT_TRUE(got.ok());
  for (uint32_t i = 0; i < kCount; ++i) {
    uint32_t want = 0;
    for (int k = 0; k < 2 * kDispatches; ++k) want = want * shared::kChunkProbeMultiplier + i;
    ASSERT_EQ((*got)[i], want) << i;
  }
}

// A submission that outlives its timeout returns Unavailable; the CommandBuffer refuses to Begin
// until the work is done, and destroying it waits for the work instead of freeing live objects.
TEST_F(CommandsTest, SubmitTimeoutIsUnavailableAndRecoverable) {
  ComputePipelineOptions options;
  options.shader = ShaderId::kLoopProbe;
  options.push_constant_bytes = sizeof(shared::LoopProbePush);
  StatusOr<ComputePipeline> pipeline = ComputePipeline::Create(ctx(), options);
  // Enough work that no device finishes it the moment it is submitted, within every device's
  // loop budget: ~1e9 LCG steps on a CPU device (a fraction of a second on lavapipe), ~6e10 on a
  // GPU (milliseconds).
  const uint32_t kInvocations = ctx().info().IsSoftware() ? (1u << 14) : (1u << 20);
  const uint32_t iterations = std::min<uint32_t>(60000, MaxLoopIterationsPerInvocation(ctx()) - 1);
  StatusOr<Buffer> out =
      Buffer::Create(ctx(), kInvocations * sizeof(shared::LoopProbeResult), MemoryKind::kDevice);
  ASSERT_TRUE(pipeline.ok() && out.ok());
  const shared::LoopProbePush push{shared::kLoopProbeSingle, iterations, 0, kInvocations};
  for (bool destroy_while_pending : {false, true}) {
    StatusOr<CommandBuffer> cmd = CommandBuffer::Create(ctx());
    ASSERT_TRUE(cmd.ok());
    ASSERT_TRUE(cmd->Begin().ok());
    ASSERT_TRUE(cmd->Dispatch(*pipeline, {Bind(*out)}, PushConstants::Of(push),
                              kInvocations / options.local_size_x)
                    .ok());
    const Status timed_out = cmd->SubmitAndWait(0.0);
    ASSERT_EQ(timed_out.code(), StatusCode::kUnavailable) << timed_out.ToString();
    EXPECT_THAT(timed_out.message(), HasSubstr("did not finish"));
    if (destroy_while_pending) continue;  // ~CommandBuffer waits
    const Status begin = cmd->Begin();
    if (!begin.ok()) {
      EXPECT_EQ(begin.code(), StatusCode::kFailedPrecondition);
    }
    ASSERT_TRUE(ctx().WaitIdle().ok());
    EXPECT_TRUE(cmd->Begin().ok());
  }
}

TEST_F(CommandsTest, GpuTimerUsesTimestampsWhenTheQueueHasThem) {
  StatusOr<ComputePipeline> pipeline = ChunkProbe();
  StatusOr<Buffer> buffer = Buffer::Create(ctx(), 1 << 20, MemoryKind::kDevice);
  StatusOr<CommandBuffer> cmd = CommandBuffer::Create(ctx());
  StatusOr<GpuTimer> timer = GpuTimer::Create(ctx());
  ASSERT_TRUE(pipeline.ok() && buffer.ok() && cmd.ok() && timer.ok());
  const TimingSource expected = ctx().info().timestamp_valid_bits > 0 ? TimingSource::kGpuTimestamps
                                                                      : TimingSource::kWallClock;
  EXPECT_EQ(timer->source(), expected);
  const shared::ChunkProbePush push{0, (1 << 20) / 4};
  StatusOr<Timing> timing = timer->Run(*cmd, [&](CommandBuffer& c) {
    return c.Dispatch(*pipeline, {Bind(*buffer)}, PushConstants::Of(push),
                      static_cast<uint32_t>(GroupCount(push.count, 64)));
  });
  ASSERT_TRUE(timing.ok()) << timing.status().ToString();
  EXPECT_EQ(timing->source, expected);
  EXPECT_GT(timing->seconds, 0.0);
  EXPECT_GT(timing->wall_seconds, 0.0);
  // The device's time lies within the host's submit-to-fence interval (plus timer slack).
  EXPECT_LE(timing->seconds, timing->wall_seconds + 1e-3);
  RecordProperty("timing_source", TimingSourceName(timing->source));
  RecordProperty("dispatch_1MiB_s", StrCat(timing->seconds));

  // A failing recording fails the run with its status.
  StatusOr<Timing> failed =
      timer->Run(*cmd, [](CommandBuffer&) { return InvalidArgumentError("recording failed"); });
  EXPECT_EQ(failed.status().code(), StatusCode::kInvalidArgument);

  if (expected == TimingSource::kGpuTimestamps) {
    EXPECT_EQ(TimestampQueryPool::Create(ctx(), 0).status().code(), StatusCode::kInvalidArgument);
  } else {
    EXPECT_EQ(TimestampQueryPool::Create(ctx(), 2).status().code(), StatusCode::kUnavailable);
  }
}

}  // namespace
}  // namespace reflcap::gpu
