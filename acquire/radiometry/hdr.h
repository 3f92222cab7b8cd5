#pragma once
// `reflcap hdr`: exposure brackets (brackets/1) -> a white-balanced linear HDR capture (capture/1).
//
// Steps: (1) read and check every bracket (sizes, 8-bit codes, not all clipped, not all black);
// (2) sample pixels of the object photos and estimate the inverse response and the sensor noise
// (response.h); (3) merge the ColorChecker photograph, detect the chart and its pose (chart.h),
// and re-estimate the response with the chart's pixels anchored at their known relative radiance
// (which removes the ambiguity of brackets whose exposures are powers of one ratio); (4) gains
// (and optionally a 3×3 matrix) from the chart; (5) merge every object photo with noise-following
// weights, apply the colour correction and write the capture: images/<id>.exr (float RGB
// radiance, exposure_s = 1), variance/<id>.exr (float RGB, the variance of each value),
// capture.json (images[].saturation: the level at which the resampler must treat a pixel as
// clipped; images[].variance: the variance image; a "radiometry" block), the geometry of the
// source capture (mesh and silhouette masks copied), and radiometry/ (report.json, report.html,
// response.json, the chart's merged HDR, the weight map and the chart detection images).
//
// Saturation: a channel clipped in every exposure has no measurement; such a pixel is written
// with every channel equal to images[].saturation, a level no measured value reaches (the
// correction applied to the largest unclipped value of the shortest exposure, plus one part in
// 10⁶), so the resampler's "clipped" test (any channel >= saturation) drops it.
#include <filesystem>
#include <string>
#include <vector>

#include "acquire/radiometry/brackets.h"
#include "acquire/radiometry/chart.h"
#include "acquire/radiometry/response.h"
#include "engine/core/status.h"

namespace reflcap::radiometry {

struct HdrOptions {
  ResponseOptions response;
  ChartLayout layout;         // used when the chart geometry declares none
  bool layout_given = false;  // layout set on the command line: overrides a declared one
  bool use_chart = true;      // false: no white balance (camera RGB, gains 1)
  bool anchor_response = true;  // chart pixels anchor the response (see response.h)
  bool colour_matrix = false;   // apply the 3×3 matrix instead of the per-channel gains
  bool chart_mcc = true;        // false: skip mcc, seed the chart from its declared corners
  std::vector<std::string> holdout_lights;  // object photos lit by these become holdout
  std::string mesh;             // mesh file overriding the source capture's geometry ("" = none)
  std::string weight_map_photo; // photo id for the report's weight map ("" = first object photo)
  int threads = 0;              // 0 = all cores
  Status Validate() const;
};

// What was done and measured (the report's numbers).
struct HdrSummary {
  size_t object_photos = 0, train = 0, holdout = 0;
  std::string response_model;
  std::array<double, 3> read_sigma{};
  std::string chart_method;  // "mcc", "declared" or "none"
  Vec3d gains = Vec3d::Ones();
  double mean_delta_e_before = 0, mean_delta_e_after = 0;
  // Against ground truth, when the brackets carry it (negative = not available).
  double response_max_log_error = -1, response_median_log_error = -1;
  double hdr_median_rel_error = -1, hdr_p95_rel_error = -1;
  double gains_max_rel_error = -1, gains_max_rel_error_green_normalised = -1;
  double seconds = 0;
  std::string report_json;  // the report, as written to radiometry/report.json
};

// Reads `brackets_json` and writes the capture into `out_dir` (an empty folder the caller stages).
// Errors name the brackets file and the field (InvalidArgument, NotFound, FailedPrecondition).
StatusOr<HdrSummary> RunHdrPipeline(const std::filesystem::path& brackets_json,
                                    const std::filesystem::path& out_dir, const HdrOptions& options);

}  // namespace reflcap::radiometry
