#include "engine/fit/diffuse_falloff.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <vector>

#include "engine/core/check.h"
#include "engine/core/parallel.h"
#include "engine/fit/lobe_transfer.h"
#include "engine/fit/material_clusters.h"
#include "engine/fit/problem.h"
#include "engine/math/types.h"

namespace reflcap::fit {
namespace {

// Weighted sums of one channel over a set of samples for the model y = a + B b, b = x^n:
// enough to solve for (a, B) and to score any (a, B) on the set.
struct Sums {
  double w = 0, wb = 0, wbb = 0, wy = 0, wyb = 0, wyy = 0;

  void Add(double weight, double b, double y) {
    w += weight;
    wb += weight * b;
    wbb += weight * b * b;
    wy += weight * y;
    wyb += weight * y * b;
    wyy += weight * y * y;
  }
  Sums Plus(const Sums& o) const {
    return {w + o.w, wb + o.wb, wbb + o.wbb, wy + o.wy, wyb + o.wyb, wyy + o.wyy};
  }
  Sums Minus(const Sums& o) const {
    return {w - o.w, wb - o.wb, wbb - o.wbb, wy - o.wy, wyb - o.wyb, wyy - o.wyy};
  }
  // 1/2 sum w (y - a - B b)^2, expanded; clamped at 0 against rounding of the expansion.
  double Cost(double a, double b_coef) const {
    const double c = wyy - 2 * a * wy - 2 * b_coef * wyb + a * a * w + 2 * a * b_coef * wb +
                     b_coef * b_coef * wbb;
    return 0.5 * std::max(0.0, c);
  }
};

struct Coefficients {
  double a = 0, b = 0;
};

// Lambert only: a = sum w y / sum w (0 without weight), clamped at 0 (an albedo is >= 0).
Coefficients SolveLambert(const Sums& s) {
  return {s.w > 0 ? std::max(0.0, s.wy / s.w) : 0.0, 0.0};
}

// Non-negative least squares for (a, B): the unconstrained solution when both are >= 0, else the
// better of the two one-variable fits on the boundary (the optimum of a convex quadratic over the
// quadrant lies on one of them).
Coefficients SolveFalloff(const Sums& s) {
  const double det = s.w * s.wbb - s.wb * s.wb;
  // Relative to the product of the diagonal: below 1e-12 the two columns are collinear to double
  // precision (b nearly constant over the samples) and the split between a and B is noise.
  if (det > 1e-12 * s.w * s.wbb) {
    const Coefficients free{(s.wy * s.wbb - s.wyb * s.wb) / det, (s.w * s.wyb - s.wb * s.wy) / det};
    if (free.a >= 0 && free.b >= 0) return free;
  }
  const Coefficients lambert = SolveLambert(s);
  const Coefficients lobe{0.0, s.wbb > 0 ? std::max(0.0, s.wyb / s.wbb) : 0.0};
  return s.Cost(lobe.a, lobe.b) < s.Cost(lambert.a, lambert.b) ? lobe : lambert;
}

// A lobe lent by a neighbour or the texel's cluster (not one it fitted itself).
bool Borrowed(const FitStore& fits, size_t t) {
  return fits.donor(t) >= 0 || fits.donor(t) == FitStore::kClusterLobe;
}

// x^n for every n of kFalloffExponents, from two square roots and products instead of seven
// pow calls (the pass's main cost: 2.5 s of the million store's fit before). Exact up to float
// rounding: sqrt is correctly rounded, each product adds half an ulp.
constexpr std::array<double, 7> kGridThisComputes = {0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0};
constexpr bool IsTheGridThisComputes(const std::array<double, 7>& grid) {
  for (size_t k = 0; k < grid.size(); ++k) {
    if (grid[k] != kGridThisComputes[k]) return false;
  }
  return true;
}
static_assert(IsTheGridThisComputes(kFalloffExponents),
              "FalloffBases computes this grid: change both together");
std::array<double, 7> FalloffBases(double x) {
  const double half = std::sqrt(x), quarter = std::sqrt(half);
  return {quarter, half, half * quarter, x, x * half, x * x, x * x * x};
}

bool Candidate(const FitStore& fits, size_t t) {
  const bool lambert = fits.lambert_only(t) && fits.donor(t) == FitStore::kNoDonor;
  return (lambert || Borrowed(fits, t)) && fits.status(t) != FitStatus::kNonFiniteInput &&
         fits.samples(t) >= kMinTransferSamples;
}

}  // namespace

bool DiffuseFalloffCandidatesIn(const FitStore& fits, uint64_t first, uint64_t end) {
  for (uint64_t t = first; t < end && t < fits.size(); ++t) {
    if (Candidate(fits, size_t(t))) return true;
  }
  return false;
}

void ApplyDiffuseFalloff(const TexelSampleChunk& chunk, const FitOptions& options, int folds,
                         FitStore* fits, DiffuseFalloffStats* stats) {
  REFLCAP_CHECK(fits->lobes() >= 1) << "the fall-off lobe needs a lobe slot";
  REFLCAP_CHECK(folds >= 2 && folds <= kMaxModelFolds) << "folds " << folds;
  constexpr int kN = kFalloffExponentCount;
  std::atomic<size_t> candidates{0}, taken{0}, replaced{0};
  std::array<std::atomic<size_t>, kN> by_exponent{};
  // 64 texels per task: each is a few passes over its ~20-500 samples.
  ParallelFor(0, int64_t(chunk.texel_count), 64, [&](int64_t begin, int64_t end, int) {
    // Per texel: [fold][exponent][channel] sums (Lambert reads exponent 0's: its w, wy, wyy do
    // not depend on b), and for a borrowed lobe [fold][channel] sums of y minus the lobe.
    std::vector<Sums> sums, current;
    TexelResiduals residuals;
    std::vector<std::array<double, kN>> bases;
    size_t task_candidates = 0;  // added once a task: one shared atomic per texel contends
    for (int64_t ii = begin; ii < end; ++ii) {
      const uint32_t i = uint32_t(ii);
      const size_t t = size_t(chunk.first_texel) + i;
      if (!Candidate(*fits, t)) continue;
      sums.assign(size_t(folds) * kN * brdf::kChannels, Sums{});
      current.assign(size_t(folds) * brdf::kChannels, Sums{});
      const bool borrowed = Borrowed(*fits, t);
      // The texel's fit now: a borrowed model's lobes are scored from it, and a winner is
      // written over it.
      TexelFit fit = fits->Get(t);
      residuals.Prepare(chunk.SamplesOf(i), chunk.SampleCount(i), options.min_cos_theta, folds);
      const size_t usable = residuals.usable();
      bases.resize(usable);
      for (size_t j = 0; j < usable; ++j) {
        // x = cos theta_i cos theta_o > min_cos_theta^2 > 0 for a usable sample.
        bases[j] = FalloffBases(double(residuals.zz()[j]));
      }
      std::array<double, brdf::kChannels> brightest{};
      std::array<bool, kMaxModelFolds> held{};
      for (int c = 0; c < brdf::kChannels; ++c) {
        // A borrowed model's lobes in this channel at every sample (its albedo ignored).
        const float* lobe = borrowed ? residuals.Lobes(&fit.params, c) : nullptr;
        const float* w = residuals.w(c);
        const float* y = residuals.y(c);
        for (size_t j = 0; j < usable; ++j) {
          if (!(w[j] > 0)) continue;  // no residual in this channel
          const size_t f = residuals.fold()[j];
          held[f] = true;
          brightest[size_t(c)] = std::max(brightest[size_t(c)], double(y[j]));
          for (int k = 0; k < kN; ++k) {
            sums[(f * kN + size_t(k)) * brdf::kChannels + size_t(c)].Add(w[j], bases[j][size_t(k)],
                                                                         y[j]);
          }
          if (borrowed) {
            current[f * brdf::kChannels + size_t(c)].Add(w[j], 0.0, double(y[j]) - double(lobe[j]));
          }
        }
      }
      // Every fold must hold samples, so that every candidate is scored on each.
      if (std::count(held.begin(), held.begin() + folds, true) != folds) continue;
      ++task_candidates;
      // Totals over the folds, per exponent and channel.
      std::array<Sums, kN * brdf::kChannels> total{};
      for (int f = 0; f < folds; ++f) {
        for (size_t j = 0; j < total.size(); ++j) {
          const Sums& s = sums[size_t(f) * kN * brdf::kChannels + j];
          total[j] = total[j].Plus(s);
        }
      }
      // Held-out costs: the texel's model now — Lambert (exponent 0's sums, B = 0), or its
      // borrowed lobe with the albedo re-fitted per fold — and each exponent.
      std::array<Sums, brdf::kChannels> current_total{};
      for (int f = 0; f < folds; ++f) {
        for (int c = 0; c < brdf::kChannels; ++c) {
          current_total[size_t(c)] =
              current_total[size_t(c)].Plus(current[size_t(f) * brdf::kChannels + size_t(c)]);
        }
      }
      double current_cv = 0;
      std::array<double, kN> falloff_cv{};
      for (int f = 0; f < folds; ++f) {
        for (int k = 0; k < kN; ++k) {
          for (int c = 0; c < brdf::kChannels; ++c) {
            const size_t j = size_t(k) * brdf::kChannels + size_t(c);
            const Sums& held_out = sums[size_t(f) * kN * brdf::kChannels + j];
            const Sums train = total[j].Minus(held_out);
            const Coefficients m = SolveFalloff(train);
            falloff_cv[size_t(k)] += held_out.Cost(m.a, m.b);
            if (k == 0 && !borrowed) {
              const Coefficients l = SolveLambert(train);
              current_cv += held_out.Cost(l.a, l.b);
            } else if (k == 0) {
              const Sums& held_lobe = current[size_t(f) * brdf::kChannels + size_t(c)];
              const Coefficients l = SolveLambert(current_total[size_t(c)].Minus(held_lobe));
              current_cv += held_lobe.Cost(l.a, l.b);
            }
          }
        }
      }
      const double margin = borrowed
                                ? std::max(kFalloffMargin, kBorrowedFalloffMargin * current_cv)
                                : kFalloffMargin;
      int best = -1;
      for (int k = 0; k < kN; ++k) {
        if (!(falloff_cv[size_t(k)] < current_cv - margin)) continue;
        if (best < 0 || falloff_cv[size_t(k)] < falloff_cv[size_t(best)]) best = k;
      }
      if (best < 0) continue;
      // The winner on all samples; its lobe within the evidence bound in every channel (B is the
      // lobe's supremum, reached at normal light and view).
      const double n = kFalloffExponents[size_t(best)];
      bool within_evidence = true;
      double cost = 0;
      bool any_lobe = false;
      for (int c = 0; c < brdf::kChannels; ++c) {
        const Sums& s = total[size_t(best) * brdf::kChannels + size_t(c)];
        const Coefficients m = SolveFalloff(s);
        within_evidence = within_evidence && m.b <= kMaxLobeSupremum * brightest[size_t(c)];
        any_lobe = any_lobe || m.b > 0;
        cost += s.Cost(m.a, m.b);
        fit.params.rho_d[size_t(c)] = float(kPi * m.a);
        // B = Cz^n: Cz = B^(1/n), 0 for a channel without lobe (b = 0: the lobe is cut off).
        fit.params.lobes[0][size_t(c)] = brdf::LobeParams{0.0f, 0.0f, float(std::pow(m.b, 1.0 / n)),
                                                          float(n)};
        // A borrowed model's further lobes go with it: the fall-off lobe replaces it.
        for (int k = 1; k < fit.params.num_lobes; ++k) {
          fit.params.lobes[size_t(k)][size_t(c)] = brdf::LobeParams{0.0f, 0.0f, 0.0f, 1.0f};
        }
      }
      if (!within_evidence || !any_lobe) continue;
      fit.cost = float(cost);
      fit.lambert_only = false;
      fits->Set(t, fit);
      fits->set_donor(t, FitStore::kDiffuseFalloff);
      ++taken;
      replaced += borrowed;
      ++by_exponent[size_t(best)];
    }
    candidates += task_candidates;
  }, options.threads);
  stats->candidates += candidates;
  stats->taken += taken;
  stats->replaced += replaced;
  for (int k = 0; k < kN; ++k) stats->by_exponent[size_t(k)] += by_exponent[size_t(k)];
}

}  // namespace reflcap::fit
