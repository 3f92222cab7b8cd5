// reflcap_resample_bench: throughput of the CPU/Embree resampler and of the occlusion rays it is
// built on.
//
//   build/bench/acquire/reflcap_resample_bench --benchmark_out=resample_bench.json
//
// BM_ResampleImages/<texels>: ImageResampler::Process over every train photograph of a synthetic
// capture generated in the setup (relief object, 256 px, 2 cameras x 3 lights x 4 steps, of which
// 12 are train images; images
// decoded beforehand, so no file I/O is timed). Verified first: the noise-free samples must match
// the ground-truth BRDF (median relative error below kMaxMedianError). Counters:
// texel_image_pairs_per_s, samples_per_s, rays_per_s (all ray kinds), kept_fraction.
//
// BM_ResampleImagesVulkan/<texels>: the same photographs through VulkanMasks::Process
// (`--backend vulkan`: light map, camera map and per-texel tests on the Vulkan device; on lavapipe
// that is the CPU). Verified first against the CPU path on every photograph: the same outcome for
// at least kMinAgreement of the pairs and equal values (kMaxValueDiff) for the samples both keep.
// Counters as BM_ResampleImages, plus agreement and gpu_s_per_image (submit + fence wait). The
// device name is printed in the benchmark's label.
//
// BM_ResampleCapture: ResampleCapture end to end (reading images, resampling, reorder, store,
// maps, report) on the same capture. Counter: texel_image_pairs_per_s.
//
// BM_Occluded{Single,Packet16}/<order>: occlusion rays from every texel of the relief object's
// 512² atlas (offset along the normal) to one point light, in atlas order (coherent: neighbours
// are consecutive) or shuffled (incoherent), as RayScene::Occluded one ray at a time or
// Occluded16 sixteen at a time. Verified first: packets give exactly the single-ray answers.
// Counters: rays_per_s, occluded_fraction, rays_per_pass, triangles.
//
// BM_ReadPhotograph/threads:N: one 2048^2 float EXR photograph decoded by N threads at once
// (REFLCAP_BENCH_PHOTOGRAPH=<file> decodes that file). Counter: images_per_s.
#include <benchmark/benchmark.h>

#include <unistd.h>

#include <algorithm>
#include <cstdlib>
#include <map>
#include <memory>
#include <mutex>
#include <random>

#include "acquire/resample/image_resampler.h"
#include "acquire/resample/mask_agreement.h"
#include "acquire/resample/vulkan_masks.h"
#include "acquire/resample/resample.h"
#include "acquire/synth/synth.h"
#include "engine/brdf/lafortune.h"
#include "engine/capture/capture.h"
#include "engine/core/log.h"
#include "engine/image/exr_io.h"
#include "engine/image/image_io.h"
#include "engine/mesh/mesh_io.h"
#include "engine/mesh/ray_scene.h"
#include "engine/mesh/texel_atlas.h"
#include "engine/texel/brdf_maps.h"

