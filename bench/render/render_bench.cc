// reflcap_render_bench: images per second of the CPU reference renderer and of the Vulkan
// renderer re-rendering a synthetic capture, as `reflcap render` does (one image with its mask
// and aux buffers per call, read back to host memory; files are not written).
//
//   BM_Render/<backend>/<size>[/distorted]   backend cpu or vulkan; size = image width = height;
//                                            "distorted": the capture's camera gets real lens
//                                            distortion (the Vulkan renderer's resolve path).
//   BM_RenderBatch/vulkan/<size>[/distorted]/<n>
//                                            n images per call through VulkanRenderer::
//                                            RenderImages (the capture's images, cycled):
//                                            several images per submission, submissions in
//                                            flight, parallel read-back — what `reflcap render
//                                            --backend vulkan` does. Every image still draws its
//                                            own shadow map (kept maps off), as BM_Render's do.
//
// Each capture is synthesised at start-up (noise-free; 1 camera x 2 lights x 2 turntable steps;
// 20,000 texels at 192 px, scaled with the image area up to 1,000,000) and every image of it is
// rendered by both backends and compared before anything is timed: the Vulkan render must meet
// the criterion (PSNR >= 50 dB excluding 2 px around shadow edges and silhouettes,
// render/vulkan/render_agreement.h), else that capture's benchmarks fail with the numbers.
//
// Timing: host wall clock per image (Google Benchmark's real time): CPU rendering on all cores;
// Vulkan = record + submit + fence wait + read-back; the gpu_s counter is the submit + fence part.
// BM_RenderBatch first checks that its results are bit-identical to BM_Render's verified
// per-image Vulkan renders, then times calls of n images (real time per call; images_per_s).
// On lavapipe the Vulkan "GPU" is this machine's CPU (LLVM-compiled shaders on all cores), shared
// with everything else running: its numbers are CPU numbers. See bench/render/README.md.
#include <benchmark/benchmark.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <map>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "acquire/synth/synth.h"
#include "engine/capture/capture.h"
#include "engine/core/log.h"
#include "engine/core/parallel.h"
#include "engine/core/status.h"
#include "render/reference/render_capture.h"
#include "render/vulkan/render_agreement.h"
#include "render/vulkan/vulkan_render_capture.h"
#include "render/vulkan/vulkan_renderer.h"

