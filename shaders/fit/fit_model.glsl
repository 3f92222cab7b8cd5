// GLSL twin of engine/fit/model.h's fitting model (float): LobeValueAndSlopes and EvalModel for
// one compile-time layout, and of lm.h's RobustLoss — same names (with a Fit prefix where GLSL
// would clash), argument order, parameter layouts, clamps and saturation.
//
// Four residuals at a time: every function here takes and returns vec4, one residual per
// component, each component computed with the scalar C++ twin's formulas for its one residual.
// Why: lavapipe runs a shader 8 invocations wide, one SIMD lane each, so a scalar sample loop is
// one long dependency chain per iteration (log, exp, a division: latency-bound at ~1.4
// instructions per cycle, measured with perf on its JIT code), and every loop-carried
// accumulator costs a masked load-blend-store per iteration. Four components are four independent
// chains the CPU overlaps, and the accumulators take one update per four residuals (with
// lm_fit.comp's residual quads: ~105,000 -> ~170,000 fits/s on lavapipe, bench/RESULTS.md). A GPU
// runs the same component arithmetic; only the order in which the normal equations are summed
// changes.
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

// Whether FitExp and FitLog use the device's own exp and log: a specialization constant of
// lm_fit_cluster.comp (FIT_NATIVE_MATH_CONSTANT_ID defined; true on GPUs, whose exp2/log2 units
// are within a few ulps — the agreement tests' bounds hold, fit_vulkan_test.cc measures them),
// false everywhere else (lavapipe's built-ins are far looser: common/precise_math.glsl).
#ifdef FIT_NATIVE_MATH_CONSTANT_ID
layout(constant_id = FIT_NATIVE_MATH_CONSTANT_ID) const bool kFitNativeMath = false;
#else
const bool kFitNativeMath = false;
#endif

// e^x for x in [kFitMinLobeLogArg, kFitMaxLobeLogArg] (the callers clamp): Cody and Waite's
// reduction x = k ln 2 + r, |r| <= ln(2) / 2 (k ln 2 split in two, k C1 exact for |k| < 2^15),
// e^r by its Taylor series through r^7 (truncation (ln(2) / 2)^8 / 8! < 6e-9 relative, a tenth
// of an ulp), times 2^k built from its exponent bits (exact: k is in [-115, 22] over the
// clamped range, so 2^k and the product stay normal). Within 2 ulp of glibc's expf.
vec4 FitExp(vec4 x) {
  if (kFitNativeMath) return exp(x);
  vec4 k = floor(x * 1.44269504088896341 + 0.5);
  precise vec4 r = (x - k * 0.693359375) - k * -2.12194440e-4;
  precise vec4 p = 1.0 + r * (1.0 + r * (0.5 + r * (1.0 / 6.0 + r * (1.0 / 24.0 + r * (1.0 / 120.0 +
                   r * (1.0 / 720.0 + r * (1.0 / 5040.0)))))));
  return p * uintBitsToFloat(uvec4(ivec4(k) + 127) << 23);
}

// log(x) for a positive, finite, normal x (callers pass x > kPowBaseMin), within 1 ulp of
// glibc's logf: fdlibm's e_logf.c. x = 2^k m, m in [sqrt(1/2), sqrt(2)), f = m - 1 (exact);
// log(1 + f) = f - (f^2 / 2 - s (f^2 / 2 + R(s^2))), s = f / (2 + f), R a degree-4 minimax
// polynomial in s^2 (error < 2^-34), k ln 2 split in two so that k ln2_hi is exact. The large
// term f enters exactly, which is what keeps the result within an ulp (common/precise_math.glsl's
// PreciseLog, 2 atanh(s) summed as one series, is within 3, and b^n turns an ulp of log b into
// n ulps of the lobe: the CPU paths use libm's correctly rounded logf).
vec4 FitLog(vec4 x) {
  if (kFitNativeMath) return log(x);
  ivec4 e;
  vec4 m = frexp(x, e);  // m in [0.5, 1)
  bvec4 low = lessThan(m, vec4(0.70710678118654752));
  m = mix(m, m * 2.0, low);  // exact
  e -= ivec4(low);
  precise vec4 f = m - 1.0;
  precise vec4 k = vec4(e);
  precise vec4 s = f / (2.0 + f);
  precise vec4 z = s * s;
  precise vec4 w = z * z;
  precise vec4 t1 = w * (0.40000972152 + w * 0.24279078841);
  precise vec4 t2 = z * (0.66666662693 + w * 0.28498786688);
  precise vec4 r = t2 + t1;
  precise vec4 hfsq = 0.5 * f * f;
  precise vec4 result = k * 6.9313812256e-01 - ((hfsq - (s * (hfsq + r) + k * 9.0580006145e-06)) - f);
  return result;
}

