// reflcap_fit_bench: fits per second of the batched CPU fitter, the Vulkan fitter and the Ceres
// reference on the same synthetic texels, in one run — one fit is one colour channel of one
// texel: Lambert + one anisotropic Lafortune lobe, 5 parameters, N samples (64 for the issues'
// goals).
//
//   BM_Fit<Backend>/samples       N = 16 .. 1024 samples per texel at kTexels texels
//   BM_FitTexels<Backend>/texels  10^3 .. 10^6 texels at 64 samples; 10^6 is fitted as 16 chunks
//                                 of 62,500 texels, as `reflcap fit` streams a sample store
//                                 (memory stays at one chunk); Ceres stops at 10^4
//   BM_LobeTests{PerSample,VectorLanes}  the post-fit passes' candidate-lobe scoring, both ways
//   BM_BuildMaterialClusters/threads  the material clusters' build over 10^6 texels
//   BM_PrepareTexel, BM_FinishProblem    the host's work before and after every backend's LM, on
//                                 one thread (what sets a GPU run's prepare_s and finish_s)
//
// Every benchmark first fits its data once and checks the result against ground truth
// (converged fraction and median relative errors, reported as counters); timing only counts
// when that verification passes. Data: the five synth materials that have a lobe (glossy, sharp,
// anisotropic, coloured texture, coloured lobe), 1 % noise, 12 % of the samples near the mirror
// direction.
//
//   build/bench/engine/reflcap_fit_bench --benchmark_out=fit_bench.json
//   REFLCAP_BENCH_VK_DEVICE=NAME|INDEX picks the Vulkan device (default: automatic).
//
// Counters: fits_per_second (wall clock), fits_per_cpu_second (fits / process CPU time, all
// threads of the process — on lavapipe the "GPU" threads are CPU threads of this process, so
// this is the per-core rate of every backend alike), converged (fraction), err_rho/err_peak/
// err_n (median relative errors vs ground truth), iterations (mean LM steps per texel, max over
// its channels); Vulkan also device_s (wall-clock seconds of the device's batches per
// iteration, overlapped with CPU preparation) and dispatches.
#include <benchmark/benchmark.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdlib>
#include <ctime>
#include <map>
#include <memory>
#include <tuple>

#include "engine/core/parallel.h"
#include "engine/fit/fit_store.h"
#include "engine/fit/fitter.h"
#include "engine/fit/lobe_transfer.h"
#include "engine/fit/material_clusters.h"
#include "engine/fit/problem.h"
#include "engine/fit/synthetic_samples.h"
#include "engine/fit/vulkan_fitter.h"
#ifdef REFLCAP_HAVE_DEVICE_PEAK
#include "bench/gpu/device_peak.h"
#endif

