// GLSL twin of engine/fit/model.h's fitting model (float): LobeValueAndSlopes and EvalModel for
// one compile-time layout, and of lm.h's RobustLoss — same names (with a Fit prefix where GLSL
// would clash), argument order, parameter layouts, clamps and saturation.
//
// The layout is fixed by the includer's defines (one shader permutation per layout):
//   FIT_MODEL  0 aniso [rho, (Cx, Cy, Cz, n) per lobe], 1 iso [rho, (Cxy, Cz, n) per lobe],
//              2 shared [rho_R, rho_G, rho_B, (Cx, Cy, n, s_R, s_G, s_B) per lobe]
//   FIT_LOBES  K, the lobe count
// and gives FIT_P = NumParams(model, K).
//
// A lobe is exp(n log b), the exponent argument clamped to [kFitMinLobeLogArg,
// kFitMaxLobeLogArg], value 0 for b <= kPowBaseMin, saturated at kFitMaxLobeValue with zero
// slope, slope n value / b. model.h writes the cut-offs of the slopes as clamped steep ramps
// (a SIMD code-generation matter); for float inputs those ramps are exactly the step functions
// used here: (arg0 - kFitMinLobeLogArg) 1e30 is either <= 0 or far above 1 because float
// spacing near 80 is 7.6e-6, and (kFitMaxLobeValue - raw) 1e30 likewise (spacing 0.06 at 1e6).
//
// exp and log: lavapipe's built-ins are far looser than libm's (common/precise_math.glsl says
// how much), so exp and log are FitExp and FitLog below, each within an ulp of glibc's expf and
// logf that the CPU paths call. The base is `precise` (no fused multiply-add), as in
// common/lafortune.glsl: b^n magnifies a 1-ulp difference in b n-fold.
#ifndef REFLCAP_SHADERS_FIT_FIT_MODEL_GLSL_
#define REFLCAP_SHADERS_FIT_FIT_MODEL_GLSL_

#include "shared/fit_gpu.h"
#include "shared/fit_status.h"
#include "shared/math_constants.h"

#if FIT_MODEL == 0
#define FIT_LAMBERT 1
#define FIT_PER_LOBE 4
#elif FIT_MODEL == 1
#define FIT_LAMBERT 1
#define FIT_PER_LOBE 3
#elif FIT_MODEL == 2
#define FIT_LAMBERT 3
#define FIT_PER_LOBE 6
#else
#error "FIT_MODEL must be 0 (aniso), 1 (iso) or 2 (shared)"
#endif
#define FIT_P (FIT_LAMBERT + FIT_PER_LOBE * FIT_LOBES)
#define FIT_PACKED (FIT_P * (FIT_P + 1) / 2)
// Residual channels of one problem: shared couples all three.
#if FIT_MODEL == 2
#define FIT_CHANNELS 3
#else
#define FIT_CHANNELS 1
#endif

// True for finite x, by its bits: comparisons with NaN and isnan/isinf may be folded away by a
// driver compiler that assumes no NaN or Inf, bit tests cannot.
bool FitIsFinite(float x) { return (floatBitsToUint(x) & 0x7F800000u) != 0x7F800000u; }
bool FitIsNan(float x) { return (floatBitsToUint(x) & 0x7FFFFFFFu) > 0x7F800000u; }

// e^x for x in [kFitMinLobeLogArg, kFitMaxLobeLogArg] (the callers clamp): Cody and Waite's
// reduction x = k ln 2 + r, |r| <= ln(2) / 2 (k ln 2 split in two, k C1 exact for |k| < 2^15),
// e^r by its Taylor series through r^8 (truncation < 3e-10 relative), scaled by 2^k. Within
// 2 ulp of glibc's expf; 2^k stays normal (k >= -116) over the clamped range.
float FitExp(float x) {
  float k = floor(x * 1.44269504088896341 + 0.5);
  precise float r = (x - k * 0.693359375) - k * -2.12194440e-4;
  precise float p = 1.0 + r * (1.0 + r * (0.5 + r * (1.0 / 6.0 + r * (1.0 / 24.0 + r * (1.0 / 120.0 +
                    r * (1.0 / 720.0 + r * (1.0 / 5040.0 + r * (1.0 / 40320.0))))))));
  return ldexp(p, int(k));
}

// log(x) for a positive, finite, normal x (callers pass x > kPowBaseMin), within 1 ulp of
// glibc's logf: fdlibm's e_logf.c. x = 2^k m, m in [sqrt(1/2), sqrt(2)), f = m - 1 (exact);
// log(1 + f) = f - (f^2 / 2 - s (f^2 / 2 + R(s^2))), s = f / (2 + f), R a degree-4 minimax
// polynomial in s^2 (error < 2^-34), k ln 2 split in two so that k ln2_hi is exact. The large
// term f enters exactly, which is what keeps the result within an ulp (common/precise_math.glsl's
// PreciseLog, 2 atanh(s) summed as one series, is within 3, and b^n turns an ulp of log b into
// n ulps of the lobe: the CPU paths use libm's correctly rounded logf).
float FitLog(float x) {
  int e;
  float m = frexp(x, e);  // m in [0.5, 1)
  if (m < 0.70710678118654752) {
    m *= 2.0;
    e -= 1;
  }
  precise float f = m - 1.0;
  precise float k = float(e);
  precise float s = f / (2.0 + f);
  precise float z = s * s;
  precise float w = z * z;
  precise float t1 = w * (0.40000972152 + w * 0.24279078841);
  precise float t2 = z * (0.66666662693 + w * 0.28498786688);
  precise float r = t2 + t1;
  precise float hfsq = 0.5 * f * f;
  precise float result = k * 6.9313812256e-01 - ((hfsq - (s * (hfsq + r) + k * 9.0580006145e-06)) - f);
  return result;
}

