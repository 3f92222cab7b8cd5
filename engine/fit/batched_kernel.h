#pragma once
// The SIMD half of the batched CPU fitter: normal equations of kLanes problems at once, one
// problem per lane, structure of arrays. batched_fitter.cc runs the LM decisions (lm.h's
// LmAdvance<float>) per lane around it.
//
// Vector transcendental functions: the lobe needs one exp and one log per residual. glibc's
// libmvec has 16-, 8- and 4-lane expf/logf, but GCC only vectorises calls to them under
// -ffast-math (math-vector.h declares them to the vectoriser only when __FAST_MATH__ is set, and
// -fno-finite-math-only clears __FAST_MATH__). Instead of fast-math, the kernel calls libmvec's
// exported vector-ABI symbols (_ZGVeN16v_expf and friends, glibc >= 2.22) directly, so it keeps
// IEEE semantics and is compiled with ordinary flags (-O3 only).
//
// ISA: the kernel is built three times, for x86-64-v4 (AVX-512, 16-float vectors), x86-64-v3
// (AVX2+FMA, 8) and baseline x86-64 (SSE2, 4), by GCC target attributes, and the widest the CPU
// supports is picked once at run time (__builtin_cpu_supports): the binary runs on any x86-64
// and never needs -march=native. LaneKernelIsa() names the one in use.
#include <cstdint>

#include "engine/fit/fitter.h"
#include "engine/fit/model.h"

namespace reflcap::fit {

// Problems evaluated together: one AVX-512 register of floats (two AVX2, four SSE registers).
constexpr int kLanes = 16;

// One batch. Residual i of channel block c of lane l is at index (c * capacity + i) * kLanes + l
// of xx, yy, zz, y and sw; slots past a lane's residual count hold sw = 0 (no contribution).
struct LaneBatch {
  int capacity = 0;                   // residual slots per channel block
  int block_count[3] = {0, 0, 0};     // slots to sum per block (max over active lanes)
  float* xx = nullptr;
  float* yy = nullptr;
  float* zz = nullptr;
  float* y = nullptr;
  float* sw = nullptr;
  alignas(64) float x[kMaxParams][kLanes];     // where to evaluate, per lane
  alignas(64) float loss_scale[kLanes];        // robust scale per lane (normalised units)
  alignas(64) float a[kMaxPacked][kLanes];     // out: J^T W J, packed lower triangle
  alignas(64) float g[kMaxParams][kLanes];     // out: J^T W r
  alignas(64) float cost[kLanes];              // out: 1/2 sum rho(r^2)
};

// Fills a, g and cost of every lane from x (the layout's NumParams entries per lane).
void EvaluateLanes(const ProblemLayout& layout, LossKind loss, LaneBatch* batch);

// out[i] = the summed lobes of one channel (EvalChannel layout, the albedo slot ignored) at the
// direction products (xx, yy, zz)[i] (wi_j wo_j), for i < padded, a multiple of kLanes: with
// the vector exp and log of LaneKernelIsa() (exp(n log b), a few float ulps from
// brdf::EvalChannel's pow), natural units, 0 where a lobe is cut off, kMaxLobeValue where
// saturated. For the post-fit lobe tests, which evaluate every candidate lobe at every sample.
void EvaluateLobeSum(const float* xx, const float* yy, const float* zz, size_t padded,
                     const float* channel, int lobes, float* out);

// The instruction set the dispatcher picked: "x86-64-v4", "x86-64-v3" or "x86-64".
const char* LaneKernelIsa();

}  // namespace reflcap::fit
