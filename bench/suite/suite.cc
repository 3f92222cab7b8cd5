// `reflcap bench`'s matrix (suite.h): the sizes per scale, the fitters, and the run.
#include "bench/suite/suite.h"

#include <algorithm>
#include <chrono>
#include <ctime>

#ifdef REFLCAP_HAVE_DEVICE_PEAK
#include "bench/gpu/device_peak.h"
#endif
#include "engine/core/log.h"
#include "engine/core/progress.h"
#include "engine/fit/vulkan_fitter.h"

#ifndef REFLCAP_VERSION
#define REFLCAP_VERSION "unknown"
#endif
#ifndef REFLCAP_BUILD_TYPE
#define REFLCAP_BUILD_TYPE "unknown"
#endif

namespace reflcap::benchsuite {
namespace {

// speed_vs_error points: iteration caps at the default tolerance, then tolerances at the
// default cap (fit::FitOptions: 100 steps, 1e-5).
std::vector<std::pair<int, double>> SpeedErrorPoints(const std::vector<int>& caps,
                                                     const std::vector<double>& tolerances) {
  const fit::FitOptions defaults;
  std::vector<std::pair<int, double>> points;
  for (int cap : caps) points.emplace_back(cap, defaults.step_tolerance);
  for (double tol : tolerances) points.emplace_back(defaults.max_iterations, tol);
  return points;
}

// The rig of the scaling sweep: 3 cameras x 4 lights x 8 steps = 96 images, whatever the size,
// so the samples per texel stay alike and only the texel count (and image size, which must
// grow with it for the photographs to resolve the texels) changes.
CaptureSpec ScalingSpec(int64_t texels, int image_size) {
  CaptureSpec s;
  s.texels = texels;
  s.image_size = image_size;
  s.cameras = 3;
  s.lights = 4;
  s.steps = 8;
  return s;
}

CaptureSpec Rig(int64_t texels, int image_size, int cameras, int lights, int steps) {
  CaptureSpec s;
  s.texels = texels;
  s.image_size = image_size;
  s.cameras = cameras;
  s.lights = lights;
  s.steps = steps;
  return s;
}

std::string UtcNow() {
  const std::time_t now = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&now, &tm);
  char buf[32];
  std::strftime(buf, sizeof(buf), "%Y-%m-%dT%H:%M:%SZ", &tm);
  return buf;
}

// Points of the fit sweeps of `backends`, and of the pipeline sweeps when `pipeline`, for the
// progress total.
int64_t CountPoints(const SuiteConfig& c, const SuiteOptions& o,
                    const std::vector<fit::Backend>& backends, bool pipeline) {
  auto has = [&](const char* sweep) {
    return std::find(o.sweeps.begin(), o.sweeps.end(), sweep) != o.sweeps.end();
  };
  int64_t n = 0;
  for (fit::Backend backend : backends) {
    const bool ceres = backend == fit::Backend::kCeres;
    if (has("fit")) {
      for (int s : c.fit.samples) n += !ceres || s <= c.fit.ceres_max_samples;
    }
    if (has("speed_vs_error")) n += int64_t(c.speed_vs_error.points.size());
    if (has("init_schemes")) {
      for (int s : c.init.samples) n += 2 * (!ceres || s <= c.init.ceres_max_samples);
    }
  }
  if (pipeline && has("scaling")) n += int64_t(c.scaling.sizes.size());
  if (pipeline && has("viewpoints")) n += int64_t(c.viewpoints.rigs.size());
  return n;
}

}  // namespace

const char* SuiteScaleName(SuiteScale scale) {
  switch (scale) {
    case SuiteScale::kTiny: return "tiny";
    case SuiteScale::kQuick: return "quick";
    case SuiteScale::kFull: return "full";
  }
  return "?";
}

