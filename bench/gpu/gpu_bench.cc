// reflcap_gpu_bench: what the Vulkan foundation costs on the chosen device.
//
//   BM_SubmitAndWait          one empty dispatch per submission: the host's submit + fence
//                             latency (wall clock), what every short GPU call pays;
//   BM_EmptyDispatch/N        N empty one-workgroup dispatches in one submission (time per
//                             submission; us_per_dispatch = the fixed cost of one dispatch with
//                             its descriptor set and barrier, on the device);
//   BM_Upload/BM_Download     host <-> buffer bandwidth through Upload/Download (a memcpy into
//                             mapped memory on unified-memory devices such as lavapipe);
//   BM_UploadStaged/..Staged  the same through a host staging buffer and vkCmdCopyBuffer (the path
//                             for device memory the host cannot map);
//   BM_DeviceCopy             vkCmdCopyBuffer between two device buffers;
//   BM_MadThroughput          float multiply-add throughput (shaders/bench/mad_throughput.comp),
//                             checked against a double-precision model before any timing counts.
//
// Device timings use GPU timestamps when the compute queue has them, else the wall clock around
// submit + fence wait; the context line and each benchmark's label say which. BM_MadThroughput
// subtracts the empty-dispatch time measured at start-up. On lavapipe the "GPU" is this machine's
// CPU, shared with everything else running: its numbers are CPU numbers.
#include <benchmark/benchmark.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <string>
#include <vector>

#include "engine/core/status.h"
#include "engine/gpu/chunking.h"
#include "engine/gpu/device_info.h"
#include "engine/gpu/vk_buffer.h"
#include "engine/gpu/vk_commands.h"
#include "engine/gpu/vk_context.h"
#include "engine/gpu/vk_pipeline.h"
#include "engine/gpu/vk_timestamps.h"
#include "shaders/shared/bench.h"