// model.h LobeValueAndSlopes: max(0, base)^n (capped), d value / d base, d value / d n.
float FitLobeValueAndSlopes(float base, float n, out float dvalue_dbase, out float dvalue_dn) {
  float safe_base = base > kPowBaseMin ? base : 1.0;  // log(1) = 0: a stand-in
  float log_base = FitLog(safe_base);
  float arg0 = n * log_base;
  float arg = arg0 > kFitMaxLobeLogArg ? kFitMaxLobeLogArg : arg0;
  arg = arg < kFitMinLobeLogArg ? kFitMinLobeLogArg : arg;
  float raw = base > kPowBaseMin ? FitExp(arg) : 0.0;
  float value = kFitMaxLobeValue > raw ? raw : kFitMaxLobeValue;
  // Slopes, 0 where cut off (value = 0), floored or saturated (the value is a constant there).
  float live = (arg0 > kFitMinLobeLogArg && kFitMaxLobeValue > raw) ? 1.0 : 0.0;
  dvalue_dbase = live * n * value / safe_base;
  dvalue_dn = live * value * log_base;
  return value;
}

// model.h EvalModel<M, K>: f of residual channel `channel` (0..2; only shared uses it) at
// parameters x (normalised units) and its gradient with respect to all FIT_P parameters.
float FitEvalModel(float x[FIT_P], float xx, float yy, float zz, int channel,
                   out float grad[FIT_P]) {
  float f;
#if FIT_MODEL == 2
  float rho = channel == 0 ? x[0] : (channel == 1 ? x[1] : x[2]);
  f = rho * kInvPi;
  grad[0] = channel == 0 ? kInvPi : 0.0;
  grad[1] = channel == 1 ? kInvPi : 0.0;
  grad[2] = channel == 2 ? kInvPi : 0.0;
#else
  f = x[0] * kInvPi;
  grad[0] = kInvPi;
#endif
  [[unroll]] for (int k = 0; k < FIT_LOBES; ++k) {
    int o = FIT_LAMBERT + FIT_PER_LOBE * k;
    float dvdb, dvdn;
#if FIT_MODEL == 0
    precise float base = x[o] * xx + x[o + 1] * yy + x[o + 2] * zz;
    f += FitLobeValueAndSlopes(base, x[o + 3], dvdb, dvdn);
    grad[o] = dvdb * xx;
    grad[o + 1] = dvdb * yy;
    grad[o + 2] = dvdb * zz;
    grad[o + 3] = dvdn;
#elif FIT_MODEL == 1
    precise float xy = xx + yy;
    precise float base = x[o] * xy + x[o + 1] * zz;
    f += FitLobeValueAndSlopes(base, x[o + 2], dvdb, dvdn);
    grad[o] = dvdb * xy;
    grad[o + 1] = dvdb * zz;
    grad[o + 2] = dvdn;
#else
    precise float base = x[o] * xx + x[o + 1] * yy + zz;
    float shape = FitLobeValueAndSlopes(base, x[o + 2], dvdb, dvdn);
    float scale = channel == 0 ? x[o + 3] : (channel == 1 ? x[o + 4] : x[o + 5]);
    f += scale * shape;
    grad[o] = scale * dvdb * xx;
    grad[o + 1] = scale * dvdb * yy;
    grad[o + 2] = scale * dvdn;
    grad[o + 3] = channel == 0 ? shape : 0.0;
    grad[o + 4] = channel == 1 ? shape : 0.0;
    grad[o + 5] = channel == 2 ? shape : 0.0;
#endif
  }
  return f;
}

// lm.h RobustLoss: rho(s) and rho'(s) at s = r^2, scale a > 0; `loss` is kFitLoss*.
void FitRobustLoss(int loss, float s, float a, out float rho, out float rho1) {
  if (loss == kFitLossHuber) {
    float root = sqrt(s > a * a ? s : 1.0);
    rho = s > a * a ? 2.0 * a * root - a * a : s;
    rho1 = s > a * a ? a / root : 1.0;
  } else if (loss == kFitLossCauchy) {
    float u = 1.0 + s / (a * a);
    rho = a * a * FitLog(u);
    rho1 = 1.0 / u;
  } else {
    rho = s;
    rho1 = 1.0;
  }
}

#endif  // REFLCAP_SHADERS_FIT_FIT_MODEL_GLSL_