Status SuiteOptions::Validate() const {
  if (backends.empty()) return InvalidArgumentError("backends: at least one is needed");
  if (sweeps.empty()) return InvalidArgumentError("sweeps: at least one is needed");
  for (const std::string& s : sweeps) {
    if (std::find(AllSweeps().begin(), AllSweeps().end(), s) == AllSweeps().end()) {
      return InvalidArgumentError("sweeps: unknown sweep \"", s,
                                  "\" (fit, speed_vs_error, init_schemes, scaling, viewpoints)");
    }
  }
  if (work_dir.empty()) return InvalidArgumentError("work_dir: must be given");
  if (threads < 0) return InvalidArgumentError("threads: must be >= 0 (got ", threads, ")");
  return OkStatus();
}

SuiteConfig ConfigForScale(SuiteScale scale) {
  SuiteConfig c;
  switch (scale) {
    case SuiteScale::kTiny:
      c.fit = {48, {16, 64}, 16, 0.0};
      c.speed_vs_error = {48, 32, SpeedErrorPoints({2, 100}, {1e-2}), 0.0};
      c.init = {48, {32}, 32, 0.0};
      c.scaling.sizes = {Rig(1000, 48, 2, 3, 4)};
      c.viewpoints.rigs = {Rig(1000, 48, 1, 3, 4), Rig(1000, 48, 2, 3, 4)};
      break;
    case SuiteScale::kQuick:
      c.fit = {1024, {16, 32, 64, 128, 256, 512, 1024}, 64, 0.2};
      c.speed_vs_error = {1024, 64, SpeedErrorPoints({1, 2, 3, 5, 10, 20, 100}, {1e-2, 1e-3, 1e-4, 1e-7}), 0.1};
      c.init = {1024, {64, 256}, 64, 0.1};
      c.scaling.sizes = {ScalingSpec(1000, 64), ScalingSpec(10000, 128)};
      c.viewpoints.rigs = {Rig(4000, 96, 3, 4, 4), Rig(4000, 96, 3, 4, 8), Rig(4000, 96, 3, 4, 16)};
      break;
    case SuiteScale::kFull:
      c.fit = {4096, {16, 32, 64, 128, 256, 512, 1024}, 256, 1.0};
      c.speed_vs_error = {4096, 64, SpeedErrorPoints({1, 2, 3, 5, 10, 20, 50, 100}, {1e-1, 1e-2, 1e-3, 1e-4, 1e-6, 1e-8}), 0.5};
      c.init = {4096, {64, 256}, 64, 0.5};
      c.scaling.sizes = {ScalingSpec(1000, 64), ScalingSpec(10000, 128), ScalingSpec(100000, 256),
                         ScalingSpec(1000000, 512)};
      // The small preset's rig (3 cameras x 8 lights x 12 steps), fewer and more turntable
      // steps, then fewer and more cameras.
      c.viewpoints.rigs = {Rig(20000, 192, 3, 8, 4),  Rig(20000, 192, 3, 8, 8),
                           Rig(20000, 192, 3, 8, 12), Rig(20000, 192, 3, 8, 24),
                           Rig(20000, 192, 1, 8, 12), Rig(20000, 192, 2, 8, 12),
                           Rig(20000, 192, 4, 8, 12)};
      break;
  }
  return c;
}

