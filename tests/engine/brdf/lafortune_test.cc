#include "engine/brdf/lafortune.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include <ceres/jet.h>
#include <gtest/gtest.h>

namespace reflcap::brdf {
namespace {

constexpr int kNumRandomCases = 500;
constexpr double kFloatEps = std::numeric_limits<float>::epsilon();  // 1.2e-7

using Params = std::array<double, kMaxParamsPerChannel>;

// A uniformly distributed unit vector; in the upper hemisphere (z >= 0) when `upper`.
Vec3d RandomDirection(std::mt19937* rng, bool upper) {
  std::normal_distribution<double> normal(0.0, 1.0);
  Vec3d w;
  do {
    w = Vec3d(normal(*rng), normal(*rng), normal(*rng));
  } while (w.norm() < 1e-6);
  w.normalize();
  if (upper) w.z() = std::abs(w.z());
  return w;
}

// Random channel parameters: rho_d in [rho_min, 1], signed C's (|C| <= 1.2, so |b| <= 1.2 for
// unit directions), n in [kMinExponent, n_max].
Params RandomParams(std::mt19937* rng, int num_lobes, double rho_min, double n_max) {
  std::uniform_real_distribution<double> rho(rho_min, 1.0);
  std::uniform_real_distribution<double> coefficient(-1.2, 1.2);
  std::uniform_real_distribution<double> exponent(kMinExponent, n_max);
  Params p{};
  p[0] = rho(*rng);
  for (int k = 0; k < num_lobes; ++k) {
    p[1 + 4 * k] = coefficient(*rng);
    p[2 + 4 * k] = coefficient(*rng);
    p[3 + 4 * k] = coefficient(*rng);
    p[4 + 4 * k] = exponent(*rng);
  }
  return p;
}

// The model written out independently of the library, in double.
double ReferenceChannel(const Vec3d& wi, const Vec3d& wo, const Params& p, int num_lobes) {
  double f = p[0] / kPi;
  for (int k = 0; k < num_lobes; ++k) {
    const double b = p[1 + 4 * k] * wi.x() * wo.x() + p[2 + 4 * k] * wi.y() * wo.y() +
                     p[3 + 4 * k] * wi.z() * wo.z();
    if (b > 0) f += std::pow(b, p[4 + 4 * k]);
  }
  return f;
}

Vec3d Mirror(const Vec3d& w) { return Vec3d(-w.x(), -w.y(), w.z()); }

// Smallest |base| over the lobes, to keep finite differences away from the cut-off b = 0, where
// the lobe is not smooth.
double MinAbsBase(const Vec3d& wi, const Vec3d& wo, const Params& p, int num_lobes) {
  double m = std::numeric_limits<double>::infinity();
  for (int k = 0; k < num_lobes; ++k) {
    const double b = p[1 + 4 * k] * wi.x() * wo.x() + p[2 + 4 * k] * wi.y() * wo.y() +
                     p[3 + 4 * k] * wi.z() * wo.z();
    m = std::min(m, std::abs(b));
  }
  return m;
}

TEST(LafortuneLobe, IsReciprocal) {
  // Exact: the base multiplies wi_j wo_j first, and IEEE multiplication commutes.
  std::mt19937 rng(7);
  for (int i = 0; i < kNumRandomCases; ++i) {
    const Vec3d wi = RandomDirection(&rng, true);
    const Vec3d wo = RandomDirection(&rng, true);
    const Params p = RandomParams(&rng, kMaxLobes, 0.0, 60.0);
    const double f_io = EvalChannel(wi.data(), wo.data(), p.data(), kMaxLobes);
    const double f_oi = EvalChannel(wo.data(), wi.data(), p.data(), kMaxLobes);
    EXPECT_EQ(f_io, f_oi) << "case " << i;
  }
}

TEST(EvalChannel, IsNonNegativeForAnyDirections) {
  std::mt19937 rng(11);
  for (int i = 0; i < kNumRandomCases; ++i) {
    // Below-hemisphere directions too: the formula itself must never go negative.
    const Vec3d wi = RandomDirection(&rng, false);
    const Vec3d wo = RandomDirection(&rng, false);
    const Params p = RandomParams(&rng, kMaxLobes, 0.0, 60.0);
    EXPECT_GE(EvalChannel(wi.data(), wo.data(), p.data(), kMaxLobes), 0.0) << "case " << i;
    const Vec3f wi_f = wi.cast<float>(), wo_f = wo.cast<float>();
    std::array<float, kMaxParamsPerChannel> p_f;
    std::transform(p.begin(), p.end(), p_f.begin(), [](double x) { return float(x); });
    EXPECT_GE(EvalChannel(wi_f.data(), wo_f.data(), p_f.data(), kMaxLobes), 0.0f) << "case " << i;
  }
}

TEST(EvalChannel, MatchesIndependentReference) {
  // Same closed form, same double arithmetic up to operation order.
  constexpr double kReferenceTol = 1e-12;
  std::mt19937 rng(13);
  for (int i = 0; i < kNumRandomCases; ++i) {
    const int num_lobes = i % (kMaxLobes + 1);
    const Vec3d wi = RandomDirection(&rng, true);
    const Vec3d wo = RandomDirection(&rng, true);
    const Params p = RandomParams(&rng, num_lobes, 0.0, 60.0);
    const double expected = ReferenceChannel(wi, wo, p, num_lobes);
    EXPECT_NEAR(EvalChannel(wi.data(), wo.data(), p.data(), num_lobes), expected,
                kReferenceTol * std::max(1.0, expected));
  }
}

TEST(EvalChannel, FloatAgreesWithDouble) {
  // Both evaluate the same float-rounded inputs, so only float arithmetic differs: the base's
  // rounding (a few 1e-8) is amplified n-fold by b^n, so with n <= 20 and rho_d >= 0.05 keeping f
  // away from 0, 1e-5 relative holds with margin.
  constexpr double kFloatVsDoubleTol = 1e-5;
  std::mt19937 rng(17);
  for (int i = 0; i < kNumRandomCases; ++i) {
    const Vec3f wi_f = RandomDirection(&rng, true).cast<float>();
    const Vec3f wo_f = RandomDirection(&rng, true).cast<float>();
    const Params p = RandomParams(&rng, kMaxLobes, 0.05, 20.0);
    std::array<float, kMaxParamsPerChannel> p_f;
    std::transform(p.begin(), p.end(), p_f.begin(), [](double x) { return float(x); });
    Params p_d;
    std::copy(p_f.begin(), p_f.end(), p_d.begin());
    const Vec3d wi_d = wi_f.cast<double>(), wo_d = wo_f.cast<double>();
    const double f_d = EvalChannel(wi_d.data(), wo_d.data(), p_d.data(), kMaxLobes);
    const float f_f = EvalChannel(wi_f.data(), wo_f.data(), p_f.data(), kMaxLobes);
    EXPECT_NEAR(f_f, f_d, kFloatVsDoubleTol * f_d) << "case " << i;
  }
}

TEST(EvalChannelWithGradient, ValueEqualsEvalChannel) {
  std::mt19937 rng(19);
  for (int i = 0; i < kNumRandomCases; ++i) {
    const Vec3d wi = RandomDirection(&rng, true);
    const Vec3d wo = RandomDirection(&rng, true);
    const Params p = RandomParams(&rng, kMaxLobes, 0.0, 60.0);
    Params grad;
    EXPECT_EQ(EvalChannelWithGradient(wi.data(), wo.data(), p.data(), kMaxLobes, grad.data()),
              EvalChannel(wi.data(), wo.data(), p.data(), kMaxLobes));
  }
}

TEST(EvalChannelWithGradient, MatchesJetAutodiff) {
  // Autodiff differentiates pow(b, n) with Ceres' rules n b^(n-1) and b^n log b, the same closed
  // forms as the analytic gradient, in double: they agree to ~1e-15 relative; 1e-9 leaves room for
  // a different operation order without hiding a wrong term.
  constexpr double kJetRelTol = 1e-9;
  using Jet = ceres::Jet<double, kMaxParamsPerChannel>;
  std::mt19937 rng(23);
  for (int i = 0; i < kNumRandomCases; ++i) {
    const int num_lobes = 1 + i % kMaxLobes;
    const int num_params = ParamsPerChannel(num_lobes);
    const Vec3d wi = RandomDirection(&rng, true);
    const Vec3d wo = RandomDirection(&rng, true);
    const Params p = RandomParams(&rng, num_lobes, 0.0, 60.0);
    std::array<Jet, 3> wi_j, wo_j;
    for (int j = 0; j < 3; ++j) {
      wi_j[j] = Jet(wi[j]);
      wo_j[j] = Jet(wo[j]);
    }
    std::array<Jet, kMaxParamsPerChannel> p_j;
    for (int j = 0; j < kMaxParamsPerChannel; ++j) p_j[j] = Jet(p[j], j);
    const Jet f_j = EvalChannel(wi_j.data(), wo_j.data(), p_j.data(), num_lobes);
    Params grad;
    const double f = EvalChannelWithGradient(wi.data(), wo.data(), p.data(), num_lobes, grad.data());
    EXPECT_NEAR(f, f_j.a, kJetRelTol * std::max(1.0, std::abs(f_j.a)));
    for (int j = 0; j < num_params; ++j) {
      EXPECT_NEAR(grad[j], f_j.v[j], kJetRelTol * std::max(1.0, std::abs(f_j.v[j])))
          << "case " << i << ", parameter " << j;
    }
  }
}

TEST(EvalChannelWithGradient, MatchesCentralDifferences) {
  // Step h relative to the parameter: truncation error h^2 f'''/6 and rounding eps f / h balance
  // near h = 1e-5 for these smooth cases; 1e-6 relative to max(1, |g|) holds with margin.
  // Cases with a lobe base within kMinBase of the cut-off are skipped: the lobe is not smooth
  // there (f'' ~ n (n - 1) b^(n-2) diverges for n < 2), so differences are meaningless.
  constexpr double kRelativeStep = 1e-5;
  constexpr double kCentralDiffTol = 1e-6;
  constexpr double kMinBase = 0.05;
  std::mt19937 rng(29);
  int checked = 0;
  for (int i = 0; i < kNumRandomCases; ++i) {
    const Vec3d wi = RandomDirection(&rng, true);
    const Vec3d wo = RandomDirection(&rng, true);
    const Params p = RandomParams(&rng, kMaxLobes, 0.0, 60.0);
    if (MinAbsBase(wi, wo, p, kMaxLobes) < kMinBase) continue;
    ++checked;
    Params grad;
    EvalChannelWithGradient(wi.data(), wo.data(), p.data(), kMaxLobes, grad.data());
    for (int j = 0; j < ParamsPerChannel(kMaxLobes); ++j) {
      const double h = kRelativeStep * std::max(1.0, std::abs(p[j]));
      Params plus = p, minus = p;
      plus[j] += h;
      minus[j] -= h;
      const double numeric = (EvalChannel(wi.data(), wo.data(), plus.data(), kMaxLobes) -
                              EvalChannel(wi.data(), wo.data(), minus.data(), kMaxLobes)) /
                             (2 * h);
      EXPECT_NEAR(grad[j], numeric, kCentralDiffTol * std::max(1.0, std::abs(numeric)))
          << "case " << i << ", parameter " << j;
    }
  }
  EXPECT_GT(checked, kNumRandomCases / 10);
}

// Value and gradient of one lobe whose base equals `base` (wi = wo = normal, Cz = base), in T.
template <typename T>
T LobeAtBase(double base, double n, std::array<T, 5>* grad) {
  const T w[3] = {T(0), T(0), T(1)};
  const T params[5] = {T(0), T(0), T(0), T(base), T(n)};
  return EvalChannelWithGradient(w, w, params, 1, grad->data());
}

TEST(LafortuneLobe, IsExactlyZeroWithZeroGradientAtAndBelowCutOff) {
  for (double base : {0.0, -0.0, -1e-300, -1e-12, -0.5, 1e-31, kPowBaseMin}) {
    for (double n : {kMinExponent, 1.5, kMaxExponent}) {
      std::array<double, 5> grad;
      EXPECT_EQ(LobeAtBase(base, n, &grad), 0.0) << base << "^" << n;
      for (int j = 1; j < 5; ++j) EXPECT_EQ(grad[j], 0.0) << base << "^" << n << ", " << j;
      std::array<float, 5> grad_f;
      EXPECT_EQ(LobeAtBase(base, n, &grad_f), 0.0f) << base << "^" << n;
      for (int j = 1; j < 5; ++j) EXPECT_EQ(grad_f[j], 0.0f) << base << "^" << n << ", " << j;
    }
  }
  // A base of 0 reached through the directions rather than through C: wi = normal, wo grazing.
  const double wi[3] = {0, 0, 1}, wo[3] = {1, 0, 0};
  const LobeParams mirror = MirrorLobe(5.0, 10.0);
  EXPECT_EQ(LafortuneLobe<double>(wi, wo, mirror.cx, mirror.cy, mirror.cz, mirror.n), 0.0);
}

TEST(LafortuneLobe, IsFiniteAtExponentLimitsForAnyBase) {
  // Tiny positive bases just above the cut-off, ordinary ones, and bases above 1 (which overflow
  // b^n at large n unless saturated).
  for (double base : {1.0000001e-30, 1e-29, 1e-20, 1e-5, 0.5, 1.0, 1.001, 2.0, 1e10, 1e38}) {
    for (double n : {kMinExponent, kMaxExponent}) {
      std::array<double, 5> grad;
      const double f = LobeAtBase(base, n, &grad);
      EXPECT_TRUE(std::isfinite(f)) << base << "^" << n;
      EXPECT_LE(f, kMaxLobeValue);
      for (int j = 1; j < 5; ++j) EXPECT_TRUE(std::isfinite(grad[j])) << base << "^" << n;
      std::array<float, 5> grad_f;
      const float f_f = LobeAtBase(base, n, &grad_f);
      EXPECT_TRUE(std::isfinite(f_f)) << base << "^" << n;
      for (int j = 1; j < 5; ++j) EXPECT_TRUE(std::isfinite(grad_f[j])) << base << "^" << n;
    }
  }
  // Just above the cut-off with n = 1 the lobe is live: value b, d/dCz = 1.
  std::array<double, 5> grad;
  EXPECT_DOUBLE_EQ(LobeAtBase(1e-29, kMinExponent, &grad), 1e-29);
  EXPECT_DOUBLE_EQ(grad[3], 1.0);
}

TEST(LafortuneLobe, SaturatesWithZeroGradientInsteadOfOverflowing) {
  std::array<double, 5> grad;
  EXPECT_EQ(LobeAtBase(2.0, kMaxExponent, &grad), kMaxLobeValue);
  for (int j = 1; j < 5; ++j) EXPECT_EQ(grad[j], 0.0);
  std::array<float, 5> grad_f;
  EXPECT_EQ(LobeAtBase(2.0, kMaxExponent, &grad_f), static_cast<float>(kMaxLobeValue));
  for (int j = 1; j < 5; ++j) EXPECT_EQ(grad_f[j], 0.0f);
}

TEST(LafortuneLobe, JetDerivativesAreFiniteAtExponentLimits) {
  using Jet = ceres::Jet<double, 4>;
  const Jet w[3] = {Jet(0), Jet(0), Jet(1)};
  for (double base : {-1e-12, 0.0, 1e-31, 1e-29, 0.5, 2.0}) {
    for (double n : {kMinExponent, kMaxExponent}) {
      const Jet f = LafortuneLobe(w, w, Jet(0.0, 0), Jet(0.0, 1), Jet(base, 2), Jet(n, 3));
      EXPECT_TRUE(std::isfinite(f.a));
      for (int j = 0; j < 4; ++j) EXPECT_TRUE(std::isfinite(f.v[j])) << base << "^" << n;
    }
  }
}

// Directional albedo a(wi) = integral of f(wi, wo) cos(theta_o) over the hemisphere, by
// jittered stratified quadrature in (theta_o, phi_o).
double DirectionalAlbedo(const Vec3d& wi, const Params& p, int num_lobes, std::mt19937* rng) {
  constexpr int kThetaStrata = 300;
  constexpr int kPhiStrata = 600;
  std::uniform_real_distribution<double> jitter(0.0, 1.0);
  const double d_theta = 0.5 * kPi / kThetaStrata;
  const double d_phi = 2.0 * kPi / kPhiStrata;
  double sum = 0;
  for (int i = 0; i < kThetaStrata; ++i) {
    for (int j = 0; j < kPhiStrata; ++j) {
      const double theta = (i + jitter(*rng)) * d_theta;
      const double phi = (j + jitter(*rng)) * d_phi;
      const Vec3d wo(std::sin(theta) * std::cos(phi), std::sin(theta) * std::sin(phi),
                     std::cos(theta));
      sum += EvalChannel(wi.data(), wo.data(), p.data(), num_lobes) * wo.z() * std::sin(theta);
    }
  }
  return sum * d_theta * d_phi;
}

TEST(LafortuneEnergy, DirectionalAlbedoOfNormalisedLobeIsAtMostOne) {
  // A lobe of peak ks (n + 2) / (2 pi) (normalised Phong) reflects at most ks, exactly ks at normal
  // incidence, so with rho_d + ks = 1 the albedo is 1 there: the bound is tight and the tolerance
  // is the quadrature's error (measured < 1e-4 for n <= 50 with this grid).
  constexpr double kAlbedoTol = 1e-3;
  constexpr double kRhoD = 0.4;
  constexpr double kSpecular = 1.0 - kRhoD;
  std::mt19937 rng(31);
  for (double n : {1.0, 10.0, 50.0}) {
    const LobeParams lobe = MirrorLobe(kSpecular * (n + 2) / (2 * kPi), n);
    const Params p{kRhoD, lobe.cx, lobe.cy, lobe.cz, lobe.n};
    for (double theta_i_deg : {0.0, 30.0, 60.0, 85.0}) {
      const double theta_i = DegToRad(theta_i_deg);
      const Vec3d wi(std::sin(theta_i), 0, std::cos(theta_i));
      const double albedo = DirectionalAlbedo(wi, p, 1, &rng);
      EXPECT_LE(albedo, 1.0 + kAlbedoTol) << "n " << n << ", theta_i " << theta_i_deg;
      EXPECT_GE(albedo, kRhoD - kAlbedoTol) << "n " << n << ", theta_i " << theta_i_deg;
      if (theta_i_deg == 0.0) {
        EXPECT_NEAR(albedo, 1.0, kAlbedoTol) << "n " << n;
      }
    }
  }
}

TEST(LafortuneEnergy, QuadratureReproducesLambertAlbedo) {
  constexpr double kAlbedoTol = 1e-3;  // as above
  std::mt19937 rng(37);
  const Params p{0.7};
  EXPECT_NEAR(DirectionalAlbedo(Vec3d(0.6, 0, 0.8), p, 0, &rng), 0.7, kAlbedoTol);
}

TEST(MirrorLobe, PeakValueAtMirrorDirectionEqualsRequest) {
  std::mt19937 rng(41);
  for (double peak : {0.1, 1.0, 30.0}) {
    for (double n : {1.0, 5.0, 50.0, 500.0}) {
      // C is stored as float: its rounding (eps / 2 relative) is amplified n-fold in c^n.
      const double tol = n * kFloatEps * peak;
      const LobeParams lobe = MirrorLobe(peak, n);
      EXPECT_FLOAT_EQ(lobe.cx, lobe.cy);
      EXPECT_FLOAT_EQ(lobe.cz, -lobe.cx);
      for (int i = 0; i < 10; ++i) {
        const Vec3d wi = RandomDirection(&rng, true);
        const Vec3d wo = Mirror(wi);
        const double at_peak =
            LafortuneLobe<double>(wi.data(), wo.data(), lobe.cx, lobe.cy, lobe.cz, lobe.n);
        EXPECT_NEAR(at_peak, peak, tol) << "peak " << peak << ", n " << n;
        // Any other outgoing direction sees less.
        const Vec3d other = RandomDirection(&rng, true);
        EXPECT_LE(LafortuneLobe<double>(wi.data(), other.data(), lobe.cx, lobe.cy, lobe.cz, lobe.n),
                  at_peak + tol);
      }
    }
  }
}

TEST(MirrorLobe, AnisotropicLobeKeepsPeakAtNormalIncidence) {
  const LobeParams lobe = MirrorLobe(4.0, 20.0, 2.0);
  EXPECT_FLOAT_EQ(lobe.cx, 4 * lobe.cy);  // -c a versus -c / a with a = 2
  const double normal[3] = {0, 0, 1};
  EXPECT_NEAR(LafortuneLobe<double>(normal, normal, lobe.cx, lobe.cy, lobe.cz, lobe.n), 4.0,
              20 * kFloatEps * 4.0);
}

BrdfParams TwoLobeParams() {
  BrdfParams p;
  p.num_lobes = 2;
  p.rho_d = {0.5f, 0.4f, 0.3f};
  for (int c = 0; c < kChannels; ++c) {
    p.lobes[0][c] = MirrorLobe(2.0 + c, 20.0);
    p.lobes[1][c] = MirrorLobe(0.5, 3.0 + c, 1.5);
  }
  return p;
}

TEST(EvalRgb, MatchesReferencePerChannel) {
  constexpr double kFloatEvalTol = 1e-5;  // float evaluation, n <= 20 (see FloatAgreesWithDouble)
  const BrdfParams p = TwoLobeParams();
  std::mt19937 rng(43);
  for (int i = 0; i < 100; ++i) {
    const Vec3f wi = RandomDirection(&rng, true).cast<float>();
    const Vec3f wo = RandomDirection(&rng, true).cast<float>();
    const Vec3f f = EvalRgb(p, wi, wo);
    for (int c = 0; c < kChannels; ++c) {
      const std::array<float, kMaxParamsPerChannel> channel = p.Channel(c);
      Params channel_d;
      std::copy(channel.begin(), channel.end(), channel_d.begin());
      const double expected =
          ReferenceChannel(wi.cast<double>(), wo.cast<double>(), channel_d, p.num_lobes);
      EXPECT_NEAR(f[c], expected, kFloatEvalTol * expected) << "case " << i << ", channel " << c;
    }
  }
}

TEST(BrdfParams, IsFiniteChecksOnlyActiveLobes) {
  BrdfParams p = TwoLobeParams();
  EXPECT_TRUE(IsFinite(p));
  p.lobes[2][1].n = std::numeric_limits<float>::quiet_NaN();  // lobe 2 is unused
  EXPECT_TRUE(IsFinite(p));
  p.lobes[1][2].cy = std::numeric_limits<float>::infinity();
  EXPECT_FALSE(IsFinite(p));
  p = TwoLobeParams();
  p.rho_d[1] = std::numeric_limits<float>::quiet_NaN();
  EXPECT_FALSE(IsFinite(p));
}

TEST(BrdfParams, ToStringListsAlbedoAndActiveLobes) {
  const std::string s = TwoLobeParams().ToString();
  EXPECT_NE(s.find("num_lobes=2"), std::string::npos) << s;
  EXPECT_NE(s.find("rho_d=(0.5, 0.4, 0.3)"), std::string::npos) << s;
  EXPECT_NE(s.find("lobe1="), std::string::npos) << s;
  EXPECT_EQ(s.find("lobe2="), std::string::npos) << s;
}

}  // namespace
}  // namespace reflcap::brdf
