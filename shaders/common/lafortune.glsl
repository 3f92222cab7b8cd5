// GLSL twin of engine/brdf/lafortune.h (float): LafortuneLobe, EvalChannel and
// EvalChannelWithGradient with the C++ names, argument order, parameter layout, cut-offs and
// saturation. The model, per colour channel:
//
//   f(wi, wo) = rho_d / pi + sum_k max(0, Cx,k wix wox + Cy,k wiy woy + Cz,k wiz woz)^n_k
//
// wi, wo: unit vectors in the texel's tangent frame (z = shading normal), away from the surface.
// params: [rho_d, Cx_0, Cy_0, Cz_0, n_0, Cx_1, ...] (kMaxParamsPerChannel floats; the first
// 1 + 4 num_lobes are used). A lobe is 0 where its base b <= kPowBaseMin and kMaxLobeValue where
// b^n exceeds it; its gradient is 0 in both cases. n must lie in [kMinLobeExponent, kMaxExponent]
// of lafortune.h, and in [kMinExponent, kMaxExponent] for the gradient (the C++ DCHECKs this;
// here it is the caller's job).
//
// The products wi_j wo_j and the base are `precise` (no fused multiply-add), so the base is the
// same float as the C++ twin's, bit for bit: b^n turns a 1-ulp difference in b into an n-fold
// relative difference (6e-4 at n = 1e4), far above the 1e-5 the twins test asks for. pow and log
// are common/precise_math.glsl's, for the same reason.
// tests/engine/gpu/twins_test.cc compares this file with the C++ float twin.
#ifndef REFLCAP_SHADERS_COMMON_LAFORTUNE_GLSL_
#define REFLCAP_SHADERS_COMMON_LAFORTUNE_GLSL_

#include "common/precise_math.glsl"
#include "common/safe_math.glsl"
#include "shared/lafortune_constants.h"
#include "shared/math_constants.h"

// One lobe max(0, Cx wix wox + Cy wiy woy + Cz wiz woz)^n, saturated at kMaxLobeValue.
float LafortuneLobe(vec3 wi, vec3 wo, float cx, float cy, float cz, float n) {
  precise float xx = wi.x * wo.x;
  precise float yy = wi.y * wo.y;
  precise float zz = wi.z * wo.z;
  precise float base = cx * xx + cy * yy + cz * zz;
  float value = SafePow(base, n);
  if (value > kMaxLobeValue) return kMaxLobeValue;
  return value;
}

// f_c(wi, wo) for one channel, 0 <= num_lobes <= kMaxLobes.
float EvalChannel(vec3 wi, vec3 wo, float params[kMaxParamsPerChannel], int num_lobes) {
  precise float f = params[0] * kInvPi;
  for (int k = 0; k < num_lobes; ++k) {
    int p = 1 + 4 * k;
    f += LafortuneLobe(wi, wo, params[p], params[p + 1], params[p + 2], params[p + 3]);
  }
  return f;
}

// EvalChannel and its analytic gradient with respect to params (same layout):
//   d/drho_d = 1/pi,   d/dCx = n b^(n-1) wix wox (Cy, Cz alike),   d/dn = b^n log b,
// 0 for a lobe that is cut off or saturated, and 0 past 1 + 4 num_lobes (the C++ twin leaves
// those entries untouched).
float EvalChannelWithGradient(vec3 wi, vec3 wo, float params[kMaxParamsPerChannel],
                              int num_lobes, out float grad[kMaxParamsPerChannel]) {
  for (int i = 0; i < kMaxParamsPerChannel; ++i) grad[i] = 0.0;
  precise float f = params[0] * kInvPi;
  grad[0] = kInvPi;
  precise float xx = wi.x * wo.x;
  precise float yy = wi.y * wo.y;
  precise float zz = wi.z * wo.z;
  for (int k = 0; k < num_lobes; ++k) {
    int p = 1 + 4 * k;
    float n = params[p + 3];
    precise float base = params[p] * xx + params[p + 1] * yy + params[p + 2] * zz;
    float value = SafePow(base, n);
    if (base <= kPowBaseMin || value > kMaxLobeValue) {
      if (value > kMaxLobeValue) f += kMaxLobeValue;
      continue;  // gradient entries stay 0
    }
    f += value;
    float slope = n * PrecisePow(base, n - 1.0);  // d(b^n)/db; n - 1 >= 0 and b > 0: defined
    grad[p] = slope * xx;
    grad[p + 1] = slope * yy;
    grad[p + 2] = slope * zz;
    grad[p + 3] = value * PreciseLog(base);
  }
  return f;
}

#endif  // REFLCAP_SHADERS_COMMON_LAFORTUNE_GLSL_
