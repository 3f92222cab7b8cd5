#pragma once
// Helpers of the fitting tests: error metrics against ground truth and status counts.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "engine/fit/fit_store.h"
#include "engine/fit/fitter.h"
#include "engine/fit/synthetic_samples.h"
#include "engine/mesh/texel_atlas.h"

namespace reflcap::fit::testing {

// The fits as the FIT driver holds them (one lobe per texel), none borrowed or filled yet.
inline FitStore StoreOf(const std::vector<TexelFit>& fits) {
  FitStore store(fits.size(), 1);
  for (size_t t = 0; t < fits.size(); ++t) store.Set(t, fits[t]);
  return store;
}

// A texels x 1 atlas whose texel t is pixel t.
inline TexelAtlas LineAtlas(int texels) {
  TexelAtlas atlas;
  atlas.width = texels;
  atlas.height = 1;
  for (int t = 0; t < texels; ++t) atlas.pixel_of_texel.push_back(uint32_t(t));
  return atlas;
}

inline double RelativeError(double estimate, double truth) {
  return std::abs(estimate - truth) / std::max(std::abs(truth), 1e-12);
}

inline double Median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

// Median relative errors of rho_d, lobe-0 peak (LobePeak) and exponent over all channels of all
// texels whose truth has a lobe in that channel (rho_d: every channel).
struct RecoveryErrors {
  double rho = 0, peak = 0, n = 0;            // medians
  double mean_peak = 0, mean_n = 0;            // means, each texel's error capped at 1
  double converged_fraction = 0;
  std::array<int, kFitStatusCount> counts{};
  double mean_iterations = 0;
};

inline RecoveryErrors Compare(const std::vector<brdf::BrdfParams>& truth,
                              const std::vector<TexelFit>& fits) {
  RecoveryErrors e;
  std::vector<double> rho, peak, n;
  double iterations = 0;
  for (size_t t = 0; t < truth.size(); ++t) {
    ++e.counts[int(fits[t].status)];
    iterations += fits[t].iterations;
    for (int c = 0; c < 3; ++c) {
      rho.push_back(RelativeError(fits[t].params.rho_d[c], truth[t].rho_d[c]));
      const double true_peak = LobePeak(truth[t].lobes[0][c]);
      if (truth[t].num_lobes > 0 && true_peak > 0) {
        peak.push_back(RelativeError(LobePeak(fits[t].params.lobes[0][c]), true_peak));
        n.push_back(RelativeError(fits[t].params.lobes[0][c].n, truth[t].lobes[0][c].n));
      }
    }
  }
  for (double v : peak) e.mean_peak += std::min(v, 1.0) / std::max<size_t>(1, peak.size());
  for (double v : n) e.mean_n += std::min(v, 1.0) / std::max<size_t>(1, n.size());
  e.rho = Median(rho);
  e.peak = Median(peak);
  e.n = Median(n);
  e.converged_fraction = double(e.counts[0]) / std::max<size_t>(1, truth.size());
  e.mean_iterations = iterations / std::max<size_t>(1, truth.size());
  return e;
}

// Visits every parameter slot of two fits with its standard deviation in `a`.
template <typename Fn>
void ForEachSlot(const TexelFit& a, const TexelFit& b, Fn fn) {
  for (int c = 0; c < 3; ++c) {
    fn(a.params.rho_d[c], b.params.rho_d[c], a.sigma.rho_d[c]);
    for (int k = 0; k < a.params.num_lobes; ++k) {
      const brdf::LobeParams &la = a.params.lobes[k][c], &lb = b.params.lobes[k][c], &s = a.sigma.lobes[k][c];
      fn(la.cx, lb.cx, s.cx);
      fn(la.cy, lb.cy, s.cy);
      fn(la.cz, lb.cz, s.cz);
      fn(la.n, lb.n, s.n);
    }
  }
}

// Well-conditioned slot: the fit determines it to 1 % (sigma < 1e-2 |v|), so a difference there
// is the solvers', not the data's.
inline bool WellConditioned(double value, double sigma) {
  return sigma >= 0 && sigma <= 1e-2 * std::abs(value);
}

// Counts the well-conditioned slots of texels converged in both a and b where a and b differ by
// more than `tolerance` relative (*compared: how many slots were compared; *max_relative, when
// given: the largest relative difference among them).
inline int CountDisagreements(const std::vector<TexelFit>& a, const std::vector<TexelFit>& b,
                              double tolerance, int* compared, double* max_relative = nullptr) {
  int bad = 0;
  for (size_t t = 0; t < a.size(); ++t) {
    if (a[t].status != FitStatus::kConverged || b[t].status != FitStatus::kConverged) continue;
    ForEachSlot(a[t], b[t], [&](double va, double vb, double sigma) {
      if (!WellConditioned(va, sigma)) return;
      ++*compared;
      const double relative = std::abs(va - vb) / std::max(std::abs(vb), 1e-6);
      if (max_relative) *max_relative = std::max(*max_relative, relative);
      if (relative > tolerance) ++bad;
    });
  }
  return bad;
}

inline std::string CountsString(const std::array<int, kFitStatusCount>& counts) {
  std::string s;
  for (int i = 0; i < kFitStatusCount; ++i) {
    if (!counts[i]) continue;
    s += std::string(s.empty() ? "" : ", ") + FitStatusName(FitStatus(i)) + " " + std::to_string(counts[i]);
  }
  return s;
}

}  // namespace reflcap::fit::testing