// model.h LobeValueAndSlopes: max(0, base)^n (capped), d value / d base, d value / d n.
vec4 FitLobeValueAndSlopes(vec4 base, vec4 n, out vec4 dvalue_dbase, out vec4 dvalue_dn) {
  bvec4 lit = greaterThan(base, vec4(kPowBaseMin));
  vec4 safe_base = mix(vec4(1.0), base, lit);  // log(1) = 0: a stand-in
  vec4 log_base = FitLog(safe_base);
  vec4 arg0 = n * log_base;
  vec4 arg = min(arg0, vec4(kFitMaxLobeLogArg));
  arg = max(arg, vec4(kFitMinLobeLogArg));
  vec4 raw = mix(vec4(0.0), FitExp(arg), lit);
  vec4 value = min(raw, vec4(kFitMaxLobeValue));
  // Slopes, 0 where cut off (value = 0), floored or saturated (the value is a constant there).
  vec4 live = mix(vec4(0.0), vec4(1.0), greaterThan(arg0, vec4(kFitMinLobeLogArg))) *
              mix(vec4(0.0), vec4(1.0), lessThan(raw, vec4(kFitMaxLobeValue)));
  dvalue_dbase = live * n * value / safe_base;
  dvalue_dn = live * value * log_base;
  return value;
}

// Per component: `a` where `channel` is 0, `b` where 1, `c` where 2.
vec4 FitByChannel(ivec4 channel, float a, float b, float c) {
  return mix(mix(vec4(a), vec4(b), equal(channel, ivec4(1))), vec4(c), equal(channel, ivec4(2)));
}

// model.h EvalModel<M, K>: f of four residuals of channels `channel` (0..2; only shared uses it)
// at parameters x (normalised units) and their gradients with respect to all FIT_P parameters.
vec4 FitEvalModel(float x[FIT_P], vec4 xx, vec4 yy, vec4 zz, ivec4 channel,
                  out vec4 grad[FIT_P]) {
  vec4 f;
#if FIT_MODEL == 2
  f = FitByChannel(channel, x[0], x[1], x[2]) * kInvPi;
  grad[0] = FitByChannel(channel, kInvPi, 0.0, 0.0);
  grad[1] = FitByChannel(channel, 0.0, kInvPi, 0.0);
  grad[2] = FitByChannel(channel, 0.0, 0.0, kInvPi);
#else
  f = vec4(x[0] * kInvPi);
  grad[0] = vec4(kInvPi);
#endif
  [[unroll]] for (int k = 0; k < FIT_LOBES; ++k) {
    int o = FIT_LAMBERT + FIT_PER_LOBE * k;
    vec4 dvdb, dvdn;
#if FIT_MODEL == 0
    precise vec4 base = x[o] * xx + x[o + 1] * yy + x[o + 2] * zz;
    f += FitLobeValueAndSlopes(base, vec4(x[o + 3]), dvdb, dvdn);
    grad[o] = dvdb * xx;
    grad[o + 1] = dvdb * yy;
    grad[o + 2] = dvdb * zz;
    grad[o + 3] = dvdn;
#elif FIT_MODEL == 1
    precise vec4 xy = xx + yy;
    precise vec4 base = x[o] * xy + x[o + 1] * zz;
    f += FitLobeValueAndSlopes(base, vec4(x[o + 2]), dvdb, dvdn);
    grad[o] = dvdb * xy;
    grad[o + 1] = dvdb * zz;
    grad[o + 2] = dvdn;
#else
    precise vec4 base = x[o] * xx + x[o + 1] * yy + zz;
    vec4 shape = FitLobeValueAndSlopes(base, vec4(x[o + 2]), dvdb, dvdn);
    vec4 scale = FitByChannel(channel, x[o + 3], x[o + 4], x[o + 5]);
    f += scale * shape;
    grad[o] = scale * dvdb * xx;
    grad[o + 1] = scale * dvdb * yy;
    grad[o + 2] = scale * dvdn;
    grad[o + 3] = shape * FitByChannel(channel, 1.0, 0.0, 0.0);
    grad[o + 4] = shape * FitByChannel(channel, 0.0, 1.0, 0.0);
    grad[o + 5] = shape * FitByChannel(channel, 0.0, 0.0, 1.0);
#endif
  }
  return f;
}

// lm.h RobustLoss: rho(s) and rho'(s) at s = r^2, scale a > 0; `loss` is kFitLoss*.
void FitRobustLoss(int loss, vec4 s, float a, out vec4 rho, out vec4 rho1) {
  if (loss == kFitLossHuber) {
    bvec4 outer = greaterThan(s, vec4(a * a));
    vec4 root = sqrt(mix(vec4(1.0), s, outer));
    rho = mix(s, 2.0 * a * root - a * a, outer);
    rho1 = mix(vec4(1.0), a / root, outer);
  } else if (loss == kFitLossCauchy) {
    vec4 u = 1.0 + s / (a * a);
    rho = a * a * FitLog(u);
    rho1 = 1.0 / u;
  } else {
    rho = s;
    rho1 = vec4(1.0);
  }
}

#endif  // REFLCAP_SHADERS_FIT_FIT_MODEL_GLSL_
