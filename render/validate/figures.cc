// Figures of `reflcap validate` (see figures.h).
#include "render/validate/figures.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>

#include "render/validate/metrics.h"

namespace reflcap::validate {
namespace {

// 5x7 glyphs, one byte per row (bit 4 = leftmost column), top row first.
struct Glyph {
  char c;
  uint8_t rows[7];
};
constexpr Glyph kFont[] = {
    {'0', {0x0E, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0E}}, {'1', {0x04, 0x0C, 0x04, 0x04, 0x04, 0x04, 0x0E}},
    {'2', {0x0E, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1F}}, {'3', {0x1F, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0E}},
    {'4', {0x02, 0x06, 0x0A, 0x12, 0x1F, 0x02, 0x02}}, {'5', {0x1F, 0x10, 0x1E, 0x01, 0x01, 0x11, 0x0E}},
    {'6', {0x06, 0x08, 0x10, 0x1E, 0x11, 0x11, 0x0E}}, {'7', {0x1F, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08}},
    {'8', {0x0E, 0x11, 0x11, 0x0E, 0x11, 0x11, 0x0E}}, {'9', {0x0E, 0x11, 0x11, 0x0F, 0x01, 0x02, 0x0C}},
    {'A', {0x0E, 0x11, 0x11, 0x11, 0x1F, 0x11, 0x11}}, {'B', {0x1E, 0x11, 0x11, 0x1E, 0x11, 0x11, 0x1E}},
    {'C', {0x0E, 0x11, 0x10, 0x10, 0x10, 0x11, 0x0E}}, {'D', {0x1C, 0x12, 0x11, 0x11, 0x11, 0x12, 0x1C}},
    {'E', {0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x1F}}, {'F', {0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x10}},
    {'G', {0x0E, 0x11, 0x10, 0x17, 0x11, 0x11, 0x0F}}, {'H', {0x11, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11}},
    {'I', {0x0E, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E}}, {'J', {0x07, 0x02, 0x02, 0x02, 0x02, 0x12, 0x0C}},
    {'K', {0x11, 0x12, 0x14, 0x18, 0x14, 0x12, 0x11}}, {'L', {0x10, 0x10, 0x10, 0x10, 0x10, 0x10, 0x1F}},
    {'M', {0x11, 0x1B, 0x15, 0x15, 0x11, 0x11, 0x11}}, {'N', {0x11, 0x11, 0x19, 0x15, 0x13, 0x11, 0x11}},
    {'O', {0x0E, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E}}, {'P', {0x1E, 0x11, 0x11, 0x1E, 0x10, 0x10, 0x10}},
    {'Q', {0x0E, 0x11, 0x11, 0x11, 0x15, 0x12, 0x0D}}, {'R', {0x1E, 0x11, 0x11, 0x1E, 0x14, 0x12, 0x11}},
    {'S', {0x0F, 0x10, 0x10, 0x0E, 0x01, 0x01, 0x1E}}, {'T', {0x1F, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04}},
    {'U', {0x11, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E}}, {'V', {0x11, 0x11, 0x11, 0x11, 0x11, 0x0A, 0x04}},
    {'W', {0x11, 0x11, 0x11, 0x15, 0x15, 0x15, 0x0A}}, {'X', {0x11, 0x11, 0x0A, 0x04, 0x0A, 0x11, 0x11}},
    {'Y', {0x11, 0x11, 0x11, 0x0A, 0x04, 0x04, 0x04}}, {'Z', {0x1F, 0x01, 0x02, 0x04, 0x08, 0x10, 0x1F}},
    {'.', {0x00, 0x00, 0x00, 0x00, 0x00, 0x0C, 0x0C}}, {'%', {0x18, 0x19, 0x02, 0x04, 0x08, 0x13, 0x03}},
    {'-', {0x00, 0x00, 0x00, 0x1F, 0x00, 0x00, 0x00}}, {'+', {0x00, 0x04, 0x04, 0x1F, 0x04, 0x04, 0x00}},
    {'/', {0x00, 0x01, 0x02, 0x04, 0x08, 0x10, 0x00}}, {'|', {0x04, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04}},
    {':', {0x00, 0x0C, 0x0C, 0x00, 0x0C, 0x0C, 0x00}}, {'(', {0x02, 0x04, 0x08, 0x08, 0x08, 0x04, 0x02}},
    {')', {0x08, 0x04, 0x02, 0x02, 0x02, 0x04, 0x08}}, {'=', {0x00, 0x00, 0x1F, 0x00, 0x1F, 0x00, 0x00}},
    {',', {0x00, 0x00, 0x00, 0x00, 0x0C, 0x04, 0x08}}, {'_', {0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x1F}},
};

const Glyph* FindGlyph(char c) {
  if (c >= 'a' && c <= 'z') c = char(c - 'a' + 'A');
  for (const Glyph& g : kFont) {
    if (g.c == c) return &g;
  }
  return nullptr;
}

constexpr Rgb kBackground = {0.12f, 0.12f, 0.12f};
constexpr Rgb kNotEvaluated = {0.22f, 0.22f, 0.22f};
constexpr Rgb kText = {0.92f, 0.92f, 0.92f};
constexpr Rgb kRegionColour[kRegionCount] = {
    {0.95f, 0.25f, 0.2f}, {0.25f, 0.45f, 1.0f}, {0.95f, 0.8f, 0.1f}, {0, 0, 0}};
// Categorical palette (Tableau 10): distinguishable, also in print.
constexpr Rgb kPalette[] = {{0.12f, 0.47f, 0.71f}, {1.0f, 0.5f, 0.05f}, {0.17f, 0.63f, 0.17f},
                            {0.84f, 0.15f, 0.16f}, {0.58f, 0.4f, 0.74f}, {0.55f, 0.34f, 0.29f},
                            {0.89f, 0.47f, 0.76f}, {0.5f, 0.5f, 0.5f},   {0.74f, 0.74f, 0.13f},
                            {0.09f, 0.75f, 0.81f}};

void Blit(const Image& src, Image* dst, int x0, int y0) {
  for (int y = 0; y < src.height; ++y) {
    for (int x = 0; x < src.width; ++x) {
      for (int c = 0; c < 3; ++c) dst->at(x0 + x, y0 + y, c) = src.at(x, y, std::min(c, src.channels - 1));
    }
  }
}

// Font scale for images of this height: legible next to the panels (1 below 320 px, then 2, ...).
int FontScale(int height) { return std::max(1, height / 160); }

}  // namespace

Rgb Viridis(double t) {
  static constexpr float kStops[9][3] = {
      {0.267004f, 0.004874f, 0.329415f}, {0.282623f, 0.140926f, 0.457517f},
      {0.253935f, 0.265254f, 0.529983f}, {0.206756f, 0.371758f, 0.553117f},
      {0.163625f, 0.471133f, 0.558148f}, {0.127568f, 0.566949f, 0.550556f},
      {0.134692f, 0.658636f, 0.517649f}, {0.266941f, 0.748751f, 0.440573f},
      {0.993248f, 0.906157f, 0.143936f}};
  if (!(t > 0)) t = 0;  // also NaN
  if (t > 1) t = 1;
  const double s = t * 8;
  const int i = std::min(7, int(s));
  const double f = s - i;
  Rgb out;
  for (int c = 0; c < 3; ++c) out[c] = float(kStops[i][c] + f * (kStops[i + 1][c] - kStops[i][c]));
  return out;
}

int TextWidth(const std::string& text, int scale) {
  return text.empty() ? 0 : int(text.size()) * 6 * scale - scale;
}

void DrawText(Image* image, int x, int y, const std::string& text, int scale, const Rgb& colour) {
  for (size_t k = 0; k < text.size(); ++k) {
    const Glyph* g = FindGlyph(text[k]);
    if (!g) continue;
    const int gx = x + int(k) * 6 * scale;
    for (int row = 0; row < 7; ++row) {
      for (int col = 0; col < 5; ++col) {
        if (!(g->rows[row] & (0x10 >> col))) continue;
        for (int sy = 0; sy < scale; ++sy) {
          for (int sx = 0; sx < scale; ++sx) {
            const int px = gx + col * scale + sx, py = y + row * scale + sy;
            if (px < 0 || py < 0 || px >= image->width || py >= image->height) continue;
            for (int c = 0; c < 3; ++c) image->at(px, py, c) = colour[c];
          }
        }
      }
    }
  }
}

void FillRect(Image* image, int x, int y, int w, int h, const Rgb& colour) {
  for (int yy = std::max(0, y); yy < std::min(image->height, y + h); ++yy) {
    for (int xx = std::max(0, x); xx < std::min(image->width, x + w); ++xx) {
      for (int c = 0; c < 3; ++c) image->at(xx, yy, c) = colour[c];
    }
  }
}

double NiceCeil(double x) {
  if (!(x > 0) || !std::isfinite(x)) return 1;
  const double decade = std::pow(10.0, std::floor(std::log10(x)));
  for (double m : {1.0, 2.0, 2.5, 5.0, 10.0}) {
    // Relative slack so that x = 0.05 (stored as 0.05000000000000000277) stays 0.05.
    if (m * decade >= x * (1 - 1e-12)) return m * decade;
  }
  return 10 * decade;
}

std::string FormatPercent(double fraction) {
  char text[32];
  std::snprintf(text, sizeof text, "%.3g%%", fraction * 100);
  return text;
}

Image ComposeFigure(const Image& photo_tm, const Image& render_tm, const Image& error,
                    double error_scale, const std::string& caption) {
  const int w = photo_tm.width, h = photo_tm.height;
  const int s = FontScale(h);
  const int pad = 4 * s, line = kGlyphHeight * s;
  const int title_h = line + 2 * pad;
  const int bar_w = 10 * s;
  const std::string labels[3] = {"0%", FormatPercent(error_scale / 2), FormatPercent(error_scale)};
  int label_w = 0;
  for (const auto& l : labels) label_w = std::max(label_w, TextWidth(l, s));
  const int width = 3 * w + 4 * pad + bar_w + pad + label_w + pad;
  const int height = title_h + h + 2 * pad + line + pad;
  Image figure(width, height, 3);
  FillRect(&figure, 0, 0, width, height, kBackground);
  const char* titles[3] = {"PHOTOGRAPH", "RE-RENDER", "|R - P| / PEAK"};
  for (int k = 0; k < 3; ++k) {
    const int x0 = pad + k * (w + pad);
    DrawText(&figure, x0 + (w - TextWidth(titles[k], s)) / 2, pad, titles[k], s, kText);
  }
  Blit(photo_tm, &figure, pad, title_h);
  Blit(render_tm, &figure, 2 * pad + w, title_h);
  const int ex = 3 * pad + 2 * w;
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const float e = error.at(x, y);
      const Rgb c = e < 0 ? kNotEvaluated : Viridis(e / error_scale);
      for (int k = 0; k < 3; ++k) figure.at(ex + x, title_h + y, k) = c[k];
    }
  }
  // Colour bar: top = error_scale (values above it saturate), bottom = 0.
  const int bx = ex + w + pad;
  for (int y = 0; y < h; ++y) {
    const Rgb c = Viridis(1 - double(y) / std::max(1, h - 1));
    FillRect(&figure, bx, title_h + y, bar_w, 1, c);
  }
  const int lx = bx + bar_w + pad;
  DrawText(&figure, lx, title_h, labels[2], s, kText);
  DrawText(&figure, lx, title_h + (h - line) / 2, labels[1], s, kText);
  DrawText(&figure, lx, title_h + h - line, labels[0], s, kText);
  DrawText(&figure, pad, title_h + h + pad, caption, s, kText);
  return figure;
}

