#pragma once
// From a texel's BrdfSamples to prepared fitting problems, and from solved problems back to a
// TexelFit: the work every backend shares before and after its LM, so that all of them see the
// same residuals, start values, stages and classification, and report alike.
//
// PrepareTexel, per texel (in double; deterministic, so float and double solvers get identical
// inputs and the statuses decided here cannot differ between them):
//   1. Masking. A sample with a non-finite direction component, and a channel with a non-finite
//      value or weight, is dropped and flags the texel kNonFiniteInput. Directions are
//      re-normalised (a direction shorter than kMinDirectionNorm is dropped). Samples with
//      cos(theta_i) or cos(theta_o) < min_cos_theta (grazing) and channels with weight <= 0 are
//      masked. Negative values are kept (noise around a dark texel is legitimately negative).
//   2. Normalisation (model.h): scale S = the largest |value| of the problem's valid residuals
//      (1 when all are 0); values y / S; weights divided by the mean of w (y / S)^2 (by the mean
//      weight when every value is 0), so the weighted values have unit RMS. The least-squares
//      problem is unchanged up to a constant factor, every weighted residual is O(1), the
//      Jacobi scaling sees each parameter's influence, and J^T J stays in float range for values
//      from 1e-6 to 1e4 and any noise model.
//   3. Classification, in this order:
//        valid samples < max(min_samples, parameters + 1)     → Lambert-only, kTooFewSamples
//        lobes > 0 and no sample within highlight_cone_deg of the mirror configuration
//                                                              → Lambert-only, kUnidentifiableLobe
//        lobes > 0 and no lobe evidence (below)                → Lambert-only, lobe absent
//      A Lambert-only problem has zero lobes (C = 0, s = 0) and fits only rho.
//   4. Start values and stages: seed.h (StartValues).
//
// Lobe evidence: with rho0 the seed's start albedo (π x the median value) and σ the noise
// estimated from the values' lower quartile (kQuartileToSigma), some valid value within
// kEvidenceConeDeg of the mirror configuration (or within highlight_cone_deg, if wider) must
// exceed rho0 / π by more than evidence_sigmas σ + kEvidenceFloor rho0 / π (any channel for
// shared). A bright sample far from the mirror is no evidence of a specular lobe: it is an
// outlier (on synthetic captures such samples, up to 20 σ from the diffuse level either way,
// cluster on texels at atlas chart borders), or light that a lobe would also have put into the
// samples nearer the mirror, which did not show it.
//
// FinishProblem, per solved problem: the rank test on the final J^T J (kSingular), parameter
// standard deviations, the map to natural units, and the texel's combined status.
#include <cstddef>
#include <cstdint>
#include <vector>

#include "engine/fit/fitter.h"
#include "engine/fit/lm.h"
#include "engine/fit/model.h"
#include "engine/texel/samples.h"

