#pragma once
// The pipeline behind `reflcap run` and `reflcap demo` (implemented in verb_run.cc).
#include <filesystem>
#include <string>

#include "cli/cli.h"
#include "acquire/resample/resample.h"
#include "engine/core/status.h"
#include "engine/fit/fitter.h"
#include "engine/fit/vulkan_fitter.h"
#include "render/validate/validate.h"

namespace reflcap::cli {

// The pipeline behind `reflcap run` and `reflcap demo` (verb_run.cc).
struct PipelineOptions {
  resample::ResampleOptions resample;  // its split is forced to train
  fit::Backend fit_backend = fit::Backend::kCpu;
  std::string fit_device;         // --device (Vulkan), empty = automatic
  fit::VulkanFitterOptions fit_vulkan;  // --vulkan-kernel, --cluster-size (device: fit_device)
  std::string fit_backend_choice;  // how --backend auto chose, for fit_report.json
  fit::FitOptions fit;
  // The holdout render's interreflection (--indirect, --indirect-bounces, --indirect-rays).
  render::IndirectMode indirect = render::IndirectMode::kAuto;
  int indirect_bounces = 2, indirect_rays = 64;
  // The holdout render's pixel model (--supersample N|auto; render::kAutoSupersampling = auto).
  int supersampling = render::kAutoSupersampling;
  double pixel_footprint = render::kAutoPixelFootprint;  // --pixel-footprint W|auto
  // Normal-map captures: the holdout render's point spread (--psf auto|none|SIGMA).
  double psf_sigma_px = render::kAutoPsf;
  // Normal-map captures: the holdout render's height field (--height-field auto|ls|l1); the
  // resample's shadow test keeps the least-squares one.
  render::HeightFieldChoice height_field = render::HeightFieldChoice::kAuto;
  bool overwrite = false;
};
struct PipelineSummary {
  uint64_t texels = 0;
  double resample_s = 0, fit_s = 0, render_s = 0, validate_s = 0;
  std::string fit_device;
  double fits_per_second = 0;
  validate::ValidateSummary validation;
};
// The fit backend a verb runs with. `name` is auto, cpu, ceres or vulkan; auto applies
// fit::ChooseAutoBackend's rule (a GPU -> vulkan; lavapipe or no Vulkan -> cpu) and logs the
// choice, a warning when there was no usable device. `device` (--device) needs vulkan or auto.
// A bad name or combination is InvalidArgument (a usage error).
struct FitBackendChoice {
  fit::Backend backend = fit::Backend::kCpu;
  std::string choice;  // "auto: cpu (...)" when auto chose, else empty
};
StatusOr<FitBackendChoice> ResolveFitBackend(const std::string& name, const std::string& device);

// The fitting options `fit` and `run` share — lobes, lobe model, start, loss, the post-fit steps
// and their knobs, the step cap: Register binds them to `args` (numbers straight into *options),
// Apply, after Parse, turns the names and switches into *options (InvalidArgument for an unknown
// name: a usage error). Implemented in verb_fit.cc.
struct FitFlags {
  std::string lobe_model = "aniso", init = "seed", loss = "none", vulkan_kernel = "auto";
  std::string model_choice = "kfold";
  int cluster_size = 0, chunks_in_flight = 0;
  bool no_channel_retry = false, no_albedo_fill = false, no_lobe_transfer = false;
  bool no_material_clusters = false;
  bool no_diffuse_falloff = false;
  // The Vulkan fitter's kernel, cluster size and chunks in flight (after Apply; its device
  // comes from --device).
  fit::VulkanFitterOptions vulkan;
  void Register(ArgParser* args, fit::FitOptions* options);
  Status Apply(fit::FitOptions* options);
};

// Resample (train) -> fit -> render (holdout) -> validate into `out` (staged).
StatusOr<PipelineSummary> RunPipeline(const std::filesystem::path& capture,
                                      const std::filesystem::path& out,
                                      const PipelineOptions& options);
// "holdout PSNR 38.2 dB (noise bound 38.5 dB), rel. RMSE 0.031; resample 2.1s, fit 0.4s (cpu), ..."
std::string PipelineSummaryLine(const PipelineSummary& summary);

}  // namespace reflcap::cli