int ColourBarTicks(double error_scale) {
  if (!(error_scale > 0) || !std::isfinite(error_scale)) return 5;
  const double mantissa = error_scale / std::pow(10.0, std::floor(std::log10(error_scale)));
  // A NiceCeil mantissa up to rounding of the power of ten.
  constexpr double kMantissaTolerance = 1e-9;
  for (double m : {2.5, 5.0}) {
    if (std::abs(mantissa - m) < kMantissaTolerance * m) return 6;
  }
  return 5;
}

Image ComposeColourBar(double error_scale, const std::string& title) {
  constexpr int kScale = 2;        // font scale: legible at the page's width
  constexpr int kBarWidth = 512;   // px; wide enough for five labels of up to six characters
  constexpr int kBarHeight = 24;   // px
  const int pad = 4 * kScale, line = kGlyphHeight * kScale, tick = 3 * kScale;
  const int ticks = ColourBarTicks(error_scale);
  std::vector<std::string> labels(static_cast<size_t>(ticks));
  int label_w = 0;
  for (int k = 0; k < ticks; ++k) {
    labels[k] = FormatPercent(error_scale * k / (ticks - 1));
    if (k == ticks - 1) labels[k] += "+";
    label_w = std::max(label_w, TextWidth(labels[k], kScale));
  }
  const int x0 = pad + label_w / 2;
  const int width = std::max(x0 + kBarWidth + label_w / 2 + pad, TextWidth(title, kScale) + 2 * pad);
  const int height = pad + line + pad + kBarHeight + tick + pad + line + pad;
  Image figure(width, height, 3);
  FillRect(&figure, 0, 0, width, height, kBackground);
  DrawText(&figure, pad, pad, title, kScale, kText);
  const int by = 3 * pad / 2 + line + pad / 2;
  for (int x = 0; x < kBarWidth; ++x) {
    FillRect(&figure, x0 + x, by, 1, kBarHeight, Viridis(double(x) / (kBarWidth - 1)));
  }
  for (int k = 0; k < ticks; ++k) {
    const int tx = x0 + (kBarWidth - 1) * k / (ticks - 1);
    FillRect(&figure, tx - kScale / 2, by + kBarHeight, kScale, tick, kText);
    const int lw = TextWidth(labels[k], kScale);
    DrawText(&figure, std::clamp(tx - lw / 2, 0, width - lw), by + kBarHeight + tick + pad,
             labels[k], kScale, kText);
  }
  return figure;
}

