// Buffer layout of shaders/probe/brdf_probe.comp, which evaluates the GLSL twins of
// engine/math/safe_math.h and engine/brdf/lafortune.h on a list of cases so that
// tests/engine/gpu/twins_test.cc can compare them with the C++ float twins element by element.
#ifndef REFLCAP_SHADERS_SHARED_BRDF_PROBE_H_
#define REFLCAP_SHADERS_SHARED_BRDF_PROBE_H_

#include "interop.h"
#include "lafortune_constants.h"

REFLCAP_SHARED_BEGIN

// One case (binding 0, read-only).
struct BrdfProbeCase {
  float wi[3];                          // tangent frame, unit
  float wo[3];                          // tangent frame, unit
  float params[kMaxParamsPerChannel];   // EvalChannel layout; entries past num_lobes ignored
  int num_lobes;                        // 0..kMaxLobes
  float a;                              // scalar arguments of the safe_math twins (see below)
  float b;
  float c;
};
REFLCAP_STD430_SIZE(BrdfProbeCase, 92);
REFLCAP_STD430_OFFSET(BrdfProbeCase, wo, 12);
REFLCAP_STD430_OFFSET(BrdfProbeCase, params, 24);
REFLCAP_STD430_OFFSET(BrdfProbeCase, num_lobes, 76);
REFLCAP_STD430_OFFSET(BrdfProbeCase, c, 88);

// One result (binding 1, write-only), same index as its case.
struct BrdfProbeResult {
  float safe_sqrt;   // SafeSqrt(a)
  float safe_acos;   // SafeAcos(a)
  float safe_div;    // SafeDiv(a, b, c)
  float safe_log;    // SafeLog(a)
  float safe_pow;    // SafePow(a, b)
  float clamp;       // Clamp(a, b, c)
  float raw_pow;     // GLSL pow(a, b) unguarded: records the device's answer (e.g. pow(0, 0))
  float lobe;        // LafortuneLobe(wi, wo, params[1..4])
  float value;       // EvalChannel(wi, wo, params, num_lobes)
  float value_with_gradient;          // EvalChannelWithGradient's return value
  float gradient[kMaxParamsPerChannel];  // its gradient; entries past num_lobes are 0
};
REFLCAP_STD430_SIZE(BrdfProbeResult, 92);
REFLCAP_STD430_OFFSET(BrdfProbeResult, raw_pow, 24);
REFLCAP_STD430_OFFSET(BrdfProbeResult, gradient, 40);

// Push constants.
struct BrdfProbePush {
  uint count;  // number of cases
};
REFLCAP_STD430_SIZE(BrdfProbePush, 4);

REFLCAP_SHARED_END

#endif  // REFLCAP_SHADERS_SHARED_BRDF_PROBE_H_
