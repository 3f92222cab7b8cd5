// `reflcap hdr BRACKETS.json --out CAPTURE`: exposure brackets (brackets/1) -> a white-balanced
// linear HDR capture/1 with per-pixel variance (acquire/radiometry/hdr.h).
#include <cstdio>
#include <sstream>

#include "cli/cli.h"
#include "acquire/radiometry/hdr.h"
#include "engine/core/atomic_file.h"
#include "engine/core/progress.h"

namespace reflcap::cli {

namespace {

std::vector<std::string> SplitList(const std::string& text) {
  std::vector<std::string> out;
  std::stringstream in(text);
  std::string item;
  while (std::getline(in, item, ',')) {
    if (!item.empty()) out.push_back(item);
  }
  return out;
}

}  // namespace

int RunHdr(int argc, char** argv) {
  std::string brackets, out, holdout_lights;
  radiometry::HdrOptions options;
  bool overwrite = false, no_chart = false, no_anchor = false, declared_only = false;
  double patch_mm = 0, gap_mm = 0;
  ArgParser args(
      "hdr", "BRACKETS.json --out CAPTURE [options]",
      "Merge exposure brackets (brackets/1: 8-bit PNGs at several exposure times per view) into a\n"
      "capture/1 of linear HDR photographs: estimate the camera's inverse response and noise per\n"
      "channel (Debevec-Malik and parametric families, chosen by fit; the ColorChecker photo's\n"
      "pixels anchor it), merge each bracket with inverse-variance weights, white-balance with the\n"
      "ColorChecker (found by OpenCV mcc; gains, optionally a 3x3 matrix) and write images/*.exr\n"
      "(radiance, exposure_s = 1), variance/*.exr, capture.json (images[].saturation and\n"
      "images[].variance) and radiometry/report.{json,html}. When the brackets carry ground truth,\n"
      "the accuracy of the response, the merge and the gains is reported.");
  args.AddPositional("BRACKETS", &brackets, "brackets.json (or its folder)");
  args.AddString("out", &out, "CAPTURE", "output folder (must not exist or be empty)");
  args.AddString("response", &options.response.model, "MODEL",
                 "auto (default: the simplest family that fits, else Debevec), debevec, gamma, "
                 "offsetgamma, loglogistic, logpolynomial or polynomial");
  args.AddDouble("smoothness", &options.response.smoothness,
                 "Debevec smoothness, relative to the mean data weight per code (default 1)");
  args.AddInt("samples-per-bin", &options.response.samples_per_bin,
              "pixels sampled per value bin and channel (default 2000)");
  args.AddFlag("no-chart", &no_chart, "no white balance: the capture stays in camera RGB");
  args.AddFlag("no-chart-anchor", &no_anchor,
               "estimate the response from the object photos alone (the chart still white-balances)");
  args.AddFlag("chart-declared", &declared_only,
               "skip OpenCV mcc: seed the chart from the corners its geometry file declares");
  args.AddFlag("colour-matrix", &options.colour_matrix,
               "apply the chart's 3x3 colour matrix instead of per-channel gains");
  args.AddString("holdout-lights", &holdout_lights, "ID,ID",
                 "object photos lit by these lights become holdout (others keep their split)");
  args.AddString("mesh", &options.mesh, "FILE", "the object's mesh (default: the source capture's)");
  args.AddString("weight-map-photo", &options.weight_map_photo, "ID",
                 "photo whose merge weights the report shows (default: the first object photo)");
  args.AddDouble("chart-patch-mm", &patch_mm, "chart patch size in mm (default: declared, else 40)");
  args.AddDouble("chart-gap-mm", &gap_mm, "chart gap between patches in mm (default: declared, else 6)");
  args.AddInt("threads", &options.threads, "worker threads (default: all cores)");
  args.AddFlag("overwrite", &overwrite, "replace CAPTURE if it exists (only once the new one is complete)");
  bool help = false;
  if (Status s = args.Parse(argc, argv, 2, &help); !s.ok()) {
    std::fprintf(stderr, "reflcap hdr: %s\n", s.message().c_str());
    return kExitUsage;
  }
  if (help) {
    std::printf("%s", args.Help().c_str());
    return 0;
  }
  if (out.empty()) {
    std::fprintf(stderr, "reflcap hdr: --out CAPTURE is required\n");
    return kExitUsage;
  }
  options.use_chart = !no_chart;
  options.anchor_response = !no_anchor;
  options.chart_mcc = !declared_only;
  options.holdout_lights = SplitList(holdout_lights);
  if (patch_mm != 0 || gap_mm != 0) {
    if (patch_mm != 0) options.layout.patch_m = patch_mm / 1000;
    if (gap_mm != 0) options.layout.gap_m = gap_mm / 1000;
    options.layout_given = true;
  }
  if (Status s = options.Validate(); !s.ok()) {
    std::fprintf(stderr, "reflcap hdr: %s\n", s.message().c_str());
    return kExitUsage;
  }
  auto staging = StagingDir::Create(out, overwrite);
  if (!staging.ok()) return ReportError("hdr", staging.status());
  auto summary = radiometry::RunHdrPipeline(brackets, staging->path(), options);
  if (!summary.ok()) return ReportError("hdr", summary.status());
  if (Status s = staging->Commit(); !s.ok()) return ReportError("hdr", s);
  const radiometry::HdrSummary& r = *summary;
  std::printf("merged %zu photos (train %zu, holdout %zu) in %s; response %s, read noise %.2g/%.2g/%.2g "
              "of the clip level\n",
              r.object_photos, r.train, r.holdout, FormatDuration(r.seconds).c_str(), r.response_model.c_str(),
              r.read_sigma[0], r.read_sigma[1], r.read_sigma[2]);
  if (r.chart_method != "none") {
    std::printf("chart: found by %s; gains %.5f %.5f %.5f; mean dE00 %.2f before, %.2f after\n",
                r.chart_method.c_str(), r.gains[0], r.gains[1], r.gains[2], r.mean_delta_e_before,
                r.mean_delta_e_after);
  } else {
    std::printf("chart: none (--no-chart): camera RGB, no white balance\n");
  }
  if (r.response_max_log_error >= 0) {
    std::printf("vs truth: response max |log error| %.4f (median %.4f) over codes 20-235", r.response_max_log_error,
                r.response_median_log_error);
    if (r.hdr_median_rel_error >= 0) {
      std::printf("; HDR relative error median %.4f, p95 %.4f", r.hdr_median_rel_error, r.hdr_p95_rel_error);
    }
    if (r.gains_max_rel_error >= 0) {
      std::printf("; gains max relative error %.4f (green-normalised %.4f)", r.gains_max_rel_error,
                  r.gains_max_rel_error_green_normalised);
    }
    std::printf("\n");
  }
  std::printf("capture: %s/capture.json\nreport: %s/radiometry/report.html\n", out.c_str(), out.c_str());
  return 0;
}

}  // namespace reflcap::cli
