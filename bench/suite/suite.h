#pragma once
// `reflcap bench` as a library: the whole benchmark matrix on synthetic data it generates
// itself — fits/s against samples per texel per backend, speed against error, time and peak
// memory per pipeline stage against texel count, the seed's two-stage start against the fixed
// start, holdout accuracy against viewpoints — and its outputs: bench_results.json, one CSV per
// sweep, SVG plots and index.html (bench/README.md documents every field).
//
// Every record is verified against ground truth before its timing counts (records.h,
// VerifyBounds); a record that fails keeps its numbers with valid = false and the reason. A
// backend that cannot be created (no Vulkan driver, a build without Vulkan, a --device that
// matches nothing) is left out of every sweep with its reason, and the run still succeeds.
#include <filesystem>
#include <string>
#include <vector>

#include "bench/suite/records.h"
#include "bench/suite/sweeps.h"
#include "engine/core/status.h"
#include "engine/fit/fitter.h"

namespace reflcap::benchsuite {

// How big the matrix is.
enum class SuiteScale {
  kTiny,   // a few seconds: for tests only, numbers meaningless
  kQuick,  // about 1-2 minutes on two cores: small sizes, short timings
  kFull,   // up to ~20 minutes on two cores: 10^6 texels in the scaling sweep
};
const char* SuiteScaleName(SuiteScale scale);

// The sweeps by name (the pipeline sweeps run first: see RunSuite).
inline const std::vector<std::string>& AllSweeps() {
  static const std::vector<std::string> kSweeps = {"fit", "speed_vs_error", "init_schemes",
                                                   "scaling", "viewpoints"};
  return kSweeps;
}

struct SuiteOptions {
  SuiteScale scale = SuiteScale::kFull;
  // Backends to measure (cpu, vulkan, ceres). Unavailable ones are omitted with a reason.
  std::vector<fit::Backend> backends = {fit::Backend::kCpu, fit::Backend::kVulkan,
                                        fit::Backend::kCeres};
  std::string vulkan_device;  // "" = automatic, else an index or a name substring
  std::vector<std::string> sweeps = AllSweeps();  // a subset of AllSweeps()
  // Scratch space for captures and sample stores (must exist; emptied of what the run made).
  std::filesystem::path work_dir;
  int threads = 0;  // worker threads, 0 = all
  VerifyBounds bounds;

  Status Validate() const;  // InvalidArgument naming the field
};

// The sweeps' sizes for a scale (exposed so tests and the README can show them).
struct SuiteConfig {
  FitSweepConfig fit;
  SpeedErrorConfig speed_vs_error;
  InitConfig init;
  ScalingConfig scaling;
  ViewpointConfig viewpoints;
};
SuiteConfig ConfigForScale(SuiteScale scale);

// Runs the matrix (progress on stderr). Fails only for invalid options; everything a sweep can
// get wrong is recorded in its records.
StatusOr<SuiteResults> RunSuite(const SuiteOptions& options);

// Writes bench_results.json, <sweep>.csv, the SVG plots and index.html into `dir` (which must
// exist; the caller stages it).
Status WriteSuiteOutputs(const SuiteResults& results, const std::filesystem::path& dir);

// The JSON document of bench_results.json.
std::string SuiteResultsJson(const SuiteResults& results);

// A few lines for the terminal: machine, device, key numbers per sweep, invalid records.
std::string SuiteSummaryText(const SuiteResults& results);

}  // namespace reflcap::benchsuite