namespace reflcap::resample {
namespace {
namespace fs = std::filesystem;

// Noise-free samples against the ground truth (see resample_test.cc for why ~1e-3 at 256 px).
constexpr double kMaxMedianError = 2e-3;
// The Vulkan path against the CPU path (the acceptance bar of tests/acquire/resample/
// vulkan_masks_test.cc): the same outcome for this fraction of pairs, values within this relative
// difference for the samples both keep.
constexpr double kMinAgreement = 0.995;
// --sample-point pixel (the default): the GPU's hit normal comes from the rasteriser, ~0.01 px
// from the CPU's exact hit; the test's tolerance is the 1e-3 radiometric floor.
constexpr double kMaxValueDiff = 1e-3;

// A temporary folder removed at exit.
struct TempDir {
  fs::path path;
  TempDir() {
    path = fs::temp_directory_path() / ("reflcap_resample_bench_" + std::to_string(::getpid()));
    fs::remove_all(path);
    fs::create_directories(path);
  }
  ~TempDir() {
    std::error_code ec;
    fs::remove_all(path, ec);
  }
};

TempDir& Temp() {
  static TempDir dir;
  return dir;
}

struct Loaded {
  fs::path dir;
  Capture capture;
  TriangleMesh mesh;
  TexelAtlas atlas;
  std::unique_ptr<RayScene> scene;
  BrdfMaps truth;
  std::vector<uint32_t> train;
  std::vector<Image> images;  // decoded train photographs, in `train` order
};

// The synthetic capture with about `texels` texels, generated and decoded once per size.
const Loaded* GetCapture(int texels, benchmark::State& state) {
  static std::map<int, std::unique_ptr<Loaded>> cache;
  auto it = cache.find(texels);
  if (it != cache.end()) return it->second.get();
  auto c = std::make_unique<Loaded>();
  c->dir = Temp().path / ("synth_" + std::to_string(texels));
  synth::SynthOptions o;
  o.noise = 0;
  o.texels = texels;
  o.image_size = 256;
  o.cameras = 2;
  o.lights = 3;
  o.steps = 4;
  const LogLevel level = LogThreshold();
  SetLogThreshold(LogLevel::kWarning);  // no progress bars inside the benchmark output
  const bool ok = synth::WriteSyntheticCapture(o, c->dir).ok();
  SetLogThreshold(level);
  if (!ok) {
    state.SkipWithError("synth failed");
    return nullptr;
  }
  c->capture = ReadCapture(c->dir).value();
  c->mesh = LoadMesh(c->dir / "mesh.obj").value();
  // The synth atlas size is recorded in the capture; resample it as ResampleCapture would.
  std::vector<std::string> names;
  const Image params = ReadExrChannels(c->dir / "gt/params.exr", &names).value();
  c->atlas = BuildTexelAtlas(c->mesh, params.width, params.height).value();
  c->scene = RayScene::Create(c->mesh).value();
  c->truth = ReadBrdfMaps(c->dir / "gt/params.exr", c->atlas).value();
  for (uint32_t i = 0; i < c->capture.images.size(); ++i) {
    if (c->capture.images[i].split != Split::kTrain) continue;
    c->train.push_back(i);
    c->images.push_back(ReadExrRgb(c->dir / c->capture.images[i].file).value());
  }
  return cache.emplace(texels, std::move(c)).first->second.get();
}

void BM_ResampleImages(benchmark::State& state) {
  const Loaded* c = GetCapture(int(state.range(0)), state);
  if (c == nullptr) return;
  NoiseModel noise;  // noise-free capture
  auto resampler = ImageResampler::Create(c->capture, c->atlas, c->scene.get(), noise, kDefaultMinCos);
  if (!resampler.ok()) {
    state.SkipWithError(resampler.status().ToString().c_str());
    return;
  }
  // Verify once: noise-free values equal the true BRDF.
  ImageOutput out;
  std::vector<double> errors;
  for (size_t k = 0; k < c->train.size(); ++k) {
    if (!(*resampler)->Process(c->train[k], c->images[k], &out).ok()) {
      state.SkipWithError("Process failed");
      return;
    }
    for (const TexelSample& s : out.kept) {
      const Vec3f truth =
          brdf::EvalRgb(c->truth.texels[s.texel], Vec3f(s.sample.wi[0], s.sample.wi[1], s.sample.wi[2]),
                        Vec3f(s.sample.wo[0], s.sample.wo[1], s.sample.wo[2]));
      errors.push_back(std::abs(s.sample.value[1] - truth[1]) / truth[1]);
    }
  }
  std::nth_element(errors.begin(), errors.begin() + errors.size() / 2, errors.end());
  const double median = errors.empty() ? 1.0 : errors[errors.size() / 2];
  state.counters["median_rel_error"] = median;
  if (!(median < kMaxMedianError)) {
    state.SkipWithError("verification failed: noise-free samples do not match the ground truth");
    return;
  }
  uint64_t pairs = 0, kept = 0, rays = 0;
  for (auto _ : state) {
    for (size_t k = 0; k < c->train.size(); ++k) {
      (void)(*resampler)->Process(c->train[k], c->images[k], &out);
      pairs += c->atlas.TexelCount();
      kept += out.kept.size();
      rays += out.primary_rays + out.tap_shadow_rays + out.visibility_rays + out.shadow_rays;
    }
  }
  state.counters["texels"] = double(c->atlas.TexelCount());
  state.counters["texel_image_pairs_per_s"] = benchmark::Counter(double(pairs), benchmark::Counter::kIsRate);
  state.counters["samples_per_s"] = benchmark::Counter(double(kept), benchmark::Counter::kIsRate);
  state.counters["rays_per_s"] = benchmark::Counter(double(rays), benchmark::Counter::kIsRate);
  state.counters["kept_fraction"] = double(kept) / double(pairs);
}
BENCHMARK(BM_ResampleImages)->Arg(20000)->Arg(150000)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_ResampleImagesVulkan(benchmark::State& state) {
  const Loaded* c = GetCapture(int(state.range(0)), state);
  if (c == nullptr) return;
  NoiseModel noise;  // noise-free capture
  auto resampler = ImageResampler::Create(c->capture, c->atlas, c->scene.get(), noise, kDefaultMinCos);
  VulkanMaskOptions options;
  if (const char* device = std::getenv("REFLCAP_BENCH_VK_DEVICE")) options.device = device;
  auto masks = VulkanMasks::Create(c->capture, c->atlas, c->mesh, c->scene->SurfaceOffset(), noise,
                                   kDefaultMinCos, options);
  if (!resampler.ok() || !masks.ok()) {
    state.SkipWithError((!masks.ok() ? masks.status() : resampler.status()).ToString().c_str());
    return;
  }
  // Verify once: the CPU path's outcomes and values.
  ImageOutput cpu, out;
  CameraMapView map;
  MaskAgreement agreement;
  for (size_t k = 0; k < c->train.size(); ++k) {
    if (!(*resampler)->Process(c->train[k], c->images[k], &cpu).ok() ||
        !(*masks)->Process(c->train[k], c->images[k], &out, &map).ok()) {
      state.SkipWithError("Process failed");
      return;
    }
    agreement.Add(c->atlas.position, cpu.outcome, out.outcome, cpu.kept, out.kept, map);
  }
  state.counters["agreement"] = agreement.AgreeingFraction();
  if (!(agreement.AgreeingFraction() >= kMinAgreement) ||
      !(agreement.max_value_rel_diff <= kMaxValueDiff)) {
    state.SkipWithError("verification failed: the Vulkan masks disagree with the CPU path");
    return;
  }
  uint64_t pairs = 0, kept = 0, images = 0;
  double gpu_s = 0;
  for (auto _ : state) {
    for (size_t k = 0; k < c->train.size(); ++k) {
      (void)(*masks)->Process(c->train[k], c->images[k], &out);
      pairs += c->atlas.TexelCount();
      kept += out.kept.size();
      gpu_s += (*masks)->last_stats().gpu_seconds;
      ++images;
    }
  }
  state.SetLabel((*masks)->device_name() + ", light map " + (*masks)->last_stats().light_map + " " +
                 std::to_string((*masks)->last_stats().light_resolution));
  state.counters["texels"] = double(c->atlas.TexelCount());
  state.counters["texel_image_pairs_per_s"] = benchmark::Counter(double(pairs), benchmark::Counter::kIsRate);
  state.counters["samples_per_s"] = benchmark::Counter(double(kept), benchmark::Counter::kIsRate);
  state.counters["kept_fraction"] = double(kept) / double(pairs);
  state.counters["gpu_s_per_image"] = images ? gpu_s / double(images) : 0.0;
}
BENCHMARK(BM_ResampleImagesVulkan)->Arg(20000)->Arg(150000)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_ResampleCapture(benchmark::State& state) {
  const Loaded* c = GetCapture(int(state.range(0)), state);
  if (c == nullptr) return;
  uint64_t pairs = 0;
  const LogLevel level = LogThreshold();
  SetLogThreshold(LogLevel::kWarning);
  for (auto _ : state) {
    const fs::path out = Temp().path / "store";
    fs::remove_all(out);
    fs::create_directories(out);
    auto summary = ResampleCapture(c->dir, ResampleOptions(), out);
    if (!summary.ok()) {
      state.SkipWithError(summary.status().ToString().c_str());
      break;
    }
    pairs += summary->texels * summary->images;
  }
  SetLogThreshold(level);
  state.counters["texel_image_pairs_per_s"] = benchmark::Counter(double(pairs), benchmark::Counter::kIsRate);
}
BENCHMARK(BM_ResampleCapture)->Arg(20000)->Unit(benchmark::kMillisecond)->UseRealTime();

// ---- Occlusion rays ------------------------------------------------------------------------------

struct RaySet {
  std::unique_ptr<RayScene> scene;
  std::vector<Vec3f> origin, dir;
  std::vector<float> tfar;
  std::vector<uint8_t> truth;  // single-ray answers
};

// Rays from every texel (facing the light) of the relief object's 512² atlas to a light 1 m
// away; order 0 = atlas order (coherent), 1 = shuffled.
const RaySet* GetRays(int order, benchmark::State& state) {
  static std::mutex mutex;  // the Threads(2) runs call this from two threads
  std::lock_guard<std::mutex> lock(mutex);
  static std::map<int, std::unique_ptr<RaySet>> cache;
  auto it = cache.find(order);
  if (it != cache.end()) return it->second.get();
  auto r = std::make_unique<RaySet>();
  const TriangleMesh mesh = synth::MakeReliefObject(96, 1);
  r->scene = RayScene::Create(mesh).value();
  const TexelAtlas atlas = BuildTexelAtlas(mesh, 512, 512).value();
  const Vec3f light(0.7f, 0.4f, 0.75f);
  const float offset = r->scene->SurfaceOffset();
  std::vector<size_t> order_of(atlas.TexelCount());
  for (size_t t = 0; t < order_of.size(); ++t) order_of[t] = t;
  if (order == 1) std::shuffle(order_of.begin(), order_of.end(), std::mt19937(7));
  for (size_t t : order_of) {
    const Vec3f& n = atlas.geometric_normal[t];
    const Vec3f o = atlas.position[t] + offset * n;
    const Vec3f d = light - o;
    if (n.dot(d) <= 0) continue;
    r->origin.push_back(o);
    r->dir.push_back(d.normalized());
    r->tfar.push_back(d.norm());
  }
  // Multiple of 16, so packets are full.
  const size_t n = r->origin.size() / 16 * 16;
  r->origin.resize(n);
  r->dir.resize(n);
  r->tfar.resize(n);
  for (size_t i = 0; i < n; ++i) r->truth.push_back(r->scene->Occluded(r->origin[i], r->dir[i], 0, r->tfar[i]));
  // Verify: packets give exactly the single-ray answers.
  std::array<bool, 16> valid, occluded;
  valid.fill(true);
  std::array<Vec3f, 16> o, d;
  std::array<float, 16> tnear, tfar;
  tnear.fill(0);
  for (size_t base = 0; base < n; base += 16) {
    for (int i = 0; i < 16; ++i) {
      o[i] = r->origin[base + i];
      d[i] = r->dir[base + i];
      tfar[i] = r->tfar[base + i];
    }
    r->scene->Occluded16(valid, o, d, tnear, tfar, &occluded);
    for (int i = 0; i < 16; ++i) {
      if (occluded[i] != bool(r->truth[base + i])) {
        state.SkipWithError("verification failed: Occluded16 differs from Occluded");
        return nullptr;
      }
    }
  }
  return cache.emplace(order, std::move(r)).first->second.get();
}

void BM_OccludedSingle(benchmark::State& state) {
  const RaySet* r = GetRays(int(state.range(0)), state);
  if (r == nullptr) return;
  uint64_t rays = 0, hits = 0;
  for (auto _ : state) {
    for (size_t i = 0; i < r->origin.size(); ++i) {
      hits += r->scene->Occluded(r->origin[i], r->dir[i], 0, r->tfar[i]);
    }
    rays += r->origin.size();
  }
  state.counters["rays_per_s"] = benchmark::Counter(double(rays), benchmark::Counter::kIsRate);
  state.counters["occluded_fraction"] =
      benchmark::Counter(double(hits) / double(rays), benchmark::Counter::kAvgThreads);
  state.counters["rays_per_pass"] = benchmark::Counter(double(r->origin.size()), benchmark::Counter::kAvgThreads);
  state.counters["triangles"] = benchmark::Counter(double(r->scene->mesh().TriangleCount()), benchmark::Counter::kAvgThreads);
}

void BM_OccludedPacket16(benchmark::State& state) {
  const RaySet* r = GetRays(int(state.range(0)), state);
  if (r == nullptr) return;
  uint64_t rays = 0, hits = 0;
  std::array<bool, 16> valid, occluded;
  valid.fill(true);
  std::array<Vec3f, 16> o, d;
  std::array<float, 16> tnear, tfar;
  tnear.fill(0);
  for (auto _ : state) {
    for (size_t base = 0; base < r->origin.size(); base += 16) {
      for (int i = 0; i < 16; ++i) {
        o[i] = r->origin[base + i];
        d[i] = r->dir[base + i];
        tfar[i] = r->tfar[base + i];
      }
      r->scene->Occluded16(valid, o, d, tnear, tfar, &occluded);
      for (int i = 0; i < 16; ++i) hits += occluded[i];
    }
    rays += r->origin.size();
  }
  state.counters["rays_per_s"] = benchmark::Counter(double(rays), benchmark::Counter::kIsRate);
  state.counters["occluded_fraction"] =
      benchmark::Counter(double(hits) / double(rays), benchmark::Counter::kAvgThreads);
}

// Single-threaded ray calls; run one copy per core to see the machine's rate.
BENCHMARK(BM_OccludedSingle)->ArgName("shuffled")->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_OccludedPacket16)->ArgName("shuffled")->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_OccludedSingle)->ArgName("shuffled")->Arg(0)->Threads(2)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_OccludedPacket16)->ArgName("shuffled")->Arg(0)->Threads(2)->Unit(benchmark::kMillisecond)->UseRealTime();

