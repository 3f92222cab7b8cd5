// MaxLoopIterationsPerInvocation against what the device really does
// (shaders/probe/loop_probe.comp).
//
// lavapipe (Mesa's llvmpipe) gives each shader invocation a budget of loop steps shared by all of
// its loops — every iteration and every normal loop exit takes a step, nested inner iterations
// and consecutive loops all count, and invocations running in lockstep share it — and when the
// budget runs out every loop exits early without any error (engine/gpu/device_info.h has the
// details and the numbers measured on Mesa 22.3.6). A GPU fitter that loops over LM iterations
// and samples would silently return unconverged results. These tests hold the helper to its
// promise on the device they run on, so that a promise that is too large and one that is too
// small both fail:
//   - loops whose steps add up to the promise run in full, in every shape (one loop, two in a
//     row, nested, and divergent lanes);
//   - on a device with a finite promise, a much longer loop is cut, and no earlier than the
//     promise nor later than the promise plus the reserve the helper keeps for compiler-added
//     loops. On devices without a known limit, a loop of kLargestCheckedIterations + 1 must run
//     in full instead.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdint>
#include <string>
#include <vector>

#include "engine/gpu/chunking.h"
#include "engine/gpu/device_info.h"
#include "engine/gpu/vk_buffer.h"
#include "engine/gpu/vk_commands.h"
#include "engine/gpu/vk_pipeline.h"
#include "shaders/shared/loop_probe.h"
#include "tests/engine/gpu/gpu_test_util.h"

namespace reflcap::gpu {
namespace {

using shared::LoopProbePush;
using shared::LoopProbeResult;

// Iteration counts above this are not run even on devices without a limit: 2^20 iterations of
// an LCG take milliseconds on a GPU, and the point is only to pass lavapipe's budget by far.
constexpr uint32_t kLargestCheckedIterations = 1u << 20;
// Two workgroups of 64 (16 subgroups of 8 on lavapipe), so that a budget shared more widely than
// the helper assumes would show.
constexpr uint32_t kInvocations = 128;
// Steps the helper keeps in reserve on lavapipe (the counter less the promise).
constexpr uint32_t kLavapipeReserve = kLavapipeLoopCounter - kLavapipeMaxLoopIterations;

uint32_t ExpectedHash(uint32_t invocation, uint64_t steps) {
  uint32_t h = invocation;
  for (uint64_t k = 0; k < steps; ++k) h = h * shared::kLoopProbeLcgA + shared::kLoopProbeLcgC;
  return h;
}

class LoopLimitTest : public testing::VulkanTest {
 protected:
  // The probe's per-invocation results (empty after a failed expectation).
  std::vector<LoopProbeResult> Run(uint32_t mode, uint32_t iterations, uint32_t second) {
    StatusOr<std::vector<LoopProbeResult>> r = RunProbe(mode, iterations, second);
    EXPECT_TRUE(r.ok()) << r.status().ToString();
    return r.ok() ? *r : std::vector<LoopProbeResult>();
  }

  // Expects every invocation to report exactly `first` and `second` iterations (for invocation
  // i in kLoopProbeAlternating, odd i swap them), with the matching LCG hash.
  void ExpectCounts(const std::vector<LoopProbeResult>& results, uint32_t mode, uint32_t first,
                    uint32_t second, const std::string& what) {
    ASSERT_EQ(results.size(), kInvocations) << what;
    for (uint32_t i = 0; i < kInvocations; ++i) {
      const bool swap = mode == shared::kLoopProbeAlternating && (i & 1u);
      const uint32_t f = swap ? second : first;
      const uint32_t s = swap ? first : second;
      const uint64_t steps = mode == shared::kLoopProbeNested ? uint64_t{f} * s : uint64_t{f} + s;
      const uint32_t expected_second = mode == shared::kLoopProbeNested ? f * s : s;
      ASSERT_EQ(results[i].invocation, i) << what;
      ASSERT_EQ(results[i].first_count, f) << what << ", invocation " << i;
      ASSERT_EQ(results[i].second_count, expected_second) << what << ", invocation " << i;
      ASSERT_EQ(results[i].hash, ExpectedHash(i, steps)) << what << ", invocation " << i;
    }
  }

