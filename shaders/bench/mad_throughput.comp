#version 460
// Floating-point multiply-add throughput: each invocation runs kMadChains independent vec4
// chains x <- x * a + b for `iterations` loop iterations and writes the sum of its chains.
// bench/gpu/gpu_bench.cc checks every output against a double-precision model before it counts
// the timing (a driver that cut the loop short, see MaxLoopIterationsPerInvocation, would fail).
//
// Bindings (set 0): 0 = float[] (write), one per invocation.
// Push constants:   MadThroughputPush {count, iterations, a, b} (shared/bench.h).
// Specialization:   constant_id 0 = local_size_x (default 64).
// C++ twin:         MadThroughputExpected in bench/gpu/gpu_bench.cc.
//
// Chain c of invocation i starts at x0 = float(i % 1024) / 1024 + c / 8 (component-wise offsets
// 0, 1/32, 2/32, 3/32); with |a| < 1 the chains converge to b / (1 - a) and rounding errors stay
// bounded by eps / (1 - |a|).
#extension GL_GOOGLE_include_directive : require

#include "shared/bench.h"

layout(local_size_x = 64, local_size_x_id = 0) in;

layout(std430, set = 0, binding = 0) writeonly buffer Out { float result[]; };
layout(push_constant) uniform Push { MadThroughputPush push; };

void main() {
  uint i = gl_GlobalInvocationID.x;
  if (i >= push.count) return;
  float base = float(i % 1024u) / 1024.0;
  // kMadChains = 4 chains, written out so that no inner loop counts against a loop budget.
  vec4 offsets = vec4(0.0, 1.0, 2.0, 3.0) / 32.0;
  vec4 x0 = vec4(base) + offsets;
  vec4 x1 = vec4(base) + offsets + 1.0 / 8.0;
  vec4 x2 = vec4(base) + offsets + 2.0 / 8.0;
  vec4 x3 = vec4(base) + offsets + 3.0 / 8.0;
  vec4 a = vec4(push.a);
  vec4 b = vec4(push.b);
  for (uint k = 0u; k < push.iterations; ++k) {
    x0 = x0 * a + b;
    x1 = x1 * a + b;
    x2 = x2 * a + b;
    x3 = x3 * a + b;
  }
  vec4 sum = x0 + x1 + x2 + x3;
  result[i] = sum.x + sum.y + sum.z + sum.w;
}
