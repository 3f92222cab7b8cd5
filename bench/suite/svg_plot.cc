#include "bench/suite/svg_plot.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <sstream>

#include "engine/core/status.h"

namespace reflcap::benchsuite {
namespace {

// Colour-blind-safe palette (Okabe-Ito), cycled.
constexpr const char* kPalette[] = {"#0072B2", "#D55E00", "#009E73", "#CC79A7",
                                    "#E69F00", "#56B4E9", "#000000", "#F0E442"};
constexpr int kPaletteSize = sizeof(kPalette) / sizeof(kPalette[0]);

// Plot-area margins in pixels: room for tick labels and axis titles (left, bottom), the title
// (top) and the legend (right).
constexpr double kMarginLeft = 78, kMarginRight = 190, kMarginTop = 36, kMarginBottom = 56;

std::string Num(double v) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%.2f", v);
  return buf;
}

// Tick labels: plain for 1e-3 <= |v| < 1e5, else mantissa-e-exponent ("1e6", "2.5e-4").
std::string FormatTick(double v) {
  if (v == 0) return "0";
  const double a = std::abs(v);
  char buf[32];
  if (a >= 1e-3 && a < 1e5) {
    std::snprintf(buf, sizeof(buf), "%.6g", v);
    return buf;
  }
  const int e = int(std::floor(std::log10(a) + 1e-9));
  const double m = v / std::pow(10.0, e);
  std::snprintf(buf, sizeof(buf), "%.3ge%d", m, e);
  return buf;
}

// A 1-2-5 step near range / target.
double NiceStep(double range, int target) {
  const double raw = range / std::max(1, target);
  const double p = std::pow(10.0, std::floor(std::log10(raw)));
  for (double m : {1.0, 2.0, 2.5, 5.0, 10.0}) {
    if (m * p >= raw) return m * p;
  }
  return 10 * p;
}

struct Axis {
  bool log = false;
  double lo = 0, hi = 1;  // in transformed units (log10 for a log axis)
  double T(double v) const { return log ? std::log10(v) : v; }
  // Values (untransformed) at which to draw ticks.
  std::vector<double> Ticks() const {
    std::vector<double> ticks;
    if (!log) {
      const double step = NiceStep(hi - lo, 6);
      for (double t = std::ceil(lo / step - 1e-9) * step; t <= hi + 1e-9 * step; t += step) {
        ticks.push_back(std::abs(t) < step * 1e-9 ? 0.0 : t);
      }
      return ticks;
    }
    const int d0 = int(std::floor(lo)), d1 = int(std::ceil(hi));
    const int every = std::max(1, (d1 - d0 + 7) / 8);  // at most ~8 decade labels
    const bool minor = d1 - d0 <= 2;                  // short ranges also get 2 and 5
    for (int d = d0; d <= d1; ++d) {
      for (double m : {1.0, 2.0, 5.0}) {
        if (m != 1.0 && !minor) continue;
        if (m == 1.0 && (d - d0) % every != 0) continue;
        const double v = m * std::pow(10.0, d);
        const double tv = std::log10(v);
        if (tv >= lo - 1e-9 && tv <= hi + 1e-9) ticks.push_back(v);
      }
    }
    if (ticks.size() < 2) {
      // A range narrower than the gaps between 1, 2 and 5 (e.g. 150..190): evenly spaced
      // values of the untransformed range instead, so the axis still reads.
      ticks.clear();
      const double a = std::pow(10.0, lo), b = std::pow(10.0, hi);
      const double step = NiceStep(b - a, 4);
      for (double t = std::ceil(a / step) * step; t <= b; t += step) ticks.push_back(t);
    }
    return ticks;
  }
};

// The range of the drawable values `v` (already filtered), padded; for no value a default.
Axis MakeAxis(const std::vector<double>& v, bool log) {
  Axis a;
  a.log = log;
  if (v.empty()) {
    a.lo = 0;
    a.hi = 1;
    return a;
  }
  double lo = std::numeric_limits<double>::infinity(), hi = -lo;
  for (double x : v) {
    lo = std::min(lo, a.T(x));
    hi = std::max(hi, a.T(x));
  }
  if (hi - lo < 1e-12 * std::max(1.0, std::abs(hi))) {
    // One distinct value: half a decade (log) or 10 % / 1 unit (linear) either side.
    const double pad = log ? 0.5 : std::max(std::abs(hi) * 0.1, 1.0);
    lo -= pad;
    hi += pad;
  } else {
    const double pad = 0.05 * (hi - lo);
    lo -= pad;
    hi += pad;
  }
  a.lo = lo;
  a.hi = hi;
  return a;
}

}  // namespace

std::string XmlEscape(const std::string& text) {
  std::string out;
  out.reserve(text.size());
  for (char c : text) {
    switch (c) {
      case '&': out += "&amp;"; break;
      case '<': out += "&lt;"; break;
      case '>': out += "&gt;"; break;
      case '"': out += "&quot;"; break;
      case '\'': out += "&apos;"; break;
      default:
        // Control characters are not allowed in XML 1.0 (except tab/newline): drop them.
        if (static_cast<unsigned char>(c) >= 0x20 || c == '\t' || c == '\n') out += c;
    }
  }
  return out;
}

