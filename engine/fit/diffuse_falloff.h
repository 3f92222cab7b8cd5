#pragma once
// Diffuse fall-off: a texel left Lambert-only may take Lafortune's generalized diffuse lobe,
// when its own held-out photographs say so.
//
// Why: many real diffuse surfaces are darker than Lambert at grazing light. On DiLiGenT's pot1
// the photograph / Lambert render ratio of lit pixels is 0.41 / 0.70 / 0.86 / 0.93 / 1.01 at
// cos theta_i 0.1 / 0.15 / 0.3 / 0.5 / 0.7 (cat 0.80 ... 1.02): about as the Fresnel transmission
// into a dielectric falls (glaze, varnish, a smooth binder). A Lambert fit spreads that error
// over every sample (pot1's in-sample residual +10 % at cos theta_i 0.1-0.2, -2 % above 0.7) and
// the re-render is too bright near every terminator.
//
// The model stays Lambert + Lafortune: the lobe is Lafortune et al.'s generalized diffuse one,
// Cx = Cy = 0, which their paper gives for non-Lambertian diffuse reflection:
//
//   f_c = rho_c / pi + (Cz,c cos theta_i cos theta_o)^n  =  a_c + B_c x^n,   x = wiz woz,
//
// with n in kFalloffExponents (>= brdf::kMinLobeExponent), so every renderer, exporter and
// backend evaluates it as any other lobe; n < 1 is this lobe's alone (the LM keeps its lobes at
// n >= 1). For a fixed n the model is linear in (a_c, B_c) >= 0, solved in closed form per
// channel (weighted least squares, non-negative); n is shared by the channels (the fall-off is a
// property of the surface layer, not of the pigment). The radiance
// ratio to Lambert is (a + B x^n) / (a + B x0^n): flat where the lobe is small, falling towards
// grazing light or view.
//
// Which texels: after lobe transfer and material clusters, every texel that is Lambert-only (no
// lobe of its own, none lent) or holds a borrowed lobe (a neighbour's or its cluster's), with
// usable samples in every one of `folds` folds (PhotographFold, as the clusters' model choice).
// Texels with a lobe of their own keep it. The choice is by prediction, as the clusters'
// (ModelChoice::kKFold): each exponent, and the texel's model now (Lambert, or the borrowed lobe
// with the albedo re-fitted), is fitted without each fold and scored on it (1/2 sum w r^2 over
// the held-out samples); the lowest-scoring exponent wins when it beats the texel's model by more
// than kFalloffMargin — by more than kBorrowedFalloffMargin of its held-out cost as well when that
// model is a borrowed lobe — and its lobe must stay within the evidence bound (problem.h
// kMaxLobeSupremum times the texel's brightest sample, per channel). The winner is then fitted
// on all the texel's samples. A texel that takes it gets donor FitStore::kDiffuseFalloff
// (status.exr `lobe_donor` -3, TexelModel kFalloffLobe), keeps its status, and its sigmas are
// unknown (-1): the albedo is re-fitted here, not by the LM.
//
// Runs after the fit on every backend alike (it reads the FitStore and the samples, nothing of
// the fitter), so CPU and Vulkan fits take the same lobes given the same fits.
#include <array>
#include <cstddef>
#include <cstdint>

#include "engine/brdf/lafortune.h"
#include "engine/fit/fit_store.h"
#include "engine/fit/fitter.h"
#include "engine/texel/samples.h"

namespace reflcap::fit {

// The exponents tried: brdf::kMinLobeExponent to 3. On DiLiGenT pot1 and cat the exponents
// below 1 are half of the choices and add 0.11 / 0.14 dB of holdout PSNR-L over 1-3 alone;
// exponents 4-20 (a throw-away prototype of this pass) took 17 % of pot1's fall-off texels and
// lost 0.01 dB of PSNR-L and 0.4 dB of PSNR: such a lobe peaks at normal incidence instead of
// falling off at grazing.
constexpr std::array<double, 7> kFalloffExponents = {0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0};
static_assert(kFalloffExponents[0] >= brdf::kMinLobeExponent, "below the evaluation range");
constexpr int kFalloffExponentCount = int(kFalloffExponents.size());

// A held-out cost lower than Lambert's by less than this is no evidence for the lobe: the same
// half of one residual's squared standard deviation as the clusters' k-fold choice
// (material_clusters.cc kKFoldMargin); costs are 1/2 sum w r^2 with w the inverse variance.
constexpr double kFalloffMargin = 0.5;

// A borrowed lobe gives way only to a clear win: a fall-off lobe must predict the texel's held-out
// photographs with this much less cost (relative). The lobe may carry a highlight that none of
// the texel's photographs showed, which they cannot judge: at 0.05 chance wins dropped true
// highlights on the in-model seed-11 capture (holdout 53.54 -> 52.63 dB; with the absolute
// margin alone 51.91 dB); at 0.15 it and the demo are unchanged while DiLiGenT's glossy objects
// keep most of the gain (ball16 PSNR-L +1.5 dB, goblet +0.4 dB).
constexpr double kBorrowedFalloffMargin = 0.15;

struct DiffuseFalloffStats {
  size_t candidates = 0;  // Lambert-only or borrowed-lobe texels with samples in every fold
  size_t taken = 0;       // of those, texels that took a fall-off lobe
  size_t replaced = 0;    // of those, texels whose borrowed lobe it replaced
  std::array<size_t, kFalloffExponentCount> by_exponent{};  // taken, per kFalloffExponents entry
};

// True when some texel in [first, end) is a candidate by its FitStore entry alone (Lambert-only
// with no donor, or a borrowed lobe; samples >= 3): the chunks worth reading.
bool DiffuseFalloffCandidatesIn(const FitStore& fits, uint64_t first, uint64_t end);

// Tests and applies the fall-off lobe to the candidates of one chunk (lobe 0 of fits; fits must
// have lobes() >= 1). `folds` as MaterialClusterOptions::folds (2..kMaxModelFolds).
void ApplyDiffuseFalloff(const TexelSampleChunk& chunk, const FitOptions& options, int folds,
                         FitStore* fits, DiffuseFalloffStats* stats);

}  // namespace reflcap::fit
