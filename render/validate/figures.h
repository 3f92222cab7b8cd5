#pragma once
// Figure-ready images of `reflcap validate`, drawn without any plotting library: a viridis-like
// colour map, a built-in 5x7 bitmap font (digits, capitals, a few signs), and the composers of the
// comparison figure (photograph | re-render | error heat map with a labelled colour bar), the region
// map and the fit-status map. Images are RGB floats in [0, 1] holding display (already tone-mapped
// / gamma-encoded) values, ready for WritePng.
#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "engine/image/image.h"

namespace reflcap::validate {

using Rgb = std::array<float, 3>;

// Perceptually uniform blue-green-yellow map (matplotlib's viridis, sampled at 9 points and
// interpolated linearly); t is clamped to [0, 1].
Rgb Viridis(double t);

// The 5x7 font: each glyph 5 px wide, 7 tall, advanced by 6 px, all times `scale`. Lower-case
// letters print as capitals; characters without a glyph print as a blank.
int TextWidth(const std::string& text, int scale);
constexpr int kGlyphHeight = 7;
void DrawText(Image* image, int x, int y, const std::string& text, int scale, const Rgb& colour);
void FillRect(Image* image, int x, int y, int w, int h, const Rgb& colour);

// Smallest of {1, 2, 2.5, 5} x 10^k that is >= x (x > 0); 1 for x <= 0.
double NiceCeil(double x);
// A fraction as a percentage with at most 3 significant digits: 0.025 -> "2.5%".
std::string FormatPercent(double fraction);

// photograph | re-render | error heat map, side by side, with titles, a colour bar for the error
// map (0 .. error_scale, labelled in % of the photograph's peak) and `caption` (one line) below.
// photo_tm / render_tm: 3 channels, display values; error: 1 channel, |r - p| / P, < 0 where not
// evaluated (drawn dark grey). All three the same size.
Image ComposeFigure(const Image& photo_tm, const Image& render_tm, const Image& error,
                    double error_scale, const std::string& caption);

// The legend of the error maps' shared colour scale, on its own: a horizontal Viridis bar from 0 to
// error_scale (values above it saturate: the top label ends in "+"), labelled in % of the
// photograph's peak at ColourBarTicks(error_scale) evenly spaced ticks from 0 to the scale, `title`
// (one line) above.
Image ComposeColourBar(double error_scale, const std::string& title);
// Ticks of that legend, ends included: round steps for the scales NiceCeil picks (1 and 2 x 10^k in
// quarters, 2.5 and 5 x 10^k in fifths: 0.5 and 1 x 10^k), quarters for any other scale.
int ColourBarTicks(double error_scale);

// The region labels of an image over its tone-mapped photograph (dimmed): shadow_edge red,
// high_curvature blue, grazing yellow (where several apply, the first of these), elsewhere the
// photograph (dimmed), not evaluated black; with a legend below.
Image ComposeRegionMap(const Image& photo_tm, const std::vector<uint8_t>& region_bits);

// A categorical map of integer codes (e.g. per-texel fit status) with a legend: each distinct
// code present gets a colour, its name (names[code] when given, else "CODE k") and its count.
// `valid` (same size, 1 channel, optional) marks the pixels that carry a code; others are black.
Image ComposeCategoricalMap(const Image& codes, const Image* valid,
                            const std::vector<std::string>& names);

}  // namespace reflcap::validate
