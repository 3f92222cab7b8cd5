#pragma once
// Helpers of the fitting tests: error metrics against ground truth and status counts.
#include <algorithm>
#include <array>
#include <cmath>
#include <string>
#include <vector>

#include "engine/fit/fitter.h"
#include "engine/fit/synthetic_samples.h"

namespace reflcap::fit::testing {

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

inline std::string CountsString(const std::array<int, kFitStatusCount>& counts) {
  std::string s;
  for (int i = 0; i < kFitStatusCount; ++i) {
    if (!counts[i]) continue;
    s += std::string(s.empty() ? "" : ", ") + FitStatusName(FitStatus(i)) + " " + std::to_string(counts[i]);
  }
  return s;
}

}  // namespace reflcap::fit::testing
