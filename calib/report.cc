#include "calib/report.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <sstream>

#include <opencv2/imgproc.hpp>

#include "engine/capture/json_fields.h"
#include "calib/report_json.h"
#include "engine/core/atomic_file.h"
#include "engine/core/html.h"
#include "engine/image/png_io.h"

namespace reflcap::calib {
namespace fs = std::filesystem;
using jsonio::Json;

namespace {

// Residual vectors are drawn magnified so that the 95th percentile is this long (pixels).
constexpr double kVectorP95Px = 20;
// Residual photos are cropped to the corners and enlarged to about this size (pixels).
constexpr double kCropPx = 900;
constexpr char kAdjustedColour[] = "#d62728";
constexpr char kBaselineColour[] = "#1f77b4";

std::string Fmt(double v, int digits = 3) {
  // No "-0.000": a value that rounds to zero prints as zero.
  if (std::abs(v) < 0.5 * std::pow(10.0, -digits)) v = 0;
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.*f", digits, v);
  return buf;
}

// A "nice" axis maximum >= v (1, 2, 5 x 10^k).
double NiceMax(double v) {
  if (!(v > 0)) return 1;
  const double e = std::pow(10.0, std::floor(std::log10(v)));
  for (double m : {1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0}) {
    if (m * e >= v) return m * e;
  }
  return 10 * e;
}

struct Series {
  std::string name;
  std::string colour;
  std::vector<double> values;
};

constexpr int kPlotW = 560, kPlotH = 260, kMarginL = 56, kMarginR = 12, kMarginT = 28, kMarginB = 46;

std::string SvgOpen(const std::string& title) {
  std::ostringstream o;
  o << "<svg xmlns='http://www.w3.org/2000/svg' width='" << kPlotW << "' height='" << kPlotH
    << "' font-family='sans-serif' font-size='11'><rect width='100%' height='100%' fill='white'/>"
    << "<text x='" << kPlotW / 2 << "' y='16' text-anchor='middle' font-size='13'>" << HtmlEscape(title) << "</text>";
  return o.str();
}

// Y axis with 5 ticks from 0 to y_max; returns the y pixel of a value.
std::string YAxis(double y_max, const std::string& label) {
  std::ostringstream o;
  const int h = kPlotH - kMarginT - kMarginB;
  for (int i = 0; i <= 5; ++i) {
    const double v = y_max * i / 5;
    const int y = kPlotH - kMarginB - h * i / 5;
    o << "<line x1='" << kMarginL << "' x2='" << kPlotW - kMarginR << "' y1='" << y << "' y2='" << y
      << "' stroke='#ddd'/><text x='" << kMarginL - 4 << "' y='" << y + 4 << "' text-anchor='end'>"
      << Fmt(v, y_max >= 50 ? 0 : y_max < 0.1 ? 3 : 2) << "</text>";
  }
  o << "<text transform='translate(12," << (kMarginT + h / 2) << ") rotate(-90)' text-anchor='middle'>"
    << HtmlEscape(label) << "</text>";
  return o.str();
}

std::string BarChart(const std::string& title, const std::string& y_label, const std::vector<std::string>& labels,
                     const std::vector<Series>& series) {
  double mx = 0;
  for (const Series& s : series) {
    for (double v : s.values) mx = std::max(mx, v);
  }
  const double y_max = NiceMax(mx);
  std::ostringstream o;
  o << SvgOpen(title) << YAxis(y_max, y_label);
  const int w = kPlotW - kMarginL - kMarginR, h = kPlotH - kMarginT - kMarginB;
  const double group = double(w) / std::max<size_t>(1, labels.size());
  const double bar = group * 0.8 / std::max<size_t>(1, series.size());
  for (size_t g = 0; g < labels.size(); ++g) {
    for (size_t s = 0; s < series.size(); ++s) {
      if (g >= series[s].values.size()) continue;
      const double v = series[s].values[g];
      const double bh = h * v / y_max;
      const double x = kMarginL + g * group + group * 0.1 + s * bar;
      o << "<rect x='" << Fmt(x, 1) << "' y='" << Fmt(kPlotH - kMarginB - bh, 1) << "' width='" << Fmt(bar, 1)
        << "' height='" << Fmt(bh, 1) << "' fill='" << series[s].colour << "'><title>" << HtmlEscape(series[s].name)
        << " " << HtmlEscape(labels[g]) << ": " << Fmt(v, 4) << "</title></rect>";
    }
    o << "<text x='" << Fmt(kMarginL + (g + 0.5) * group, 1) << "' y='" << kPlotH - kMarginB + 14
      << "' text-anchor='middle'>" << HtmlEscape(labels[g]) << "</text>";
  }
  int lx = kMarginL + 8;
  for (const Series& s : series) {
    o << "<rect x='" << lx << "' y='" << kPlotH - 18 << "' width='10' height='10' fill='" << s.colour
      << "'/><text x='" << lx + 14 << "' y='" << kPlotH - 9 << "'>" << HtmlEscape(s.name) << "</text>";
    lx += 20 + 7 * int(s.name.size());
  }
  o << "</svg>";
  return o.str();
}

std::string Histogram(const std::string& title, const std::string& x_label, const std::vector<double>& values,
                      int bins) {
  double mx = 0;
  for (double v : values) mx = std::max(mx, v);
  const double x_max = NiceMax(mx);
  std::vector<int> count(bins, 0);
  for (double v : values) count[std::min(bins - 1, int(v / x_max * bins))]++;
  const double c_max = NiceMax(std::max(1, *std::max_element(count.begin(), count.end())));
  std::ostringstream o;
  o << SvgOpen(title) << YAxis(c_max, "corners");
  const int w = kPlotW - kMarginL - kMarginR, h = kPlotH - kMarginT - kMarginB;
  const double y_scale = double(h) / c_max;
  for (int b = 0; b < bins; ++b) {
    const double bh = count[b] * y_scale;
    o << "<rect x='" << Fmt(kMarginL + double(w) * b / bins, 1) << "' y='" << Fmt(kPlotH - kMarginB - bh, 1)
      << "' width='" << Fmt(double(w) / bins - 1, 1) << "' height='" << Fmt(bh, 1) << "' fill='" << kAdjustedColour
      << "'/>";
  }
  for (int i = 0; i <= 5; ++i) {
    o << "<text x='" << Fmt(kMarginL + double(w) * i / 5, 1) << "' y='" << kPlotH - kMarginB + 14
      << "' text-anchor='middle'>" << Fmt(x_max * i / 5, 3) << "</text>";
  }
  o << "<text x='" << kMarginL + w / 2 << "' y='" << kPlotH - 8 << "' text-anchor='middle'>" << HtmlEscape(x_label)
    << "</text></svg>";
  return o.str();
}

// Residual components (dx, dy) of every corner, both axes symmetric.
std::string Scatter(const std::string& title, const std::vector<Vec2d>& pts) {
  double mx = 0;
  for (const Vec2d& p : pts) mx = std::max({mx, std::abs(p.x()), std::abs(p.y())});
  const double r = NiceMax(mx);
  const int size = kPlotH - kMarginT - kMarginB;
  const int x0 = (kPlotW - size) / 2, y0 = kMarginT;
  std::ostringstream o;
  o << SvgOpen(title) << "<rect x='" << x0 << "' y='" << y0 << "' width='" << size << "' height='" << size
    << "' fill='none' stroke='#999'/><line x1='" << x0 + size / 2 << "' x2='" << x0 + size / 2 << "' y1='" << y0
    << "' y2='" << y0 + size << "' stroke='#ddd'/><line x1='" << x0 << "' x2='" << x0 + size << "' y1='"
    << y0 + size / 2 << "' y2='" << y0 + size / 2 << "' stroke='#ddd'/>";
  for (const Vec2d& p : pts) {
    o << "<circle cx='" << Fmt(x0 + size * (0.5 + 0.5 * p.x() / r), 1) << "' cy='"
      << Fmt(y0 + size * (0.5 + 0.5 * p.y() / r), 1) << "' r='1' fill='" << kAdjustedColour << "' fill-opacity='0.4'/>";
  }
  o << "<text x='" << x0 + size + 6 << "' y='" << y0 + size / 2 + 4 << "'>dx ±" << Fmt(r, 3) << " px</text>"
    << "<text x='" << x0 + size / 2 << "' y='" << y0 + size + 16 << "' text-anchor='middle'>dy ±" << Fmt(r, 3)
    << " px</text></svg>";
  return o.str();
}

// The frame with every used corner (intrinsics coverage) and the 8x8 cells holding one.
std::string FramePlot(const std::string& title, int width, int height, const std::vector<Vec2d>& pts) {
  const int size = kPlotH - kMarginT - kMarginB + 20;
  const double s = double(size) / std::max(width, height);
  const int x0 = (kPlotW - int(width * s)) / 2, y0 = kMarginT;
  std::vector<uint8_t> cells(64, 0);
  for (const Vec2d& p : pts) {
    cells[std::clamp(int(p.y() / height * 8), 0, 7) * 8 + std::clamp(int(p.x() / width * 8), 0, 7)] = 1;
  }
  std::ostringstream o;
  o << SvgOpen(title);
  for (int c = 0; c < 64; ++c) {
    o << "<rect x='" << Fmt(x0 + (c % 8) * width * s / 8, 1) << "' y='" << Fmt(y0 + (c / 8) * height * s / 8, 1)
      << "' width='" << Fmt(width * s / 8, 1) << "' height='" << Fmt(height * s / 8, 1) << "' fill='"
      << (cells[c] ? "#e6f2e6" : "#f6e0e0") << "' stroke='#ccc'/>";
  }
  for (const Vec2d& p : pts) {
    o << "<circle cx='" << Fmt(x0 + p.x() * s, 1) << "' cy='" << Fmt(y0 + p.y() * s, 1) << "' r='0.8' fill='#333'/>";
  }
  o << "</svg>";
  return o.str();
}

// Draws a photo with its corners and residual vectors (magnified by `scale`) and writes a PNG.
struct DrawnVectors {
  std::vector<Vec2d> corners, residuals, baseline;
};

// The photo is cropped to the corners (plus a margin) and enlarged so that the vectors can be seen.
Status WriteResidualPng(const fs::path& photo, const DrawnVectors& v, double scale, const fs::path& out) {
  auto grey = LoadGrey(photo);
  if (!grey.ok()) return grey.status();
  cv::Mat full(grey->height, grey->width, CV_8U);
  for (int y = 0; y < grey->height; ++y) {
    for (int x = 0; x < grey->width; ++x) {
      // Dimmed so that the vectors stand out.
      full.at<uint8_t>(y, x) = uint8_t(std::clamp(std::lround(grey->at(x, y) * 170.0 + 40.0), 0L, 255L));
    }
  }
  double x0 = grey->width, y0 = grey->height, x1 = 0, y1 = 0;
  for (const Vec2d& c : v.corners) {
    x0 = std::min(x0, c.x());
    y0 = std::min(y0, c.y());
    x1 = std::max(x1, c.x());
    y1 = std::max(y1, c.y());
  }
  const int margin = 24;
  const cv::Rect roi = cv::Rect(int(x0) - margin, int(y0) - margin, int(x1 - x0) + 2 * margin,
                                int(y1 - y0) + 2 * margin) & cv::Rect(0, 0, grey->width, grey->height);
  if (roi.width <= 0 || roi.height <= 0) return OkStatus();
  // Enlarged up to 4x: beyond, pixels only become bigger blocks.
  const double up = std::clamp(kCropPx / std::max(roi.width, roi.height), 1.0, 4.0);
  cv::Mat crop, img;
  cv::resize(full(roi), crop, cv::Size(), up, up, cv::INTER_CUBIC);
  cv::cvtColor(crop, img, cv::COLOR_GRAY2BGR);
  // Pixel centres at integers: crop pixel (x, y) covers photo (roi.x + (x + 0.5) / up - 0.5, ...).
  auto pt = [&](const Vec2d& p) {
    const double x = (p.x() - roi.x + 0.5) * up - 0.5, y = (p.y() - roi.y + 0.5) * up - 0.5;
    return cv::Point(int(std::lround(x * 16)), int(std::lround(y * 16)));
  };
  const double s = scale / up;  // vectors are scaled in displayed pixels
  for (size_t k = 0; k < v.corners.size(); ++k) {
    const Vec2d& c = v.corners[k];
    cv::circle(img, pt(c), 3 * 16, cv::Scalar(60, 160, 60), 1, cv::LINE_AA, 4);
    if (k < v.baseline.size()) {
      cv::line(img, pt(c), pt(c + s * v.baseline[k]), cv::Scalar(180, 119, 31), 2, cv::LINE_AA, 4);
    }
    cv::line(img, pt(c), pt(c + s * v.residuals[k]), cv::Scalar(40, 39, 214), 2, cv::LINE_AA, 4);
  }
  Image out_img(img.cols, img.rows, 3);
  for (int y = 0; y < img.rows; ++y) {
    for (int x = 0; x < img.cols; ++x) {
      const cv::Vec3b p = img.at<cv::Vec3b>(y, x);
      out_img.at(x, y, 0) = p[2] / 255.0f;
      out_img.at(x, y, 1) = p[1] / 255.0f;
      out_img.at(x, y, 2) = p[0] / 255.0f;
    }
  }
  return WritePng(out, out_img);
}

double VectorScale(const std::vector<double>& lengths) {
  if (lengths.empty()) return 1;
  std::vector<double> l = lengths;
  std::nth_element(l.begin(), l.begin() + l.size() * 95 / 100, l.end());
  const double p95 = l[l.size() * 95 / 100];
  // Round to 1, 2 or 5 x 10^k so that the legend reads plainly.
  return p95 > 0 ? NiceMax(kVectorP95Px / p95) / 2 : 100;
}

const char* kStyle =
    "<style>body{font-family:sans-serif;margin:24px;max-width:1200px}table{border-collapse:collapse;"
    "margin:8px 0 18px}td,th{border:1px solid #ccc;padding:3px 8px;text-align:right}th{background:#f0f0f0}"
    "td.l,th.l{text-align:left}h2{margin-top:28px}.plots svg{margin:4px}.note{color:#555}"
    "img{max-width:48%;margin:4px;border:1px solid #ccc}</style>";

std::string Row(const std::vector<std::string>& cells, bool header = false) {
  std::string o = "<tr>";
  for (size_t i = 0; i < cells.size(); ++i) {
    const std::string tag = header ? "th" : "td";
    o += "<" + tag + (i == 0 ? " class='l'" : "") + ">" + cells[i] + "</" + tag + ">";
  }
  return o + "</tr>";
}

}  // namespace

Status WriteTurntableReport(const CalibFile& file, const TurntableResult& r, const TurntableOptions& options,
                            const std::string& intrinsics_note, const fs::path& dir) {
  const Json report = internal::TurntableReportJson(file, r, options, intrinsics_note);
  REFLCAP_RETURN_IF_ERROR(WriteTextFileAtomic(dir / "report.json", report.dump(2) + "\n"));

  // Residual photos: per camera, its photo with the most used corners.
  std::vector<std::string> images_html;
  std::vector<double> lengths;
  for (const FaceView& v : r.views) {
    if (!v.used) continue;
    for (size_t k = 0; k < v.valid.size(); ++k) {
      if (v.valid[k]) lengths.push_back(v.residuals[k].norm());
    }
  }
  const double scale = VectorScale(lengths);
  for (size_t c = 0; c < file.cameras.size(); ++c) {
    std::map<int, int> corners_of_photo;
    for (const FaceView& v : r.views) {
      if (v.used && file.images[v.image].camera == int(c)) corners_of_photo[v.image] += v.corners_used;
    }
    if (corners_of_photo.empty()) continue;
    const int photo = std::max_element(corners_of_photo.begin(), corners_of_photo.end(),
                                       [](const auto& a, const auto& b) { return a.second < b.second; })->first;
    DrawnVectors dv;
    for (const FaceView& v : r.views) {
      if (!v.used || v.image != photo) continue;
      for (size_t k = 0; k < v.valid.size(); ++k) {
        if (!v.valid[k]) continue;
        dv.corners.push_back(v.corners[k]);
        dv.residuals.push_back(v.residuals[k]);
        dv.baseline.push_back(v.baseline_residuals[k]);
      }
    }
    const std::string png = StrCat("residuals_", file.cameras[c].id, ".png");
    REFLCAP_RETURN_IF_ERROR(WriteResidualPng(file.Resolve(file.images[photo].file), dv, scale, dir / png));
    images_html.push_back(StrCat("<figure style='display:inline-block;width:48%;margin:4px'><img src='", png,
                                 "' style='max-width:100%'><figcaption>", HtmlEscape(file.images[photo].file),
                                 "</figcaption></figure>"));
  }

  std::ostringstream h;
  h << "<!DOCTYPE html><html><head><meta charset='utf-8'><title>reflcap calibrate turntable</title>" << kStyle
    << "</head><body><h1>Turntable calibration</h1><p class='note'>" << HtmlEscape(file.json_path.string())
    << " &mdash; intrinsics: " << HtmlEscape(intrinsics_note) << "; detection " << Fmt(r.detect_s, 1)
    << " s, adjustment " << Fmt(r.solve_s, 1) << " s</p>";
  int used = 0;
  for (const FaceView& v : r.views) used += v.used;
  int empty_photos = 0;
  for (const ImageResult& im : r.images) empty_photos += im.status == "no board found";
  h << "<h2>Reprojection</h2><table>" << Row({"", "bundle adjustment", "baseline (averaged poses)"}, true)
    << Row({"RMS (px)", Fmt(r.total.rms_px, 4), Fmt(r.baseline_total.rms_px, 4)})
    << Row({"max (px)", Fmt(r.total.max_px, 3), "&nbsp;"})
    << Row({"corners", std::to_string(r.total.corners), std::to_string(r.baseline_total.corners)})
    << Row({"face views used", StrCat(used, " of ", r.views.size()), ""})
    << Row({"photos without any board", std::to_string(empty_photos), ""});
  if (r.board_total.corners > 0) {
    h << Row({"board photos: RMS (px), corners", StrCat(Fmt(r.board_total.rms_px, 4), ", ", r.board_total.corners), ""});
  }
  h << "</table>";
  auto add = [](const TruthComparison* c, auto get, int digits) { return c ? Fmt(get(*c), digits) : std::string("-"); };
  if (r.truth) {
    const TruthComparison* a = &*r.truth;
    const TruthComparison* b = &*r.baseline_truth;
    h << "<h2>Against ground truth</h2><p class='note'>Gauge-free: axis and point in camera 0's frame, cameras "
         "relative to camera 0, the cuboid's pose in every photo.</p><table>"
      << Row({"", "bundle adjustment", "baseline"}, true)
      << Row({"axis direction (deg)", add(a, [](auto& c) { return c.axis_deg; }, 5), add(b, [](auto& c) { return c.axis_deg; }, 5)})
      << Row({"axis point (mm)", add(a, [](auto& c) { return c.point_mm; }, 4), add(b, [](auto& c) { return c.point_mm; }, 4)})
      << Row({"camera rotation, max (deg)", add(a, [](auto& c) { return c.max_camera_rotation_deg; }, 5),
              add(b, [](auto& c) { return c.max_camera_rotation_deg; }, 5)})
      << Row({"camera centre, max (mm)", add(a, [](auto& c) { return c.max_camera_centre_mm; }, 4),
              add(b, [](auto& c) { return c.max_camera_centre_mm; }, 4)})
      << Row({"cuboid rotation per photo, median / max (deg)",
              Fmt(a->box_rotation_median_deg, 4) + " / " + Fmt(a->box_rotation_max_deg, 4),
              Fmt(b->box_rotation_median_deg, 4) + " / " + Fmt(b->box_rotation_max_deg, 4)})
      << Row({"cuboid translation per photo, median / max (mm)",
              Fmt(a->box_translation_median_mm, 4) + " / " + Fmt(a->box_translation_max_mm, 4),
              Fmt(b->box_translation_median_mm, 4) + " / " + Fmt(b->box_translation_max_mm, 4)});
    for (size_t i = 0; i < a->intrinsics_error.size() && options.refine_intrinsics; ++i) {
      const auto& e = a->intrinsics_error[i];
      h << Row({StrCat(HtmlEscape(file.cameras[i].id), ": fx, fy, cx, cy error (px)"),
                Fmt(e[kFx], 2) + ", " + Fmt(e[kFy], 2) + ", " + Fmt(e[kCx], 2) + ", " + Fmt(e[kCy], 2), ""});
    }
    h << "</table>";
  }
  h << "<h2>Cameras</h2><table>"
    << Row({"camera", "centre (world, m)", "RMS (px)", "max (px)", "baseline RMS", "corners", "&sigma; rotation (deg)",
            "&sigma; centre (mm)", "fx", "fy", "cx", "cy"}, true);
  for (size_t c = 0; c < file.cameras.size(); ++c) {
    const Vec3d centre = r.rig.cam_from_world[c].Inverse().translation;
    const IntrinsicParams& p = r.rig.intrinsics[c];
    auto with_sigma = [&](int k) {
      return options.refine_intrinsics ? Fmt(p[k], 2) + " &plusmn; " + Fmt(r.sigma.intrinsics[c][k], 2) : Fmt(p[k], 2);
    };
    h << Row({HtmlEscape(file.cameras[c].id),
              Fmt(centre.x(), 4) + ", " + Fmt(centre.y(), 4) + ", " + Fmt(centre.z(), 4),
              Fmt(r.per_camera[c].rms_px, 4), Fmt(r.per_camera[c].max_px, 3), Fmt(r.baseline_per_camera[c].rms_px, 4),
              std::to_string(r.per_camera[c].corners), Fmt(r.sigma.camera_rotation_deg[c].norm(), 5),
              Fmt(r.sigma.camera_centre_mm[c].norm(), 4), with_sigma(kFx), with_sigma(kFy), with_sigma(kCx),
              with_sigma(kCy)});
  }
  h << "</table><p class='note'>Sigmas relative to camera " << HtmlEscape(file.cameras[0].id)
    << " (the adjustment's gauge).</p>";
  const Vec3d axis_cam0 = r.rig.cam_from_world[0].rotation * r.rig.axis;
  h << "<h2>Turntable and cuboid</h2><table>" << Row({"", "value", "&sigma;"}, true)
    << Row({StrCat("axis in camera ", HtmlEscape(file.cameras[0].id), "'s frame"),
            Fmt(axis_cam0.x(), 6) + ", " + Fmt(axis_cam0.y(), 6) + ", " + Fmt(axis_cam0.z(), 6), ""})
    << Row({"axis (world)", Fmt(r.rig.axis.x(), 6) + ", " + Fmt(r.rig.axis.y(), 6) + ", " + Fmt(r.rig.axis.z(), 6),
            Fmt(r.sigma.axis_deg, 5) + " deg"})
    << Row({"axis point (world, m)", Fmt(r.rig.point.x(), 5) + ", " + Fmt(r.rig.point.y(), 5) + ", " + Fmt(r.rig.point.z(), 5),
            Fmt(r.sigma.point_mm, 4) + " mm"})
    << Row({"cuboid at 0: translation (m)",
            Fmt(r.rig.world_from_box0.translation.x(), 5) + ", " + Fmt(r.rig.world_from_box0.translation.y(), 5) +
                ", " + Fmt(r.rig.world_from_box0.translation.z(), 5),
            Fmt(r.sigma.box_translation_mm.norm(), 4) + " mm"});
  if (options.angle_offsets) {
    for (size_t a = 0; a < file.angles_deg.size(); ++a) {
      h << Row({StrCat("offset at ", file.angles_deg[a], " deg (deg)"), Fmt(r.rig.angle_offset_deg[a], 4),
                Fmt(r.sigma.angle_offset_deg[a], 4)});
    }
  }
  h << "</table>";

  std::vector<std::string> cam_labels, angle_labels, face_labels;
  Series cam_a{"adjusted", kAdjustedColour, {}}, cam_b{"baseline", kBaselineColour, {}};
  for (size_t c = 0; c < file.cameras.size(); ++c) {
    cam_labels.push_back(file.cameras[c].id);
    cam_a.values.push_back(r.per_camera[c].rms_px);
    cam_b.values.push_back(r.baseline_per_camera[c].rms_px);
  }
  Series ang{"adjusted", kAdjustedColour, {}}, fac{"adjusted", kAdjustedColour, {}};
  for (size_t a = 0; a < file.angles_deg.size(); ++a) {
    angle_labels.push_back(Fmt(file.angles_deg[a], 0));
    ang.values.push_back(r.per_angle[a].rms_px);
  }
  for (size_t f = 0; f < file.faces.size(); ++f) {
    face_labels.push_back(file.faces[f].name);
    fac.values.push_back(r.per_face[f].rms_px);
  }
  std::vector<Vec2d> all;
  std::vector<double> norms;
  for (const FaceView& v : r.views) {
    if (!v.used) continue;
    for (size_t k = 0; k < v.valid.size(); ++k) {
      if (!v.valid[k]) continue;
      all.push_back(v.residuals[k]);
      norms.push_back(v.residuals[k].norm());
    }
  }
  h << "<h2>Per turntable angle and face</h2><table>" << Row({"", "RMS (px)", "max (px)", "corners"}, true);
  for (size_t a = 0; a < file.angles_deg.size(); ++a) {
    h << Row({StrCat(file.angles_deg[a], " deg"), Fmt(r.per_angle[a].rms_px, 4), Fmt(r.per_angle[a].max_px, 3),
              std::to_string(r.per_angle[a].corners)});
  }
  for (size_t f = 0; f < file.faces.size(); ++f) {
    h << Row({"face " + HtmlEscape(file.faces[f].name), Fmt(r.per_face[f].rms_px, 4), Fmt(r.per_face[f].max_px, 3),
              std::to_string(r.per_face[f].corners)});
  }
  h << "</table>";
  h << "<h2>Plots</h2><div class='plots'>"
    << BarChart("RMS reprojection per camera", "px", cam_labels, {cam_a, cam_b})
    << BarChart("RMS reprojection per turntable angle (deg)", "px", angle_labels, {ang})
    << BarChart("RMS reprojection per face", "px", face_labels, {fac})
    << Histogram("Residual length, all corners", "px", norms, 30) << Scatter("Residuals (dx, dy)", all) << "</div>";
  h << "<h2>Residuals on the photos</h2><p class='note'>Green circles: detected corners; red: adjusted residual; "
       "blue: the baseline's; vectors magnified &times;"
    << Fmt(scale, 0) << ".</p>";
  for (const std::string& s : images_html) h << s;

  h << "<h2>Not used</h2><table>" << Row({"photo", "face", "why"}, true);
  for (const FaceView& v : r.views) {
    if (v.used && v.corners_rejected == 0) continue;
    h << Row({HtmlEscape(file.images[v.image].file), HtmlEscape(file.faces[v.face].name),
              v.used ? StrCat(v.corners_rejected, " corner(s) rejected as outliers") : HtmlEscape(v.status)});
  }
  for (const ImageResult& im : r.images) {
    for (const std::string& why : im.refused) h << Row({HtmlEscape(im.file), "", "refused: " + HtmlEscape(why)});
    if (im.status == "no board found") h << Row({HtmlEscape(im.file), "", "no board found"});
  }
  for (const BoardViewResult& v : r.board_views) {
    if (v.used) continue;
    h << Row({HtmlEscape(v.file), "board", HtmlEscape(v.status)});
  }
  h << "</table><p class='note'>Every number: report.json.</p></body></html>\n";
  return WriteTextFileAtomic(dir / "index.html", h.str());
}

Status WriteIntrinsicsReport(const CalibFile& file, const IntrinsicsResult& r, const IntrinsicsOptions& options,
                             const fs::path& dir) {
  REFLCAP_RETURN_IF_ERROR(WriteTextFileAtomic(dir / "report.json", IntrinsicsToJson(file, r, options)));
  std::ostringstream h;
  h << "<!DOCTYPE html><html><head><meta charset='utf-8'><title>reflcap calibrate intrinsics</title>" << kStyle
    << "</head><body><h1>Camera intrinsics</h1><p class='note'>" << HtmlEscape(file.json_path.string())
    << " &mdash; estimated: " << HtmlEscape(options.model.ToString()) << "; detection " << Fmt(r.detect_s, 1)
    << " s, adjustment " << Fmt(r.solve_s, 1) << " s</p><table>"
    << Row({"camera", "fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "RMS (px)", "views", "coverage"}, true);
  for (const IntrinsicsCameraResult& c : r.cameras) {
    std::vector<std::string> row = {HtmlEscape(c.intrinsics.id)};
    for (int k = 0; k < kIntrinsicCount; ++k) {
      const int digits = k < kK1 ? 2 : 5;
      row.push_back(Fmt(c.intrinsics.params[k], digits) + " &plusmn; " + Fmt(c.intrinsics.sigma[k], digits));
    }
    row.push_back(Fmt(c.rms_px, 4));
    row.push_back(StrCat(c.views_used, " of ", c.views_found, " found"));
    row.push_back(StrCat(Fmt(100 * c.coverage_cells, 0), "% cells, ", Fmt(100 * c.coverage_hull, 0), "% hull"));
    h << Row(row);
    if (c.error) {
      std::vector<std::string> e = {"&nbsp;&nbsp;error vs truth"};
      for (int k = 0; k < kIntrinsicCount; ++k) e.push_back(Fmt((*c.error)[k], k < kK1 ? 2 : 5));
      e.insert(e.end(), {"", "", ""});
      h << Row(e);
    }
  }
  h << "</table>";
  std::vector<double> lengths;
  for (const BoardViewResult& v : r.views) {
    for (size_t k = 0; v.used && k < v.valid.size(); ++k) {
      if (v.valid[k]) lengths.push_back(v.residuals[k].norm());
    }
  }
  const double scale = VectorScale(lengths);
  for (const IntrinsicsCameraResult& c : r.cameras) {
    const int cam = file.FindCamera(c.intrinsics.id);
    std::vector<std::string> labels;
    Series rms{"view RMS", kAdjustedColour, {}};
    std::vector<Vec2d> pts;
    const BoardViewResult* best = nullptr;
    for (const BoardViewResult& v : r.views) {
      if (v.camera != cam || !v.used) continue;
      labels.push_back(fs::path(v.file).stem().string());
      rms.values.push_back(v.rms_px);
      for (size_t k = 0; k < v.valid.size(); ++k) {
        if (v.valid[k]) pts.push_back(v.corners[k]);
      }
      if (best == nullptr || v.corners_used > best->corners_used) best = &v;
    }
    h << "<h2>" << HtmlEscape(c.intrinsics.id) << "</h2><div class='plots'>"
      << BarChart("Reprojection RMS per view", "px", labels, {rms})
      << FramePlot(StrCat("Coverage: ", Fmt(100 * c.coverage_cells, 0), "% of 8x8 cells, radius ",
                          Fmt(100 * c.coverage_radius, 0), "% of the half diagonal"),
                   c.intrinsics.width, c.intrinsics.height, pts)
      << "</div>";
    if (best != nullptr) {
      DrawnVectors dv;
      for (size_t k = 0; k < best->valid.size(); ++k) {
        if (!best->valid[k]) continue;
        dv.corners.push_back(best->corners[k]);
        dv.residuals.push_back(best->residuals[k]);
      }
      const std::string png = StrCat("residuals_", c.intrinsics.id, ".png");
      REFLCAP_RETURN_IF_ERROR(WriteResidualPng(file.Resolve(best->file), dv, scale, dir / png));
      h << "<figure><img src='" << png << "'><figcaption>" << HtmlEscape(best->file) << ": residuals &times;"
        << Fmt(scale, 0) << "</figcaption></figure>";
    }
  }
  h << "<h2>Views not used</h2><table>" << Row({"photo", "why"}, true);
  for (const BoardViewResult& v : r.views) {
    if (!v.used) h << Row({HtmlEscape(v.file), HtmlEscape(v.status)});
  }
  h << "</table><p class='note'>Every number: report.json.</p></body></html>\n";
  return WriteTextFileAtomic(dir / "index.html", h.str());
}

}  // namespace reflcap::calib
