// reflcap_fit_bench: fits per second of the batched CPU fitter, the Vulkan fitter and the Ceres
// reference on the same synthetic texels, in one run — one fit is one colour channel of one
// texel: Lambert + one anisotropic Lafortune lobe, 5 parameters, N samples (64 for the issues'
// goals).
//
//   BM_Fit<Backend>/samples       N = 16 .. 1024 samples per texel at kTexels texels
//   BM_FitTexels<Backend>/texels  10^3 .. 10^6 texels at 64 samples; 10^6 is fitted as 16 chunks
//                                 of 62,500 texels, as `reflcap fit` streams a sample store
//                                 (memory stays at one chunk); Ceres stops at 10^4
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
#include <cstdlib>
#include <ctime>
#include <map>
#include <memory>

#include "engine/core/parallel.h"
#include "engine/fit/fitter.h"
#include "engine/fit/synthetic_samples.h"
#include "engine/fit/vulkan_fitter.h"

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

// One fitter per backend for the whole run (the Vulkan pipelines are compiled once).
Fitter* GetFitter(Backend backend, std::string* error) {
  static std::map<Backend, std::unique_ptr<Fitter>> fitters;
  static std::map<Backend, std::string> errors;
  if (!fitters.count(backend) && !errors.count(backend)) {
    const char* device = std::getenv("REFLCAP_BENCH_VK_DEVICE");
    auto created = CreateFitter(backend, 0, device ? device : "");
    if (created.ok()) {
      fitters[backend] = std::move(created).value();
    } else {
      errors[backend] = created.status().ToString();
    }
  }
  if (errors.count(backend)) {
    *error = errors[backend];
    return nullptr;
  }
  return fitters[backend].get();
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
void RunFits(benchmark::State& state, Backend backend, int texels, int samples, int chunks = 1) {
  std::string error;
  Fitter* fitter = GetFitter(backend, &error);
  if (fitter == nullptr) {
    state.SkipWithError(error.c_str());
    return;
  }
  const Data& d = GetData(texels, samples);
  const FitOptions options;  // seed start + two-stage LM, aniso, K = 1, all cores
  if (!Verify(*fitter, d, options, state)) return;
  std::vector<TexelFit> results;
  double device_seconds = 0, dispatches = 0;
  const std::clock_t cpu_start = std::clock();
  for (auto _ : state) {
    for (int c = 0; c < chunks; ++c) {
      benchmark::DoNotOptimize(fitter->Fit(d.chunk, options, &results));
      if (auto* vk = dynamic_cast<VulkanFitter*>(fitter)) {
        device_seconds += vk->last_stats().device_seconds;
        dispatches += vk->last_stats().dispatches;
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
  }
  state.SetLabel(fitter->device());
}

void BM_FitBatchedCpu(benchmark::State& state) { RunFits(state, Backend::kCpu, kTexels, int(state.range(0))); }
void BM_FitVulkan(benchmark::State& state) { RunFits(state, Backend::kVulkan, kTexels, int(state.range(0))); }
void BM_FitCeres(benchmark::State& state) { RunFits(state, Backend::kCeres, kTexels, int(state.range(0))); }

// texels <= 10^5: one Fit call; 10^6: 16 calls on a 62,500-texel chunk (a streamed store).
void Texels(benchmark::State& state, Backend backend) {
  const int texels = int(state.range(0));
  if (texels > 100000) {
    RunFits(state, backend, kStreamChunkTexels, 64, texels / kStreamChunkTexels);
  } else {
    RunFits(state, backend, texels, 64);
  }
}
void BM_FitTexelsBatchedCpu(benchmark::State& state) { Texels(state, Backend::kCpu); }
void BM_FitTexelsVulkan(benchmark::State& state) { Texels(state, Backend::kVulkan); }
void BM_FitTexelsCeres(benchmark::State& state) { Texels(state, Backend::kCeres); }

#define REFLCAP_SAMPLES_SWEEP(bench) \
  BENCHMARK(bench)->Arg(64)->Arg(16)->Arg(32)->Arg(128)->Arg(256)->Arg(512)->Arg(1024) \
      ->Unit(benchmark::kMillisecond)->UseRealTime()
REFLCAP_SAMPLES_SWEEP(BM_FitVulkan);
REFLCAP_SAMPLES_SWEEP(BM_FitBatchedCpu);
BENCHMARK(BM_FitCeres)->Arg(64)->Arg(16)->Arg(256)->Iterations(1)
    ->Unit(benchmark::kMillisecond)->UseRealTime();

BENCHMARK(BM_FitTexelsVulkan)->Arg(1000)->Arg(10000)->Arg(100000)->Arg(1000000)
    ->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(1);
BENCHMARK(BM_FitTexelsBatchedCpu)->Arg(1000)->Arg(10000)->Arg(100000)->Arg(1000000)
    ->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(1);
BENCHMARK(BM_FitTexelsCeres)->Arg(1000)->Arg(10000)
    ->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(1);

}  // namespace
}  // namespace reflcap::fit

// Google Benchmark's main, plus the Vulkan device (or why there is none) in the context block.
int main(int argc, char** argv) {
  std::string error;
  reflcap::fit::Fitter* vk = reflcap::fit::GetFitter(reflcap::fit::Backend::kVulkan, &error);
  benchmark::AddCustomContext("vulkan_device", vk ? vk->device() : "unavailable: " + error);
  std::printf("Vulkan device: %s\n", vk ? vk->device().c_str() : ("unavailable: " + error).c_str());
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
