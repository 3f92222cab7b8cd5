#include "bench/gpu/device_peak.h"

#include <algorithm>
#include <cmath>
#include <memory>
#include <vector>

#include "engine/gpu/device_info.h"
#include "engine/gpu/vk_buffer.h"
#include "engine/gpu/vk_commands.h"
#include "engine/gpu/vk_pipeline.h"
#include "engine/gpu/vk_timestamps.h"
#include "shaders/shared/bench.h"

namespace reflcap::bench {
namespace {

// What mad_throughput.comp writes for invocation i, in double: kMadChains vec4 chains
// x <- x a + b from x0 = base + offsets, summed.
double MadExpected(uint32_t i, uint32_t iterations, float a, float b) {
  const double base = (i % 1024u) / 1024.0;
  double sum = 0;
  for (int chain = 0; chain < gpu::shared::kMadChains; ++chain) {
    for (int component = 0; component < 4; ++component) {
      double x = base + component / 32.0 + chain / 8.0;
      for (uint32_t k = 0; k < iterations; ++k) x = x * a + b;
      sum += x;
    }
  }
  return sum;
}

// Median of `repeats` timings of `record`.
template <typename Record>
StatusOr<double> MedianSeconds(gpu::GpuTimer& timer, gpu::CommandBuffer& cmd, Record record,
                               int repeats) {
  std::vector<double> times;
  for (int r = 0; r < repeats; ++r) {
    REFLCAP_ASSIGN_OR_RETURN(gpu::Timing t, timer.Run(cmd, record));
    times.push_back(t.seconds);
  }
  std::nth_element(times.begin(), times.begin() + times.size() / 2, times.end());
  return times[times.size() / 2];
}

}  // namespace

double FitFlopsPerResidualEvaluation(int num_params) {
  return double(num_params) * (num_params + 1) + 2.0 * num_params + 40;
}

StatusOr<DevicePeak> MeasureDevicePeak(gpu::VkContext& ctx) {
  using namespace gpu;
  DevicePeak peak;
  peak.device = ctx.info().ToString();
  peak.software = ctx.info().IsSoftware();
  // Enough work to fill a large GPU for a millisecond; a CPU device gets a sixteenth of it.
  const uint32_t invocations = peak.software ? (1u << 16) : (1u << 20);
  const uint32_t iterations = std::min<uint32_t>(1024, MaxLoopIterationsPerInvocation(ctx) - 1);
  const shared::MadThroughputPush push{invocations, iterations, 0.9f, 0.1f};
  ComputePipelineOptions options;
  options.shader = ShaderId::kBenchMadThroughput;
  options.num_buffers = 1;
  options.push_constant_bytes = sizeof(push);
  REFLCAP_ASSIGN_OR_RETURN(ComputePipeline mad, ComputePipeline::Create(ctx, options));
  ComputePipelineOptions empty_options;
  empty_options.shader = ShaderId::kBenchEmpty;
  empty_options.num_buffers = 1;
  REFLCAP_ASSIGN_OR_RETURN(ComputePipeline empty, ComputePipeline::Create(ctx, empty_options));
  REFLCAP_ASSIGN_OR_RETURN(Buffer out, Buffer::Create(ctx, invocations * sizeof(float), MemoryKind::kDevice));
  REFLCAP_ASSIGN_OR_RETURN(CommandBuffer cmd, CommandBuffer::Create(ctx));
  REFLCAP_ASSIGN_OR_RETURN(GpuTimer timer, GpuTimer::Create(ctx));
  peak.timing = TimingSourceName(timer.source());
  const uint32_t groups = uint32_t(GroupCount(invocations, options.local_size_x));
  auto record_mad = [&](CommandBuffer& c) {
    return c.Dispatch(mad, {Bind(out)}, PushConstants::Of(push), groups);
  };
  auto record_empty = [&](CommandBuffer& c) {
    return c.Dispatch(empty, {Bind(out)}, PushConstants{}, 1);
  };
  // Verify first (|a| < 1: rounding stays within eps / (1 - a) per chain value, ~1.2e-6; 16
  // values summed, compared at 1e-5 relative).
  REFLCAP_RETURN_IF_ERROR(timer.Run(cmd, record_mad).status());
  REFLCAP_ASSIGN_OR_RETURN(std::vector<float> got, DownloadVector<float>(ctx, out, invocations));
  for (uint32_t i = 0; i < invocations; i += std::max(1u, invocations / 4096)) {
    const double want = MadExpected(i, iterations, push.a, push.b);
    if (!(std::abs(got[i] - want) <= 1e-5 * std::abs(want))) {
      return InternalError("mad_throughput on ", ctx.info().name, ": invocation ", i, " wrote ",
                           got[i], ", expected ", want);
    }
  }
  REFLCAP_ASSIGN_OR_RETURN(const double empty_s, MedianSeconds(timer, cmd, record_empty, 20));
  REFLCAP_ASSIGN_OR_RETURN(const double mad_s, MedianSeconds(timer, cmd, record_mad, 5));
  const double flops = 2.0 * 4 * shared::kMadChains * double(iterations) * invocations;
  peak.mad_gflops = flops / std::max(mad_s - empty_s, 1e-9) * 1e-9;

  const uint64_t bytes = (peak.software ? 16 : 256) * (uint64_t{1} << 20);
  REFLCAP_ASSIGN_OR_RETURN(Buffer a, Buffer::Create(ctx, bytes, MemoryKind::kDevice));
  REFLCAP_ASSIGN_OR_RETURN(Buffer b, Buffer::Create(ctx, bytes, MemoryKind::kDevice));
  REFLCAP_ASSIGN_OR_RETURN(
      const double copy_s,
      MedianSeconds(timer, cmd, [&](CommandBuffer& c) { return c.CopyBuffer(a, 0, b, 0, bytes); }, 5));
  peak.copy_gbps = double(bytes) / std::max(copy_s, 1e-9) * 1e-9;
  return peak;
}

StatusOr<DevicePeak> MeasureDevicePeak(const std::string& device) {
  gpu::ContextOptions options;
  options.device = device;
  REFLCAP_ASSIGN_OR_RETURN(std::unique_ptr<gpu::VkContext> ctx, gpu::VkContext::Create(options));
  return MeasureDevicePeak(*ctx);
}

}  // namespace reflcap::bench
