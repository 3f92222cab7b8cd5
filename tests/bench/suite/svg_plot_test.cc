// The SVG plot writer: well-formed, self-contained output for the edge cases a benchmark run
// produces (one point, no point, values a log axis cannot show, names that need escaping).
#include "bench/suite/svg_plot.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <string>
#include <vector>

namespace reflcap::benchsuite {
namespace {

// A small XML well-formedness check: balanced, properly nested elements; quoted attributes;
// no raw '<' or unescaped '&' in text; one root element; nothing but whitespace after it.
::testing::AssertionResult IsWellFormedXml(const std::string& xml) {
  std::vector<std::string> stack;
  size_t i = 0;
  bool root_seen = false;
  auto fail = [&](const std::string& what) {
    return ::testing::AssertionFailure() << what << " at offset " << i << ": "
                                         << xml.substr(i, 60);
  };
  while (i < xml.size()) {
    if (xml[i] != '<') {
      if (xml[i] == '&') {
        const size_t semi = xml.find(';', i);
        const std::string entity = semi == std::string::npos ? "" : xml.substr(i, semi - i + 1);
        if (entity != "&amp;" && entity != "&lt;" && entity != "&gt;" && entity != "&quot;" &&
            entity != "&apos;") {
          return fail("bad entity");
        }
      }
      if (stack.empty() && root_seen && !std::isspace(static_cast<unsigned char>(xml[i]))) {
        return fail("text after the root element");
      }
      ++i;
      continue;
    }
    if (xml.compare(i, 5, "<?xml") == 0) {
      const size_t end = xml.find("?>", i);
      if (end == std::string::npos) return fail("unterminated declaration");
      i = end + 2;
      continue;
    }
    const size_t end = xml.find('>', i);
    if (end == std::string::npos) return fail("unterminated tag");
    std::string tag = xml.substr(i + 1, end - i - 1);
    // Quotes must balance inside the tag and '<' must not appear in it.
    if (std::count(tag.begin(), tag.end(), '"') % 2 != 0) return fail("unbalanced quotes");
    if (tag.find('<') != std::string::npos) return fail("'<' inside a tag");
    if (!tag.empty() && tag[0] == '/') {
      const std::string name = tag.substr(1);
      if (stack.empty() || stack.back() != name) return fail("mismatched </" + name + ">");
      stack.pop_back();
    } else {
      const bool self_closing = !tag.empty() && tag.back() == '/';
      const std::string name = tag.substr(0, tag.find_first_of(" \t\n/"));
      if (name.empty()) return fail("empty tag name");
      if (stack.empty()) {
        if (root_seen) return fail("second root element");
        root_seen = true;
      }
      if (!self_closing) stack.push_back(name);
    }
    i = end + 1;
  }
  if (!stack.empty()) return ::testing::AssertionFailure() << "unclosed <" << stack.back() << ">";
  if (!root_seen) return ::testing::AssertionFailure() << "no root element";
  return ::testing::AssertionSuccess();
}

int Count(const std::string& text, const std::string& what) {
  int n = 0;
  for (size_t p = text.find(what); p != std::string::npos; p = text.find(what, p + 1)) ++n;
  return n;
}

// Markers carry a <title> tooltip; decorations (legend swatches, highlight rings) do not.
int DataMarkers(const std::string& svg) { return Count(svg, "\"><title>"); }

Plot BasePlot() {
  Plot p;
  p.title = "title";
  p.x_label = "x";
  p.y_label = "y";
  return p;
}

TEST(BenchSvgPlot, SinglePointIsWellFormed) {
  for (bool log : {false, true}) {
    Plot p = BasePlot();
    p.log_x = p.log_y = log;
    p.series.push_back({"only", {64}, {1000}, {}, true});
    const PlotOutput out = RenderSvgPlot(p);
    EXPECT_TRUE(IsWellFormedXml(out.svg)) << out.svg;
    EXPECT_EQ(out.svg.rfind("<?xml", 0), 0u);
    EXPECT_NE(out.svg.find("xmlns=\"http://www.w3.org/2000/svg\""), std::string::npos);
    EXPECT_EQ(DataMarkers(out.svg), 1);
    EXPECT_EQ(out.svg.find("nan"), std::string::npos);
    EXPECT_EQ(out.svg.find("inf"), std::string::npos);
    EXPECT_TRUE(out.notes.empty());
    // A one-value axis still gets labelled ticks.
    EXPECT_GE(Count(out.svg, "text-anchor=\"end\""), 2) << out.svg;
  }
}

TEST(BenchSvgPlot, NonPositiveValuesOnLogAxesAreSkippedWithAReason) {
  Plot p = BasePlot();
  p.log_x = p.log_y = true;
  p.series.push_back({"cpu", {0, -1, 10, 100, 1000}, {1, 2, 0, 5, 7}, {}, true});
  const PlotOutput out = RenderSvgPlot(p);
  EXPECT_TRUE(IsWellFormedXml(out.svg)) << out.svg;
  EXPECT_EQ(DataMarkers(out.svg), 2);
  ASSERT_EQ(out.notes.size(), 2u);
  EXPECT_NE(out.notes[0].find("2 points with x <= 0 skipped (log x axis)"), std::string::npos)
      << out.notes[0];
  EXPECT_NE(out.notes[1].find("1 points with y <= 0 skipped (log y axis)"), std::string::npos)
      << out.notes[1];
  // The same values on linear axes are all drawn.
  p.log_x = p.log_y = false;
  const PlotOutput linear = RenderSvgPlot(p);
  EXPECT_EQ(DataMarkers(linear.svg), 5);
  EXPECT_TRUE(linear.notes.empty());
}

TEST(BenchSvgPlot, NonFiniteValuesAreSkippedWithAReason) {
  Plot p = BasePlot();
  p.series.push_back({"a", {1, 2, 3}, {1, std::nan(""), HUGE_VAL}, {}, true});
  const PlotOutput out = RenderSvgPlot(p);
  EXPECT_TRUE(IsWellFormedXml(out.svg));
  EXPECT_EQ(DataMarkers(out.svg), 1);
  ASSERT_EQ(out.notes.size(), 1u);
  EXPECT_NE(out.notes[0].find("2 points with a non-finite value"), std::string::npos);
}

TEST(BenchSvgPlot, EmptyPlotSaysNoData) {
  Plot p = BasePlot();
  p.log_y = true;
  const PlotOutput none = RenderSvgPlot(p);
  EXPECT_TRUE(IsWellFormedXml(none.svg));
  EXPECT_NE(none.svg.find("no data"), std::string::npos);
  p.series.push_back({"empty", {}, {}, {}, true});
  const PlotOutput empty_series = RenderSvgPlot(p);
  EXPECT_TRUE(IsWellFormedXml(empty_series.svg));
  EXPECT_NE(empty_series.svg.find("no data"), std::string::npos);
}

TEST(BenchSvgPlot, EscapesTextAndDrawsLegendAndHighlights) {
  Plot p = BasePlot();
  p.title = "speed & error <log>";
  p.highlight_label = "Pareto front";
  p.series.push_back({"cpu \"batched\" <simd>", {1, 10, 100}, {3, 2, 1}, {true, false, true}, false});
  p.series.push_back({"vulkan", {2, 20}, {4, 3}, {}, true});
  const PlotOutput out = RenderSvgPlot(p);
  EXPECT_TRUE(IsWellFormedXml(out.svg)) << out.svg;
  EXPECT_NE(out.svg.find("speed &amp; error &lt;log&gt;"), std::string::npos);
  EXPECT_NE(out.svg.find("cpu &quot;batched&quot; &lt;simd&gt;"), std::string::npos);
  EXPECT_NE(out.svg.find("Pareto front"), std::string::npos);
  EXPECT_EQ(Count(out.svg, "r=\"7\""), 3);  // two highlighted points + the legend entry
  EXPECT_EQ(Count(out.svg, "<polyline"), 1);  // only the second series is joined
}

TEST(BenchSvgPlot, LogAxisGetsDecadeTicks) {
  Plot p = BasePlot();
  p.log_x = p.log_y = true;
  p.series.push_back({"s", {16, 64, 256, 1024}, {5e5, 1e5, 2e4, 5e3}, {}, true});
  const PlotOutput out = RenderSvgPlot(p);
  EXPECT_TRUE(IsWellFormedXml(out.svg));
  EXPECT_NE(out.svg.find(">100</text>"), std::string::npos);
  EXPECT_NE(out.svg.find(">1000</text>"), std::string::npos);
  EXPECT_NE(out.svg.find(">1e5</text>"), std::string::npos) << out.svg;
  EXPECT_NE(out.svg.find("(log scale)"), std::string::npos);
}

}  // namespace
}  // namespace reflcap::benchsuite