Image ComposeRegionMap(const Image& photo_tm, const std::vector<uint8_t>& region_bits) {
  const int w = photo_tm.width, h = photo_tm.height;
  const int s = FontScale(h);
  const int pad = 4 * s, line = kGlyphHeight * s;
  const int legend_w = TextWidth("HIGH CURVATURE", s) + line + 3 * pad;
  const int width = std::max(w + 2 * pad, legend_w + 2 * pad);
  const int height = h + 2 * pad + 4 * (line + pad) + pad;
  Image figure(width, height, 3);
  FillRect(&figure, 0, 0, width, height, kBackground);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const uint8_t b = region_bits.empty() ? 0 : region_bits[size_t(y) * w + x];
      Rgb c = {0, 0, 0};
      if (b & (1u << kElsewhere)) {
        for (int k = 0; k < 3; ++k) c[k] = 0.6f * photo_tm.at(x, y, k);
      } else {
        // The first region listed wins where several apply (mixed colours would read as others).
        for (int r = kElsewhere - 1; r >= 0; --r) {
          if (b & (1u << r)) c = kRegionColour[r];
        }
      }
      for (int k = 0; k < 3; ++k) figure.at(pad + x, pad + y, k) = c[k];
    }
  }
  const char* names[4] = {"SHADOW EDGE", "HIGH CURVATURE", "GRAZING", "ELSEWHERE (PHOTO)"};
  for (int r = 0; r < kRegionCount; ++r) {
    const int y = h + 2 * pad + r * (line + pad);
    Rgb swatch = kRegionColour[r];
    if (r == kElsewhere) swatch = {0.45f, 0.45f, 0.45f};
    FillRect(&figure, pad, y, line, line, swatch);
    DrawText(&figure, 2 * pad + line, y, names[r], s, kText);
  }
  return figure;
}

