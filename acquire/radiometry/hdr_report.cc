// HTML/SVG/PNG side of the `reflcap hdr` report (see hdr_report.h).
#include "acquire/radiometry/hdr_report.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <sstream>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "engine/core/atomic_file.h"
#include "engine/core/html.h"
#include "engine/image/png_io.h"

namespace reflcap::radiometry {
namespace fs = std::filesystem;
using Json = nlohmann::json;

namespace {

// The chart drawing is upscaled so that patch numbers stay legible on small photographs.
constexpr int kChartDrawScale = 3;

std::string Num(double v, int digits = 4) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.*g", digits, v);
  return buf;
}

std::string NumJ(const Json& j, int digits = 4) { return j.is_number() ? Num(j.get<double>(), digits) : "–"; }

// Blue (short) -> cyan -> green -> yellow -> red (long).
Vec3d Palette(double t) {
  static const Vec3d stops[5] = {{0.15, 0.25, 1.0}, {0.0, 0.85, 0.95}, {0.1, 0.85, 0.1},
                                 {0.95, 0.85, 0.0}, {1.0, 0.15, 0.1}};
  t = std::clamp(t, 0.0, 1.0) * 4;
  const int i = std::min(3, int(t));
  const double f = t - i;
  return (1 - f) * stops[i] + f * stops[i + 1];
}

Image WeightMap(const MergedBracket& m) {
  const int E = m.weight_share.channels;
  Image out(m.weight_share.width, m.weight_share.height, 3);
  for (size_t p = 0; p < out.PixelCount(); ++p) {
    Vec3d colour = Vec3d::Zero();
    double total = 0;
    for (int e = 0; e < E; ++e) {
      const double s = m.weight_share.data[p * size_t(E) + size_t(e)];
      colour += s * Palette(E > 1 ? double(e) / (E - 1) : 0.5);
      total += s;
    }
    for (int c = 0; c < 3; ++c) out.data[p * 3 + size_t(c)] = float(total > 0 ? colour[c] : 0);
  }
  return out;
}

cv::Mat ToneMapRgb(const Image& hdr) {
  std::vector<double> lum;
  for (size_t p = 0; p < hdr.PixelCount(); ++p) {
    const float* v = &hdr.data[p * 3];
    lum.push_back(0.2126 * v[0] + 0.7152 * v[1] + 0.0722 * v[2]);
  }
  std::vector<double> sorted = lum;
  const size_t k = std::min(sorted.size() - 1, size_t(0.99 * double(sorted.size())));
  std::nth_element(sorted.begin(), sorted.begin() + long(k), sorted.end());
  const double white = std::max(sorted[k], 1e-30);
  cv::Mat out(hdr.height, hdr.width, CV_8UC3);
  for (int y = 0; y < hdr.height; ++y) {
    for (int x = 0; x < hdr.width; ++x) {
      const float* v = hdr.pixel(x, y);
      for (int c = 0; c < 3; ++c) {
        out.at<cv::Vec3b>(y, x)[c] =
            uint8_t(std::lround(255 * std::pow(std::clamp(double(v[c]) / white, 0.0, 1.0), 1 / 2.2)));
      }
    }
  }
  return out;
}

Image ChartDrawing(const MergedBracket& chart, const ChartDetection& d) {
  cv::Mat rgb = ToneMapRgb(chart.value);
  const int s = kChartDrawScale;
  cv::resize(rgb, rgb, cv::Size(), s, s, cv::INTER_NEAREST);
  auto pt = [&](const Vec2d& p) { return cv::Point(int(std::lround((p.x() + 0.5) * s - 0.5)),
                                                   int(std::lround((p.y() + 0.5) * s - 0.5))); };
  if (d.mcc_box.size() == 4) {
    std::vector<cv::Point> box;
    for (const Vec2d& p : d.mcc_box) box.push_back(pt(p));
    cv::polylines(rgb, box, true, cv::Scalar(255, 40, 40), 1, cv::LINE_AA);
  }
  for (int i = 0; i < kChartPatches; ++i) {
    std::vector<cv::Point> quad;
    Vec2d centre = Vec2d::Zero();
    for (const Vec2d& p : d.corners_px[size_t(i)]) {
      quad.push_back(pt(p));
      centre += 0.25 * p;
    }
    cv::polylines(rgb, quad, true, cv::Scalar(40, 255, 40), 1, cv::LINE_AA);
    const std::string label = std::to_string(i + 1);
    const cv::Point at = pt(centre) + cv::Point(-6 * int(label.size()), 6);
    cv::putText(rgb, label, at, cv::FONT_HERSHEY_SIMPLEX, 0.5, cv::Scalar(0, 0, 0), 3, cv::LINE_AA);
    cv::putText(rgb, label, at, cv::FONT_HERSHEY_SIMPLEX, 0.5, cv::Scalar(255, 255, 255), 1, cv::LINE_AA);
  }
  Image out(rgb.cols, rgb.rows, 3);
  for (int y = 0; y < rgb.rows; ++y) {
    for (int x = 0; x < rgb.cols; ++x) {
      for (int c = 0; c < 3; ++c) out.at(x, y, c) = rgb.at<cv::Vec3b>(y, x)[c] / 255.0f;
    }
  }
  return out;
}

std::string Table(const std::vector<std::string>& header, const std::vector<std::vector<std::string>>& rows) {
  std::ostringstream o;
  o << "<table><tr>";
  for (const auto& h : header) o << "<th>" << HtmlEscape(h) << "</th>";
  o << "</tr>\n";
  for (const auto& r : rows) {
    o << "<tr>";
    for (const auto& c : r) o << "<td>" << c << "</td>";
    o << "</tr>\n";
  }
  o << "</table>\n";
  return o.str();
}

}  // namespace