namespace reflcap::fit {

// A direction shorter than this is not a direction (a zeroed record); longer ones are
// re-normalised, which absorbs float rounding in the resampler's unit vectors.
constexpr double kMinDirectionNorm = 0.5;
// Lobe evidence floor: a lobe peaking less than 2 % above the diffuse level cannot be told from
// calibration error of the irradiance (a few percent), whatever the noise.
constexpr double kEvidenceFloor = 0.02;
// The lobe-evidence test looks for its sample within 45 degrees of the mirror configuration:
// a lobe of exponent 2 is still at half its peak there, so every lobe worth fitting shows its
// evidence inside the cone, while the outliers of the rest of the hemisphere are ignored.
// Measured on an all-matte synthetic capture (`synth --materials matte`): without the cone 1.4 %
// of the texels fitted a spurious lobe from such a sample and lent it on, costing 2.2 dB of
// holdout PSNR (38.01 dB against 40.18 dB for a Lambert-only fit); with it, 40.16 dB. suzanne and
// all six DiLiGenT objects score the same with and without it (README.md).
constexpr double kEvidenceConeDeg = 45;
// The noise σ of the lobe-evidence test is (median - lower quartile) / 0.6745, Gaussian σ from
// the lower half of the values only: a lobe lifts the upper half (and would inflate a MAD), the
// lower half is diffuse level plus noise (and shadows, which only make the test stricter).
constexpr double kQuartileToSigma = 0.6745;

// Storage for the residuals of a range of texels (one per worker, reused: it only grows, and
// only in Reserve, outside the per-texel loop).
struct ProblemArena {
  std::vector<float> xx, yy, zz, y, sw;
  std::vector<float> scratch;   // medians, one texel's channel values
  std::vector<float> products;  // one texel's direction products per sample
  std::vector<uint32_t> src;    // residual -> index of its sample within the texel
  // Room for `residuals` residuals and one texel of up to `max_samples` samples.
  void Reserve(size_t residuals, size_t max_samples);
};

struct PreparedProblem {
  ProblemLayout layout;
  int texel = 0;    // index within the chunk
  int problem = 0;  // channel for aniso/iso, 0 for shared
  ResidualView residuals;
  int samples = 0;           // valid samples (shared: residuals / 3)
  double scale = 1;          // normalisation S (natural value = S x normalised value)
  double weight_scale = 1;   // raw weight = weight_scale x normalised weight
                             // (natural cost = S^2 weight_scale x normalised cost)
  double loss_scale = 1;     // robust scale in normalised residual units
  bool nonfinite_input = false;
  bool lambert_only = false;
  FitStatus preset = FitStatus::kConverged;  // kTooFewSamples / kUnidentifiableLobe or converged
  int num_stages = 0;
  uint32_t stage_mask[2] = {0, 0};
  double x0[kMaxParams] = {};
  double lower[kMaxParams] = {};
  double upper[kMaxParams] = {};
};

// Prepares the ProblemsPerTexel(layout.model) problems of one texel into out[]; residuals are
// written to the arena from *cursor on (advanced). The arena must hold room for 3 x count more
// residuals and one texel of `count` samples.
void PrepareTexel(const FitOptions& options, const ProblemLayout& layout,
                  const BrdfSample* samples, size_t count, int texel, ProblemArena* arena,
                  size_t* cursor, PreparedProblem* out);

// The outcome of a problem's LM: final parameters (normalised), the normal equations at them,
// the free mask of the last stage, its status, and evaluated steps over all stages.
struct SolvedProblem {
  double x[kMaxParams] = {};
  double a[kMaxPacked] = {};
  double cost = 0;
  uint32_t free_mask = 0;
  FitStatus status = FitStatus::kConverged;
  int iterations = 0;
};

// Resets a TexelFit before its problems are finished: zero parameters with `lobes` lobes,
// sigma -1, status converged.
void BeginTexel(int lobes, TexelFit* fit);
// A lobe whose supremum over the hemisphere exceeds this many times the problem's brightest
// value (normalised units: the brightest value is 1) is extrapolation, not measurement: the
// samples never came near where it peaks, so its height there is set by the model's form, not by
// data (on the small synthetic preset, such lobes made isolated holdout pixels 1e3-1e28 times too
// bright). 10 keeps every lobe whose brightest sample is within a decade of its peak, which the
// highlight-cone test's sample near the mirror direction gives for n up to ~600 (a sample 5
// degrees off the peak: cos^n 5° >= 0.1); sharper lobes
// seen only off-peak fall back to Lambert (measured on the demo: holdout PSNR 18.8 dB at 1e3,
// 30.8 dB at 10, 30.4 dB at 3).
constexpr double kMaxLobeSupremum = 10;

// True when a lobe of x (normalised units) exceeds kMaxLobeSupremum somewhere on the hemisphere.
bool LobeExceedsEvidence(const ProblemLayout& layout, const double* x);
// Overwrites x with the problem's Lambert-only fit (weighted least squares of rho per channel,
// lobes zeroed with their exponents at the start value) and returns its cost (no robust loss).
double LambertFallback(const PreparedProblem& q, double* x);

// Channel retry (FitOptions::channel_retry; per-channel lobe models aniso and iso). A channel
// whose LM ended far worse than its texel's best channel — reduced cost 2 cost / (residuals -
// free parameters), in noise units, more than kChannelRetryCostRatio times the best channel's
// (and than 1) — is solved again from the best channel's lobes, moved to its own normalisation
// (the same natural lobe: highlights are mostly the colour of the light), with its own start
// rho, and keeps whichever solution has the lower cost. Why: a sharp lobe started at
// start_exponent can end in a wrong basin in one channel while the texel's other channels find
// it (bench/RESULTS.md, reflcap bench section 1: 11 of 4,096 synthetic texels, reduced costs
// 360-2,000 where 99 % are below 1.2, carried 96 % of the holdout error). 4: far outside the
// spread of reduced costs between channels of well-fitted texels (1.0 +- 0.2 at 1 % noise).
constexpr double kChannelRetryCostRatio = 4;

// Writes to retry[] copies of those of a texel's `per_texel` problems q[] (solved[]) that the
// channel retry takes, their starts moved to the best channel's lobes, and their indices (0 ..
// per_texel - 1) to channel[]; returns how many (0 for the shared model, Lambert-only layouts,
// or a texel without a converged channel whose lobe stays within the evidence).
int PrepareChannelRetries(const PreparedProblem* q, const SolvedProblem* solved, int per_texel,
                          PreparedProblem* retry, int* channel);
// solved[channel[i]] = retried[i] for each retry whose cost is lower; returns how many were taken.
int AdoptChannelRetries(const SolvedProblem* retried, const int* channel, int count,
                        SolvedProblem* solved);

// Folds one solved problem into its texel's TexelFit (parameters, sigma, status, cost, counts).
// A problem that ended kSingular, or whose lobe exceeds the evidence (LobeExceedsEvidence), is
// replaced by its Lambert-only fit (status kSingular, resp. kUnidentifiableLobe; sigma unknown).
// That fallback reads the residuals: when it is needed and the view holds only their counts
// (data pointers null), nothing is written and the result is false — prepare the texel again
// (PrepareTexel is deterministic) and finish it from there. True otherwise.
bool FinishProblem(const PreparedProblem& problem, const SolvedProblem& solved, TexelFit* fit);

// Runs one prepared problem through all its stages with the scalar LM in T (float or double).
template <typename T>
SolvedProblem SolveScalar(const PreparedProblem& problem, const LmSettings& settings,
                          LossKind loss);

}  // namespace reflcap::fit
