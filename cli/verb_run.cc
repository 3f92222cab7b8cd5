// `reflcap run CAPTURE --out DIR`: the whole pipeline in one command — resample the train split,
// fit, re-render the holdout split, validate — with the same outputs the single verbs write, laid
// out as DIR/samples, DIR/fit, DIR/renders, DIR/report. `reflcap demo` runs it on a small
// synthetic capture. The DIR folder is staged: it appears only when every stage succeeded.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>

#include "cli/cli.h"
#include "cli/pipeline.h"
#include "acquire/resample/resample.h"
#include "acquire/resample/vulkan_masks.h"
#include "acquire/synth/synth.h"
#include "engine/capture/capture.h"
#include "engine/core/atomic_file.h"
#include "engine/core/log.h"
#include "engine/core/progress.h"
#include "engine/fit/fit_driver.h"
#include "engine/fit/fitter.h"
#include "engine/fit/vulkan_fitter.h"
#include "render/reference/render_capture.h"
#include "render/validate/validate.h"
#ifdef REFLCAP_HAVE_VULKAN_RENDERER
#include "render/vulkan/vulkan_render_capture.h"  // render stage on the fit's GPU (issue 14.3)
#endif

namespace reflcap::cli {
namespace fs = std::filesystem;

namespace {

double SecondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

std::string FormatDb(const std::optional<double>& db) {
  return db ? StrCat(std::round(*db * 100) / 100, " dB") : std::string("n/a");
}

}  // namespace

StatusOr<FitBackendChoice> ResolveFitBackend(const std::string& name, const std::string& device) {
  FitBackendChoice result;
  if (name != "auto") {
    auto backend = fit::ParseBackend(name);
    if (!backend.ok()) return InvalidArgumentError(backend.status().message(), " or auto");
    if (!device.empty() && *backend != fit::Backend::kVulkan) {
      return InvalidArgumentError("--device needs --backend vulkan or auto");
    }
    result.backend = *backend;
    return result;
  }
  REFLCAP_ASSIGN_OR_RETURN(fit::AutoBackendChoice chosen, fit::ChooseAutoBackend(device));
  result.backend = chosen.backend;
  result.choice = StrCat("auto: ", fit::BackendName(chosen.backend), " (", chosen.reason, ")");
  if (chosen.fell_back) {
    REFLCAP_LOG(kWarning) << "--backend auto: " << chosen.reason;
  } else {
    REFLCAP_LOG(kInfo) << "--backend auto: " << fit::BackendName(chosen.backend) << " ("
                       << chosen.reason << ")";
  }
  return result;
}

StatusOr<PipelineSummary> RunPipeline(const fs::path& capture_path, const fs::path& out,
                                      const PipelineOptions& options) {
  PipelineSummary summary;
  REFLCAP_ASSIGN_OR_RETURN(Capture capture, ReadCapture(capture_path));
  CaptureFilesReport files;
  REFLCAP_RETURN_IF_ERROR(ValidateCaptureFiles(capture, &files));
  if (capture.CountSplit(Split::kHoldout) == 0) {
    return FailedPreconditionError(capture.json_path.string(),
                                   ": images: no holdout photograph to validate against");
  }
  REFLCAP_ASSIGN_OR_RETURN(StagingDir staging, StagingDir::Create(out, options.overwrite));
  const fs::path dir = staging.path();

  auto start = std::chrono::steady_clock::now();
  REFLCAP_LOG(kInfo) << "run 1/4: resampling the train split";
  resample::ResampleOptions resample_options = options.resample;
  resample_options.split = resample::SplitSelection::kTrain;
  if (options.fit_backend == fit::Backend::kVulkan && !capture.normal_map) {
    // After a Vulkan fit the train split resamples on the same device when it is a GPU, as the
    // holdout renders there: on an H200 the million preset resampled in 3.6-4.0 s on the GPU,
    // against 14.1-16.0 s with Embree on its host's 16 cores. A CPU device (lavapipe) would share
    // the cores Embree uses: Embree stays. (A normal-map capture casts no ray to mask.)
    const StatusOr<bool> gpu = resample::VulkanMasksOnGpu(options.fit_device, &capture);
    if (gpu.ok() && *gpu) {
      resample_options.backend = resample::Backend::kVulkan;
      resample_options.device = options.fit_device;
    } else {
      REFLCAP_LOG(kInfo) << "run: resampling on the CPU ("
                         << (gpu.ok() ? std::string("the fit's Vulkan device is a CPU device")
                                      : std::string(gpu.status().message()))
                         << ")";
    }
  }
  fs::create_directories(dir / "samples");
  REFLCAP_ASSIGN_OR_RETURN(resample::ResampleSummary resampled,
                           resample::ResampleCapture(capture, resample_options, dir / "samples",
                                                     files.mesh.get()));
  files.mesh.reset();  // the render loads what it needs
  summary.resample_s = SecondsSince(start);
  summary.texels = resampled.texels;

  start = std::chrono::steady_clock::now();
  REFLCAP_LOG(kInfo) << "run 2/4: fitting";
  REFLCAP_ASSIGN_OR_RETURN(fit::FitRunSummary fitted,
                           fit::RunFit(dir / "samples", dir / "fit", options.fit_backend,
                                       options.fit, /*overwrite=*/false, options.fit_vulkan,
                                       options.fit_backend_choice));
  summary.fit_s = SecondsSince(start);
  summary.fit_device = fitted.device;
  summary.fits_per_second = fitted.fits_per_second;

  start = std::chrono::steady_clock::now();
  REFLCAP_LOG(kInfo) << "run 3/4: re-rendering the holdout split (each image scored as it is written)";
  render::CaptureRenderOptions render_options;
  render_options.split = render::SplitSelection::kHoldout;
  // One switch for both stages: a normal-map capture's height-field shadows reject train samples
  // and darken the holdout renders, or (--no-height-shadows) neither.
  render_options.height_shadows = options.resample.height_shadows;
  render_options.indirect = options.indirect;
  render_options.indirect_bounces = options.indirect_bounces;
  render_options.indirect_rays = options.indirect_rays;
  render_options.supersampling = options.supersampling;
  render_options.pixel_footprint = options.pixel_footprint;
  render_options.psf_sigma_px = options.psf_sigma_px;
  render_options.height_field = options.height_field;
  // Validation scores each holdout image as its files are written, from memory: decoding them
  // again was a third of validate's work (million preset: 0.12 of 0.42 core-seconds an image).
  validate::ValidateOptions validate_options;
  validate_options.split = render::SplitSelection::kHoldout;
  validate_options.fit_dir = dir / "fit";
  validate_options.samples_dir = dir / "samples";
  REFLCAP_ASSIGN_OR_RETURN(
      std::unique_ptr<validate::StreamingValidation> validation,
      validate::StreamingValidation::Start(capture, dir / "renders", validate_options));
  render_options.after_write = [&validation](size_t index, const render::RenderResult& result) {
    return validation->Score(index, result);
  };
  bool rendered = false;
#ifdef REFLCAP_HAVE_VULKAN_RENDERER
  // After a Vulkan fit the holdout renders on the same device (issue 14.3): a GPU renders it
  // with the Vulkan renderer, a CPU device (lavapipe) with the CPU reference renderer.
  if (options.fit_backend == fit::Backend::kVulkan) {
    REFLCAP_RETURN_IF_ERROR(render::RenderCaptureOnFitDevice(capture, dir / "fit" / "params.exr",
                                                             dir / "renders", render_options,
                                                             options.fit_device)
                                .status());
    rendered = true;
  }
#endif
  if (!rendered) {
    REFLCAP_RETURN_IF_ERROR(
        render::RenderCapture(capture, dir / "fit" / "params.exr", dir / "renders", render_options)
            .status());
  }
  summary.render_s = SecondsSince(start);

  start = std::chrono::steady_clock::now();
  REFLCAP_LOG(kInfo) << "run 4/4: validating against the holdout photographs";
  REFLCAP_ASSIGN_OR_RETURN(summary.validation, validation->Finish(dir / "report"));
  summary.validate_s = SecondsSince(start);
  // The reports name the samples, fit and renders they describe: by their final paths.
  REFLCAP_RETURN_IF_ERROR(staging.NameFinalPaths());
  REFLCAP_RETURN_IF_ERROR(staging.Commit());
  return summary;
}

std::string PipelineSummaryLine(const PipelineSummary& s) {
  return StrCat("holdout PSNR ", FormatDb(s.validation.psnr_db),
                s.validation.noise_bound_psnr_db
                    ? StrCat(" (noise bound ", FormatDb(s.validation.noise_bound_psnr_db), ")")
                    : std::string(),
                ", PSNR-L ", FormatDb(s.validation.psnr_l_db), ", rel. RMSE ",
                s.validation.rel_rmse ? StrCat(std::round(*s.validation.rel_rmse * 1e4) / 1e4)
                                      : std::string("n/a"),
                "; resample ", FormatDuration(s.resample_s), ", fit ", FormatDuration(s.fit_s),
                " (", s.fit_device, "), render ", FormatDuration(s.render_s), ", validate ",
                FormatDuration(s.validate_s));
}

int RunRun(int argc, char** argv) {
  std::string capture, out, backend = "auto", device;
  PipelineOptions options;
  FitFlags fit_flags;
  ArgParser args("run", "CAPTURE --out DIR [options]",
                 "The whole pipeline: resample the train split -> fit -> re-render the holdout\n"
                 "split -> validate. DIR gets samples/, fit/, renders/ and report/ (the outputs of\n"
                 "the single verbs) and appears only when every stage succeeded.");
  args.AddPositional("CAPTURE", &capture, "capture.json, or the folder holding it");
  args.AddString("out", &out, "DIR", "output folder (must not exist or be empty)");
  args.AddInt("atlas-res", &options.resample.atlas_resolution,
              "atlas resolution R (default: the capture's ground truth atlas, else 512)");
  args.AddDouble("min-cos", &options.resample.min_cos, "sample acceptance: n.l and n.v above this (default 0.15)");
  args.AddFlag("variance-weights", &options.resample.use_variance,
               "resample: weight photographs that have images[].variance by it (default: the "
               "noise model)");
  std::string supersample = "auto";
  args.AddString("supersample", &supersample, "N|auto",
                 "holdout render: N x N rays per pixel averaged over it, 1..16, or auto (default: "
                 "4 x 4 when the train photographs integrate over their pixels, else 1)");
  std::string footprint = "auto";
  args.AddString("pixel-footprint", &footprint, "W|auto",
                 "holdout render, mesh captures: the square, W px wide (1..4), that a pixel's "
                 "rays cover; auto (default: with --supersample auto the train photographs "
                 "decide, else 1)");
  std::string psf = "auto";
  args.AddString("psf", &psf, "auto|none|SIGMA",
                 "holdout render, normal-map captures: the photographs' point spread, a Gaussian "
                 "of SIGMA px within the mask; auto (default: the train photographs decide) or "
                 "none");
  std::string height_field = "auto";
  args.AddString("height-field", &height_field, "auto|ls|l1",
                 "holdout render, normal-map captures: the shadows' height field, least squares "
                 "(ls) or L1 (l1: depth steps stay sharp); auto (default: the train photographs "
                 "decide); the resample's shadow test keeps least squares");
  std::string sample_point = "pixel";
  args.AddString("sample-point", &sample_point, "pixel|texel",
                 "resample: measure each texel at its nearest pixel's surface point (pixel, "
                 "default) or interpolate pixels at the texel centre (texel)");
  std::string pixel_filter = "capture";
  args.AddString("pixel-filter", &pixel_filter, "capture|area|point",
                 "resample: what a photograph's pixel measures, its footprint (area) or its "
                 "centre's ray (point); default capture: cameras[].pixel_filter, else area");
  bool no_height_shadows = false;
  args.AddFlag("no-height-shadows", &no_height_shadows,
               "normal-map captures: no cast shadows from the height field integrated from the "
               "normal map, neither rejecting train samples nor in the holdout renders");
  std::string indirect = "auto";
  args.AddString("indirect", &indirect, "MODE",
                 "light not straight from the lamp: interreflection (mesh captures) or the "
                 "room's stray light (normal-map captures); auto (default: added when the train "
                 "photographs show light where no direct light reaches), on or off");
  args.AddInt("indirect-bounces", &options.indirect_bounces,
              "bounces of interreflection, 1..8 (default 2)");
  args.AddInt("indirect-rays", &options.indirect_rays,
              "rays per texel gathering interreflection, 1..1024 (default 64)");
  args.AddString("backend", &backend, "NAME",
                 "fit backend: auto (default: a GPU if there is one, else cpu), cpu, ceres or "
                 "vulkan; on a GPU the train split's resample and the holdout render run there too");
  args.AddString("device", &device, "NAME|INDEX", "Vulkan device for the fit (index or name substring)");
  fit_flags.Register(&args, &options.fit);
  args.AddFlag("overwrite", &options.overwrite, "replace DIR if it exists (only once the new one is complete)");
  bool help = false;
  if (Status s = args.Parse(argc, argv, 2, &help); !s.ok()) {
    std::fprintf(stderr, "reflcap run: %s\n", s.message().c_str());
    return kExitUsage;
  }
  if (help) {
    std::printf("%s", args.Help().c_str());
    return 0;
  }
  if (out.empty()) {
    std::fprintf(stderr, "reflcap run: --out DIR is required\n");
    return kExitUsage;
  }
  options.resample.height_shadows = !no_height_shadows;
  {
    const auto point = resample::ParseSamplePoint(sample_point);
    const auto filter = resample::ParsePixelFilter(pixel_filter);
    const auto supersampling = render::ParseSupersampling(supersample, "--supersample");
    const auto mode = render::ParseIndirectMode(indirect, "--indirect");
    const auto pixel_footprint = render::ParsePixelFootprint(footprint, "--pixel-footprint");
    const auto psf_sigma = render::ParsePsf(psf, "--psf");
    const auto height_choice = render::ParseHeightFieldChoice(height_field, "--height-field");
    // The render stage's ranges, checked before any stage runs.
    render::CaptureRenderOptions render_check;
    render_check.indirect_bounces = options.indirect_bounces;
    render_check.indirect_rays = options.indirect_rays;
    for (const Status& s : {point.status(), filter.status(), supersampling.status(),
                            mode.status(), pixel_footprint.status(), psf_sigma.status(),
                            height_choice.status(),
                            render_check.Validate()}) {
      if (!s.ok()) {
        std::fprintf(stderr, "reflcap run: %s\n", s.message().c_str());
        return kExitUsage;
      }
    }
    options.resample.sample_point = *point;
    options.resample.pixel_filter = *filter;
    options.supersampling = *supersampling;
    options.pixel_footprint = *pixel_footprint;
    options.indirect = *mode;
    options.psf_sigma_px = *psf_sigma;
    options.height_field = *height_choice;
  }
  if (Status s = fit_flags.Apply(&options.fit); !s.ok()) {
    std::fprintf(stderr, "reflcap run: %s\n", s.message().c_str());
    return kExitUsage;
  }
  for (const Status& s : {options.resample.Validate(), options.fit.Validate()}) {
    if (!s.ok()) {
      std::fprintf(stderr, "reflcap run: %s\n", s.message().c_str());
      return kExitUsage;
    }
  }
  auto fit_backend = ResolveFitBackend(backend, device);
  if (!fit_backend.ok()) {
    if (fit_backend.status().code() == StatusCode::kInvalidArgument) {
      std::fprintf(stderr, "reflcap run: %s\n", fit_backend.status().message().c_str());
      return kExitUsage;
    }
    return ReportError("run", fit_backend.status());
  }
  options.fit_backend = fit_backend->backend;
  options.fit_device = device;
  options.fit_vulkan = fit_flags.vulkan;
  options.fit_vulkan.device = device;
  options.fit_backend_choice = fit_backend->choice;
  auto summary = RunPipeline(capture, out, options);
  if (!summary.ok()) return ReportError("run", summary.status());
  std::printf("reflcap run: %s\n", PipelineSummaryLine(*summary).c_str());
  std::printf("  report: %s\n", (fs::path(out) / "report" / "report.html").string().c_str());
  return 0;
}

}  // namespace reflcap::cli
