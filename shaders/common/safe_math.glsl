// GLSL twin of engine/math/safe_math.h: SafeSqrt, SafeAcos, SafeDiv, SafeLog, SafePow and Clamp
// with the same names, argument order, constants (shaders/shared/math_constants.h, checked
// against the C++ ones) and fallbacks as the C++ templates instantiated for float. Keep the two
// files in step; tests/engine/gpu/twins_test.cc compares them element by element through
// shaders/probe/brdf_probe.comp.
//
// Only float: GLSL's acos, log, pow and exp have no double-precision versions (lavapipe has
// shaderFloat64 but no double exp/log either), and the GPU fitter runs in float. acos, log and
// pow come from common/precise_math.glsl, not the built-ins, whose Vulkan precision (2^-21
// absolute for log near 1, 4096 ulp for acos) is far below the C++ twins' (see there). The C++
// DCHECKs on wildly out-of-range arguments have no GLSL counterpart; the fallbacks are the same. Every guard is a comparison
// that a NaN argument fails, as in C++, but Vulkan does not promise NaN propagation unless a
// shader asks for SignedZeroInfNanPreserve, so a shader must not rely on it.
#ifndef REFLCAP_SHADERS_COMMON_SAFE_MATH_GLSL_
#define REFLCAP_SHADERS_COMMON_SAFE_MATH_GLSL_

#include "common/precise_math.glsl"
#include "shared/math_constants.h"

// sqrt(max(0, x)).
float SafeSqrt(float x) {
  if (x <= 0.0) return 0.0;
  return sqrt(x);
}

// acos(clamp(x, -1, 1)) in radians.
float SafeAcos(float x) {
  if (x >= 1.0) return 0.0;
  if (x <= -1.0) return kPi;
  return PreciseAcos(x);
}

// a / b, or `fallback` when b == 0 exactly.
float SafeDiv(float a, float b, float fallback) {
  if (b == 0.0) return fallback;
  return a / b;
}

// log(x) for x > kTiny, log(kTiny) otherwise (including x <= 0).
float SafeLog(float x) {
  if (x <= kTiny) return PreciseLog(kTiny);
  return PreciseLog(x);
}

// b^n for b > kPowBaseMin, exactly 0 otherwise, for any n. GLSL's pow is undefined for b < 0 and
// for b = 0, n <= 0 (lavapipe returns pow(0, 0) = 0, C returns 1): the guard decides both.
float SafePow(float b, float n) {
  if (b <= kPowBaseMin) return 0.0;
  return PrecisePow(b, n);
}

// x limited to [lo, hi]; lo <= hi. Unlike GLSL's clamp (min(max(x, lo), hi)), whose NaN result
// is undefined, this is the same sequence of comparisons as the C++ Clamp.
float Clamp(float x, float lo, float hi) {
  if (x < lo) return lo;
  if (x > hi) return hi;
  return x;
}

#endif  // REFLCAP_SHADERS_COMMON_SAFE_MATH_GLSL_
