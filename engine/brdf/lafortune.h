#pragma once
// The Lambert + Lafortune BRDF that reflcap fits per texel, per colour channel c:
//
//   f_c(wi, wo) = rho_d,c / pi + sum_k max(0, Cx,k wix wox + Cy,k wiy woy + Cz,k wiz woz)^n_k
//
// after Lafortune, Foo, Torrance and Greenberg, "Non-linear approximation of reflectance
// functions", SIGGRAPH 1997. wi and wo are unit vectors in the texel's tangent frame (z = shading
// normal), both pointing away from the surface. rho_d is the diffuse albedo (f_d = rho_d / pi), so
// the rho_d of Fukuda et al., who write f = rho_d + lobes, equals ours divided by pi. Every
// channel has its own rho_d and its own C and n per lobe.
//
// A lobe is 0 wherever its base b = Cx wix wox + Cy wiy woy + Cz wiz woz is <= kPowBaseMin
// (SafePow), as ALTA's nonlinear_function_lafortune adds pow(b, n) only for b > 0; pow of a
// negative base is undefined. The formula is symmetric in wi and wo (reciprocal); it does not
// test that wi and wo lie in the upper hemisphere: directions below the surface are the caller's
// business (a fitter should mask such samples, e.g. below a kMinCosTheta).
//
// A lobe's exponent lies in [kMinLobeExponent, kMaxExponent]: the fitters (their box projection)
// keep the lobes they fit in [kMinExponent, kMaxExponent]; only the generalized diffuse lobe
// (Cx = Cy = 0, engine/fit/diffuse_falloff.h), fitted in closed form, goes below 1. The
// evaluation checks the range in debug builds only. The analytic gradient
// (EvalChannelWithGradient, the fitters' tool) is exact, finite for any base and any n in
// [kMinExponent, kMaxExponent], and exactly 0 where a lobe is cut off (b <= kPowBaseMin) or
// saturated (b^n > kMaxLobeValue).
//
// Parameter layout of one channel, as the fitter, the GPU shaders and the texture sets store it:
//   [rho_d, Cx_0, Cy_0, Cz_0, n_0, Cx_1, Cy_1, Cz_1, n_1, ...]   (ParamsPerChannel(num_lobes))
// The templates run as float (the GPU's twin), double (ground truth) and ceres::Jet (checks).
#include <array>
#include <cmath>
#include <string>

#include "engine/core/check.h"
#include "engine/math/safe_math.h"
#include "engine/math/types.h"