PlotOutput RenderSvgPlot(const Plot& plot) {
  PlotOutput result;
  const double width = std::max(plot.width, 200), height = std::max(plot.height, 150);

  // Which points can be drawn: finite, and positive on a log axis.
  std::vector<std::vector<bool>> drawable(plot.series.size());
  std::vector<double> xs, ys;
  for (size_t s = 0; s < plot.series.size(); ++s) {
    const PlotSeries& series = plot.series[s];
    const size_t n = std::min(series.x.size(), series.y.size());
    if (series.x.size() != series.y.size()) {
      result.notes.push_back(StrCat("series '", series.name, "': ", series.x.size(), " x but ",
                                    series.y.size(), " y values; extra values ignored"));
    }
    size_t non_finite = 0, non_positive_x = 0, non_positive_y = 0;
    drawable[s].assign(n, false);
    for (size_t i = 0; i < n; ++i) {
      const double x = series.x[i], y = series.y[i];
      if (!std::isfinite(x) || !std::isfinite(y)) {
        ++non_finite;
      } else if (plot.log_x && x <= 0) {
        ++non_positive_x;
      } else if (plot.log_y && y <= 0) {
        ++non_positive_y;
      } else {
        drawable[s][i] = true;
        xs.push_back(x);
        ys.push_back(y);
      }
    }
    if (non_finite > 0) {
      result.notes.push_back(StrCat("series '", series.name, "': ", non_finite,
                                    " points with a non-finite value skipped"));
    }
    if (non_positive_x > 0) {
      result.notes.push_back(StrCat("series '", series.name, "': ", non_positive_x,
                                    " points with x <= 0 skipped (log x axis)"));
    }
    if (non_positive_y > 0) {
      result.notes.push_back(StrCat("series '", series.name, "': ", non_positive_y,
                                    " points with y <= 0 skipped (log y axis)"));
    }
  }
  const Axis ax = MakeAxis(xs, plot.log_x), ay = MakeAxis(ys, plot.log_y);
  const double x0 = kMarginLeft, x1 = width - kMarginRight;
  const double y0 = height - kMarginBottom, y1 = kMarginTop;  // y grows downwards
  auto px = [&](double v) { return x0 + (ax.T(v) - ax.lo) / (ax.hi - ax.lo) * (x1 - x0); };
  auto py = [&](double v) { return y0 + (ay.T(v) - ay.lo) / (ay.hi - ay.lo) * (y1 - y0); };

  std::ostringstream svg;
  svg << "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"
      << "<svg xmlns=\"http://www.w3.org/2000/svg\" version=\"1.1\" width=\"" << width
      << "\" height=\"" << height << "\" viewBox=\"0 0 " << width << " " << height
      << "\" font-family=\"sans-serif\" font-size=\"12\">\n"
      << "<title>" << XmlEscape(plot.title) << "</title>\n"
      << "<rect x=\"0\" y=\"0\" width=\"" << width << "\" height=\"" << height
      << "\" fill=\"#ffffff\"/>\n"
      << "<text x=\"" << Num(width / 2) << "\" y=\"22\" text-anchor=\"middle\" font-size=\"15\">"
      << XmlEscape(plot.title) << "</text>\n";

  // Grid, ticks and tick labels.
  svg << "<g stroke=\"#dddddd\" stroke-width=\"1\">\n";
  const std::vector<double> xticks = ax.Ticks(), yticks = ay.Ticks();
  for (double t : xticks) {
    svg << "<line x1=\"" << Num(px(t)) << "\" y1=\"" << Num(y0) << "\" x2=\"" << Num(px(t))
        << "\" y2=\"" << Num(y1) << "\"/>\n";
  }
  for (double t : yticks) {
    svg << "<line x1=\"" << Num(x0) << "\" y1=\"" << Num(py(t)) << "\" x2=\"" << Num(x1)
        << "\" y2=\"" << Num(py(t)) << "\"/>\n";
  }
  svg << "</g>\n<g fill=\"#333333\">\n";
  for (double t : xticks) {
    svg << "<text x=\"" << Num(px(t)) << "\" y=\"" << Num(y0 + 16)
        << "\" text-anchor=\"middle\">" << XmlEscape(FormatTick(t)) << "</text>\n";
  }
  for (double t : yticks) {
    svg << "<text x=\"" << Num(x0 - 6) << "\" y=\"" << Num(py(t) + 4)
        << "\" text-anchor=\"end\">" << XmlEscape(FormatTick(t)) << "</text>\n";
  }
  svg << "</g>\n";
  svg << "<rect x=\"" << Num(x0) << "\" y=\"" << Num(y1) << "\" width=\"" << Num(x1 - x0)
      << "\" height=\"" << Num(y0 - y1) << "\" fill=\"none\" stroke=\"#333333\"/>\n";
  svg << "<text x=\"" << Num((x0 + x1) / 2) << "\" y=\"" << Num(height - 14)
      << "\" text-anchor=\"middle\">"
      << XmlEscape(plot.x_label + (plot.log_x ? " (log scale)" : "")) << "</text>\n";
  svg << "<text transform=\"translate(16," << Num((y0 + y1) / 2)
      << ") rotate(-90)\" text-anchor=\"middle\">"
      << XmlEscape(plot.y_label + (plot.log_y ? " (log scale)" : "")) << "</text>\n";
  if (xs.empty()) {
    svg << "<text x=\"" << Num((x0 + x1) / 2) << "\" y=\"" << Num((y0 + y1) / 2)
        << "\" text-anchor=\"middle\" fill=\"#999999\" font-size=\"16\">no data</text>\n";
  }

  // Series: polyline, then markers (each with a tooltip), then highlight rings.
  bool any_highlight = false;
  for (size_t s = 0; s < plot.series.size(); ++s) {
    const PlotSeries& series = plot.series[s];
    const char* colour = kPalette[s % kPaletteSize];
    svg << "<g>\n";
    if (series.lines) {
      std::ostringstream points;
      int count = 0;
      for (size_t i = 0; i < drawable[s].size(); ++i) {
        if (!drawable[s][i]) continue;
        points << (count++ ? " " : "") << Num(px(series.x[i])) << "," << Num(py(series.y[i]));
      }
      if (count >= 2) {
        svg << "<polyline fill=\"none\" stroke=\"" << colour << "\" stroke-width=\"1.8\" points=\""
            << points.str() << "\"/>\n";
      }
    }
    if (series.connect_highlights) {
      std::vector<std::pair<double, double>> front;
      for (size_t i = 0; i < drawable[s].size() && i < series.highlight.size(); ++i) {
        if (drawable[s][i] && series.highlight[i]) front.emplace_back(px(series.x[i]), py(series.y[i]));
      }
      std::sort(front.begin(), front.end());
      if (front.size() >= 2) {
        svg << "<polyline fill=\"none\" stroke=\"" << colour
            << "\" stroke-width=\"1.5\" stroke-dasharray=\"5,3\" points=\"";
        for (size_t i = 0; i < front.size(); ++i) {
          svg << (i ? " " : "") << Num(front[i].first) << "," << Num(front[i].second);
        }
        svg << "\"/>\n";
      }
    }
    for (size_t i = 0; i < drawable[s].size(); ++i) {
      if (!drawable[s][i]) continue;
      svg << "<circle cx=\"" << Num(px(series.x[i])) << "\" cy=\"" << Num(py(series.y[i]))
          << "\" r=\"3.5\" fill=\"" << colour << "\"><title>"
          << XmlEscape(StrCat(series.name, ": (", FormatTick(series.x[i]), ", ",
                              FormatTick(series.y[i]), ")"))
          << "</title></circle>\n";
      if (i < series.highlight.size() && series.highlight[i]) {
        any_highlight = true;
        svg << "<circle cx=\"" << Num(px(series.x[i])) << "\" cy=\"" << Num(py(series.y[i]))
            << "\" r=\"7\" fill=\"none\" stroke=\"#000000\" stroke-width=\"1.5\"/>\n";
      }
    }
    svg << "</g>\n";
  }

  // Legend, right of the plot area.
  double ly = y1 + 8;
  const double lx = x1 + 14;
  for (size_t s = 0; s < plot.series.size(); ++s) {
    const char* colour = kPalette[s % kPaletteSize];
    svg << "<line x1=\"" << Num(lx) << "\" y1=\"" << Num(ly) << "\" x2=\"" << Num(lx + 22)
        << "\" y2=\"" << Num(ly) << "\" stroke=\"" << colour << "\" stroke-width=\"1.8\"/>\n"
        << "<circle cx=\"" << Num(lx + 11) << "\" cy=\"" << Num(ly) << "\" r=\"3.5\" fill=\""
        << colour << "\"/>\n"
        << "<text x=\"" << Num(lx + 28) << "\" y=\"" << Num(ly + 4) << "\">"
        << XmlEscape(plot.series[s].name) << "</text>\n";
    ly += 18;
  }
  if (any_highlight && !plot.highlight_label.empty()) {
    svg << "<circle cx=\"" << Num(lx + 11) << "\" cy=\"" << Num(ly)
        << "\" r=\"7\" fill=\"none\" stroke=\"#000000\" stroke-width=\"1.5\"/>\n"
        << "<text x=\"" << Num(lx + 28) << "\" y=\"" << Num(ly + 4) << "\">"
        << XmlEscape(plot.highlight_label) << "</text>\n";
  }
  svg << "</svg>\n";
  result.svg = svg.str();
  return result;
}

}  // namespace reflcap::benchsuite
