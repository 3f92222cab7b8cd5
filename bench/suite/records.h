#pragma once
// The records of `reflcap bench`: one struct per sweep, the verification bounds every record is
// checked against before its timing counts, and the whole run's results. bench/README.md
// documents every field as it appears in bench_results.json and the CSV files.
#include <cstdint>
#include <string>
#include <vector>

#include "bench/suite/machine.h"

namespace reflcap::benchsuite {

// What a record must meet to be valid (its timing to count). A record that misses a bound keeps
// its numbers but gets valid = false and an invalid_reason naming the bound.
struct VerifyBounds {
  // fit sweep (converged runs, seed start): the fits are right, not just fast. Loose enough for
  // 16 samples per texel at 1 % noise (median errors there are ~1 %).
  double min_converged_fraction = 0.9;
  double max_median_rel_error = 0.1;
  // speed_vs_error and init_schemes measure what capped or fixed-start solves give, so their
  // convergence is a result, not a bar: they are checked for sanity only — every parameter
  // finite and the median ρ_d error (which both starts estimate well before any LM step) at
  // most this.
  double max_sanity_rel_error_rho_d = 0.5;
  // Pipeline sweeps (scaling, viewpoints): some texels got samples, the fit's median ρ_d error
  // against the ground-truth maps and the holdout PSNR are sane.
  double min_texels_with_samples_fraction = 0.2;
  double max_pipeline_rel_error_rho_d = 0.5;
  double min_holdout_psnr_db = 15.0;
};

// Accuracy of a set of fits against ground truth (shared by several records).
struct Accuracy {
  double median_rel_error_rho_d = 0;  // median over texels x channels of |fit / truth - 1|
  double median_rel_error_n = 0;      // the same for the lobe exponent n
  double median_rel_error_peak = 0;   // the same for the lobe's value at normal incidence
  double converged_fraction = 0;      // texels with status converged / texels
  double mean_iterations = 0;         // LM steps per texel (max over its channels), mean
  double holdout_psnr_db = 0;         // on held-out directions, see fit_sweeps.h
  bool all_finite = true;
};

struct FitRecord {  // bench_results.json "fit"
  std::string backend;
  int samples_per_texel = 0;
  int texels = 0;
  int64_t fits = 0;  // channel fits per repetition (3 per texel)
  int repetitions = 0;
  double seconds = 0;  // wall clock per repetition
  double fits_per_second = 0;
  double fits_per_cpu_second = 0;
  // Vulkan only (0 elsewhere): the device's LM work per second of wall time, in GFLOP/s
  // (residual evaluations x bench/gpu/device_peak.h FitFlopsPerResidualEvaluation), and as a
  // fraction of the device's measured multiply-add peak (SuiteResults::device_mad_gflops).
  double gflops = 0;
  double peak_fraction = 0;
  Accuracy accuracy;
  bool valid = false;
  std::string invalid_reason;
};

struct SpeedErrorRecord {  // "speed_vs_error"
  std::string backend;
  int max_iterations = 0;
  double tolerance = 0;  // step and cost tolerance
  int samples_per_texel = 0;
  int texels = 0;
  double seconds = 0;
  double fits_per_second = 0;
  double fits_per_cpu_second = 0;
  Accuracy accuracy;
  bool pareto = false;  // on its backend's front: no valid record is faster and more accurate
  bool valid = false;
  std::string invalid_reason;
};

struct InitRecord {  // "init_schemes"
  std::string backend;
  std::string init;  // seed | fixed
  int samples_per_texel = 0;
  int texels = 0;
  double seconds = 0;
  double fits_per_second = 0;
  double fits_per_cpu_second = 0;
  Accuracy accuracy;
  bool valid = false;
  std::string invalid_reason;
};

struct ScalingRecord {  // "scaling": one per (size, stage)
  int64_t texels_target = 0;
  int64_t texels = 0;  // atlas texels of the capture
  int image_size = 0;
  int images = 0;
  std::string stage;  // synth, resample, fit, render, validate
  double seconds = 0;
  double texels_per_second = 0;
  uint64_t peak_rss_bytes = 0;
  uint64_t start_rss_bytes = 0;  // resident memory when the stage began
  std::string detail;            // stage-specific numbers (samples kept, PSNR, ...)
  bool valid = false;
  std::string invalid_reason;
};

struct ViewpointRecord {  // "viewpoints"
  int cameras = 0;
  int steps = 0;
  int lights = 0;
  int viewpoints = 0;  // cameras x steps
  int train_images = 0;
  int holdout_images = 0;
  int64_t texels = 0;
  double texels_with_samples_fraction = 0;
  double holdout_psnr_db = 0;
  double noise_bound_psnr_db = 0;  // 0 when unknown
  double median_rel_error_rho_d = 0;
  double median_rel_error_n = 0;
  double lobe_fraction = 0;  // texels with a lobe in truth that got one
  double seconds = 0;        // synth + resample + fit + render + validate
  bool valid = false;
  std::string invalid_reason;
};

struct OmittedBackend {
  std::string backend, reason;
};

struct SuiteResults {
  MachineInfo machine;
  std::string device;  // Vulkan device, driver and API version, or "unavailable: <why>"
  bool device_available = false;
  // The device's measured peaks (bench/gpu/device_peak.h; 0 when not measured).
  double device_mad_gflops = 0;
  double device_copy_gbps = 0;
  std::string date;    // ISO 8601 UTC, when the run started
  std::string reflcap_version;
  std::string scale;   // tiny | quick | full
  double total_seconds = 0;
  std::string rss_method;
  std::vector<FitRecord> fit;
  std::vector<SpeedErrorRecord> speed_vs_error;
  std::vector<ScalingRecord> scaling;
  std::vector<InitRecord> init_schemes;
  std::vector<ViewpointRecord> viewpoints;
  std::vector<OmittedBackend> omitted;
  std::vector<std::string> notes;
};

// Marks `records` on their backend's Pareto front of (fits_per_second higher, error lower),
// error = max(median_rel_error_rho_d, median_rel_error_n); invalid records are never on it.
void MarkParetoFront(std::vector<SpeedErrorRecord>* records);

}  // namespace reflcap::benchsuite
