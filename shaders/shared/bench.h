// Push constants of the benchmark shaders (shaders/bench/*.comp, bench/gpu/gpu_bench.cc).
#ifndef REFLCAP_SHADERS_SHARED_BENCH_H_
#define REFLCAP_SHADERS_SHARED_BENCH_H_

#include "interop.h"

REFLCAP_SHARED_BEGIN

// Independent multiply-add chains per invocation in mad_throughput.comp (a vec4 each), enough to
// hide ALU latency: one loop iteration is 4 * kMadChains scalar multiply-adds.
REFLCAP_CONST(int, kMadChains, 4);

struct MadThroughputPush {
  uint count;       // invocations that write a result
  uint iterations;  // loop iterations per invocation (<= MaxLoopIterationsPerInvocation)
  float a;          // x <- x * a + b, |a| < 1 so that x stays bounded and errors do not grow
  float b;
};
REFLCAP_STD430_SIZE(MadThroughputPush, 16);

REFLCAP_SHARED_END

#endif  // REFLCAP_SHADERS_SHARED_BENCH_H_
