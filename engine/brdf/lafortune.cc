#include "engine/brdf/lafortune.h"

#include <cmath>
#include <sstream>

namespace reflcap::brdf {

std::array<float, kMaxParamsPerChannel> BrdfParams::Channel(int c) const {
  REFLCAP_CHECK(c >= 0 && c < kChannels) << "channel " << c;
  REFLCAP_CHECK(num_lobes >= 0 && num_lobes <= kMaxLobes) << "num_lobes " << num_lobes;
  std::array<float, kMaxParamsPerChannel> params{};
  params[0] = rho_d[c];
  for (int k = 0; k < num_lobes; ++k) {
    const LobeParams& lobe = lobes[k][c];
    params[1 + 4 * k] = lobe.cx;
    params[2 + 4 * k] = lobe.cy;
    params[3 + 4 * k] = lobe.cz;
    params[4 + 4 * k] = lobe.n;
  }
  return params;
}

std::string BrdfParams::ToString() const {
  std::ostringstream out;
  out << "BrdfParams{num_lobes=" << num_lobes << ", rho_d=(" << rho_d[0] << ", " << rho_d[1]
      << ", " << rho_d[2] << ")";
  for (int k = 0; k < num_lobes && k < kMaxLobes; ++k) {
    out << ", lobe" << k << "=[";
    for (int c = 0; c < kChannels; ++c) {
      const LobeParams& lobe = lobes[k][c];
      out << (c ? ", " : "") << "(" << lobe.cx << ", " << lobe.cy << ", " << lobe.cz << ", "
          << lobe.n << ")";
    }
    out << "]";
  }
  out << "}";
  return out.str();
}

bool IsFinite(const BrdfParams& p) {
  if (p.num_lobes < 0 || p.num_lobes > kMaxLobes) return false;
  for (float rho : p.rho_d) {
    if (!std::isfinite(rho)) return false;
  }
  for (int k = 0; k < p.num_lobes; ++k) {
    for (const LobeParams& lobe : p.lobes[k]) {
      if (!std::isfinite(lobe.cx) || !std::isfinite(lobe.cy) || !std::isfinite(lobe.cz) ||
          !std::isfinite(lobe.n)) {
        return false;
      }
    }
  }
  return true;
}

Vec3f EvalRgb(const BrdfParams& p, const Vec3f& wi, const Vec3f& wo) {
  Vec3f f;
  for (int c = 0; c < kChannels; ++c) {
    const std::array<float, kMaxParamsPerChannel> params = p.Channel(c);
    f[c] = EvalChannel(wi.data(), wo.data(), params.data(), p.num_lobes);
  }
  return f;
}

LobeParams MirrorLobe(double peak, double n, double anisotropy) {
  REFLCAP_CHECK(peak > 0) << "MirrorLobe peak " << peak;
  REFLCAP_CHECK(n >= kMinExponent && n <= kMaxExponent) << "MirrorLobe exponent " << n;
  REFLCAP_CHECK(anisotropy > 0) << "MirrorLobe anisotropy " << anisotropy;
  const double c = std::pow(peak, 1.0 / n);
  LobeParams lobe;
  lobe.cx = static_cast<float>(-c * anisotropy);
  lobe.cy = static_cast<float>(-c / anisotropy);
  lobe.cz = static_cast<float>(c);
  lobe.n = static_cast<float>(n);
  return lobe;
}

}  // namespace reflcap::brdf
