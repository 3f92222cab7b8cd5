#pragma once
// A small, dependency-free SVG line/scatter plot writer for the benchmark reports: axes with
// ticks and labels, linear or log10 scales, one polyline and marker set per series, highlighted
// points (e.g. a Pareto front) and a legend. The output is a self-contained SVG 1.1 document
// (no scripts, fonts or external references) that any browser shows.
//
// Points that cannot be drawn are skipped, never clamped into view, and each skip is reported
// in PlotOutput::notes ("series 'cpu': 2 points with y <= 0 skipped (log axis)"), so a plot
// never shows a value that is not in the data. An empty plot still draws its frame and says
// "no data".
#include <string>
#include <vector>

namespace reflcap::benchsuite {

struct PlotSeries {
  std::string name;                // legend entry
  std::vector<double> x, y;        // same length
  std::vector<bool> highlight;     // empty, or one flag per point: drawn with a ring
  bool lines = true;               // join the points (in the given order) with a polyline
  bool connect_highlights = false; // join the highlighted points, in x order, with a dashed line
};

struct Plot {
  std::string title, x_label, y_label;
  bool log_x = false, log_y = false;
  std::vector<PlotSeries> series;
  std::string highlight_label;  // legend text for highlighted points ("Pareto front"); "" = none
  int width = 720, height = 440;  // pixels, >= 200 x 150
};

struct PlotOutput {
  std::string svg;
  std::vector<std::string> notes;  // points skipped and why
};

PlotOutput RenderSvgPlot(const Plot& plot);

// "&amp;", "&lt;", ... for text and attribute values.
std::string XmlEscape(const std::string& text);

}  // namespace reflcap::benchsuite