namespace reflcap::fit {
namespace {

// Texels of the samples-per-texel sweep (all backends fit the same texels, so their errors
// compare directly).
constexpr int kTexels = 4096;
// The 10^6-texel point is fitted in chunks of this many texels.
constexpr int kStreamChunkTexels = 62500;
// Verification bars: a sanity check that the timed fits are right (the accuracy targets are the
// recovery test's, at 100 samples); loose enough for the 16-sample end of the sweep.
constexpr double kMinConverged = 0.9;
constexpr double kMaxMedianError = 0.1;

struct Data {
  std::vector<brdf::BrdfParams> truth;
  TexelSampleChunk chunk;
};

const Data& GetData(int texels, int samples) {
  static std::map<std::pair<int, int>, Data> cache;
  auto it = cache.find({texels, samples});
  if (it != cache.end()) return it->second;
  // Only one large data set at a time: memory stays near one chunk of the sweep.
  for (auto i = cache.begin(); i != cache.end();) {
    i = i->first.first > 20000 ? cache.erase(i) : std::next(i);
  }
  Data d;
  const auto all = SynthMaterialTexels(texels * 6 / 5 + 6, 31);
  for (size_t t = 0; t < all.size() && int(d.truth.size()) < texels; ++t) {
    if (t % kSynthMaterialCount != 0) d.truth.push_back(all[t]);  // skip matte
  }
  SyntheticSampleOptions so;
  so.samples_per_texel = samples;
  so.near_mirror_samples = std::max(4, samples * 12 / 100);
  so.seed = 31;
  d.chunk = MakeSyntheticChunk(d.truth, so);
  return cache.emplace(std::make_pair(texels, samples), std::move(d)).first->second;
}

double Median(std::vector<double> v) {
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

// One fitter per configuration for the whole run (the Vulkan pipelines are compiled once),
// released by main before exit (a GPU driver's exit handlers run before static destructors).
struct FitterConfig {
  Backend backend = Backend::kCpu;
  VulkanFitKernel kernel = VulkanFitKernel::kAuto;
  uint32_t cluster_size = 0;
  bool staged = false;  // VulkanFitterOptions::map_device_records = false
  bool operator<(const FitterConfig& o) const {
    return std::tie(backend, kernel, cluster_size, staged) <
           std::tie(o.backend, o.kernel, o.cluster_size, o.staged);
  }
};
std::map<FitterConfig, std::unique_ptr<Fitter>> g_fitters;
std::map<FitterConfig, std::string> g_fitter_errors;
// The device's measured peaks (bench/gpu/device_peak.h), when a Vulkan device was measured.
double g_peak_gflops = 0;

Fitter* GetFitter(const FitterConfig& config, std::string* error) {
  if (!g_fitters.count(config) && !g_fitter_errors.count(config)) {
    const char* device = std::getenv("REFLCAP_BENCH_VK_DEVICE");
    VulkanFitterOptions vulkan;
    vulkan.device = device ? device : "";
    vulkan.kernel = config.kernel;
    vulkan.cluster_size = config.cluster_size;
    vulkan.map_device_records = !config.staged;
    auto created = CreateFitter(config.backend, 0, vulkan);
    if (created.ok()) {
      g_fitters[config] = std::move(created).value();
    } else {
      g_fitter_errors[config] = created.status().ToString();
    }
  }
  if (g_fitter_errors.count(config)) {
    *error = g_fitter_errors[config];
    return nullptr;
  }
  return g_fitters[config].get();
}
Fitter* GetFitter(Backend backend, std::string* error) {
  return GetFitter(FitterConfig{backend}, error);
}

// Fits once and reports accuracy counters; false (with a message) when below the bars.
bool Verify(Fitter& fitter, const Data& d, const FitOptions& options, benchmark::State& state) {
  std::vector<TexelFit> fits;
  if (!fitter.Fit(d.chunk, options, &fits).ok()) {
    state.SkipWithError("Fit failed");
    return false;
  }
  std::vector<double> rho, peak, n;
  double converged = 0, iterations = 0;
  for (size_t t = 0; t < fits.size(); ++t) {
    converged += fits[t].status == FitStatus::kConverged;
    iterations += fits[t].iterations;
    for (int c = 0; c < 3; ++c) {
      rho.push_back(std::abs(fits[t].params.rho_d[c] / d.truth[t].rho_d[c] - 1));
      peak.push_back(std::abs(LobePeak(fits[t].params.lobes[0][c]) / LobePeak(d.truth[t].lobes[0][c]) - 1));
      n.push_back(std::abs(fits[t].params.lobes[0][c].n / d.truth[t].lobes[0][c].n - 1));
    }
  }
  state.counters["converged"] = converged / fits.size();
  state.counters["err_rho"] = Median(rho);
  state.counters["err_peak"] = Median(peak);
  state.counters["err_n"] = Median(n);
  state.counters["iterations"] = iterations / fits.size();
  if (converged / fits.size() < kMinConverged || Median(rho) > kMaxMedianError ||
      Median(peak) > kMaxMedianError || Median(n) > kMaxMedianError) {
    state.SkipWithError("verification against ground truth failed");
    return false;
  }
  return true;
}

// Times `chunks` Fit calls on the data of `texels` texels x `samples` samples per iteration.
void RunFits(benchmark::State& state, const FitterConfig& config, int texels, int samples,
             int chunks = 1) {
  const Backend backend = config.backend;
  std::string error;
  Fitter* fitter = GetFitter(config, &error);
  if (fitter == nullptr) {
    state.SkipWithError(error.c_str());
    return;
  }
  const Data& d = GetData(texels, samples);
  const FitOptions options;  // seed start + two-stage LM, aniso, K = 1, all cores
  if (!Verify(*fitter, d, options, state)) return;
  std::vector<TexelFit> results;
  double device_seconds = 0, dispatches = 0, prepare_seconds = 0, finish_seconds = 0,
         evaluations = 0, prepare_texel_thread_s = 0, prepare_layout_thread_s = 0, reprepared = 0;
  const std::clock_t cpu_start = std::clock();
  for (auto _ : state) {
    for (int c = 0; c < chunks; ++c) {
      benchmark::DoNotOptimize(fitter->Fit(d.chunk, options, &results));
      if (auto* vk = dynamic_cast<VulkanFitter*>(fitter)) {
        device_seconds += vk->last_stats().device_seconds;
        dispatches += vk->last_stats().dispatches;
        prepare_seconds += vk->last_stats().prepare_seconds;
        prepare_texel_thread_s += vk->last_stats().prepare_texel_thread_seconds;
        prepare_layout_thread_s += vk->last_stats().prepare_layout_thread_seconds;
        finish_seconds += vk->last_stats().finish_seconds;
        reprepared += double(vk->last_stats().reprepared_texels);
        evaluations += double(vk->last_stats().residual_evaluations);
      }
    }
  }
  const double cpu_seconds = double(std::clock() - cpu_start) / CLOCKS_PER_SEC;
  const double fits = double(3 * d.truth.size()) * chunks * state.iterations();
  state.counters["fits_per_second"] = benchmark::Counter(fits, benchmark::Counter::kIsRate);
  // Fits per second of CPU time summed over all threads (lavapipe's included): the per-core
  // rate, which other load on a shared machine does not dilute (wall-clock fits_per_second does).
  state.counters["fits_per_cpu_second"] = fits / std::max(cpu_seconds, 1e-9);
  state.counters["threads"] = HardwareThreads();
  if (backend == Backend::kVulkan) {
    state.counters["device_s"] = device_seconds / std::max<double>(1, state.iterations());
    state.counters["dispatches"] = dispatches / std::max<double>(1, state.iterations());
    state.counters["prepare_s"] = prepare_seconds / std::max<double>(1, state.iterations());
    // Thread-seconds of the preparation: PrepareTexel, and the layout for the device.
    state.counters["prepare_texel_ts"] = prepare_texel_thread_s / std::max<double>(1, state.iterations());
    state.counters["prepare_layout_ts"] = prepare_layout_thread_s / std::max<double>(1, state.iterations());
    state.counters["finish_s"] = finish_seconds / std::max<double>(1, state.iterations());
    // Texels prepared again while finishing (fallbacks, channel retries read their residuals).
    state.counters["reprepared"] = reprepared / std::max<double>(1, state.iterations());
    // The device's LM work as FLOP/s over the device's batches and over the whole wall time,
    // and as a fraction of the measured multiply-add peak (bench/gpu/device_peak.h).
#ifdef REFLCAP_HAVE_DEVICE_PEAK
    const double flops =
        evaluations * bench::FitFlopsPerResidualEvaluation(ProblemLayout{options.lobe_model,
                                                                         options.lobes}.NumParams());
    state.counters["device_gflops"] = flops / std::max(device_seconds, 1e-9) * 1e-9;
    if (g_peak_gflops > 0) {
      state.counters["device_peak_pct"] =
          100 * flops / std::max(device_seconds, 1e-9) * 1e-9 / g_peak_gflops;
    }
#endif
    if (auto* vk = dynamic_cast<VulkanFitter*>(fitter)) {
      const VulkanFitStats& st = vk->last_stats();
      state.SetLabel(StrCat(fitter->device(), " [", VulkanFitKernelName(st.kernel),
                            st.kernel == VulkanFitKernel::kClusters
                                ? StrCat(" x", st.cluster_size, st.native_math ? ", native exp/log" : "")
                                : std::string(),
                            st.records_mapped ? ", records mapped" : ", records staged", "]"));
    }
  }
  if (backend != Backend::kVulkan) state.SetLabel(fitter->device());
}

void BM_FitBatchedCpu(benchmark::State& state) { RunFits(state, {Backend::kCpu}, kTexels, int(state.range(0))); }
void BM_FitVulkan(benchmark::State& state) { RunFits(state, {Backend::kVulkan}, kTexels, int(state.range(0))); }
void BM_FitCeres(benchmark::State& state) { RunFits(state, {Backend::kCeres}, kTexels, int(state.range(0))); }

// texels <= 10^5: one Fit call; 10^6: 16 calls on a 62,500-texel chunk (a streamed store).
void Texels(benchmark::State& state, const FitterConfig& config, int64_t texels) {
  if (texels > 100000) {
    RunFits(state, config, kStreamChunkTexels, 64, int(texels / kStreamChunkTexels));
  } else {
    RunFits(state, config, int(texels), 64);
  }
}
void BM_FitTexelsBatchedCpu(benchmark::State& state) { Texels(state, {Backend::kCpu}, state.range(0)); }
void BM_FitTexelsVulkan(benchmark::State& state) { Texels(state, {Backend::kVulkan}, state.range(0)); }
// The same with the residual quads uploaded through the staging ring even where the device's
// memory is host-visible (a discrete GPU's resizable BAR): which of the two is faster there.
void BM_FitTexelsVulkanStaged(benchmark::State& state) {
  FitterConfig config{Backend::kVulkan};
  config.staged = true;
  Texels(state, config, state.range(0));
}
void BM_FitTexelsCeres(benchmark::State& state) { Texels(state, {Backend::kCeres}, state.range(0)); }
// The host's per-texel preparation alone (problem.h PrepareTexel: masking, normalisation,
// classification, start values) on one thread, 62,500 texels x 64 samples, aniso, one lobe: what
// every backend does before its LM (BM_FitTexelsVulkan's prepare_s on a GPU).
void BM_PrepareTexel(benchmark::State& state) {
  const Data& d = GetData(kStreamChunkTexels, 64);
  const FitOptions options;
  const ProblemLayout layout{options.lobe_model, options.lobes};
  ProblemArena arena;
  uint64_t max_samples = 1;
  for (uint32_t t = 0; t < d.chunk.texel_count; ++t) {
    max_samples = std::max<uint64_t>(max_samples, d.chunk.SampleCount(t));
  }
  arena.Reserve(3 * max_samples, max_samples);
  std::vector<PreparedProblem> problems(size_t(ProblemsPerTexel(layout.model)));
  for (auto _ : state) {
    for (uint32_t t = 0; t < d.chunk.texel_count; ++t) {
      size_t cursor = 0;
      PrepareTexel(options, layout, d.chunk.SamplesOf(t), d.chunk.SampleCount(t), int(t), &arena,
                   &cursor, problems.data());
      benchmark::DoNotOptimize(problems.data());
    }
  }
  state.counters["texels_per_second"] = benchmark::Counter(
      double(d.chunk.texel_count) * double(state.iterations()), benchmark::Counter::kIsRate);
  state.counters["us_per_texel"] = benchmark::Counter(
      double(d.chunk.texel_count) * double(state.iterations()),
      benchmark::Counter::kIsRate | benchmark::Counter::kInvert);
}
BENCHMARK(BM_PrepareTexel)->Unit(benchmark::kMillisecond)->UseRealTime();

// The host's post-processing of solved problems alone (problem.h FinishProblem: rank test,
// standard deviations, natural units, status folding) on one thread, the 187,500 problems of
// BM_PrepareTexel's texels solved once beforehand by the scalar float LM: what every backend
// does after its LM (BM_FitTexelsVulkan's finish_s on a GPU, with the channel retries).
void BM_FinishProblem(benchmark::State& state) {
  const Data& d = GetData(kStreamChunkTexels, 64);
  const FitOptions options;
  const ProblemLayout layout{options.lobe_model, options.lobes};
  const int per_texel = ProblemsPerTexel(layout.model);
  ProblemArena arena;  // one arena for every texel: the problems' residual views stay valid
  uint64_t max_samples = 1;
  for (uint32_t t = 0; t < d.chunk.texel_count; ++t) {
    max_samples = std::max<uint64_t>(max_samples, d.chunk.SampleCount(t));
  }
  arena.Reserve(3 * d.chunk.samples.size(), max_samples);
  std::vector<PreparedProblem> problems(size_t(d.chunk.texel_count) * per_texel);
  size_t cursor = 0;
  for (uint32_t t = 0; t < d.chunk.texel_count; ++t) {
    PrepareTexel(options, layout, d.chunk.SamplesOf(t), d.chunk.SampleCount(t), int(t), &arena,
                 &cursor, &problems[size_t(t) * per_texel]);
  }
  // The solutions as a device returns them (parameters, packed normal equations, cost, mask,
  // status, iterations in floats; the Vulkan fitter's Finish), read into a texel's local
  // SolvedProblems before FinishProblem, as the backends do: a SolvedProblem per problem kept
  // in memory (1.3 KB each) would time this machine's memory instead.
  const int P = layout.NumParams(), packed = PackedIndex(P, 0), stride = P + packed + 4;
  std::vector<float> results(problems.size() * size_t(stride));
  const LmSettings settings = MakeLmSettings(options);
  ParallelFor(0, int64_t(problems.size()), 256, [&](int64_t b, int64_t e, int) {
    for (int64_t i = b; i < e; ++i) {
      const SolvedProblem s = SolveScalar<float>(problems[size_t(i)], settings, options.loss);
      float* w = &results[size_t(i) * stride];
      for (int j = 0; j < P; ++j) w[j] = float(s.x[j]);
      for (int k = 0; k < packed; ++k) w[P + k] = float(s.a[k]);
      w[P + packed] = float(s.cost);
      w[P + packed + 1] = float(s.free_mask);
      w[P + packed + 2] = float(int(s.status));
      w[P + packed + 3] = float(s.iterations);
    }
  });
  std::vector<TexelFit> fits(d.chunk.texel_count);
  constexpr int kMaxPerTexel = 3;
  for (auto _ : state) {
    for (uint32_t t = 0; t < d.chunk.texel_count; ++t) {
      SolvedProblem solved[kMaxPerTexel];
      for (int p = 0; p < per_texel; ++p) {
        const float* w = &results[(size_t(t) * per_texel + p) * stride];
        solved[p] = SolvedProblem{};
        for (int j = 0; j < P; ++j) solved[p].x[j] = w[j];
        for (int k = 0; k < packed; ++k) solved[p].a[k] = w[P + k];
        solved[p].cost = w[P + packed];
        solved[p].free_mask = uint32_t(w[P + packed + 1]);
        solved[p].status = FitStatus(int(w[P + packed + 2]));
        solved[p].iterations = int(w[P + packed + 3]);
      }
      BeginTexel(layout.lobes, &fits[t]);
      for (int p = 0; p < per_texel; ++p) {
        FinishProblem(problems[size_t(t) * per_texel + p], solved[p], &fits[t]);
      }
    }
    benchmark::DoNotOptimize(fits.data());
  }
  // Seconds a problem (shown with an SI prefix: 290n = 290 ns).
  state.counters["s_per_problem"] = benchmark::Counter(
      double(problems.size()) * double(state.iterations()),
      benchmark::Counter::kIsRate | benchmark::Counter::kInvert);
}
BENCHMARK(BM_FinishProblem)->Unit(benchmark::kMillisecond)->UseRealTime();

// What one ParallelFor call costs beyond its work: 64 chunks of a few nanoseconds each on all
// hardware threads (the fit makes ~1,200 such calls per million texels, most with real work).
// The time column is the time per call; checked: every chunk ran once per call.
void BM_ParallelForCall(benchmark::State& state) {
  std::vector<int> hits(64, 0);
  for (auto _ : state) {
    ParallelFor(0, int64_t(hits.size()), 1, [&](int64_t b, int64_t e, int) {
      for (int64_t i = b; i < e; ++i) ++hits[size_t(i)];
    });
  }
  for (int h : hits) {
    if (h != int(state.iterations())) {
      state.SkipWithError("a chunk did not run exactly once per call");
      return;
    }
  }
  state.SetLabel(std::to_string(HardwareThreads()) + " hardware threads");
}
BENCHMARK(BM_ParallelForCall)->UseRealTime()->Unit(benchmark::kMicrosecond);

// The Vulkan fitter's kernels side by side at 10^6 texels: /kernel/cluster_size/texels, kernel
// 0 = lanes, 1 = clusters (bench/RESULTS.md's GPU sweep; slow on lavapipe: run it on a GPU).
void BM_FitVulkanKernel(benchmark::State& state) {
  const FitterConfig config{Backend::kVulkan,
                            state.range(0) == 0 ? VulkanFitKernel::kLanes : VulkanFitKernel::kClusters,
                            uint32_t(state.range(1))};
  Texels(state, config, state.range(2));
}
BENCHMARK(BM_FitVulkanKernel)
    ->Args({0, 0, 1000000})
    ->Args({1, 4, 1000000})
    ->Args({1, 8, 1000000})
    ->Args({1, 16, 1000000})
    ->Args({1, 32, 1000000})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->Iterations(1);

// The post-fit lobe tests (lobe transfer, material clusters, diffuse fall-off): the albedo
// re-fit cost of a candidate lobe on a texel's samples, as they score every candidate at every
// sample. Per texel of the sweep's data (64 samples) three candidate lobes — the texel's own
// truth and two other texels' — are scored, per sample (ChannelResidual, scalar pow) or on the
// texel's prepared residuals (TexelResiduals: the directions once, the lobes on vector lanes).
// Counter lobe_tests_per_second; check: both give the same costs (to 0.05 noise units).
void LobeTests(benchmark::State& state, bool vector_lanes) {
  const Data& d = GetData(kTexels, 64);
  const TexelSampleChunk& chunk = d.chunk;
  std::vector<UsableSample> usable;
  TexelResiduals residuals;
  const auto costs = [&](uint32_t i, double* out) {
    const BrdfSample* samples = chunk.SamplesOf(i);
    const size_t count = chunk.SampleCount(i);
    std::array<float, brdf::kChannels> rho{};
    if (vector_lanes) {
      residuals.Prepare(samples, count, 0.05);
    } else {
      usable.resize(count);
      for (size_t s = 0; s < count; ++s) usable[s] = PrepareUsableSample(samples[s], 0.05);
    }
    for (int k = 0; k < 3; ++k) {
      const brdf::BrdfParams& lobe = d.truth[(i + 997 * size_t(k)) % d.truth.size()];
      out[k] = vector_lanes ? RefitAlbedoCost(&residuals, &lobe, &rho)
                            : RefitAlbedoCost(samples, count, usable.data(), &lobe, &rho);
    }
  };
  // The two paths agree (the float lobe evaluation's rounding apart) before anything is timed.
  {
    double a[3], b[3];
    const bool saved = vector_lanes;
    for (uint32_t i = 0; i < 64; ++i) {
      vector_lanes = true;
      costs(i, a);
      vector_lanes = false;
      costs(i, b);
      for (int k = 0; k < 3; ++k) {
        // Costs are in noise units (1/2 sum w r^2); the passes decide by margins of >= 0.5, so a
        // tenth of that is agreement (a sharp lobe's n-fold float rounding moves its own
        // texel's cost by ~0.01).
        if (!(std::abs(a[k] - b[k]) <= 0.05 + 1e-4 * std::abs(b[k]))) {
          state.SkipWithError("the vector and per-sample costs disagree");
          return;
        }
      }
    }
    vector_lanes = saved;
  }
  double sink = 0;
  for (auto _ : state) {
    for (uint32_t i = 0; i < chunk.texel_count; ++i) {
      double c[3];
      costs(i, c);
      sink += c[0] + c[1] + c[2];
    }
  }
  benchmark::DoNotOptimize(sink);
  state.counters["lobe_tests_per_second"] = benchmark::Counter(
      3.0 * chunk.texel_count * double(state.iterations()), benchmark::Counter::kIsRate);
}
void BM_LobeTestsPerSample(benchmark::State& state) { LobeTests(state, false); }
void BM_LobeTestsVectorLanes(benchmark::State& state) { LobeTests(state, true); }
BENCHMARK(BM_LobeTestsPerSample)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_LobeTestsVectorLanes)->Unit(benchmark::kMillisecond)->UseRealTime();

// The material clusters' build (material_clusters.h step 1: features, bisecting 2-means) over a
// million-texel store on /threads threads (0: all): a serial stage of `reflcap fit` until its
// sums were taken per block (0.13 s at 16 threads on the H200 host). 700,000 texels with
// samples, of eight albedos with a 1 % jitter; 300,000 with too few samples to cluster.
// Checked: eight clusters, each one material's.
void BM_BuildMaterialClusters(benchmark::State& state) {
  constexpr size_t kStoreTexels = 1000000;
  constexpr int kMaterials = 8;
  const auto material = [](size_t t) { return int((t * 2654435761u >> 9) % kMaterials); };
  static const FitStore* store = [&] {
    auto* fits = new FitStore(kStoreTexels, 1);
    for (size_t t = 0; t < kStoreTexels; ++t) {
      TexelFit fit;
      fit.params.num_lobes = 1;
      const int m = material(t);
      for (int c = 0; c < brdf::kChannels; ++c) {
        const double base = 0.1 + 0.08 * ((m * 3 + c * 5) % 8);
        const double jitter = 0.99 + 0.02 * double((t * 7 + size_t(c) * 13) % 101) / 100.0;
        fit.params.rho_d[size_t(c)] = float(base * jitter);
      }
      fit.status = FitStatus::kConverged;
      fit.lambert_only = true;
      fit.samples = t % 10 < 7 ? 64 : 2;
      fits->Set(t, fit);
    }
    return fits;
  }();
  const MaterialClusterOptions options;
  MaterialClusters clusters;
  for (auto _ : state) {
    MaterialClusterStats stats;
    clusters = BuildMaterialClusters(*store, options, &stats, int(state.range(0)));
    benchmark::DoNotOptimize(clusters.count);
  }
  std::vector<int> of_material(kMaterials, -2);
  for (size_t t = 0; t < kStoreTexels; ++t) {
    if (store->samples(t) < kMinTransferSamples) continue;
    int& k = of_material[size_t(material(t))];
    if (k == -2) k = clusters.cluster_of[t];
    if (clusters.cluster_of[t] != k || k < 0) {
      state.SkipWithError("a material's texels are not one cluster");
      return;
    }
  }
  if (clusters.count != kMaterials) {
    state.SkipWithError("not one cluster per material");
    return;
  }
  state.counters["clusters"] = clusters.count;
  state.counters["texels_per_second"] =
      benchmark::Counter(double(kStoreTexels) * double(state.iterations()),
                         benchmark::Counter::kIsRate);
}
BENCHMARK(BM_BuildMaterialClusters)->Arg(1)->Arg(2)->Arg(0)
    ->Unit(benchmark::kMillisecond)->UseRealTime();

#define REFLCAP_SAMPLES_SWEEP(bench) \
  BENCHMARK(bench)->Arg(64)->Arg(16)->Arg(32)->Arg(128)->Arg(256)->Arg(512)->Arg(1024) \
      ->Unit(benchmark::kMillisecond)->UseRealTime()
REFLCAP_SAMPLES_SWEEP(BM_FitVulkan);
REFLCAP_SAMPLES_SWEEP(BM_FitBatchedCpu);
BENCHMARK(BM_FitCeres)->Arg(64)->Arg(16)->Arg(256)->Iterations(1)
    ->Unit(benchmark::kMillisecond)->UseRealTime();

BENCHMARK(BM_FitTexelsVulkan)->Arg(1000)->Arg(10000)->Arg(100000)->Arg(1000000)
    ->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(1);
BENCHMARK(BM_FitTexelsVulkanStaged)->Arg(1000000)
    ->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(1);
BENCHMARK(BM_FitTexelsBatchedCpu)->Arg(1000)->Arg(10000)->Arg(100000)->Arg(1000000)
    ->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(1);
BENCHMARK(BM_FitTexelsCeres)->Arg(1000)->Arg(10000)
    ->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(1);

}  // namespace
}  // namespace reflcap::fit

