// `reflcap validate CAPTURE RENDERS --out REPORT`: re-renders against photographs — metrics,
// figures and an HTML report (render/validate/validate.h).
#include <cstdio>
#include <filesystem>

#include "cli/cli.h"
#include "engine/capture/capture.h"
#include "engine/core/atomic_file.h"
#include "engine/core/progress.h"
#include "render/validate/validate.h"

namespace reflcap::cli {
namespace fs = std::filesystem;
namespace {

std::string Db(const std::optional<double>& v) {
  if (!v) return "n/a";
  char text[32];
  std::snprintf(text, sizeof text, "%.2f dB", *v);
  return text;
}
std::string Num(const std::optional<double>& v) {
  if (!v) return "n/a";
  char text[32];
  std::snprintf(text, sizeof text, "%.4f", *v);
  return text;
}

}  // namespace

int RunValidate(int argc, char** argv) {
  std::string capture_path, renders, out, split = "holdout", fit, samples;
  validate::ValidateOptions options;
  bool overwrite = false;
  ArgParser args(
      "validate", "CAPTURE RENDERS --out REPORT [--split holdout|train|all] [--fit FIT] [--samples SAMPLES]",
      "Compare re-renders (from reflcap render) with the photographs, on the object mask eroded\n"
      "by 2 px: HDR PSNR (peak = the photograph's max), PSNR-L (LDR: both images over the\n"
      "photograph's 99th percentile, clipped, sRGB), relative RMSE and SSIM on tone-mapped\n"
      "images, raw and with a per-channel least-squares scale (Stanford-ORB), per image, pooled\n"
      "and by region (shadow_edge, high_curvature, grazing, elsewhere), the share of the squared\n"
      "error in the worst 0.1 % and 1 % of pixels and the worst pixels themselves, with the PSNR\n"
      "the capture's noise allows when it is known. Writes REPORT/metrics.json, REPORT/figures/\n"
      "and REPORT/report.html (with the fit's status, model and cluster maps given --fit;\n"
      "definitions in README.md).");
  args.AddPositional("CAPTURE", &capture_path, "capture.json, or the folder holding it");
  args.AddPositional("RENDERS", &renders, "output folder of reflcap render");
  args.AddString("out", &out, "REPORT", "output folder (must not exist or be empty)");
  args.AddString("split", &split, "S", "holdout (default), train or all");
  args.AddString("fit", &fit, "FIT",
                 "fit folder: its fit_report.json and status.exr join the report, and each worst "
                 "pixel names the texel it shows (params.exr's atlas) and its model");
  args.AddString("samples", &samples, "SAMPLES",
                 "sample store: its coverage.png joins the report, and each worst pixel's texel "
                 "its train samples (how many, the brightest)");
  args.AddInt("max-figures", &options.max_figures,
              StrCat("figures at most, evenly spaced over the images (default ",
                     validate::kDefaultMaxFigures, ")"));
  args.AddDouble("error-scale", &options.error_scale,
                 "heat-map range as a fraction of the peak (default 0 = automatic)");
  args.AddInt("threads", &options.threads,
              "threads scoring images and writing figures (default 0: one per hardware thread; "
              "the numbers do not depend on it)");
  args.AddFlag("overwrite", &overwrite, "replace REPORT if it exists (only once the new one is complete)");
  bool help = false;
  if (Status s = args.Parse(argc, argv, 2, &help); !s.ok()) {
    std::fprintf(stderr, "reflcap validate: %s\n", s.message().c_str());
    return kExitUsage;
  }
  if (help) {
    std::printf("%s", args.Help().c_str());
    return 0;
  }
  auto usage = [](const std::string& message) {
    std::fprintf(stderr, "reflcap validate: %s\n", message.c_str());
    return kExitUsage;
  };
  if (out.empty()) return usage("--out REPORT is required");
  auto selection = render::ParseSplitSelection(split, "--split");
  if (!selection.ok()) return usage(selection.status().message());
  options.split = *selection;
  options.fit_dir = fit;
  options.samples_dir = samples;
  if (Status s = options.Validate(); !s.ok()) return usage(s.message());
  auto capture = ReadCapture(capture_path);
  if (!capture.ok()) return ReportError("validate", capture.status());
  std::error_code ec;
  if (!fs::is_directory(renders, ec)) {
    return ReportError("validate", NotFoundError(renders, ": not a folder (the output of reflcap render)"));
  }
  auto staging = StagingDir::Create(out, overwrite);
  if (!staging.ok()) return ReportError("validate", staging.status());
  auto summary = validate::RunValidation(*capture, renders, staging->path(), options);
  if (!summary.ok()) return ReportError("validate", summary.status());
  if (Status s = staging->Commit(); !s.ok()) return ReportError("validate", s);
  const validate::ValidateSummary& r = *summary;
  std::printf("validated %zu %s images (%zu pixels) in %s\n", r.images,
              render::SplitSelectionName(*selection), r.pixels, FormatDuration(r.seconds).c_str());
  std::printf("  raw        PSNR %s  PSNR-L %s  rel. RMSE %s  SSIM %s\n", Db(r.psnr_db).c_str(),
              Db(r.psnr_l_db).c_str(), Num(r.rel_rmse).c_str(), Num(r.ssim).c_str());
  std::printf("  LS-scaled  PSNR %s  PSNR-L %s  rel. RMSE %s  SSIM %s  (per-channel least-squares "
              "scale)\n", Db(r.scaled_psnr_db).c_str(), Db(r.scaled_psnr_l_db).c_str(),
              Num(r.scaled_rel_rmse).c_str(), Num(r.scaled_ssim).c_str());
  std::printf("  worst 0.1 %% of pixels carry %s of the squared error (worst 1 %%: %s)\n",
              Num(r.worst_0_1pct_error_share).c_str(), Num(r.worst_1pct_error_share).c_str());
  if (r.noise_bound_psnr_db) {
    std::printf("  noise bound PSNR %s (what a perfect re-render scores under the capture's noise "
                "model); raw PSNR is %+.2f dB from it\n",
                Db(r.noise_bound_psnr_db).c_str(), r.psnr_db ? *r.psnr_db - *r.noise_bound_psnr_db : 0.0);
  } else {
    std::printf("  noise bound: unknown (the capture has no ground_truth.noise)\n");
  }
  std::printf("report: %s (%zu figures)\n", (fs::path(out) / "report.html").string().c_str(), r.figures);
  return 0;
}

}  // namespace reflcap::cli
