// Buffer layout of shaders/probe/loop_probe.comp, which counts how many loop iterations one
// invocation really executes (lavapipe silently exits loops after a budget; see
// engine/gpu/device_info.h, MaxLoopIterationsPerInvocation).
#ifndef REFLCAP_SHADERS_SHARED_LOOP_PROBE_H_
#define REFLCAP_SHADERS_SHARED_LOOP_PROBE_H_

#include "interop.h"

REFLCAP_SHARED_BEGIN

// LoopProbePush::mode values.
REFLCAP_CONST(uint, kLoopProbeSingle, 0u);      // one loop of `iterations`
REFLCAP_CONST(uint, kLoopProbeSequential, 1u);  // a loop of `iterations`, then one of `second`
REFLCAP_CONST(uint, kLoopProbeNested, 2u);      // `iterations` outer x `second` inner iterations
// kLoopProbeSequential for even invocations; odd ones swap the two counts (divergent lanes).
REFLCAP_CONST(uint, kLoopProbeAlternating, 3u);

struct LoopProbePush {
  uint mode;
  uint iterations;
  uint second;
  uint num_invocations;  // invocations past this return at once
};
REFLCAP_STD430_SIZE(LoopProbePush, 16);

// Per invocation (binding 0, write-only).
struct LoopProbeResult {
  uint first_count;   // iterations executed by the first (or outer) loop
  uint second_count;  // by the second loop, or the inner loop's total over all outer iterations
  uint hash;          // LCG state after every iteration: proves the body ran that many times
  uint invocation;    // gl_GlobalInvocationID.x
};
REFLCAP_STD430_SIZE(LoopProbeResult, 16);
REFLCAP_STD430_OFFSET(LoopProbeResult, hash, 8);

// The LCG step of the probe's loop bodies (Numerical Recipes' constants), state = state * a + c.
REFLCAP_CONST(uint, kLoopProbeLcgA, 1664525u);
REFLCAP_CONST(uint, kLoopProbeLcgC, 1013904223u);

REFLCAP_SHARED_END

#endif  // REFLCAP_SHADERS_SHARED_LOOP_PROBE_H_