namespace reflcap::brdf {

constexpr int kMaxLobes = 3;
constexpr int kChannels = 3;

// Number of parameters of one colour channel: rho_d, then (Cx, Cy, Cz, n) per lobe.
constexpr int ParamsPerChannel(int num_lobes) { return 1 + 4 * num_lobes; }
constexpr int kMaxParamsPerChannel = ParamsPerChannel(kMaxLobes);

// n = 1 is the broadest lobe we model (a clamped cosine). Below 1 the lobe would be broader than
// that, which no glossy material shows, and its slope n b^(n-1) grows without bound as b -> 0+.
// For n > 1 the lobe is C1 at the cut-off b = 0 (slope -> 0), so zeroing its gradient there is
// exact; n = 1 has a finite kink.
constexpr double kMinExponent = 1.0;
// The generalized diffuse lobe (Cx = Cy = 0) is no glossy lobe: (Cz cos theta_i cos theta_o)^n
// with n < 1 darkens a surface towards grazing light and view without the sharp cut-off of
// n >= 1 (DiLiGenT pot1 and cat choose n = 0.25-0.75 for 47 % and 40 % of their texels). Its
// value is finite and continuous for every n > 0 (b^n -> 0 as b -> 0+); 0.25 is the smallest
// exponent engine/fit/diffuse_falloff.h tries. Its gradient is never taken (not fitted by LM).
constexpr double kMinLobeExponent = 0.25;
// n = 1e4 gives a lobe about 1/sqrt(n) = 0.01 rad (0.6 degrees) wide, narrower than a capture's
// angular resolution (light source and pixel footprints ~1 degree). It also bounds float error:
// rounding of b (6e-8 relative) is amplified n-fold in b^n, 6e-4 at most.
constexpr double kMaxExponent = 1e4;
// A lobe value b^n above this is returned as this constant (gradient 0) instead of overflowing.
// No real BRDF comes near it (a perfect mirror seen through a 1e-6 sr pixel is ~1e6), and
// kMaxExponent * kMaxLobeValue = 1e34 is still below float's maximum (3.4e38), so the gradient
// n b^(n-1) <= n b^n of an unsaturated lobe stays finite in float.
constexpr double kMaxLobeValue = 1e30;

// One Lafortune lobe max(0, Cx wix wox + Cy wiy woy + Cz wiz woz)^n, saturated at kMaxLobeValue.
// wi, wo: 3-vectors in the tangent frame; n in [kMinLobeExponent, kMaxExponent].
template <typename T>
T LafortuneLobe(const T* wi, const T* wo, const T& cx, const T& cy, const T& cz, const T& n) {
  REFLCAP_DCHECK(!(n < kMinLobeExponent) && !(n > kMaxExponent)) << "Lafortune exponent " << n;
  // Products wi_j wo_j first: IEEE multiplication commutes, so f(wi, wo) == f(wo, wi) exactly and
  // EvalChannelWithGradient, which forms the same products, returns the same value bit for bit.
  const T base = cx * (wi[0] * wo[0]) + cy * (wi[1] * wo[1]) + cz * (wi[2] * wo[2]);
  const T value = SafePow(base, n);
  if (value > T(kMaxLobeValue)) return T(kMaxLobeValue);
  return value;
}

// f_c(wi, wo) for one channel; `params` holds ParamsPerChannel(num_lobes) values (layout above),
// 0 <= num_lobes <= kMaxLobes.
template <typename T>
T EvalChannel(const T* wi, const T* wo, const T* params, int num_lobes) {
  REFLCAP_DCHECK(num_lobes >= 0 && num_lobes <= kMaxLobes) << "num_lobes " << num_lobes;
  T f = params[0] * T(kInvPi);
  for (int k = 0; k < num_lobes; ++k) {
    const T* lobe = params + 1 + 4 * k;
    f += LafortuneLobe(wi, wo, lobe[0], lobe[1], lobe[2], lobe[3]);
  }
  return f;
}

// EvalChannel and its analytic gradient with respect to `params`; `grad` receives
// ParamsPerChannel(num_lobes) values in the same layout. With b the base of lobe k:
//   d/drho_d = 1/pi,   d/dCx = n b^(n-1) wix wox (Cy, Cz alike),   d/dn = b^n log b,
// all exactly 0 where b <= kPowBaseMin (lobe cut off) or b^n > kMaxLobeValue (lobe saturated).
// Finite for every b and every n in [kMinExponent, kMaxExponent]: for b in (kPowBaseMin, 1],
// b^(n-1) <= 1 and |b^n log b| <= 1/(e n); for b > 1 both are bounded via kMaxLobeValue.
template <typename T>
T EvalChannelWithGradient(const T* wi, const T* wo, const T* params, int num_lobes, T* grad) {
  REFLCAP_DCHECK(num_lobes >= 0 && num_lobes <= kMaxLobes) << "num_lobes " << num_lobes;
  using std::log;
  using std::pow;
  T f = params[0] * T(kInvPi);
  grad[0] = T(kInvPi);
  const T xx = wi[0] * wo[0];
  const T yy = wi[1] * wo[1];
  const T zz = wi[2] * wo[2];
  for (int k = 0; k < num_lobes; ++k) {
    const T* lobe = params + 1 + 4 * k;
    T* lobe_grad = grad + 1 + 4 * k;
    const T& n = lobe[3];
    REFLCAP_DCHECK(!(n < kMinExponent) && !(n > kMaxExponent)) << "Lafortune exponent " << n;
    const T base = lobe[0] * xx + lobe[1] * yy + lobe[2] * zz;
    const T value = SafePow(base, n);
    if (base <= T(kPowBaseMin) || value > T(kMaxLobeValue)) {
      // Cut off (value 0) or saturated (value kMaxLobeValue): constant in every parameter.
      if (value > T(kMaxLobeValue)) f += T(kMaxLobeValue);
      for (int i = 0; i < 4; ++i) lobe_grad[i] = T(0);
      continue;
    }
    f += value;
    const T slope = n * pow(base, n - T(1));  // d(b^n)/db; n - 1 >= 0 and b > 0: defined.
    lobe_grad[0] = slope * xx;
    lobe_grad[1] = slope * yy;
    lobe_grad[2] = slope * zz;
    lobe_grad[3] = value * log(base);
  }
  return f;
}

// One lobe's parameters for one channel.
struct LobeParams {
  float cx = 0, cy = 0, cz = 0, n = 1;
};

// A texel's full BRDF: num_lobes in [0, kMaxLobes] lobes, each with per-channel C and n.
struct BrdfParams {
  int num_lobes = 0;
  std::array<float, kChannels> rho_d{};  // diffuse albedo per channel, in [0, 1]
  std::array<std::array<LobeParams, kChannels>, kMaxLobes> lobes{};  // [lobe][channel]

  // Channel c in the EvalChannel layout; entries past ParamsPerChannel(num_lobes) are 0.
  std::array<float, kMaxParamsPerChannel> Channel(int c) const;
  // "BrdfParams{num_lobes=1, rho_d=(0.5, 0.4, 0.3), lobe0=[(Cx,Cy,Cz,n) x3]}".
  std::string ToString() const;
};

// True when rho_d and the C's and n's of the first num_lobes lobes are all finite.
bool IsFinite(const BrdfParams& p);

// (f_r, f_g, f_b)(wi, wo): EvalChannel in float per channel; wi, wo unit, tangent frame.
Vec3f EvalRgb(const BrdfParams& p, const Vec3f& wi, const Vec3f& wo);

// A specular lobe around the mirror direction of wi, with value `peak` there and exponent n.
// The standard lobe has Cx = Cy = -c, Cz = c: its base is c (-wix wox - wiy woy + wiz woz) =
// c cos(angle between wo and the mirror (-wix, -wiy, wiz) of wi), so its peak value is c^n and
// c = peak^(1/n). `anisotropy` a > 0 sets Cx = -c a and Cy = -c / a: for a > 1 the lobe reaches
// further along the tangent x axis than along y. Only a = 1 keeps the value `peak` at the mirror
// direction for every wi; for a != 1 it holds at normal incidence (where the x, y terms vanish).
// peak > 0; n in [kMinExponent, kMaxExponent].
LobeParams MirrorLobe(double peak, double n, double anisotropy = 1.0);

}  // namespace reflcap::brdf
