#pragma once
// The human-readable side of `reflcap hdr`'s report: radiometry/report.html (self-contained but
// for its two PNGs), with the recovered response against the truth (inline SVG), the merge's
// weight map for one photo (weights.png: each pixel coloured by the exposures that carry its
// weight, blue = shortest ... red = longest), the chart detection drawn on the tone-mapped chart
// photograph (chart_detection.png: refined patch outlines in green with their numbers, mcc's
// outline in red), the gains and the ΔE00 table.
#include <filesystem>
#include <vector>

#include <nlohmann/json.hpp>

#include "acquire/radiometry/chart.h"
#include "acquire/radiometry/merge.h"
#include "acquire/radiometry/response.h"
#include "engine/core/status.h"

namespace reflcap::radiometry {

struct ReportImages {
  const MergedBracket* weights = nullptr;   // merged with keep_weights
  const MergedBracket* chart = nullptr;     // the merged chart photograph
  const ChartDetection* detection = nullptr;
  const InverseResponse* response = nullptr;
  const std::vector<double>* truth_x_of_code = nullptr;
};

// Writes report.html, weights.png and chart_detection.png into `dir` (atomically, each).
Status WriteHdrReport(const std::filesystem::path& dir, const nlohmann::json& report,
                      const ReportImages& images);

// The SVG plot of ln x(code) per channel (and the truth, dashed) over its error panel.
std::string ResponseSvg(const InverseResponse& response, const std::vector<double>* truth);

}  // namespace reflcap::radiometry
