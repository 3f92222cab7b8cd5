// Per-texel coverage statistics (see coverage.h).
#include "acquire/resample/coverage.h"

#include <algorithm>
#include <bitset>
#include <cmath>
#include <limits>

#include "engine/core/parallel.h"
#include "engine/math/safe_math.h"
#include "engine/math/types.h"

namespace reflcap::resample {
namespace {

int ThetaBin(float cos_theta) {
  const double theta_deg = RadToDeg(SafeAcos(double(cos_theta)));
  return std::clamp(int(theta_deg / (90.0 / kThetaBins)), 0, kThetaBins - 1);
}

// A tangent-plane projection shorter than this (sin θ < 1e-6, θ < 0.2") has no usable azimuth:
// the sample sits at normal incidence and every azimuth bin describes it equally; it goes to 0.
constexpr double kMinProjection = 1e-6;

}  // namespace

int DomainCell(const float wi[3], const float wo[3]) {
  int a = ThetaBin(wi[2]), b = ThetaBin(wo[2]);
  if (a > b) std::swap(a, b);
  const int pair = a * kThetaBins - a * (a - 1) / 2 + (b - a);
  const double li = std::hypot(double(wi[0]), double(wi[1]));
  const double lo = std::hypot(double(wo[0]), double(wo[1]));
  int phi_bin = 0;
  if (li > kMinProjection && lo > kMinProjection) {
    const double c = (double(wi[0]) * wo[0] + double(wi[1]) * wo[1]) / (li * lo);
    const double phi_deg = RadToDeg(SafeAcos(std::clamp(c, -1.0, 1.0)));
    phi_bin = std::clamp(int(phi_deg / (180.0 / kPhiBins)), 0, kPhiBins - 1);
  }
  return pair * kPhiBins + phi_bin;
}

float HalfAngleDeg(const float wi[3], const float wo[3]) {
  const Vec3d h(double(wi[0]) + wo[0], double(wi[1]) + wo[1], double(wi[2]) + wo[2]);
  const double n = h.norm();
  if (!(n > 0)) return 90.0f;  // wi = -wo: no half vector; as far from specular as it gets
  return float(RadToDeg(SafeAcos(std::clamp(h.z() / n, -1.0, 1.0))));
}

TexelCoverage::TexelCoverage(size_t texels)
    : samples_(texels, 0),
      views_(texels, 0),
      last_view_(texels, -1),
      seen_(texels, 0),
      observations_(texels, 0),
      cells_(texels, {0, 0}),
      min_half_deg_(texels, 90.0f) {}

void TexelCoverage::AddImage(const std::vector<uint8_t>& outcome,
                             const std::vector<TexelSample>& kept, int view, int threads) {
  REFLCAP_CHECK(outcome.size() == seen_.size());
  ParallelFor(
      0, int64_t(outcome.size()), 1 << 16,
      [&](int64_t b, int64_t e, int) {
        for (int64_t t = b; t < e; ++t) {
          seen_[t] |= uint8_t(Seen(Outcome(outcome[t])));
          observations_[t] += Observed(Outcome(outcome[t]));
        }
      },
      threads);
  ParallelFor(
      0, int64_t(kept.size()), 4096,
      [&](int64_t b, int64_t e, int) {
        for (int64_t i = b; i < e; ++i) {
          const uint32_t t = kept[i].texel;
          const BrdfSample& s = kept[i].sample;
          ++samples_[t];
          if (last_view_[t] != view) {
            last_view_[t] = view;
            if (views_[t] < std::numeric_limits<uint16_t>::max()) ++views_[t];
          }
          const int cell = DomainCell(s.wi, s.wo);
          cells_[t][cell / 64] |= uint64_t(1) << (cell % 64);
          min_half_deg_[t] = std::min(min_half_deg_[t], HalfAngleDeg(s.wi, s.wo));
        }
      },
      threads);
}

int TexelCoverage::cells(size_t t) const {
  return int(std::bitset<64>(cells_[t][0]).count() + std::bitset<64>(cells_[t][1]).count());
}

}  // namespace reflcap::resample