StatusOr<SuiteResults> RunSuite(const SuiteOptions& options) {
  REFLCAP_RETURN_IF_ERROR(options.Validate());
  const auto start = std::chrono::steady_clock::now();
  SuiteResults results;
  results.date = UtcNow();
  results.machine = DescribeMachine();
  results.reflcap_version = StrCat(REFLCAP_VERSION, " (", REFLCAP_BUILD_TYPE, " build of ",
                                   __DATE__, " ", __TIME__, ", GCC/Clang ", __VERSION__, ")");
  results.scale = SuiteScaleName(options.scale);
  results.rss_method = PeakRssScope().method();
  REFLCAP_LOG(kInfo) << "bench: machine: " << results.machine.ToString();

  const SuiteConfig config = ConfigForScale(options.scale);
  auto has = [&](const char* sweep) {
    return std::find(options.sweeps.begin(), options.sweeps.end(), sweep) != options.sweeps.end();
  };
  Progress progress(StrCat("bench (", results.scale, ")"),
                    CountPoints(config, options, options.backends, /*pipeline=*/true));
  const PointDone done = [&progress] { progress.Advance(); };

  // The pipeline sweeps run first, before any Vulkan driver is loaded, so the per-stage peak
  // memory holds the stage and the process's small base, not a driver's.
  if (has("scaling")) {
    results.scaling = RunScalingSweep(config.scaling, options.work_dir, options.threads,
                                      options.bounds, done);
  }
  if (has("viewpoints")) {
    results.viewpoints = RunViewpointSweep(config.viewpoints, options.work_dir, options.threads,
                                           options.bounds, done);
  }

  FitterSet fitters;
  fitters.threads = options.threads;
  const bool want_vulkan = std::find(options.backends.begin(), options.backends.end(),
                                     fit::Backend::kVulkan) != options.backends.end();
  results.device = "not measured (--backends leaves vulkan out)";
  for (fit::Backend backend : options.backends) {
    if (fitters.fitters.count(backend)) continue;
    StatusOr<std::unique_ptr<fit::Fitter>> fitter = UnavailableError("not created");
    if (backend == fit::Backend::kVulkan) {
      fit::VulkanFitterOptions vo;
      vo.device = options.vulkan_device;
      vo.threads = options.threads;
      auto vk = fit::CreateVulkanFitter(vo);
      if (vk.ok()) {
        results.device = (*vk)->device();
        if ((*vk)->software_device()) {
          results.device += " (a CPU implementation: its timings are CPU timings)";
        }
        results.device_available = true;
#ifdef REFLCAP_HAVE_DEVICE_PEAK
        // The device's peaks, so that its fits/s can be read as a fraction of what it can do.
        StatusOr<bench::DevicePeak> peak = bench::MeasureDevicePeak(options.vulkan_device);
        if (peak.ok()) {
          results.device_mad_gflops = peak->mad_gflops;
          results.device_copy_gbps = peak->copy_gbps;
          fitters.peak_gflops = peak->mad_gflops;
        } else {
          REFLCAP_LOG(kWarning) << "bench: device peaks not measured: " << peak.status().ToString();
        }
#endif
        fitter = std::unique_ptr<fit::Fitter>(std::move(vk).value());
      } else {
        fitter = vk.status();
      }
    } else {
      fitter = fit::CreateFitter(backend, options.threads);
    }
    if (fitter.ok()) {
      fitters.fitters[backend] = std::move(fitter).value();
    } else {
      const std::string reason = fitter.status().ToString();
      results.omitted.push_back({fit::BackendName(backend), reason});
      if (backend == fit::Backend::kVulkan) results.device = "unavailable: " + reason;
      REFLCAP_LOG(kWarning) << "bench: backend " << fit::BackendName(backend)
                            << " left out: " << reason;
      // Its points will not run.
      progress.Advance(CountPoints(config, options, {backend}, /*pipeline=*/false));
    }
  }
  if (want_vulkan) REFLCAP_LOG(kInfo) << "bench: Vulkan device: " << results.device;
  if (!fitters.fitters.empty()) {
    if (has("fit")) results.fit = RunFitSweep(config.fit, fitters, options.bounds, done);
    if (has("speed_vs_error")) {
      results.speed_vs_error =
          RunSpeedErrorSweep(config.speed_vs_error, fitters, options.bounds, done);
    }
    if (has("init_schemes")) {
      results.init_schemes = RunInitSweep(config.init, fitters, options.bounds, done);
    }
  }
  progress.Finish();
  results.total_seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return results;
}

}  // namespace reflcap::benchsuite
