// The pipeline sweeps of `reflcap bench` (sweeps.h): time and peak memory per stage against
// texel count, and holdout accuracy against the number of viewpoints (the seed paper's
// Figs. 20-21), both on synthetic captures run through the pipeline's library calls.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <optional>

#include "bench/suite/sweeps.h"
#include "acquire/resample/resample.h"
#include "acquire/synth/synth.h"
#include "engine/capture/capture.h"
#include "engine/core/log.h"
#include "engine/fit/fit_driver.h"
#include "engine/image/exr_io.h"
#include "render/reference/render_capture.h"
#include "render/validate/validate.h"

namespace reflcap::benchsuite {
namespace fs = std::filesystem;
namespace {

// Below this truth albedo a channel's relative ρ_d error is dominated by noise, not the fit.
constexpr double kMinTruthRho = 0.02;

// Raises the log threshold to warnings while the pipeline's stages run (their own progress bars
// and info lines would bury the suite's), restoring the caller's threshold afterwards.
class QuietStages {
 public:
  QuietStages() : previous_(LogThreshold()) {
    SetLogThreshold(std::max(previous_, LogLevel::kWarning));
  }
  ~QuietStages() { SetLogThreshold(previous_); }

 private:
  LogLevel previous_;
};

struct StageResult {
  std::string stage;
  Status status;
  double seconds = 0;
  uint64_t peak_rss_bytes = 0, start_rss_bytes = 0;
};

struct PipelineOutcome {
  std::vector<StageResult> stages;
  synth::SynthSummary synth;
  resample::ResampleSummary resampled;
  fit::FitRunSummary fitted;
  validate::ValidateSummary validation;
  std::optional<MapAccuracy> accuracy;
  Status accuracy_status;
  std::string rss_method;
  bool ok() const { return !stages.empty() && stages.back().status.ok(); }
};

// Runs `body` as one stage, timing it and measuring its peak resident memory.
template <typename Body>
bool RunStage(const std::string& name, PipelineOutcome* out, Body body) {
  StageResult s;
  s.stage = name;
  s.start_rss_bytes = CurrentRssBytes();
  PeakRssScope rss;
  const auto start = std::chrono::steady_clock::now();
  {
    QuietStages quiet;
    s.status = body();
  }
  s.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  s.peak_rss_bytes = rss.PeakBytes();
  out->rss_method = rss.method();
  out->stages.push_back(s);
  return s.status.ok();
}

// synth -> resample (train) -> fit (cpu) [-> render (holdout) -> validate] in `dir`; stops at
// the first failing stage.
PipelineOutcome RunCapturePipeline(const CaptureSpec& spec, const fs::path& dir, int threads,
                                   bool render_and_validate) {
  PipelineOutcome out;
  const fs::path capture_dir = dir / "capture", samples = dir / "samples", fit_dir = dir / "fit",
                 renders = dir / "renders", report = dir / "report";
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (!RunStage("synth", &out, [&]() -> Status {
        synth::SynthOptions o;
        o.preset = "small";
        o.seed = spec.seed;
        o.texels = spec.texels;
        o.image_size = spec.image_size;
        o.cameras = spec.cameras;
        o.lights = spec.lights;
        o.steps = spec.steps;
        REFLCAP_RETURN_IF_ERROR(o.Validate());
        REFLCAP_ASSIGN_OR_RETURN(out.synth, synth::WriteSyntheticCapture(o, capture_dir));
        return OkStatus();
      })) {
    return out;
  }
  if (!RunStage("resample", &out, [&]() -> Status {
        resample::ResampleOptions o;
        o.threads = threads;
        fs::create_directories(samples);
        REFLCAP_ASSIGN_OR_RETURN(out.resampled,
                                 resample::ResampleCapture(capture_dir / "capture.json", o, samples));
        return OkStatus();
      })) {
    return out;
  }
  if (!RunStage("fit", &out, [&]() -> Status {
        fit::FitOptions o;
        o.threads = threads;
        REFLCAP_ASSIGN_OR_RETURN(out.fitted,
                                 fit::RunFit(samples, fit_dir, fit::Backend::kCpu, o, false));
        return OkStatus();
      })) {
    return out;
  }
  // Accuracy against the truth maps, outside every timed stage.
  auto accuracy = CompareWithGroundTruth(capture_dir / "gt" / "params.exr", samples, fit_dir);
  if (accuracy.ok()) {
    out.accuracy = *accuracy;
  } else {
    out.accuracy_status = accuracy.status();
  }
  // The pipeline's sample store is the largest intermediate; the later stages do not read it.
  fs::remove_all(samples, ec);
  if (!render_and_validate) return out;
  auto capture = ReadCapture(capture_dir / "capture.json");
  if (!capture.ok()) {
    out.stages.push_back({"render", capture.status()});
    return out;
  }
  if (!RunStage("render", &out, [&]() -> Status {
        render::CaptureRenderOptions o;
        o.split = render::SplitSelection::kHoldout;
        return render::RenderCapture(*capture, fit_dir / "params.exr", renders, o).status();
      })) {
    return out;
  }
  RunStage("validate", &out, [&]() -> Status {
    validate::ValidateOptions o;
    o.split = render::SplitSelection::kHoldout;
    o.fit_dir = fit_dir;
    o.max_figures = 0;  // the metrics are what the bench needs, not the report's figures
    REFLCAP_ASSIGN_OR_RETURN(out.validation,
                             validate::RunValidation(*capture, renders, report, o));
    return OkStatus();
  });
  return out;
}

std::string Pct(double v) { return StrCat(std::round(v * 1e4) / 1e2, " %"); }
std::string Db(double v) { return StrCat(std::round(v * 100) / 100, " dB"); }

double TexelsWithSamplesFraction(const PipelineOutcome& o) {
  return o.resampled.texels ? double(o.resampled.texels_with_samples) / o.resampled.texels : 0;
}

// "" when the fit's accuracy against the truth maps is sane.
std::string CheckAccuracy(const PipelineOutcome& o, const VerifyBounds& b) {
  if (!o.accuracy) return StrCat("no ground-truth comparison: ", o.accuracy_status.ToString());
  if (!(o.accuracy->median_rel_error_rho_d <= b.max_pipeline_rel_error_rho_d)) {
    return StrCat("median rel. error of rho_d ", Pct(o.accuracy->median_rel_error_rho_d), " > ",
                  Pct(b.max_pipeline_rel_error_rho_d));
  }
  return {};
}

std::string CheckPsnr(const PipelineOutcome& o, const VerifyBounds& b) {
  if (!o.validation.psnr_db) return "no holdout PSNR";
  if (!(*o.validation.psnr_db >= b.min_holdout_psnr_db)) {
    return StrCat("holdout PSNR ", Db(*o.validation.psnr_db), " < ", Db(b.min_holdout_psnr_db));
  }
  return {};
}

double Median(std::vector<double> v) {
  if (v.empty()) return std::numeric_limits<double>::quiet_NaN();
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

// Index of channel `name` in `names`, or -1.
int ChannelIndex(const std::vector<std::string>& names, const std::string& name) {
  auto it = std::find(names.begin(), names.end(), name);
  return it == names.end() ? -1 : int(it - names.begin());
}

}  // namespace

StatusOr<MapAccuracy> CompareWithGroundTruth(const fs::path& gt_params_exr,
                                             const fs::path& samples_dir, const fs::path& fit_dir) {
  std::vector<std::string> gt_names, fit_names, status_names, coverage_names;
  REFLCAP_ASSIGN_OR_RETURN(Image coverage,
                           ReadExrChannels(samples_dir / "coverage.exr", &coverage_names));
  REFLCAP_ASSIGN_OR_RETURN(Image gt, ReadExrChannels(gt_params_exr, &gt_names));
  REFLCAP_ASSIGN_OR_RETURN(Image fitted, ReadExrChannels(fit_dir / "params.exr", &fit_names));
  REFLCAP_ASSIGN_OR_RETURN(Image status, ReadExrChannels(fit_dir / "status.exr", &status_names));
  if (gt.width != fitted.width || gt.height != fitted.height || gt.width != status.width ||
      gt.height != status.height || gt.width != coverage.width || gt.height != coverage.height) {
    return InvalidArgumentError(fit_dir.string(), ": params.exr is ", fitted.width, "x",
                                fitted.height, ", the ground truth ", gt.width, "x", gt.height);
  }
  const int status_c = ChannelIndex(status_names, "status");
  if (status_c < 0) return InvalidArgumentError(fit_dir.string(), "/status.exr: no status channel");
  const char* kRgb[] = {"R", "G", "B"};
  int gt_rho[3], fit_rho[3], gt_cz[3], fit_cz[3], gt_n[3], fit_n[3];
  for (int c = 0; c < 3; ++c) {
    gt_rho[c] = ChannelIndex(gt_names, StrCat("rho_d.", kRgb[c]));
    fit_rho[c] = ChannelIndex(fit_names, StrCat("rho_d.", kRgb[c]));
    gt_cz[c] = ChannelIndex(gt_names, StrCat("lobe0.Cz.", kRgb[c]));
    fit_cz[c] = ChannelIndex(fit_names, StrCat("lobe0.Cz.", kRgb[c]));
    gt_n[c] = ChannelIndex(gt_names, StrCat("lobe0.n.", kRgb[c]));
    fit_n[c] = ChannelIndex(fit_names, StrCat("lobe0.n.", kRgb[c]));
    if (gt_rho[c] < 0 || fit_rho[c] < 0) {
      return InvalidArgumentError("no rho_d.", kRgb[c], " channel in ", gt_params_exr.string(),
                                  " or ", fit_dir.string(), "/params.exr");
    }
  }
  std::vector<double> rho, n;
  int64_t truth_lobes = 0, both_lobes = 0;
  MapAccuracy a;
  for (size_t p = 0; p < gt.PixelCount(); ++p) {
    const float code = status.data[p * status.channels + status_c];
    if (code < 0 || coverage.data[p * coverage.channels] <= 0 ||
        int(code) == int(fit::FitStatus::kNonFiniteInput)) {
      continue;  // no texel, no sample, or no fit from data
    }
    ++a.texels_compared;
    const float* g = &gt.data[p * gt.channels];
    const float* f = &fitted.data[p * fitted.channels];
    for (int c = 0; c < 3; ++c) {
      if (g[gt_rho[c]] >= kMinTruthRho) rho.push_back(std::abs(f[fit_rho[c]] / g[gt_rho[c]] - 1));
    }
    // A lobe exists where its Cz > 0 (lobes are 0 elsewhere; fits without one hold zeros).
    const bool truth_lobe = gt_cz[0] >= 0 && g[gt_cz[0]] > 0 && gt_n[0] >= 0 && g[gt_n[0]] > 0;
    if (!truth_lobe) continue;
    ++truth_lobes;
    const bool fit_lobe = fit_cz[0] >= 0 && f[fit_cz[0]] > 0 && fit_n[0] >= 0 && f[fit_n[0]] > 0;
    if (!fit_lobe) continue;
    ++both_lobes;
    for (int c = 0; c < 3; ++c) {
      if (g[gt_n[c]] > 0) n.push_back(std::abs(f[fit_n[c]] / g[gt_n[c]] - 1));
    }
  }
  a.median_rel_error_rho_d = Median(rho);
  a.median_rel_error_n = Median(n);
  a.lobe_fraction = truth_lobes ? double(both_lobes) / truth_lobes : 0;
  return a;
}

std::vector<ScalingRecord> RunScalingSweep(const ScalingConfig& config, const fs::path& work_dir,
                                           int threads, const VerifyBounds& bounds,
                                           const PointDone& done) {
  std::vector<ScalingRecord> records;
  for (size_t i = 0; i < config.sizes.size(); ++i) {
    const CaptureSpec& spec = config.sizes[i];
    const fs::path dir = work_dir / StrCat("scaling_", i);
    const PipelineOutcome o = RunCapturePipeline(spec, dir, threads, config.render_and_validate);
    for (const StageResult& s : o.stages) {
      ScalingRecord r;
      r.texels_target = spec.texels;
      r.texels = int64_t(o.synth.texels);
      r.image_size = spec.image_size;
      r.images = int(o.synth.images);
      r.stage = s.stage;
      r.seconds = s.seconds;
      r.texels_per_second = r.texels / std::max(s.seconds, 1e-12);
      r.peak_rss_bytes = s.peak_rss_bytes;
      r.start_rss_bytes = s.start_rss_bytes;
      if (!s.status.ok()) {
        r.invalid_reason = StrCat(s.stage, " failed: ", s.status.ToString());
      } else if (s.stage == "synth") {
        r.detail = StrCat(o.synth.images, " images (", o.synth.train_images, " train, ",
                          o.synth.holdout_images, " holdout) of ", spec.image_size, " px");
      } else if (s.stage == "resample") {
        r.detail = StrCat(o.resampled.samples_kept, " samples kept, ",
                          Pct(TexelsWithSamplesFraction(o)), " of texels with samples");
        if (!(TexelsWithSamplesFraction(o) >= bounds.min_texels_with_samples_fraction)) {
          r.invalid_reason = StrCat("texels with samples ", Pct(TexelsWithSamplesFraction(o)),
                                    " < ", Pct(bounds.min_texels_with_samples_fraction));
        }
      } else if (s.stage == "fit") {
        const double fitted = std::max<size_t>(1, o.fitted.texels_with_samples);
        r.detail = StrCat(std::lround(o.fitted.fits_per_second), " fits/s, converged ",
                          Pct(o.fitted.status_counts[int(fit::FitStatus::kConverged)] / fitted));
        if (o.accuracy) {
          r.detail += StrCat(", median rel. error rho_d ", Pct(o.accuracy->median_rel_error_rho_d),
                             ", n ", Pct(o.accuracy->median_rel_error_n));
        }
        r.invalid_reason = CheckAccuracy(o, bounds);
      } else if (s.stage == "render") {
        // Checked through the validation that compares its images with the photographs.
        r.detail = "holdout split";
        if (o.stages.size() > 4 && o.stages.back().status.ok()) r.invalid_reason = CheckPsnr(o, bounds);
      } else if (s.stage == "validate") {
        r.detail = o.validation.psnr_db ? StrCat("holdout PSNR ", Db(*o.validation.psnr_db)) : "";
        r.invalid_reason = CheckPsnr(o, bounds);
      }
      r.valid = r.invalid_reason.empty();
      REFLCAP_LOG(kInfo) << "bench scaling: " << r.texels << " texels, " << r.stage << ": "
                         << r.seconds << " s, peak RSS " << (r.peak_rss_bytes >> 20) << " MiB"
                         << (r.valid ? "" : " — INVALID: " + r.invalid_reason);
      records.push_back(std::move(r));
    }
    std::error_code ec;
    fs::remove_all(dir, ec);
    if (done) done();
  }
  return records;
}

std::vector<ViewpointRecord> RunViewpointSweep(const ViewpointConfig& config,
                                               const fs::path& work_dir, int threads,
                                               const VerifyBounds& bounds,
                                               const PointDone& done) {
  std::vector<ViewpointRecord> records;
  for (size_t i = 0; i < config.rigs.size(); ++i) {
    const CaptureSpec& spec = config.rigs[i];
    const fs::path dir = work_dir / StrCat("viewpoints_", i);
    const PipelineOutcome o = RunCapturePipeline(spec, dir, threads, /*render_and_validate=*/true);
    ViewpointRecord r;
    r.cameras = spec.cameras;
    r.steps = spec.steps;
    r.lights = spec.lights;
    r.viewpoints = spec.cameras * spec.steps;
    r.train_images = int(o.synth.train_images);
    r.holdout_images = int(o.synth.holdout_images);
    r.texels = int64_t(o.synth.texels);
    r.texels_with_samples_fraction = TexelsWithSamplesFraction(o);
    for (const StageResult& s : o.stages) r.seconds += s.seconds;
    if (!o.ok()) {
      r.invalid_reason = StrCat(o.stages.back().stage, " failed: ", o.stages.back().status.ToString());
    } else {
      r.holdout_psnr_db = o.validation.psnr_db.value_or(std::numeric_limits<double>::quiet_NaN());
      r.noise_bound_psnr_db = o.validation.noise_bound_psnr_db.value_or(0);
      if (o.accuracy) {
        r.median_rel_error_rho_d = o.accuracy->median_rel_error_rho_d;
        r.median_rel_error_n = o.accuracy->median_rel_error_n;
        r.lobe_fraction = o.accuracy->lobe_fraction;
      }
      r.invalid_reason = CheckAccuracy(o, bounds);
      if (r.invalid_reason.empty()) r.invalid_reason = CheckPsnr(o, bounds);
    }
    r.valid = r.invalid_reason.empty();
    REFLCAP_LOG(kInfo) << "bench viewpoints: " << r.cameras << " cameras x " << r.steps
                       << " steps: holdout PSNR " << Db(r.holdout_psnr_db) << ", lobes "
                       << Pct(r.lobe_fraction) << (r.valid ? "" : " — INVALID: " + r.invalid_reason);
    records.push_back(std::move(r));
    std::error_code ec;
    fs::remove_all(dir, ec);
    if (done) done();
  }
  return records;
}

}  // namespace reflcap::benchsuite