namespace reflcap::render {
namespace {
namespace fs = std::filesystem;

// Texels of the synthetic capture at 192 px (the "small" preset), scaled with the image area.
constexpr double kTexelsAt192 = 20000;
constexpr double kMaxTexels = 1e6;
// Lens distortion of the "distorted" variants: barrel with decentring, as a short lens has.
constexpr std::array<double, 5> kDistortion = {-0.18, 0.09, 0.0012, -0.0008, -0.015};

// BM_RenderBatch's diagnostic variants (REFLCAP_BENCH_RENDER_VARIANTS=1: Variants() below).
enum class Variant {
  kAsVerified,
  kNoAux,
  kNoEdges,
  kKept,
  kShared,
  kResolve,
  kRasterised,
  kProfiled,
  kProfiledRasterised
};

// The renderer options of `variant` (those that differ from the batch renderer's).
VulkanRenderOptions VariantOptions(VulkanRenderOptions o, Variant variant) {
  switch (variant) {
    case Variant::kNoEdges:
      o.exact_shadow_edges = false;
      break;
    case Variant::kKept:
      o.shadow_cache_mib = VulkanRenderOptions().shadow_cache_mib;
      break;
    case Variant::kShared:
      o.per_image_targets = false;
      break;
    case Variant::kResolve:
      o.camera_shading = CameraShading::kResolve;
      break;
    case Variant::kProfiledRasterised:
      o.profile_device = true;
      [[fallthrough]];
    case Variant::kRasterised:
      o.shadow_raster = ShadowRaster::kGraphics;
      o.camera_shading = CameraShading::kFragment;
      break;
    case Variant::kProfiled:
      o.profile_device = true;
      break;
    case Variant::kAsVerified:
    case Variant::kNoAux:
      break;
  }
  return o;
}

struct Case {
  int size = 0;
  bool distorted = false;
  Capture capture;
  std::unique_ptr<FittedCapture> fitted;
  std::unique_ptr<VulkanRenderer> renderer;        // RenderImage, kept shadow maps off
  std::unique_ptr<VulkanRenderer> batch_renderer;  // RenderImages, kept shadow maps off
  // The renderers of the diagnostic variants of BM_RenderBatch that need their own options
  // (REFLCAP_BENCH_RENDER_VARIANTS=1; VariantOptions).
  std::map<Variant, std::unique_ptr<VulkanRenderer>> variant_renderers;
  std::vector<RenderResult> vulkan_renders;        // per image, verified against the CPU
  RenderAgreement agreement;  // pooled over the capture's images
  double worst_psnr_db = 0;
};

std::vector<std::unique_ptr<Case>> g_cases;

RenderOptions Options() {
  RenderOptions o;
  o.aux_buffers = true;  // as `reflcap render` renders
  return o;
}

// REFLCAP_BENCH_RENDER_VARIANTS=1 adds BM_RenderBatch variants that take one cost away at a time
// (for finding what limits the batched renderer on a device; their outputs differ from the
// verified renders by design, so those are timed unverified): .../noaux (no aux buffers: half
// the read-back), .../noedges (no shadow-edge pixels shaded on the host), .../kept (kept shadow
// maps: the 4 cycled images draw theirs once), .../shared (VulkanRenderOptions::
// per_image_targets off), .../resolve (CameraShading::kResolve), .../rasterised (shadow maps by
// the depth pass: ShadowRaster::kGraphics), .../profiled and .../profiled_rasterised (device
// timestamps around each image's phases: counters dev_*; the timestamps may serialise what they
// measure). .../shared and .../profiled render the verified bits (checked).
bool Variants() {
  const char* env = std::getenv("REFLCAP_BENCH_RENDER_VARIANTS");
  return env != nullptr && std::atoi(env) != 0;
}


StatusOr<std::unique_ptr<Case>> Prepare(int size, bool distorted, const fs::path& root,
                                        const std::string& device) {
  auto c = std::make_unique<Case>();
  c->size = size;
  c->distorted = distorted;
  const fs::path dir = root / ("capture_" + std::to_string(size));
  if (!fs::exists(dir / "capture.json")) {
    synth::SynthOptions o;
    o.noise = 0;
    o.image_size = size;
    o.texels = int64_t(std::min(kMaxTexels, kTexelsAt192 * (size / 192.0) * (size / 192.0)));
    o.cameras = 1;
    o.lights = 2;
    o.steps = 2;
    REFLCAP_RETURN_IF_ERROR(synth::WriteSyntheticCapture(o, dir).status());
  }
  REFLCAP_ASSIGN_OR_RETURN(c->capture, ReadCapture(dir / "capture.json"));
  if (distorted) {
    for (Camera& cam : c->capture.cameras) cam.dist = kDistortion;
  }
  REFLCAP_ASSIGN_OR_RETURN(c->fitted, LoadFittedCapture(c->capture, dir / "gt/params.exr"));
  // Every image draws its own shadow map (kept maps off): the bench cycles through 4 images,
  // whose maps a renderer would otherwise keep, which no capture of many lights and poses does.
  VulkanRenderOptions single_options;
  single_options.shadow_cache_mib = 0;
  REFLCAP_ASSIGN_OR_RETURN(c->renderer, VulkanRenderer::Create(device, single_options));
  REFLCAP_RETURN_IF_ERROR(SetFittedScene(*c->renderer, *c->fitted));
  // Verify before timing.
  c->worst_psnr_db = 1e9;
  for (size_t i = 0; i < c->capture.images.size(); ++i) {
    REFLCAP_ASSIGN_OR_RETURN(RenderResult cpu, RenderCaptureImage(*c->fitted, i, Options()));
    REFLCAP_ASSIGN_OR_RETURN(RenderResult gpu,
                             RenderCaptureImageVulkan(*c->renderer, *c->fitted, i, Options()));
    const RenderAgreement a = CompareRenders(cpu, gpu);
    c->worst_psnr_db = std::min(c->worst_psnr_db, a.psnr_db);
    c->agreement.Add(a);
    c->vulkan_renders.push_back(std::move(gpu));
  }
  // The batch renderer's automatic choices, or REFLCAP_BENCH_RENDER_BATCH_IMAGES /
  // REFLCAP_BENCH_RENDER_IN_FLIGHT (for tuning on a device).
  VulkanRenderOptions batch_options = single_options;
  if (const char* env = std::getenv("REFLCAP_BENCH_RENDER_BATCH_IMAGES")) {
    batch_options.batch_images = std::atoi(env);
  }
  if (const char* env = std::getenv("REFLCAP_BENCH_RENDER_IN_FLIGHT")) {
    batch_options.batches_in_flight = std::atoi(env);
  }
  REFLCAP_ASSIGN_OR_RETURN(c->batch_renderer, VulkanRenderer::Create(device, batch_options));
  REFLCAP_RETURN_IF_ERROR(SetFittedScene(*c->batch_renderer, *c->fitted));
  if (Variants()) {
    for (Variant v : {Variant::kNoEdges, Variant::kKept, Variant::kShared, Variant::kResolve,
                      Variant::kRasterised, Variant::kProfiled, Variant::kProfiledRasterised}) {
      REFLCAP_ASSIGN_OR_RETURN(std::unique_ptr<VulkanRenderer> r,
                               VulkanRenderer::Create(device, VariantOptions(batch_options, v)));
      REFLCAP_RETURN_IF_ERROR(SetFittedScene(*r, *c->fitted));
      c->variant_renderers[v] = std::move(r);
    }
  }
  return c;
}

// Images 0, 1, ... n-1 of the capture, cycled.
std::vector<size_t> Cycled(const Case& c, size_t n) {
  std::vector<size_t> indices(n);
  for (size_t i = 0; i < n; ++i) indices[i] = i % c.capture.images.size();
  return indices;
}

bool SameBits(const Image& a, const Image& b) {
  return a.width == b.width && a.height == b.height && a.channels == b.channels &&
         std::memcmp(a.data.data(), b.data.data(), a.data.size() * sizeof(float)) == 0;
}

void BM_RenderBatch(benchmark::State& state, Case* c, size_t n, Variant variant) {
  if (c->worst_psnr_db < kMinAgreementPsnrDb) {
    state.SkipWithError(StrCat("Vulkan render disagrees with the CPU reference: worst image ",
                               c->worst_psnr_db, " dB; ", c->agreement.ToString())
                            .c_str());
    return;
  }
  const std::vector<size_t> indices = Cycled(*c, n);
  const auto own = c->variant_renderers.find(variant);
  VulkanRenderer& renderer =
      own != c->variant_renderers.end() ? *own->second : *c->batch_renderer;
  RenderOptions options = Options();
  if (variant == Variant::kNoAux) options.aux_buffers = false;
  // Verify: the batched renders are the verified per-image renders, bit for bit.
  size_t mismatches = 0;
  // The variants that change only how the device is driven render the same bits.
  const bool verified = variant == Variant::kAsVerified || variant == Variant::kShared ||
                        variant == Variant::kProfiled;
  Status s = !verified ? OkStatus() : RenderCaptureImagesVulkan(
      renderer, *c->fitted, indices, options, [&](size_t k, RenderResult&& r) {
        const RenderResult& expected = c->vulkan_renders[indices[k]];
        if (!SameBits(r.pixels, expected.pixels) || !SameBits(r.mask, expected.mask) ||
            !SameBits(r.aux, expected.aux)) {
          ++mismatches;
        }
        return OkStatus();
      });
  if (!s.ok() || mismatches > 0) {
    state.SkipWithError(s.ok() ? StrCat(mismatches, " of ", n,
                                        " batched renders differ from the per-image renders")
                                     .c_str()
                               : s.ToString().c_str());
    return;
  }
  double gpu_s = 0, wait_s = 0, readback_s = 0, edge_s = 0, record_s = 0;
  double device_s = 0, device_shadow_s = 0, device_pass_s = 0, device_outputs_s = 0;
  bool device_timed = false;
  size_t submissions = 0;
  for (auto _ : state) {
    s = RenderCaptureImagesVulkan(renderer, *c->fitted, indices, options,
                                  [](size_t, RenderResult&& r) {
                                    benchmark::DoNotOptimize(r.pixels.data.data());
                                    return OkStatus();
                                  });
    if (!s.ok()) {
      state.SkipWithError(s.ToString().c_str());
      return;
    }
    const VulkanBatchStats& b = renderer.last_batch_stats();
    gpu_s += renderer.last_stats().gpu_seconds;
    wait_s += b.wait_s;
    readback_s += b.readback_s;
    edge_s += b.shadow_edge_s;
    record_s += b.record_s;
    device_timed = b.device_timed;
    device_s += b.device_s;
    device_shadow_s += b.device_shadow_s;
    device_pass_s += b.device_pass_s;
    device_outputs_s += b.device_outputs_s;
    submissions += b.submissions;
  }
  const double images = double(state.iterations()) * double(n);
  state.SetItemsProcessed(int64_t(images));
  state.counters["images_per_s"] = benchmark::Counter(images, benchmark::Counter::kIsRate);
  state.counters["images_per_submission"] = images / double(std::max<size_t>(1, submissions));
  // Submit to fence signalled, per image (submissions overlap: an upper bound of device time).
  state.counters["gpu_s"] = gpu_s / std::max(1.0, images);
  state.counters["wait_s"] = wait_s / std::max(1.0, images);          // host blocked on fences
  state.counters["readback_s"] = readback_s / std::max(1.0, images);  // host copies, parallel
  state.counters["edge_s"] = edge_s / std::max(1.0, images);  // host rays (part of readback_s)
  state.counters["record_s"] = record_s / std::max(1.0, images);
  if (device_timed) {  // timestamps (profiled variants): device time per image and its phases
    state.counters["dev_s"] = device_s / std::max(1.0, images);
    state.counters["dev_shadow_s"] = device_shadow_s / std::max(1.0, images);
    state.counters["dev_pass_s"] = device_pass_s / std::max(1.0, images);
    state.counters["dev_outputs_s"] = device_outputs_s / std::max(1.0, images);
  }
  state.counters["psnr_worst_db"] = c->worst_psnr_db;
  state.counters["in_flight"] = renderer.options().batches_in_flight;
  state.SetLabel(renderer.device().name + "; " + renderer.last_stats().shadow_map +
                 " shadow map " + std::to_string(renderer.last_stats().shadow_resolution) +
                 " px" + (verified ? "" : "; unverified variant"));
}

size_t BatchImages() {
  if (const char* env = std::getenv("REFLCAP_BENCH_RENDER_BATCH")) {
    const int n = std::atoi(env);
    if (n > 0) return size_t(n);
  }
  return 64;
}

void BM_Render(benchmark::State& state, Case* c, bool vulkan) {
  if (c->worst_psnr_db < kMinAgreementPsnrDb) {
    state.SkipWithError(StrCat("Vulkan render disagrees with the CPU reference: worst image ",
                               c->worst_psnr_db, " dB; ", c->agreement.ToString())
                            .c_str());
    return;
  }
  const size_t n = c->capture.images.size();
  size_t i = 0;
  double gpu_s = 0;
  for (auto _ : state) {
    StatusOr<RenderResult> r =
        vulkan ? RenderCaptureImageVulkan(*c->renderer, *c->fitted, i % n, Options())
               : RenderCaptureImage(*c->fitted, i % n, Options());
    if (!r.ok()) {
      state.SkipWithError(r.status().ToString().c_str());
      return;
    }
    benchmark::DoNotOptimize(r->pixels.data.data());
    if (vulkan) gpu_s += c->renderer->last_stats().gpu_seconds;
    ++i;
  }
  state.SetItemsProcessed(int64_t(state.iterations()));
  state.counters["images_per_s"] =
      benchmark::Counter(double(state.iterations()), benchmark::Counter::kIsRate);
  state.counters["texels"] = double(c->fitted->atlas.TexelCount());
  state.counters["psnr_worst_db"] = c->worst_psnr_db;
  state.counters["excluded_pct"] = 100 * c->agreement.ExcludedFraction();
  if (vulkan) {
    state.counters["gpu_s"] = gpu_s / double(std::max<int64_t>(1, state.iterations()));
    state.SetLabel(c->renderer->last_stats().shadow_map + " shadow map " +
                   std::to_string(c->renderer->last_stats().shadow_resolution) + " px");
  }
}

std::vector<int> Sizes() {
  std::vector<int> sizes = {192, 512};
  if (const char* env = std::getenv("REFLCAP_BENCH_RENDER_SIZES")) {
    sizes.clear();
    std::stringstream in(env);
    std::string item;
    while (std::getline(in, item, ',')) {
      if (!item.empty()) sizes.push_back(std::atoi(item.c_str()));
    }
  }
  return sizes;
}

}  // namespace
}  // namespace reflcap::render

