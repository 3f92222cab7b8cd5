#pragma once
// The photographs' point spread, for normal-map captures: a normal map's pixel is its texel, so
// the render shades each pixel once, exactly at its centre's normal — while a camera's optics and
// sensor spread every point over a little of its neighbours (and the normal map is registered to
// the photographs only to a fraction of a pixel): at terminators and shadow edges a sharp render
// steps from lit to dark in one pixel. On DiLiGenT a Gaussian of σ = 0.5–0.7 px removes 1.3–12 %
// of the train photographs' squared error against the sharp render.
//
// The render blurs each image within the object's mask (normalised convolution: background
// pixels neither give nor take light) after the direct light and the stray light are drawn:
//   out(x) = Σ_y m(y) g(x − y) in(y) / Σ_y m(y) g(x − y)   for x in the mask m,
// g a Gaussian of standard deviation σ px, truncated at 3σ. Mesh captures model their pixels by
// supersampling instead (CaptureRenderOptions::supersampling).
//
// Auto (kAutoPsf): up to kPsfEvidenceImages train photographs, evenly spaced, are rendered as the
// render will draw them (direct light, height-field shadows, stray light when on) and compared
// with their photographs over the usable mask pixels (finite, unsaturated) sharp and at each σ
// of kPsfCandidatesPx; the σ with the least squared error is used when it removes at least
// kMinPsfErrorReduction of the sharp render's.
#include <array>
#include <cstddef>
#include <string>
#include <vector>

#include "engine/core/status.h"
#include "engine/image/image.h"
#include "render/reference/render_capture.h"
#include "render/reference/stray_light.h"

namespace reflcap::render {

// Candidates of the auto decision (px): from about a pixel's own box (σ = 0.29 for a 1 px box)
// upwards in steps that change the error visibly; DiLiGenT chooses 0.5–0.7.
constexpr std::array<double, 7> kPsfCandidatesPx = {0.35, 0.5, 0.6, 0.7, 0.85, 1.0, 1.25};
// Evidence photographs: 8 lights already show every terminator and shadow edge many times over.
constexpr int kPsfEvidenceImages = 8;
// A blur must remove at least this share of the sharp render's squared error. Sharp synthetic
// photographs lose error under any blur (their normals are exact); DiLiGenT gains 1.3 % (ball16)
// to 12 % (bear). 1 % asks for a real gain, not noise.
constexpr double kMinPsfErrorReduction = 0.01;

// Blurs `pixels` (any channel count) within `mask` (1 channel, > 0.5 = object; the same size)
// by a Gaussian of `sigma_px` > 0, as above. Pixels outside the mask are unchanged.
void BlurWithinMask(const Image& mask, double sigma_px, Image* pixels);

struct PsfEvidence {
  int images = 0;
  int skipped = 0;
  size_t pixels = 0;
  double error_sharp = 0;
  std::array<double, kPsfCandidatesPx.size()> error{};  // per candidate σ
  double best_sigma_px = 0;  // the candidate with the least error
  double reduction = 0;      // 1 − error at best_sigma_px / error_sharp
  double sigma_px = 0;       // the chosen σ: best_sigma_px when reduction is enough, else 0
};
// `stray` (may be null): added to the evidence renders as the render adds it.
PsfEvidence MeasurePsfEvidence(const FittedCapture& fitted, bool cast_shadows,
                               const StrayLight* stray);

}  // namespace reflcap::render
