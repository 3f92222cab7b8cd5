#version 460
// The Vulkan fitter's LM for GPUs: the same per-problem state machine as lm_fit.comp
// (fit/lm_core.glsl: lm.h's LM in float and batched_kernel.cc's normal equations), laid out as
// the fastest published batched LM lays out its fits (Gpufit: a block per fit, a thread per data
// point): a *cluster* of kCluster invocations of one subgroup per problem. The cluster's
// invocations take the problem's residual quads in turn (quad q to invocation q mod kCluster:
// neighbouring invocations read neighbouring quads), sum their partial normal equations with a
// butterfly over subgroupShuffleXor, and then all run the small damped solve on the identical
// sums, so every invocation of a cluster holds the same LM state and no invocation waits on
// another. The whole solve stays on chip: a problem is taken, iterated to its end and written
// within one dispatch, with no state saved between dispatches (lm_fit.comp's ticks exist for
// lavapipe's loop budget and for devices that cannot hold a problem's state; GPUs can).
//
// Clusters are persistent: when a cluster's problem is done its leader takes the next entry of
// the dispatch's queue range (atomicAdd on control[push.control_slot].next) and broadcasts it, so
// a subgroup keeps all its clusters busy until the range is exhausted. The loop over LM steps is
// uniform across the subgroup (it runs while any cluster of the subgroup holds a problem), so the
// shuffles always run in uniform control flow; a cluster without a problem, or between an
// evaluation and its next, adds zeros.
//
// The butterfly gives every invocation of a cluster the same bits: at each step invocation i
// adds its partner's partial to its own, and its partner adds them in the opposite order, which
// floating-point addition does not distinguish. The sum order differs from lm_fit.comp's and the
// CPU's sequential one (float rounding, ~1e-7 relative), which the agreement tests allow.
//
// Bindings: as fit/lm_core.glsl (4 unused).
// Push constants: FitGpuClusterPush {queue_begin, queue_count, control_slot}.
// Specialization: 0 = local_size_x (a multiple of the subgroup size), 1 = loss,
//   2 = kCluster (a power of two, at most 32 and at most the subgroup size),
//   3 = kFitNativeMath (fit_model.glsl).
// Defines: FIT_MODEL, FIT_LOBES as lm_fit.comp.
// C++ twin: as lm_fit.comp; the host side is vulkan_fitter.cc (RunOnDeviceClusters).
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_control_flow_attributes : require
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_shuffle : require
#extension GL_KHR_shader_subgroup_vote : require

#define FIT_NATIVE_MATH_CONSTANT_ID 3
#include "fit/lm_core.glsl"

layout(local_size_x = 64, local_size_x_id = 0) in;
layout(constant_id = 2) const uint kCluster = 8u;
layout(push_constant) uniform Push { FitGpuClusterPush push; };

// Sums v over the cluster: identical bits in every invocation of it (see the file comment). The
// butterfly's steps are written out (offsets 1 .. 16: clusters of up to 32), each skipped by a
// specialization-constant test when at or beyond kCluster, so no loop remains (lavapipe counts
// every loop pass against its budget; fit_vulkan_test.cc checks the SPIR-V has two loops).
float ClusterSum(float v) {
  if (kCluster > 1u) v += subgroupShuffleXor(v, 1u);
  if (kCluster > 2u) v += subgroupShuffleXor(v, 2u);
  if (kCluster > 4u) v += subgroupShuffleXor(v, 4u);
  if (kCluster > 8u) v += subgroupShuffleXor(v, 8u);
  if (kCluster > 16u) v += subgroupShuffleXor(v, 16u);
  return v;
}

// batched_kernel.cc Kernel over the cluster: n_a, n_g and n_cost at s_x_new, this invocation's
// quads (`lane`, lane + kCluster, ...) summed here, then over the cluster. With `busy` false the
// invocation adds nothing (no problem, or no evaluation this step) but still takes part in the
// sums, which need every invocation of the subgroup.
void EvaluateCluster(bool busy, uint lane) {
  [[unroll]] for (int i = 0; i < FIT_PACKED; ++i) n_a[i] = 0.0;
  [[unroll]] for (int j = 0; j < FIT_P; ++j) n_g[j] = 0.0;
  precise float cost = 0.0;
  if (busy) {
    float x[FIT_P];
    [[unroll]] for (int j = 0; j < FIT_P; ++j) x[j] = s_x_new[j];
    uint quads = (d_count + 3u) / 4u;
    for (uint q = lane; q < quads; q += kCluster) {
      AccumulateQuad(int(d_begin + q * uint(REFLCAP_FIT_QUAD_TEXELS)), q, x, cost);
    }
  }
  [[unroll]] for (int i = 0; i < FIT_PACKED; ++i) n_a[i] = ClusterSum(n_a[i]);
  [[unroll]] for (int j = 0; j < FIT_P; ++j) n_g[j] = ClusterSum(n_g[j]);
  n_cost = ClusterSum(cost);
}

void main() {
  uint lane = gl_SubgroupInvocationID & (kCluster - 1u);
  uint leader = gl_SubgroupInvocationID & ~(kCluster - 1u);
  bool have = false;        // this cluster holds a problem
  bool want = true;         // this cluster takes the next queue entry at the top of the step
  uint evaluations = 0u;
  for (;;) {
    // Take a problem (the leader's atomic, broadcast to the cluster).
    uint index = 0xFFFFFFFFu;
    if (want && lane == 0u) index = atomicAdd(control[push.control_slot].next, 1u);
    index = subgroupShuffle(index, leader);
    if (want) {
      want = false;
      if (index < push.queue_count) {
        BeginProblem(queue[push.queue_begin + index]);
        have = true;
      }
    }
    if (subgroupAll(!have)) break;
    // One LM step of this cluster's problem: a Propose pass and the stage bookkeeping (no
    // subgroup operation inside: clusters diverge here).
    bool evaluate = false;
    if (have) {
      if (s_phase == kFitPhasePropose) ProposePass();
      if (s_phase == kFitPhaseDone) {
        // At most two stages: a stage begun with an empty free mask is done at once.
        bool complete = NextStage();
        if (!complete && s_phase == kFitPhaseDone) complete = NextStage();
        if (complete) {
          if (lane == 0u) WriteResult();
          have = false;
          want = true;
        }
      }
      evaluate = have && (s_phase == kFitPhaseEvaluateStart || s_phase == kFitPhaseEvaluateStep);
    }
    // The evaluation, in uniform control flow.
    EvaluateCluster(evaluate, lane);
    if (evaluate) {
      if (lane == 0u) evaluations += d_count;
      LmAdvance();
    }
  }
  if (evaluations > 0u) atomicAdd(control[push.control_slot].evaluations, evaluations);
}
