#pragma once
// The sweeps of `reflcap bench` (suite.h runs them). Two kinds of data:
//
// * Fit sweeps (fit, speed_vs_error, init_schemes) fit BRDF samples generated directly from
//   ground truth (engine/fit/synthetic_samples.h): the five synth materials that have a lobe,
//   1 % noise, 12 % of the samples (at least 4) near the mirror direction — the data
//   bench/engine/fit_bench.cc uses, so the numbers compare with bench/RESULTS.md. One fit is one
//   colour channel of one texel (Lambert + one anisotropic lobe, 5 parameters). Every backend
//   fits the same texels. Accuracy is measured against the truth: median relative errors of ρ_d,
//   n and the lobe peak, converged fraction, and a holdout PSNR in BRDF space: the fitted BRDF on
//   noise-free held-out directions (a second sample set of the same texels, other directions),
//   each texel's values divided by its brightest held-out truth value, PSNR = -10 log10(MSE).
//
// * Pipeline sweeps (scaling, viewpoints) write synthetic captures (acquire/synth) and run the
//   pipeline's library calls on them, as `reflcap run` does: resample (train split) -> fit (cpu
//   backend) -> render (holdout split) -> validate. Accuracy: fit/params.exr against the
//   capture's gt/params.exr, and the validation's holdout PSNR.
//
// Timing protocol: a fit is run once to verify it (which also warms caches and compiles Vulkan
// pipelines), then repeated until at least `min_seconds` of wall clock (at least once); the
// rate is fits / mean wall time per repetition, and per CPU-second of the whole process
// (lavapipe's threads included) as bench/engine/fit_bench.cc reports it.
#include <cstdint>
#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "bench/suite/records.h"
#include "engine/core/status.h"
#include "engine/fit/fitter.h"

namespace reflcap::benchsuite {

// The fitters of a run, one per backend, created once (Vulkan pipelines compile once).
struct FitterSet {
  std::map<fit::Backend, std::unique_ptr<fit::Fitter>> fitters;
  int threads = 0;
  double peak_gflops = 0;  // the Vulkan device's measured multiply-add peak (0: not measured)
};

struct FitSweepConfig {
  int texels = 4096;
  std::vector<int> samples = {16, 32, 64, 128, 256, 512, 1024};
  int ceres_max_samples = 256;  // Ceres is ~40x slower: only the small sample counts
  double min_seconds = 1.0;     // timed wall clock per point, at least one repetition
};

struct SpeedErrorConfig {
  int texels = 4096;
  int samples = 64;
  // (max_iterations, tolerance) points: the iteration caps at the default tolerance, then the
  // tolerances (step and cost) at the default cap.
  std::vector<std::pair<int, double>> points;
  double min_seconds = 0.5;
};

struct InitConfig {
  int texels = 4096;
  std::vector<int> samples = {64, 256};
  int ceres_max_samples = 64;
  double min_seconds = 0.5;
};

// Called after each point (for progress).
using PointDone = std::function<void()>;

std::vector<FitRecord> RunFitSweep(const FitSweepConfig& config, FitterSet& fitters,
                                   const VerifyBounds& bounds, const PointDone& done);
std::vector<SpeedErrorRecord> RunSpeedErrorSweep(const SpeedErrorConfig& config,
                                                 FitterSet& fitters, const VerifyBounds& bounds,
                                                 const PointDone& done);
std::vector<InitRecord> RunInitSweep(const InitConfig& config, FitterSet& fitters,
                                     const VerifyBounds& bounds, const PointDone& done);

// A synthetic capture's rig and size for the pipeline sweeps.
struct CaptureSpec {
  int64_t texels = 1000;
  int image_size = 64;
  int cameras = 3, lights = 4, steps = 8;
  uint64_t seed = 1;
};

struct ScalingConfig {
  std::vector<CaptureSpec> sizes;
  bool render_and_validate = true;
};

struct ViewpointConfig {
  std::vector<CaptureSpec> rigs;
};

// `work_dir` holds the captures and intermediate folders (each removed after its point).
// A failing stage ends that size's or rig's records with an invalid record naming the error;
// the sweep goes on.
std::vector<ScalingRecord> RunScalingSweep(const ScalingConfig& config,
                                           const std::filesystem::path& work_dir, int threads,
                                           const VerifyBounds& bounds, const PointDone& done);
std::vector<ViewpointRecord> RunViewpointSweep(const ViewpointConfig& config,
                                               const std::filesystem::path& work_dir, int threads,
                                               const VerifyBounds& bounds, const PointDone& done);

// Accuracy of a fit folder against a synthetic capture's ground truth maps: median relative ρ_d
// error over texels that got samples (SAMPLES/coverage.exr > 0; Lambert-only fits of texels with
// too few samples for a lobe included) and channels with truth ρ_d >= 0.02, n error over texels
// whose truth and fit both have a lobe, and that lobe fraction.
struct MapAccuracy {
  double median_rel_error_rho_d = 0;
  double median_rel_error_n = 0;
  double lobe_fraction = 0;
  int64_t texels_compared = 0;
};
StatusOr<MapAccuracy> CompareWithGroundTruth(const std::filesystem::path& gt_params_exr,
                                             const std::filesystem::path& samples_dir,
                                             const std::filesystem::path& fit_dir);

}  // namespace reflcap::benchsuite
