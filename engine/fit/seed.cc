// The seed's start values (section 4.2) and the fixed start; the reading is in seed.h.
#include "engine/fit/seed.h"

#include <algorithm>
#include <cmath>

namespace reflcap::fit {
namespace {

const Vec3d kMirror(-1.0, -1.0, 1.0);

double Base(const Vec3d& c, const Vec3d& wi, const Vec3d& wo) {
  return c.x() * wi.x() * wo.x() + c.y() * wi.y() * wo.y() + c.z() * wi.z() * wo.z();
}

}  // namespace

Vec3d SeedLobeDirection(const Vec3d& wi, const Vec3d& wo, double* base) {
  Vec3d c;
  for (int j = 0; j < 3; ++j) {
    const double product = wi[j] * wo[j];
    c[j] = std::abs(product) < kSeedMinProduct
               ? kMirror[j]
               : std::clamp(wi[j] / wo[j], -kSeedMaxRatio, kSeedMaxRatio);
  }
  double b = Base(c, wi, wo);
  if (b < kSeedMinBase) {
    c = kMirror;
    b = Base(c, wi, wo);
    if (b < kSeedMinBase) b = 1.0;
  }
  *base = b;
  return c;
}

void SeedLobeStart(const ProblemLayout& layout, int k, const Vec3d& wi, const Vec3d& wo,
                   const double* excess, double n, double* x) {
  double b = 1;
  Vec3d dir = SeedLobeDirection(wi, wo, &b);
  double* l = x + LobeOffset(layout.model, k);
  if (layout.model == LobeModel::kShared) {
    if (!(dir.z() > kSeedMinBase)) dir = kMirror;
    dir /= dir.z();
    double bs = Base(dir, wi, wo);
    if (bs < kSeedMinBase) bs = 1.0;
    l[0] = std::clamp(dir.x(), -kMaxC, kMaxC);
    l[1] = std::clamp(dir.y(), -kMaxC, kMaxC);
    l[2] = n;
    for (int c = 0; c < 3; ++c) {
      const double e = std::max(excess[c], kSeedMinExcess);
      l[3 + c] = std::clamp(e / std::pow(bs, n), 0.0, kMaxScale);
    }
    return;
  }
  const double kscale = std::pow(std::max(excess[0], kSeedMinExcess), 1.0 / n) / b;
  const Vec3d c = dir * kscale;
  if (layout.model == LobeModel::kAniso) {
    l[0] = std::clamp(c.x(), -kMaxC, kMaxC);
    l[1] = std::clamp(c.y(), -kMaxC, kMaxC);
    l[2] = std::clamp(c.z(), -kMaxC, kMaxC);
    l[3] = n;
  } else {
    l[0] = std::clamp(0.5 * (c.x() + c.y()), -kMaxC, kMaxC);
    l[1] = std::clamp(c.z(), -kMaxC, kMaxC);
    l[2] = n;
  }
}

void FixedStart(const ProblemLayout& layout, double n0, double scale, double* x) {
  const LobeModel m = layout.model;
  for (int c = 0; c < LambertParams(m); ++c) x[c] = kFixedAlbedo / scale;
  for (int k = 0; k < layout.lobes; ++k) {
    double* l = x + LobeOffset(m, k);
    const double n = std::min(n0 * std::pow(4.0, k), brdf::kMaxExponent);
    const double peak = kFixedPeak / (k + 1) / scale;  // normalised
    const double c = std::pow(peak, 1.0 / n);           // C' = C S^(-1/n)
    switch (m) {
      case LobeModel::kAniso:
        l[0] = -c; l[1] = -c; l[2] = c; l[3] = n;
        break;
      case LobeModel::kIso:
        l[0] = -c; l[1] = c; l[2] = n;
        break;
      case LobeModel::kShared:
        l[0] = -1; l[1] = -1; l[2] = n;
        for (int ch = 0; ch < 3; ++ch) l[3 + ch] = peak;
        break;
    }
  }
}

}  // namespace reflcap::fit
