#pragma once
// Stray light in normal-map captures: light that reaches the object from the room rather than
// straight from the lamp.
//
// A lab lamp lights the room as well as the object; walls, table and rig send some of it back.
// That light scales with the lamp's power and hardly changes with its direction, so on top of
// its direct reflection a texel t sends exposure · I_c · s_c(t) towards the camera (I the
// lamp's intensity per channel, s the texel's stray radiance per unit intensity). A direct-light
// render is black where the lamp does not reach — the texel faces away from it, or the height
// field shadows it — while DiLiGenT's photographs read 1–4 % of their white there (ball16: 60 %
// of the held-out LDR error was in those pixels).
//
// Estimate, from every train photograph (normal-map captures are small: one read each):
//   1. A texel is observed in a photograph when no direct light reaches it nor its 8 neighbours
//      (the photograph's pixel filter and the normal map's registration mix a lit neighbour into
//      a texel beside the terminator or a shadow edge) and the pixel is usable (finite,
//      unsaturated). The photograph then reads p = w · s with w = exposure · I_c.
//   2. A texel observed at least kMinStrayObservations times takes its own estimate, the least
//      squares s = Σ p w / Σ w², clamped at 0 (light is not negative; noise about 0 is).
//   3. Every other texel (one facing every lamp: a dome's lamps stand in front of the object)
//      takes the environment model s_c(t) = ρ_c(t) · max(0, e_c · (1, n(t))): a Lambertian
//      surface under a smooth environment, its irradiance to first order in the normal (the
//      first two spherical-harmonic bands), e_c fitted by least squares to the observed texels'
//      s_c / ρ_c. Concavities the model does not see as such keep their own estimates.
// Evidence (CaptureRenderOptions::indirect = kAuto): the train photographs in two folds
// (alternating in capture order); each fold's estimate (steps 2–3) predicts the other fold's
// observations. error_reduction = 1 − Σ (p − w s)² / Σ p² over them, the share of their squared
// error (against a black direct-light render) that the stray light removes; `shows` when there
// were at least kMinStrayEvidenceObservations observations and error_reduction ≥
// kMinStrayErrorReduction. A capture without stray light (any direct-light synthetic one)
// observes noise about 0 and gains nothing.
//
// The render adds exposure · I · s(t) to every texel's pixel (lit ones too: the room lights
// them as well), after whichever backend drew the direct light — the CPU computes it for every
// backend, so backends agree by construction.
#include <array>
#include <cstddef>
#include <vector>

#include "engine/image/image.h"
#include "engine/math/types.h"
#include "render/reference/render_capture.h"

namespace reflcap::render {

// A texel's own estimate needs this many observations; with fewer it takes the environment
// model (one pixel of one photograph is mostly its noise and quantisation).
constexpr int kMinStrayObservations = 2;
// Fewer observations than this over the train photographs decide nothing (auto: off).
constexpr size_t kMinStrayEvidenceObservations = 1000;
// The stray light is added when it removes at least this share of the held-out fold's squared
// error where no direct light reaches (as kMinIndirectErrorReduction: right in kind but weak in
// level is kept, mostly noise is refused). DiLiGenT: 0.48–0.87 on five objects; pot1 0.12 (its
// 8-bit shadows read 0) stays off.
constexpr double kMinStrayErrorReduction = 0.25;
// The environment model (4 unknowns per channel) is fitted only over at least this many
// observed texels; with fewer, texels without their own estimate get no stray light.
constexpr size_t kMinStrayModelTexels = 16;

struct StrayLight {
  // s(t) per texel (atlas order), radiance per unit of the lamp's intensity, ≥ 0 and finite.
  std::vector<Vec3f> per_intensity;
  size_t observed_texels = 0;   // texels with their own estimate (step 2)
  size_t modelled_texels = 0;   // texels given the environment model (step 3)
  // e_c per channel: constant, then x, y, z of the world-frame normal (step 3); zeros when
  // fewer than kMinStrayModelTexels texels were observed.
  std::array<std::array<double, 4>, 3> environment{};
  // Evidence.
  int images = 0;            // train photographs read
  int skipped = 0;           // left out (unreadable, wrong size, not renderable)
  size_t observations = 0;   // texel-photograph pairs without direct light
  double error_reduction = 0;
  bool shows = false;
  double seconds = 0;
};

// Estimates the stray light of a normal-map capture from its train photographs, with
// `cast_shadows` as the render's (height-field shadows count as "no direct light" when on).
// Photographs that cannot be read are left out with a warning (the estimate is advice).
StrayLight EstimateStrayLight(const FittedCapture& fitted, bool cast_shadows);

// Adds exposure · I · s(t) of capture image `index` to each texel's pixel of `pixels` (the
// camera's size: a normal map's pixel is its texel).
void AddStrayLight(const FittedCapture& fitted, const StrayLight& stray, size_t index,
                   Image* pixels);

}  // namespace reflcap::render