std::string ResponseSvg(const InverseResponse& response, const std::vector<double>* truth) {
  const int W = 720, H1 = 300, H2 = 160, L = 60, R = 20, T = 20, gap = 40;
  const double y_min = std::floor(std::min({response.log_x[0][1], response.log_x[1][1], response.log_x[2][1]}));
  double err_max = 0.02;
  if (truth) {
    for (int c = 0; c < 3; ++c) {
      for (int z = 20; z <= 235; ++z) {
        if ((*truth)[size_t(z)] > 0) {
          err_max = std::max(err_max, std::abs(response.log_x[size_t(c)][size_t(z)] - std::log((*truth)[size_t(z)])));
        }
      }
    }
    err_max = std::min(err_max * 1.1, 1.0);
  }
  auto X = [&](double z) { return L + (W - L - R) * z / 255.0; };
  auto Y1 = [&](double v) { return T + H1 * (0 - v) / (0 - y_min); };
  const double top2 = T + H1 + gap;
  auto Y2 = [&](double e) { return top2 + H2 * 0.5 * (1 - e / err_max); };
  const char* colours[3] = {"#d62728", "#2ca02c", "#1f77b4"};
  std::ostringstream o;
  o << "<svg xmlns='http://www.w3.org/2000/svg' width='" << W << "' height='" << top2 + H2 + 40
    << "' font-family='sans-serif' font-size='11'>\n";
  o << "<rect x='" << L << "' y='" << T << "' width='" << W - L - R << "' height='" << H1
    << "' fill='none' stroke='#888'/>\n";
  o << "<rect x='" << L << "' y='" << top2 << "' width='" << W - L - R << "' height='" << H2
    << "' fill='none' stroke='#888'/>\n";
  for (int z = 0; z <= 255; z += 32) {
    o << "<text x='" << X(z) << "' y='" << top2 + H2 + 14 << "' text-anchor='middle'>" << z << "</text>\n";
  }
  o << "<text x='" << (L + W - R) / 2 << "' y='" << top2 + H2 + 30 << "' text-anchor='middle'>code</text>\n";
  for (double v = y_min; v <= 0.001; v += 1) {
    o << "<text x='" << L - 4 << "' y='" << Y1(v) + 4 << "' text-anchor='end'>" << Num(v, 3) << "</text>\n";
    o << "<line x1='" << L << "' x2='" << W - R << "' y1='" << Y1(v) << "' y2='" << Y1(v) << "' stroke='#eee'/>\n";
  }
  o << "<text x='14' y='" << T + H1 / 2 << "' transform='rotate(-90 14 " << T + H1 / 2
    << ")' text-anchor='middle'>ln x (x = raw / clip)</text>\n";
  for (double e : {-err_max, -err_max / 2, 0.0, err_max / 2, err_max}) {
    o << "<text x='" << L - 4 << "' y='" << Y2(e) + 4 << "' text-anchor='end'>" << Num(e, 2) << "</text>\n";
    o << "<line x1='" << L << "' x2='" << W - R << "' y1='" << Y2(e) << "' y2='" << Y2(e) << "' stroke='#eee'/>\n";
  }
  o << "<text x='14' y='" << top2 + H2 / 2 << "' transform='rotate(-90 14 " << top2 + H2 / 2
    << ")' text-anchor='middle'>" << (truth ? "ln x − ln x_true" : "—") << "</text>\n";
  // Target band of the accuracy goal (codes 20–235, ±0.01).
  if (truth) {
    o << "<rect x='" << X(20) << "' y='" << Y2(0.01) << "' width='" << X(235) - X(20) << "' height='"
      << Y2(-0.01) - Y2(0.01) << "' fill='#f3f3d0'/>\n";
  }
  for (int c = 0; c < 3; ++c) {
    o << "<polyline fill='none' stroke='" << colours[c] << "' stroke-width='1.2' points='";
    for (int z = 1; z <= 255; ++z) o << X(z) << "," << Y1(response.log_x[size_t(c)][size_t(z)]) << " ";
    o << "'/>\n";
    if (truth) {
      o << "<polyline fill='none' stroke='" << colours[c] << "' stroke-width='1' points='";
      for (int z = 1; z <= 254; ++z) {
        if ((*truth)[size_t(z)] > 0) {
          const double e = std::clamp(response.log_x[size_t(c)][size_t(z)] - std::log((*truth)[size_t(z)]),
                                      -err_max, err_max);
          o << X(z) << "," << Y2(e) << " ";
        }
      }
      o << "'/>\n";
    }
  }
  if (truth) {
    o << "<polyline fill='none' stroke='black' stroke-dasharray='4,3' stroke-width='1' points='";
    for (int z = 1; z <= 255; ++z) {
      if ((*truth)[size_t(z)] > 0) o << X(z) << "," << Y1(std::log((*truth)[size_t(z)])) << " ";
    }
    o << "'/>\n";
  }
  o << "<text x='" << L + 10 << "' y='" << T + 16 << "'>" << HtmlEscape(response.model)
    << (truth ? " (R, G, B; truth dashed; lower panel: error, shaded ±0.01 over codes 20–235)" : " (R, G, B)")
    << "</text>\n";
  o << "</svg>\n";
  return o.str();
}

