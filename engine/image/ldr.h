#pragma once
// Display-referred values as PSNR-L defines them (render/validate/metrics.h): a linear value over
// the photograph's "white" (its 99th percentile), clipped to [0, 1], sRGB-encoded. Shared by
// validate's PSNR-L and the render's pixel-footprint evidence, which must weigh errors alike.
#include <algorithm>
#include <cmath>
#include <optional>
#include <vector>

#include "engine/image/srgb.h"

namespace reflcap {

// L(x) = sRGB(clip(x inv_white, 0, 1)), in float (display values need no more); NaN maps to 0.
inline float LdrValue(double x, double inv_white) {
  const double y = x * inv_white;
  if (!(y > 0)) return 0;  // also NaN
  if (!(y < 1)) return 1;
  return LinearToSrgb(float(y));
}

// The nearest-rank percentile (the ceil(fraction M)-th smallest of the M values, fraction in
// (0, 1]), found with nth_element (reorders *values); nullopt when *values is empty.
inline std::optional<float> NearestRankPercentile(std::vector<float>* values, double fraction) {
  if (values->empty()) return std::nullopt;
  const size_t m = values->size();
  // Rank ceil(fraction m) (1-based), in [1, m]. The factor (1 - 1e-12) keeps a product that is an
  // integer in exact arithmetic (0.99 · 100) but rounds up by an ulp from taking the next rank;
  // otherwise 0.99 m is at least 0.01 from an integer, far more than the shift (1e-12 m).
  const double product = fraction * double(m) * (1 - 1e-12);
  const size_t rank = std::clamp<size_t>(size_t(std::ceil(product)), 1, m);
  auto nth = values->begin() + std::ptrdiff_t(rank - 1);
  std::nth_element(values->begin(), nth, values->end());
  return *nth;
}

}  // namespace reflcap
