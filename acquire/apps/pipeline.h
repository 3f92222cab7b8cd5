#pragma once
// The pipeline behind `reflcap run` and `reflcap demo` (implemented in verb_run.cc).
#include <filesystem>
#include <string>

#include "acquire/resample/resample.h"
#include "engine/core/status.h"
#include "engine/fit/fitter.h"
#include "render/validate/validate.h"

namespace reflcap::cli {

// The pipeline behind `reflcap run` and `reflcap demo` (verb_run.cc).
struct PipelineOptions {
  resample::ResampleOptions resample;  // its split is forced to train
  fit::Backend fit_backend = fit::Backend::kCpu;
  fit::FitOptions fit;
  bool overwrite = false;
};
struct PipelineSummary {
  uint64_t texels = 0;
  double resample_s = 0, fit_s = 0, render_s = 0, validate_s = 0;
  std::string fit_device;
  double fits_per_second = 0;
  validate::ValidateSummary validation;
};
// Resample (train) -> fit -> render (holdout) -> validate into `out` (staged).
StatusOr<PipelineSummary> RunPipeline(const std::filesystem::path& capture,
                                      const std::filesystem::path& out,
                                      const PipelineOptions& options);
// "holdout PSNR 38.2 dB (noise bound 38.5 dB), rel. RMSE 0.031; resample 2.1s, fit 0.4s (cpu), ..."
std::string PipelineSummaryLine(const PipelineSummary& summary);

}  // namespace reflcap::cli
