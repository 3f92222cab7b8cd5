#version 460
// Evaluates the GLSL twins (common/safe_math.glsl, common/lafortune.glsl) on a list of cases for
// tests/engine/gpu/twins_test.cc, which runs the C++ float twins (engine/math/safe_math.h,
// engine/brdf/lafortune.h) on the same cases and compares element by element.
//
// Bindings (set 0): 0 = BrdfProbeCase[] (read), 1 = BrdfProbeResult[] (write); layouts and field
//                   meanings in shared/brdf_probe.h.
// Push constants:   BrdfProbePush {count}.
// Specialization:   constant_id 0 = local_size_x (default 64).
// C++ twin:         the test's CPU loop over the same cases.
#extension GL_GOOGLE_include_directive : require

#include "common/lafortune.glsl"
#include "common/safe_math.glsl"
#include "shared/brdf_probe.h"

layout(local_size_x = 64, local_size_x_id = 0) in;

layout(std430, set = 0, binding = 0) readonly buffer Cases { BrdfProbeCase cases[]; };
layout(std430, set = 0, binding = 1) writeonly buffer Results { BrdfProbeResult results[]; };
layout(push_constant) uniform Push { BrdfProbePush push; };

void main() {
  uint i = gl_GlobalInvocationID.x;
  if (i >= push.count) return;
  BrdfProbeCase c = cases[i];
  vec3 wi = vec3(c.wi[0], c.wi[1], c.wi[2]);
  vec3 wo = vec3(c.wo[0], c.wo[1], c.wo[2]);

  BrdfProbeResult r;
  r.safe_sqrt = SafeSqrt(c.a);
  r.safe_acos = SafeAcos(c.a);
  r.safe_div = SafeDiv(c.a, c.b, c.c);
  r.safe_log = SafeLog(c.a);
  r.safe_pow = SafePow(c.a, c.b);
  r.clamp = Clamp(c.a, c.b, c.c);
  r.raw_pow = pow(c.a, c.b);
  r.lobe = LafortuneLobe(wi, wo, c.params[1], c.params[2], c.params[3], c.params[4]);
  r.value = EvalChannel(wi, wo, c.params, c.num_lobes);
  r.value_with_gradient = EvalChannelWithGradient(wi, wo, c.params, c.num_lobes, r.gradient);
  results[i] = r;
}