// BM_ReadPhotograph/threads:N: ReadImageRgb of one 2048^2 float RGB EXR (ZIP, as `reflcap synth`
// writes the million preset's photographs: a shaded disc on black with 1 % noise, ~12 MB) by N
// threads at once, each reading it over and over (from the page cache). Counter: images_per_s over
// all threads. The GPU resample decodes photographs ahead on several threads; this says whether
// decoding scales with them. REFLCAP_BENCH_PHOTOGRAPH=<file> reads that file instead.
const fs::path& PhotographFile() {
  static const fs::path path = [] {
    if (const char* given = std::getenv("REFLCAP_BENCH_PHOTOGRAPH"); given != nullptr && *given) {
      return fs::path(given);
    }
    const fs::path dir =
        fs::temp_directory_path() / ("reflcap_read_bench_" + std::to_string(getpid()));
    fs::create_directories(dir);
    constexpr int kSide = 2048;
    Image image(kSide, kSide, 3, 0.0f);
    std::mt19937 rng(5);
    std::normal_distribution<float> noise(0.0f, 0.01f);
    for (int y = 0; y < kSide; ++y) {
      for (int x = 0; x < kSide; ++x) {
        const float u = (x + 0.5f) / kSide * 2 - 1, v = (y + 0.5f) / kSide * 2 - 1;
        const float r2 = u * u + v * v;
        if (r2 >= 0.64f) continue;  // black background outside the object
        const float shade = std::sqrt(1 - r2 / 0.64f);
        for (int c = 0; c < 3; ++c) {
          image.at(x, y, c) = std::max(0.0f, shade * (0.3f + 0.2f * c) * (1 + noise(rng)));
        }
      }
    }
    const Status written = WriteExr(dir / "photo.exr", image);
    REFLCAP_CHECK(written.ok()) << written.ToString();
    static const fs::path remove_at_exit = dir;
    std::atexit([] { std::error_code ec; fs::remove_all(remove_at_exit, ec); });
    return dir / "photo.exr";
  }();
  return path;
}

void BM_ReadPhotograph(benchmark::State& state) {
  const fs::path& path = PhotographFile();
  for (auto _ : state) {
    StatusOr<Image> image = ReadImageRgb(path);
    if (!image.ok()) {
      state.SkipWithError(image.status().ToString().c_str());
      return;
    }
    benchmark::DoNotOptimize(image->data.data());
  }
  state.counters["images_per_s"] =
      benchmark::Counter(double(state.iterations()), benchmark::Counter::kIsRate);
}
BENCHMARK(BM_ReadPhotograph)
    ->ThreadRange(1, 16)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

}  // namespace
}  // namespace reflcap::resample

BENCHMARK_MAIN();