int main(int argc, char** argv) {
  using namespace reflcap;
  using namespace reflcap::render;
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  SetLogThreshold(LogLevel::kWarning);
  const char* device_env = std::getenv("REFLCAP_BENCH_VK_DEVICE");
  const std::string device = device_env ? device_env : "";
  const fs::path root = fs::temp_directory_path() / "reflcap_render_bench";
  std::error_code ec;
  fs::create_directories(root, ec);
  for (int size : Sizes()) {
    for (bool distorted : {false, true}) {
      auto c = Prepare(size, distorted, root, device);
      if (!c.ok()) {
        std::fprintf(stderr, "reflcap_render_bench: %d px: %s\n", size,
                     c.status().ToString().c_str());
        return ExitCodeFor(c.status());
      }
      std::printf("%d px%s: %zu texels, %zu images; Vulkan vs CPU: worst image %.1f dB, %s\n", size,
                  distorted ? " (distorted)" : "", (*c)->fitted->atlas.TexelCount(),
                  (*c)->capture.images.size(), (*c)->worst_psnr_db,
                  (*c)->agreement.ToString().c_str());
      g_cases.push_back(std::move(c).value());
    }
  }
  const gpu::DeviceInfo& d = g_cases.front()->renderer->device();
  std::printf("device: %s%s\ntiming: host wall clock per image (with read-back); "
              "BM_RenderBatch: per call of n images\n",
              d.ToString().c_str(), d.IsSoftware() ? " (a CPU device: these are CPU numbers)" : "");
  benchmark::AddCustomContext("device", d.ToString());
  benchmark::AddCustomContext("host_threads", std::to_string(HardwareThreads()));
  for (const auto& c : g_cases) {
    const std::string suffix = std::to_string(c->size) + (c->distorted ? "/distorted" : "");
    benchmark::RegisterBenchmark(("BM_Render/cpu/" + suffix).c_str(), BM_Render, c.get(), false)
        ->Unit(benchmark::kMillisecond)
        ->UseRealTime();
    benchmark::RegisterBenchmark(("BM_Render/vulkan/" + suffix).c_str(), BM_Render, c.get(), true)
        ->Unit(benchmark::kMillisecond)
        ->UseRealTime();
    const size_t n = BatchImages();
    const std::string batch = "BM_RenderBatch/vulkan/" + suffix + "/" + std::to_string(n);
    benchmark::RegisterBenchmark(batch.c_str(), BM_RenderBatch, c.get(), n, Variant::kAsVerified)
        ->Unit(benchmark::kMillisecond)
        ->UseRealTime();
    if (Variants()) {
      for (auto [name, v] : {std::pair{"/noaux", Variant::kNoAux},
                             std::pair{"/noedges", Variant::kNoEdges},
                             std::pair{"/kept", Variant::kKept},
                             std::pair{"/shared", Variant::kShared},
                             std::pair{"/resolve", Variant::kResolve},
                             std::pair{"/rasterised", Variant::kRasterised},
                             std::pair{"/profiled", Variant::kProfiled},
                             std::pair{"/profiled_rasterised", Variant::kProfiledRasterised}}) {
        benchmark::RegisterBenchmark((batch + name).c_str(), BM_RenderBatch, c.get(), n, v)
            ->Unit(benchmark::kMillisecond)
            ->UseRealTime();
      }
    }
  }
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  g_cases.clear();
  return 0;
}
