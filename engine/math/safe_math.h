#pragma once
// Safe elementary functions: SafeSqrt, SafeAcos, SafeDiv, SafeLog, SafePow and Clamp, defined on
// every input where the plain function is undefined (negative roots, |x| > 1 in acos, division by
// zero, log of zero, pow with a non-positive base), with a documented fallback value instead.
//
// Why: the BRDF fit evaluates these per texel millions of times, on the CPU (float, double and
// ceres::Jet for derivative checks) and on the GPU. A single NaN poisons a texel's LM step, and
// GLSL leaves pow(b, n) undefined for b < 0 and for b = 0, n <= 0, so the CPU and GPU paths can
// only agree if both apply the same guards. shaders/common/safe_math.glsl is the GLSL twin: same
// names, argument order, constants and fallbacks; keep the two in step.
//
// Templates work for float, double and ceres::Jet: they use only +, -, *, /, comparisons (which
// for a Jet compare its scalar part) and sqrt/log/pow/acos found by argument-dependent lookup, so
// Ceres' Jet overloads apply. A fallback is always a constant, so its derivative is exactly 0 and
// never the 0 * inf = NaN that differentiating sqrt, log or acos at the clamp would give.
// After pbrt-v4's util/math.h (SafeSqrt, SafeACos). Debug builds check for wildly out-of-range
// arguments (bugs upstream); release builds only clamp. NaN arguments propagate (every guard is
// a comparison that NaN fails), so the fitter's non-finite checks still see them.
#include <cmath>

#include "engine/core/check.h"
#include "engine/math/types.h"

namespace reflcap {

// Smallest argument SafeLog takes and largest base SafePow treats as zero. Far above float's
// smallest normal (1.2e-38), so neither log nor pow ever meets a denormal (GPUs may flush those to
// 0, which would make pow undefined again); far below any radiance, BRDF value or lobe base that
// matters (a lobe base of 1e-30 contributes at most 1e-30 to a BRDF value when n >= 1).
constexpr double kTiny = 1e-30;

// SafePow(b, n) returns exactly 0 for b <= kPowBaseMin. It equals kTiny so that the pow and the
// log in a pow's exponent derivative (b^n log b) see the same domain.
constexpr double kPowBaseMin = kTiny;

// How far outside its domain a SafeSqrt / SafeAcos argument of order one may lie before a debug
// build flags it: float rounding of a dot product or of 1 - x^2 errs by ~1e-7, never by 1e-3.
constexpr double kSafeDomainSlack = 1e-3;

// sqrt(max(0, x)). x should be >= -kSafeDomainSlack (rounding noise around 0); derivative 0 for
// x <= 0 (the true one is infinite at 0).
template <typename T>
T SafeSqrt(const T& x) {
  REFLCAP_DCHECK(!(x < -kSafeDomainSlack)) << "SafeSqrt of " << x;
  if (x <= T(0)) return T(0);
  using std::sqrt;
  return sqrt(x);
}

// acos(clamp(x, -1, 1)) in radians. x should lie within kSafeDomainSlack of [-1, 1]; the
// derivative is 0 at and beyond +-1 (the true one is infinite there).
template <typename T>
T SafeAcos(const T& x) {
  REFLCAP_DCHECK(!(x < -1.0 - kSafeDomainSlack) && !(x > 1.0 + kSafeDomainSlack))
      << "SafeAcos of " << x;
  if (x >= T(1)) return T(0);
  if (x <= T(-1)) return T(kPi);
  using std::acos;
  return acos(x);
}

// a / b, or `fallback` when b == 0 exactly (the caller knows what the quotient should mean there,
// e.g. 0 for a weight over an empty sum). A tiny non-zero b still divides.
template <typename T>
T SafeDiv(const T& a, const T& b, const T& fallback) {
  if (b == T(0)) return fallback;
  return a / b;
}

// log(x) for x > kTiny, log(kTiny) (about -69.08) otherwise, including x <= 0.
template <typename T>
T SafeLog(const T& x) {
  using std::log;
  if (x <= T(kTiny)) return log(T(kTiny));
  return log(x);
}

// b^n for b > kPowBaseMin, exactly 0 otherwise, for any n. GLSL's pow is undefined for b < 0 and
// for b = 0, n <= 0 (lavapipe returns pow(0, 0) = 0 where C's pow gives 1), so the twins decide
// both cases the same way: 0, which is also the limit of b^n as b -> 0+ for every n > 0. Callers
// keep n > 0 (the Lafortune lobe keeps n >= 1); for n <= 0 the cut-off makes b^n discontinuous.
template <typename T>
T SafePow(const T& b, const T& n) {
  if (b <= T(kPowBaseMin)) return T(0);
  using std::pow;
  return pow(b, n);
}

// x limited to [lo, hi]; lo <= hi. The derivative is 0 where x is clamped.
template <typename T>
T Clamp(const T& x, const T& lo, const T& hi) {
  REFLCAP_DCHECK(!(hi < lo)) << "Clamp to [" << lo << ", " << hi << "]";
  if (x < lo) return lo;
  if (x > hi) return hi;
  return x;
}

}  // namespace reflcap