// Google Benchmark's main, plus the Vulkan device (or why there is none) and its measured peaks
// in the context block; the fitters are released before exit.
int main(int argc, char** argv) {
  using namespace reflcap;
  std::string error;
  fit::Fitter* vk = fit::GetFitter(fit::Backend::kVulkan, &error);
  benchmark::AddCustomContext("vulkan_device", vk ? vk->device() : "unavailable: " + error);
  std::printf("Vulkan device: %s\n", vk ? vk->device().c_str() : ("unavailable: " + error).c_str());
#ifdef REFLCAP_HAVE_DEVICE_PEAK
  if (vk != nullptr) {
    const char* device = std::getenv("REFLCAP_BENCH_VK_DEVICE");
    StatusOr<bench::DevicePeak> peak = bench::MeasureDevicePeak(device ? device : "");
    if (peak.ok()) {
      fit::g_peak_gflops = peak->mad_gflops;
      benchmark::AddCustomContext("device_mad_gflops", StrCat(peak->mad_gflops));
      benchmark::AddCustomContext("device_copy_gbps", StrCat(peak->copy_gbps));
      std::printf("device peaks: %.0f GFLOP/s multiply-add, %.0f GB/s device copy (%s)\n",
                  peak->mad_gflops, peak->copy_gbps, peak->timing.c_str());
    } else {
      std::printf("device peaks: not measured (%s)\n", peak.status().ToString().c_str());
    }
  }
#endif
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  fit::g_fitters.clear();
  return 0;
}
