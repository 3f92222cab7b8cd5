#pragma once
// `reflcap validate`: re-renders against photographs — metrics (metrics.h), figures (figures.h)
// and a self-contained HTML report — as a library, so tests and `reflcap run` call it directly.
//
// Inputs: a capture/1, a render folder in the layout of render/reference/render_capture.h
// (re-renders, masks/, aux/), optionally the fit folder (FIT/fit_report.json, FIT/status.exr) and
// the sample store (SAMPLES/coverage.png) for the report.
// Output folder (the caller stages it):
//   metrics.json              images (per-image metrics), overall (pooled + per-image mean,
//                             worst pixels), capture, renders, split, definitions, timings
//   figures/<key>.png         photograph | re-render | error heat map, for up to max_figures
//                             images: the kWorstImagesShown worst, the rest evenly spaced over
//                             the selection; every error map on one colour scale
//   figures/<key>_regions.png the region labels of that image
//   error_scale.png           the legend of that shared scale
//   status.png, model.png, clusters.png, coverage.png
//                             fit maps with legends, sample coverage (when given and present)
//   report.html               everything above on one page (relative links): summary, worst
//                             images large, all figures, maps, then the tables
#include <filesystem>
#include <memory>
#include <optional>
#include <string>

#include "engine/capture/capture.h"
#include "engine/core/status.h"
#include "render/reference/reference_renderer.h"
#include "render/reference/render_capture.h"
#include "render/validate/metrics.h"

namespace reflcap::validate {

// Figures written at most, by default: enough to see every camera/light family of a holdout split,
// few enough to keep a report's page light (each figure is ~3x an image).
constexpr int kDefaultMaxFigures = 24;
// The worst images (by PSNR) always drawn, first and large on the page, within max_figures: a
// reader looks at where the model fails before the typical views.
constexpr int kWorstImagesShown = 4;

struct ValidateOptions {
  render::SplitSelection split = render::SplitSelection::kHoldout;
  std::filesystem::path fit_dir;      // empty: no fit section
  std::filesystem::path samples_dir;  // empty: no coverage section
  int max_figures = kDefaultMaxFigures;  // >= 0
  // Error heat-map range as a fraction of the peak, shared by all figures; 0 = automatic: the 99th
  // percentile of the map error over all evaluated pixels of all selected images (metrics.h),
  // rounded up to 1, 2, 2.5 or 5 x 10^k.
  double error_scale = 0;
  ScoreOptions score;
  // Threads scoring images (each image reads its files and is scored on one thread) and writing
  // figures; 0 = one per hardware thread. Results do not depend on it: per-image sums are pooled
  // in image order. [0, 1024].
  int threads = 0;
  Status Validate() const;
};

struct ValidateSummary {
  size_t images = 0;
  size_t pixels = 0;
  size_t figures = 0;
  std::optional<double> psnr_db, rel_rmse, ssim;                       // overall, raw
  std::optional<double> scaled_psnr_db, scaled_rel_rmse, scaled_ssim;  // overall, LS-scaled
  std::optional<double> noise_bound_psnr_db;                           // when the noise is known
  std::optional<double> psnr_l_db, scaled_psnr_l_db;                   // overall PSNR-L
  // Overall shares of the pooled squared error carried by the worst 0.1 % / 1 % of pixels.
  std::optional<double> worst_0_1pct_error_share, worst_1pct_error_share;
  double seconds = 0;
};

// Scores every selected photograph against its re-render in `renders_dir` and writes the report
// into `out_dir` (created if missing). NotFound names a missing render or mask; InvalidArgument a
// size mismatch; FailedPrecondition when no image is selected. (StreamingValidation::Start, then
// Finish.)
StatusOr<ValidateSummary> RunValidation(const Capture& capture,
                                        const std::filesystem::path& renders_dir,
                                        const std::filesystem::path& out_dir,
                                        const ValidateOptions& options);

// RunValidation in steps, so that images are scored while a render stage still holds them in
// memory (`reflcap run`: CaptureRenderOptions::after_write), instead of decoding their files
// again: Start, Score for each image as it is rendered (any thread, any order), Finish. The
// report is the same as RunValidation's on the written files (the same floats: Score takes them
// as the files hold them), except its timings (`images_scored_while_rendering`; score_s then
// times only the images read from files). `capture` must outlive the object.
class StreamingValidation {
 public:
  // Checks the options, selects the images and starts loading the fit's look-up data.
  // FailedPrecondition when no image is selected.
  static StatusOr<std::unique_ptr<StreamingValidation>> Start(
      const Capture& capture, const std::filesystem::path& renders_dir,
      const ValidateOptions& options);
  ~StreamingValidation();
  StreamingValidation(const StreamingValidation&) = delete;
  StreamingValidation& operator=(const StreamingValidation&) = delete;

  // Scores capture image `index` against `result`, its re-render as render writes it to
  // renders_dir (pixels, mask, aux buffers). Once per image; images of different calls may be
  // scored concurrently; an image outside the selection is ignored. Errors as RunValidation's
  // (reading the photograph, size mismatch); Finish returns them too.
  Status Score(size_t index, const render::RenderResult& result);

  // Scores the images Score did not see from their files in renders_dir and writes the report
  // into `out_dir`, as RunValidation. Call once.
  StatusOr<ValidateSummary> Finish(const std::filesystem::path& out_dir);

 private:
  struct State;
  explicit StreamingValidation(std::unique_ptr<State> state);
  std::unique_ptr<State> state_;
};

}  // namespace reflcap::validate
