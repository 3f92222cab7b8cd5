#version 460
// Counts the loop iterations one invocation really executes, to catch drivers that silently
// leave long loops early (lavapipe: 65,535 iterations per invocation, summed over all its loops).
// tests/engine/gpu/loop_limit_test.cc checks engine/gpu's MaxLoopIterationsPerInvocation with it.
//
// Bindings (set 0): 0 = LoopProbeResult[] (write), one per invocation (shared/loop_probe.h).
// Push constants:   LoopProbePush {mode, iterations, second, num_invocations}:
//                   kLoopProbeSingle: one loop of `iterations`;
//                   kLoopProbeSequential: a loop of `iterations`, then a loop of `second`;
//                   kLoopProbeNested: `iterations` outer iterations of an inner loop of `second`;
//                   kLoopProbeAlternating: as kLoopProbeSequential for even invocations, with
//                   the two counts swapped for odd ones.
// Specialization:   constant_id 0 = local_size_x (default 64).
// C++ twin:         none (the test predicts counts and the LCG hash on the CPU).
//
// Each loop body advances an LCG whose state is written out, so no compiler can drop or fold the
// loop, and the test can tell from the hash how many times the body ran.
#extension GL_GOOGLE_include_directive : require

#include "shared/loop_probe.h"

layout(local_size_x = 64, local_size_x_id = 0) in;

layout(std430, set = 0, binding = 0) writeonly buffer Results { LoopProbeResult results[]; };
layout(push_constant) uniform Push { LoopProbePush push; };

void main() {
  uint i = gl_GlobalInvocationID.x;
  if (i >= push.num_invocations) return;
  uint hash = i;
  uint first_count = 0u;
  uint second_count = 0u;
  if (push.mode == kLoopProbeNested) {
    for (uint k = 0u; k < push.iterations; ++k) {
      for (uint j = 0u; j < push.second; ++j) {
        hash = hash * kLoopProbeLcgA + kLoopProbeLcgC;
        ++second_count;
      }
      ++first_count;
    }
  } else {
    uint first = push.iterations;
    uint second = push.second;
    if (push.mode == kLoopProbeAlternating && (i & 1u) == 1u) {
      first = push.second;
      second = push.iterations;
    }
    for (uint k = 0u; k < first; ++k) {
      hash = hash * kLoopProbeLcgA + kLoopProbeLcgC;
      ++first_count;
    }
    if (push.mode == kLoopProbeSequential || push.mode == kLoopProbeAlternating) {
      for (uint k = 0u; k < second; ++k) {
        hash = hash * kLoopProbeLcgA + kLoopProbeLcgC;
        ++second_count;
      }
    }
  }
  results[i] = LoopProbeResult(first_count, second_count, hash, i);
}
