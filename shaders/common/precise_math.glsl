// Float log, log2, pow and acos accurate to a few ulp, for the GLSL twins (safe_math.glsl,
// lafortune.glsl). Their C++ twins are libm's logf, powf and acosf (correctly rounded or within
// an ulp), which the C++ float templates call.
//
// Why not GLSL's built-ins: Vulkan allows log and log2 an *absolute* error of 2^-21 on [0.5, 2]
// (so any relative error near 1), pow inherits that through exp2(y log2 x) — multiplied by y, 0.3%
// at n = 1e4 — and acos 4096 ulp. lavapipe uses such approximations: log(1 - 1.2e-7) comes out
// 13% off, acos(0.25) 1e-4 off, 0.999^1e4 6e-4 off. The GPU fitter must agree with the CPU
// reference (same LM, same stopping tests) far better than that, so the twins use these
// functions, built from exact or correctly rounded operations (frexp, +, *, sqrt) and exp2 alone,
// for about ten extra multiply-adds per call.
//
// Preconditions: PreciseLog/PreciseLog2/PrecisePow need a positive, finite, normal x (the
// callers' guards ensure x > kTiny = 1e-30); PreciseAcos needs x in [-1, 1].
#ifndef REFLCAP_SHADERS_COMMON_PRECISE_MATH_GLSL_
#define REFLCAP_SHADERS_COMMON_PRECISE_MATH_GLSL_

// ln(m) for m in [sqrt(1/2), sqrt(2)): 2 atanh(s), s = (m - 1) / (m + 1), |s| <= 0.1716, by its
// series through s^11 (the next term is below 6e-11 relative). m - 1 is exact (Sterbenz).
float PreciseLogMantissa(float m) {
  precise float s = (m - 1.0) / (m + 1.0);
  precise float s2 = s * s;
  precise float series =
      1.0 + s2 * (1.0 / 3.0 + s2 * (1.0 / 5.0 + s2 * (1.0 / 7.0 + s2 * (1.0 / 9.0 + s2 / 11.0))));
  return 2.0 * s * series;
}

// x = m 2^e with m in [sqrt(1/2), sqrt(2)).
float PreciseSplit(float x, out int e) {
  float m = frexp(x, e);  // m in [0.5, 1)
  if (m < 0.70710678118654752) {
    m *= 2.0;
    e -= 1;
  }
  return m;
}

// Natural logarithm; ln 2 split in two (Cody and Waite) so that e ln 2 is exact for |e| < 2^11.
float PreciseLog(float x) {
  int e;
  float m = PreciseSplit(x, e);
  precise float fe = float(e);
  precise float result = fe * 0.693359375 + (PreciseLogMantissa(m) + fe * -2.12194440e-4);
  return result;
}

float PreciseLog2(float x) {
  int e;
  float m = PreciseSplit(x, e);
  precise float result = float(e) + PreciseLogMantissa(m) * 1.44269504088896341;
  return result;
}

// x^y = 2^(y log2 x) for x > 0. The relative error is about |y log2 x| ulp (the rounding of the
// exponent) plus exp2's own: 1e-6 for results above 1e-6, 1e-5 down to 1e-30.
float PrecisePow(float x, float y) {
  return exp2(y * PreciseLog2(x));
}

// acos(x) on [-1, 1]: Abramowitz and Stegun 4.4.46, sqrt(1 - x) times a degree-7 polynomial for
// x >= 0 (absolute error <= 2e-8), pi - acos(-x) for x < 0.
float PreciseAcos(float x) {
  float ax = abs(x);
  precise float p =
      1.5707963050 + ax * (-0.2145988016 + ax * (0.0889789874 + ax * (-0.0501743046 +
      ax * (0.0308918810 + ax * (-0.0170881256 + ax * (0.0066700901 + ax * -0.0012624911))))));
  precise float r = sqrt(1.0 - ax) * p;
  return x < 0.0 ? 3.14159265358979323846 - r : r;
}

#endif  // REFLCAP_SHADERS_COMMON_PRECISE_MATH_GLSL_