namespace reflcap::gpu {
namespace {

constexpr uint64_t kMiB = uint64_t{1} << 20;
// Empty-dispatch GPU time (seconds), measured once in main; subtracted from kernel timings.
double g_empty_dispatch_s = 0;
VkContext* g_ctx = nullptr;

// Aborts the benchmark with the status' message; true when `status` is an error.
bool Failed(benchmark::State& state, const Status& status) {
  if (status.ok()) return false;
  state.SkipWithError(status.ToString().c_str());
  return true;
}

const char* SourceLabel(TimingSource source) {
  return source == TimingSource::kGpuTimestamps ? "gpu-timestamps" : "wall-clock";
}

StatusOr<ComputePipeline> EmptyPipeline() {
  ComputePipelineOptions options;
  options.shader = ShaderId::kBenchEmpty;
  options.num_buffers = 1;
  return ComputePipeline::Create(*g_ctx, options);
}

// Median GPU time of `repeats` submissions of one empty dispatch.
StatusOr<double> MeasureEmptyDispatch(int repeats) {
  REFLCAP_ASSIGN_OR_RETURN(ComputePipeline pipeline, EmptyPipeline());
  REFLCAP_ASSIGN_OR_RETURN(Buffer buffer, Buffer::Create(*g_ctx, 256, MemoryKind::kDevice));
  REFLCAP_ASSIGN_OR_RETURN(CommandBuffer cmd, CommandBuffer::Create(*g_ctx));
  REFLCAP_ASSIGN_OR_RETURN(GpuTimer timer, GpuTimer::Create(*g_ctx));
  std::vector<double> times;
  for (int i = 0; i < repeats; ++i) {
    REFLCAP_ASSIGN_OR_RETURN(Timing t, timer.Run(cmd, [&](CommandBuffer& c) {
      return c.Dispatch(pipeline, {Bind(buffer)}, PushConstants{}, 1);
    }));
    times.push_back(t.seconds);
  }
  std::nth_element(times.begin(), times.begin() + times.size() / 2, times.end());
  return times[times.size() / 2];
}

void BM_SubmitAndWait(benchmark::State& state) {
  StatusOr<ComputePipeline> pipeline = EmptyPipeline();
  if (Failed(state, pipeline.status())) return;
  StatusOr<Buffer> buffer = Buffer::Create(*g_ctx, 256, MemoryKind::kDevice);
  StatusOr<CommandBuffer> cmd = CommandBuffer::Create(*g_ctx);
  if (Failed(state, buffer.status()) || Failed(state, cmd.status())) return;
  for (auto _ : state) {
    if (Failed(state, cmd->Begin())) return;
    if (Failed(state, cmd->Dispatch(*pipeline, {Bind(*buffer)}, PushConstants{}, 1))) return;
    if (Failed(state, cmd->SubmitAndWait())) return;
    state.SetIterationTime(cmd->last_submit_wall_s());
  }
  state.SetLabel("wall-clock");
}
BENCHMARK(BM_SubmitAndWait)->UseManualTime()->Unit(benchmark::kMicrosecond);

void BM_EmptyDispatch(benchmark::State& state) {
  const int n = static_cast<int>(state.range(0));
  StatusOr<ComputePipeline> pipeline = EmptyPipeline();
  if (Failed(state, pipeline.status())) return;
  StatusOr<Buffer> buffer = Buffer::Create(*g_ctx, 256, MemoryKind::kDevice);
  StatusOr<CommandBuffer> cmd = CommandBuffer::Create(*g_ctx);
  StatusOr<GpuTimer> timer = GpuTimer::Create(*g_ctx);
  if (Failed(state, buffer.status()) || Failed(state, cmd.status()) ||
      Failed(state, timer.status())) {
    return;
  }
  double total_s = 0;
  for (auto _ : state) {
    StatusOr<Timing> t = timer->Run(*cmd, [&](CommandBuffer& c) {
      for (int i = 0; i < n; ++i) {
        REFLCAP_RETURN_IF_ERROR(c.Dispatch(*pipeline, {Bind(*buffer)}, PushConstants{}, 1));
      }
      return OkStatus();
    });
    if (Failed(state, t.status())) return;
    state.SetIterationTime(t->seconds);  // the whole submission
    total_s += t->seconds;
  }
  state.counters["us_per_dispatch"] = total_s / (double(state.iterations()) * n) * 1e6;
  state.SetLabel(SourceLabel(timer->source()));
}
BENCHMARK(BM_EmptyDispatch)
    ->Arg(1)
    ->Arg(16)
    ->Arg(256)
    ->UseManualTime()
    ->Unit(benchmark::kMicrosecond);

enum class Direction { kUpload, kDownload };

// range(0): MiB moved; for the staged paths range(1): MiB per staging piece (the ring's slot).
void Transfer(benchmark::State& state, Direction direction, bool staged) {
  const uint64_t bytes = static_cast<uint64_t>(state.range(0)) * kMiB;
  const uint64_t piece = staged ? static_cast<uint64_t>(state.range(1)) * kMiB : 0;
  StatusOr<Buffer> buffer = Buffer::Create(*g_ctx, bytes, MemoryKind::kDevice);
  if (Failed(state, buffer.status())) return;
  std::vector<uint8_t> host(bytes, 1);
  for (auto _ : state) {
    Status s;
    if (direction == Direction::kUpload) {
      s = staged ? UploadStaged(*g_ctx, host.data(), bytes, *buffer, 0, piece)
                 : Upload(*g_ctx, host.data(), bytes, *buffer);
    } else {
      s = staged ? DownloadStaged(*g_ctx, *buffer, 0, bytes, host.data(), piece)
                 : Download(*g_ctx, *buffer, 0, bytes, host.data());
    }
    if (Failed(state, s)) return;
    benchmark::ClobberMemory();
  }
  state.SetBytesProcessed(static_cast<int64_t>(state.iterations() * bytes));
  state.SetLabel(
      staged ? "staged, wall-clock"
             : (buffer->host_visible() ? "mapped memcpy, wall-clock" : "staged, wall-clock"));
}
void BM_Upload(benchmark::State& state) { Transfer(state, Direction::kUpload, false); }
void BM_Download(benchmark::State& state) { Transfer(state, Direction::kDownload, false); }
void BM_UploadStaged(benchmark::State& state) { Transfer(state, Direction::kUpload, true); }
void BM_DownloadStaged(benchmark::State& state) { Transfer(state, Direction::kDownload, true); }
BENCHMARK(BM_Upload)->Arg(1)->Arg(16)->Arg(64)->UseRealTime()->Unit(benchmark::kMillisecond);
BENCHMARK(BM_Download)->Arg(1)->Arg(16)->Arg(64)->UseRealTime()->Unit(benchmark::kMillisecond);
// Staged: 16 and 64 MiB through the default pieces (kStagingChunkBytes), and 64 MiB through
// other piece sizes, to choose the default on a GPU (kStagingSlots slots either way).
void StagedArgs(benchmark::internal::Benchmark* b) {
  const int64_t chunk = int64_t(kStagingChunkBytes / kMiB);
  b->Args({16, chunk})->Args({64, chunk});
  for (int64_t piece : {4, 8, 16, 32}) {
    if (piece != chunk) b->Args({64, piece});
  }
}
BENCHMARK(BM_UploadStaged)->Apply(StagedArgs)->UseRealTime()->Unit(benchmark::kMillisecond);
BENCHMARK(BM_DownloadStaged)->Apply(StagedArgs)->UseRealTime()->Unit(benchmark::kMillisecond);

void BM_DeviceCopy(benchmark::State& state) {
  const uint64_t bytes = static_cast<uint64_t>(state.range(0)) * kMiB;
  StatusOr<Buffer> a = Buffer::Create(*g_ctx, bytes, MemoryKind::kDevice);
  StatusOr<Buffer> b = Buffer::Create(*g_ctx, bytes, MemoryKind::kDevice);
  StatusOr<CommandBuffer> cmd = CommandBuffer::Create(*g_ctx);
  StatusOr<GpuTimer> timer = GpuTimer::Create(*g_ctx);
  if (Failed(state, a.status()) || Failed(state, b.status()) || Failed(state, cmd.status()) ||
      Failed(state, timer.status())) {
    return;
  }
  for (auto _ : state) {
    StatusOr<Timing> t =
        timer->Run(*cmd, [&](CommandBuffer& c) { return c.CopyBuffer(*a, 0, *b, 0, bytes); });
    if (Failed(state, t.status())) return;
    state.SetIterationTime(t->seconds);
  }
  state.SetBytesProcessed(static_cast<int64_t>(state.iterations() * bytes));
  state.SetLabel(SourceLabel(timer->source()));
}
BENCHMARK(BM_DeviceCopy)->Arg(16)->Arg(64)->UseManualTime()->Unit(benchmark::kMillisecond);

// What mad_throughput.comp writes for invocation i, in double: kMadChains vec4 chains
// x <- x a + b from x0 = base + offsets, summed.
double MadThroughputExpected(uint32_t i, uint32_t iterations, float a, float b) {
  const double base = (i % 1024u) / 1024.0;
  double sum = 0;
  for (int chain = 0; chain < shared::kMadChains; ++chain) {
    for (int component = 0; component < 4; ++component) {
      double x = base + component / 32.0 + chain / 8.0;
      for (uint32_t k = 0; k < iterations; ++k) x = x * a + b;
      sum += x;
    }
  }
  return sum;
}

void BM_MadThroughput(benchmark::State& state) {
  const uint32_t invocations = static_cast<uint32_t>(state.range(0));
  // Within lavapipe's loop budget (MaxLoopIterationsPerInvocation), so nothing is cut short.
  const uint32_t iterations = std::min<uint32_t>(static_cast<uint32_t>(state.range(1)),
                                                 MaxLoopIterationsPerInvocation(*g_ctx) - 1);
  const shared::MadThroughputPush push{invocations, iterations, 0.9f, 0.1f};
  ComputePipelineOptions options;
  options.shader = ShaderId::kBenchMadThroughput;
  options.num_buffers = 1;
  options.push_constant_bytes = sizeof(push);
  StatusOr<ComputePipeline> pipeline = ComputePipeline::Create(*g_ctx, options);
  if (Failed(state, pipeline.status())) return;
  StatusOr<Buffer> out = Buffer::Create(*g_ctx, invocations * sizeof(float), MemoryKind::kDevice);
  StatusOr<CommandBuffer> cmd = CommandBuffer::Create(*g_ctx);
  StatusOr<GpuTimer> timer = GpuTimer::Create(*g_ctx);
  if (Failed(state, out.status()) || Failed(state, cmd.status()) || Failed(state, timer.status())) {
    return;
  }
  const uint32_t groups = static_cast<uint32_t>(GroupCount(invocations, options.local_size_x));
  auto record = [&](CommandBuffer& c) {
    return c.Dispatch(*pipeline, {Bind(*out)}, PushConstants::Of(push), groups);
  };

  // Verify before timing: with |a| < 1 float rounding stays within eps / (1 - a) per chain value
  // (~1.2e-6 here); 16 values summed, compared at 1e-5 relative.
  StatusOr<Timing> first = timer->Run(*cmd, record);
  if (Failed(state, first.status())) return;
  StatusOr<std::vector<float>> got = DownloadVector<float>(*g_ctx, *out, invocations);
  if (Failed(state, got.status())) return;
  for (uint32_t i = 0; i < invocations; i += std::max(1u, invocations / 4096)) {
    const double want = MadThroughputExpected(i, iterations, push.a, push.b);
    if (!(std::abs((*got)[i] - want) <= 1e-5 * std::abs(want))) {
      state.SkipWithError(StrCat("mad_throughput: invocation ", i, " wrote ", (*got)[i],
                                 ", expected ", want, " — timings would be meaningless")
                              .c_str());
      return;
    }
  }

  double total_s = 0;
  for (auto _ : state) {
    StatusOr<Timing> t = timer->Run(*cmd, record);
    if (Failed(state, t.status())) return;
    const double net = std::max(t->seconds - g_empty_dispatch_s, 1e-9);
    state.SetIterationTime(net);
    total_s += net;
  }
  const double flops = 2.0 * 4 * shared::kMadChains * double(iterations) * invocations;
  state.counters["GFLOP/s"] = flops * state.iterations() / total_s * 1e-9;
  state.counters["iterations"] = iterations;
  state.SetLabel(SourceLabel(timer->source()) +
                 std::string(", verified, empty dispatch subtracted"));
}
BENCHMARK(BM_MadThroughput)
    ->Args({1 << 14, 1024})
    ->Args({1 << 16, 1024})
    ->UseManualTime()
    ->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace reflcap::gpu

int main(int argc, char** argv) {
  using namespace reflcap;
  using namespace reflcap::gpu;
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  ContextOptions options;
  if (const char* device = std::getenv("REFLCAP_BENCH_VK_DEVICE")) options.device = device;
  StatusOr<std::unique_ptr<VkContext>> ctx = VkContext::Create(options);
  if (!ctx.ok()) {
    std::fprintf(stderr, "reflcap_gpu_bench: %s\n", ctx.status().ToString().c_str());
    return ExitCodeFor(ctx.status());
  }
  g_ctx = ctx->get();
  const DeviceInfo& d = g_ctx->info();
  const TimingSource source =
      d.timestamp_valid_bits > 0 ? TimingSource::kGpuTimestamps : TimingSource::kWallClock;
  StatusOr<double> empty = MeasureEmptyDispatch(50);
  if (!empty.ok()) {
    std::fprintf(stderr, "reflcap_gpu_bench: %s\n", empty.status().ToString().c_str());
    return ExitCodeFor(empty.status());
  }
  g_empty_dispatch_s = *empty;
  std::printf("device: %s\ntimings: %s%s\nempty dispatch (median of 50): %.2f us\n",
              d.ToString().c_str(), TimingSourceName(source),
              d.IsSoftware() ? " (a CPU device: these are CPU numbers)" : "", *empty * 1e6);
  benchmark::AddCustomContext("device", d.ToString());
  benchmark::AddCustomContext("timing", TimingSourceName(source));
  benchmark::AddCustomContext("empty_dispatch_us", StrCat(*empty * 1e6));
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  g_ctx = nullptr;
  return 0;
}