Status WriteHdrReport(const fs::path& dir, const Json& report, const ReportImages& images) {
  std::ostringstream o;
  o << "<!DOCTYPE html><html><head><meta charset='utf-8'><title>reflcap hdr report</title><style>"
       "body{font-family:sans-serif;max-width:1000px;margin:2em auto;color:#222}"
       "table{border-collapse:collapse;margin:.5em 0}td,th{border:1px solid #ccc;padding:2px 6px;"
       "font-size:13px;text-align:right}th{background:#f4f4f4}img{image-rendering:pixelated}"
       ".good{color:#080}.bad{color:#b00}</style></head><body>\n";
  o << "<h1>reflcap hdr</h1><p>Brackets: <code>" << HtmlEscape(report.value("brackets", "")) << "</code></p>\n";
  const Json& photos = report["photos"];
  o << "<p>" << photos.value("object", 0) << " object photos (train " << photos.value("train", 0)
    << ", holdout " << photos.value("holdout", 0) << "), chart photo: "
    << HtmlEscape(photos.value("chart", std::string("none"))) << ".</p>\n";

  const Json& r = report["response"];
  o << "<h2>Camera response</h2><p>Chosen model: <b>" << HtmlEscape(r.value("model", "")) << "</b>";
  if (r.contains("model_without_chart")) {
    o << " (without the chart's anchors: " << HtmlEscape(r["model_without_chart"].get<std::string>()) << ")";
  }
  o << ". Reduced χ² per channel: " << NumJ(r["reduced_chi2"][0]) << ", " << NumJ(r["reduced_chi2"][1]) << ", "
    << NumJ(r["reduced_chi2"][2]) << " (≈ 1 when the noise model describes the data). Noise (raw units, clip = 1): ";
  for (int c = 0; c < 3; ++c) {
    o << "RGB"[c] << " read σ " << NumJ(r["noise"][c]["read_sigma"], 3) << ", photon "
      << NumJ(r["noise"][c]["photon_gain"], 3) << (c < 2 ? "; " : ".");
  }
  o << "</p>\n";
  if (images.response) o << ResponseSvg(*images.response, images.truth_x_of_code);
  if (r.contains("truth")) {
    const double e = r["truth"]["max_abs_log_error"].get<double>();
    o << "<p>Against the true inverse response (codes 20–235, per-channel scale removed): max |log error| <b class='"
      << (e <= 0.01 ? "good" : "bad") << "'>" << Num(e, 3) << "</b>, median "
      << NumJ(r["truth"]["median_abs_log_error"], 3) << "; without the chart's anchors "
      << NumJ(r["truth"]["max_abs_log_error_without_chart"], 3) << ".</p>\n";
  }
  std::vector<std::vector<std::string>> rows;
  for (const Json& m : r["candidates"]) {
    rows.push_back({HtmlEscape(m["model"].get<std::string>()) + (m["chosen"].get<bool>() ? " ✔" : ""),
                    std::to_string(m["parameters"].get<int>()), NumJ(m["chi2"], 7), NumJ(m["bic"], 7),
                    m["monotone"].get<bool>() ? "yes" : "no",
                    m.contains("truth_max_abs_log_error") ? NumJ(m["truth_max_abs_log_error"], 3) : "–"});
  }
  o << "<p>Candidates: the simplest family within 1 % of the best family's χ² is used when its χ² is within "
       "5 % of the free-form (Debevec) curve's, else the free-form curve (response.h). BIC = χ² + k ln n "
       "for reference:</p>"
    << Table({"model", "parameters / channel", "χ²", "BIC", "monotone", "max |log error| vs truth"}, rows);

  const Json& m = report["merge"];
  o << "<h2>Merge</h2><p>" << m.value("pixel_channels_measured", size_t(0)) << " pixel-channels measured, "
    << m.value("pixel_channels_dark", size_t(0)) << " dark (code 0 in every exposure), "
    << m.value("pixel_channels_clipped", size_t(0)) << " clipped in every exposure (written at the saturation level "
    << NumJ(m["saturation"], 6) << ").</p>\n";
  if (m.contains("truth")) {
    o << "<p>Against <code>source_hdr</code>: median relative error <b>" << NumJ(m["truth"]["median_rel_error"], 3)
      << "</b>, p95 <b>" << NumJ(m["truth"]["p95_rel_error"], 3) << "</b>, p99 " << NumJ(m["truth"]["p99_rel_error"], 3)
      << " over " << m["truth"]["pixel_channels"].get<size_t>() << " pixel-channels ("
      << HtmlEscape(m["truth"]["definition"].get<std::string>()) << ").</p>\n";
  }
  if (images.weights) {
    REFLCAP_RETURN_IF_ERROR(WritePng(dir / "weights.png", WeightMap(*images.weights)));
    const int E = images.weights->weight_share.channels;
    o << "<p>Weight map of photo <code>" << HtmlEscape(m.value("weight_map_photo", "")) << "</code>: each pixel coloured "
      << "by the share of its merge weight (green channel) each exposure carries:";
    for (int e = 0; e < E; ++e) {
      const Vec3d c = Palette(E > 1 ? double(e) / (E - 1) : 0.5);
      char hex[16];
      std::snprintf(hex, sizeof hex, "#%02x%02x%02x", int(255 * c[0]), int(255 * c[1]), int(255 * c[2]));
      o << " <span style='background:" << hex << "'>&nbsp;e" << e << "&nbsp;</span>";
    }
    o << " (black: not measured).</p><img src='weights.png' width='" << 2 * images.weights->weight_share.width
      << "'>\n";
  }

  const Json& ch = report["chart"];
  o << "<h2>Colour chart</h2>";
  if (ch.value("method", "none") == "none") {
    o << "<p>No chart used (--no-chart): the capture is in camera RGB.</p>";
  } else {
    o << "<p>Found by <b>" << HtmlEscape(ch["method"].get<std::string>()) << "</b> (" << HtmlEscape(ch.value("seed", ""))
      << "); " << ch["edges_refined"].get<int>() << " of 96 patch edges refined, PnP reprojection RMS "
      << NumJ(ch["reprojection_rms_px"], 3) << " px, colour residual " << NumJ(ch["colour_residual"], 3) << ".";
    if (ch.contains("pose_vs_declared")) {
      o << " Pose against the declared one: " << NumJ(ch["pose_vs_declared"]["normal_deg"], 3) << "° normal, "
        << NumJ(ch["pose_vs_declared"]["translation_m"], 3) << " m.";
    }
    o << "</p>\n";
    if (images.chart && images.detection) {
      REFLCAP_RETURN_IF_ERROR(WritePng(dir / "chart_detection.png", ChartDrawing(*images.chart, *images.detection)));
      o << "<img src='chart_detection.png' width='" << images.chart->value.width * kChartDrawScale << "'>\n";
    }
    o << "<p>Gains (camera = gains · true): " << NumJ(ch["gains"][0], 6) << ", " << NumJ(ch["gains"][1], 6) << ", "
      << NumJ(ch["gains"][2], 6) << "; green-normalised " << NumJ(ch["gains_green_normalised"][0], 6) << ", 1, "
      << NumJ(ch["gains_green_normalised"][2], 6) << ". Applied: "
      << (ch["matrix_applied"].get<bool>() ? "the 3×3 matrix" : "the gains") << ".";
    if (ch.contains("truth")) {
      o << " True gains " << NumJ(ch["truth"]["gains"][0], 6) << ", " << NumJ(ch["truth"]["gains"][1], 6) << ", "
        << NumJ(ch["truth"]["gains"][2], 6) << ": max relative error " << NumJ(ch["truth"]["max_relative_error"], 3)
        << " (green-normalised " << NumJ(ch["truth"]["max_relative_error_green_normalised"], 3) << ").";
    }
    o << "</p>\n";
    rows.clear();
    for (const Json& p : ch["patches"]) {
      rows.push_back({std::to_string(p["index"].get<int>()), HtmlEscape(p["name"].get<std::string>()),
                      std::to_string(p["pixels"].get<int>()), NumJ(p["delta_e00_before"], 3),
                      NumJ(p["delta_e00_gains"], 3), NumJ(p["delta_e00_matrix"], 3)});
    }
    rows.push_back({"", "mean", "", NumJ(ch["mean_delta_e00_before"], 3), NumJ(ch["mean_delta_e00_gains"], 3),
                    NumJ(ch["mean_delta_e00_matrix"], 3)});
    o << "<p>ΔE00 per patch (albedo in CIELAB, D65):</p>"
      << Table({"#", "patch", "pixels", "before", "after gains", "after matrix"}, rows);
  }
  o << "<h2>Timings</h2><pre>" << HtmlEscape(report["timings_s"].dump(2)) << "</pre>\n</body></html>\n";
  return WriteTextFileAtomic(dir / "report.html", o.str());
}

}  // namespace reflcap::radiometry