Image ComposeCategoricalMap(const Image& codes, const Image* valid,
                            const std::vector<std::string>& names) {
  const int w = codes.width, h = codes.height;
  std::map<long, size_t> counts;
  auto code_at = [&](int x, int y) { return std::lround(codes.at(x, y, 0)); };
  auto is_valid = [&](int x, int y) {
    return (!valid || valid->at(x, y, 0) > 0.5f) && std::isfinite(codes.at(x, y, 0));
  };
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      if (is_valid(x, y)) ++counts[code_at(x, y)];
    }
  }
  std::map<long, Rgb> colour;
  std::vector<std::string> legend;
  size_t k = 0;
  for (const auto& [code, count] : counts) {
    colour[code] = kPalette[k++ % (sizeof kPalette / sizeof kPalette[0])];
    const std::string name =
        code >= 0 && size_t(code) < names.size() && !names[size_t(code)].empty()
            ? names[size_t(code)]
            : "CODE " + std::to_string(code);
    legend.push_back(std::to_string(code) + " " + name + ": " + std::to_string(count));
  }
  const int s = FontScale(std::max(h, 200));
  const int pad = 4 * s, line = kGlyphHeight * s;
  int legend_w = 0;
  for (const auto& l : legend) legend_w = std::max(legend_w, TextWidth(l, s) + line + pad);
  const int width = std::max(w, legend_w) + 2 * pad;
  const int height = h + 2 * pad + int(legend.size()) * (line + pad) + pad;
  Image figure(width, height, 3);
  FillRect(&figure, 0, 0, width, height, kBackground);
  FillRect(&figure, pad, pad, w, h, {0, 0, 0});
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      if (!is_valid(x, y)) continue;
      const Rgb& c = colour[code_at(x, y)];
      for (int ch = 0; ch < 3; ++ch) figure.at(pad + x, pad + y, ch) = c[ch];
    }
  }
  k = 0;
  for (const auto& [code, count] : counts) {
    const int y = h + 2 * pad + int(k) * (line + pad);
    FillRect(&figure, pad, y, line, line, colour[code]);
    DrawText(&figure, 2 * pad + line, y, legend[k], s, kText);
    ++k;
  }
  return figure;
}

}  // namespace reflcap::validate