 private:
  StatusOr<std::vector<LoopProbeResult>> RunProbe(uint32_t mode, uint32_t iterations,
                                                  uint32_t second) {
    ComputePipelineOptions options;
    options.shader = ShaderId::kLoopProbe;
    options.num_buffers = 1;
    options.push_constant_bytes = sizeof(LoopProbePush);
    REFLCAP_ASSIGN_OR_RETURN(ComputePipeline pipeline, ComputePipeline::Create(ctx(), options));
    REFLCAP_ASSIGN_OR_RETURN(
        Buffer out,
        Buffer::Create(ctx(), kInvocations * sizeof(LoopProbeResult), MemoryKind::kDevice));
    REFLCAP_ASSIGN_OR_RETURN(CommandBuffer cmd, CommandBuffer::Create(ctx()));
    const LoopProbePush push{mode, iterations, second, kInvocations};
    REFLCAP_RETURN_IF_ERROR(cmd.Begin());
    REFLCAP_RETURN_IF_ERROR(
        cmd.Dispatch(pipeline, {Bind(out)}, PushConstants::Of(push),
                     static_cast<uint32_t>(GroupCount(kInvocations, options.local_size_x))));
    REFLCAP_RETURN_IF_ERROR(cmd.SubmitAndWait());
    return DownloadVector<LoopProbeResult>(ctx(), out, kInvocations);
  }
};

TEST_F(LoopLimitTest, LoopsWithinThePromisedBudgetRunInFull) {
  const uint32_t promise = MaxLoopIterationsPerInvocation(ctx());
  const uint32_t budget = std::min(promise, kLargestCheckedIterations);
  RecordProperty("promise", std::to_string(promise));

  ExpectCounts(Run(shared::kLoopProbeSingle, 0, 0), shared::kLoopProbeSingle, 0, 0, "no loop");
  ExpectCounts(Run(shared::kLoopProbeSingle, 1000, 0), shared::kLoopProbeSingle, 1000, 0,
               "1000 iterations");
  // One loop: budget - 1 iterations take `budget` steps.
  const uint32_t single = budget - 1;
  ExpectCounts(Run(shared::kLoopProbeSingle, single, 0), shared::kLoopProbeSingle, single, 0,
               "one loop of the whole budget");
  // Two loops in a row: (a + 1) + (b + 1) = budget.
  const uint32_t a = budget / 2 - 1;
  const uint32_t b = budget - budget / 2 - 1;
  ExpectCounts(Run(shared::kLoopProbeSequential, a, b), shared::kLoopProbeSequential, a, b,
               "two loops in a row");
  // Nested: outer n x inner m takes n (m + 1) + n + 1 <= budget.
  const uint32_t outer = 100;
  const uint32_t inner = (budget - outer - 1) / outer - 1;
  ASSERT_LE(outer * LoopSteps(inner) + LoopSteps(outer), budget);
  ExpectCounts(Run(shared::kLoopProbeNested, outer, inner), shared::kLoopProbeNested, outer, inner,
               "nested loops");
  // Divergent lanes: even invocations run (a, b'), odd ones (b', a); in lockstep each loop costs
  // its larger count, so a = b' = budget / 2 - 1 fits.
  const uint32_t half = budget / 2 - 1;
  ExpectCounts(Run(shared::kLoopProbeAlternating, half, half), shared::kLoopProbeAlternating, half,
               half, "divergent lanes");
}

TEST_F(LoopLimitTest, LongerLoopsAreCutJustBeyondAFinitePromise) {
  const uint32_t promise = MaxLoopIterationsPerInvocation(ctx());
  if (promise >= kLargestCheckedIterations) {
    // No limit promised: a loop longer than lavapipe's budget by far must run in full.
    const uint32_t n = kLargestCheckedIterations + 1;
    ExpectCounts(Run(shared::kLoopProbeSingle, n, 0), shared::kLoopProbeSingle, n, 0,
                 "a long loop on a device without a known limit");
    return;
  }
  const uint32_t asked = 3 * promise;
  const std::vector<LoopProbeResult> results = Run(shared::kLoopProbeSingle, asked, 0);
  ASSERT_EQ(results.size(), kInvocations);
  for (uint32_t i = 0; i < kInvocations; ++i) {
    const uint32_t ran = results[i].first_count;
    ASSERT_LT(ran, asked) << "invocation " << i << " ran all " << asked << " iterations: this "
                          << "device does not cut loops at " << promise << "; fix the promise";
    // The loop ran `ran` iterations without exiting normally: ran steps were the loop's.
    ASSERT_GE(ran, promise) << "invocation " << i << ": cut below the promised budget";
    ASSERT_LE(ran, promise + kLavapipeReserve) << "invocation " << i << ": cut far beyond the "
                                               << "promise, which wastes budget";
    ASSERT_EQ(results[i].hash, ExpectedHash(i, ran)) << "invocation " << i;
  }
  if (ctx().info().IsLavapipe()) {
    // Mesa 22.3.6: 65,533 iterations (the counter less 2 steps of the shader's own overhead).
    RecordProperty("lavapipe_single_loop_cut_at", std::to_string(results[0].first_count));
  }
}

}  // namespace
}  // namespace reflcap::gpu
