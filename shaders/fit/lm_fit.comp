#version 460
// The Vulkan fitter's LM: lm.h's per-problem Levenberg–Marquardt (LmBegin, LmAdvance,
// internal::Propose) and batched_kernel.cc's normal equations, one problem per invocation, as a
// resumable state machine run a bounded number of *ticks* per dispatch.
//
// Bindings (set 0): 0-3, 5, 6 as fit/lm_core.glsl says, and
//   4 uint lanes[]   (read/write)    per lane: REFLCAP_FIT_LANE_STRIDE(FIT_P) words of LM state
// control[0] holds the queue head and the count of lanes still busy.
// Push constants:  FitGpuPush {problem_count, lane_count, ticks}.
// Specialization:  constant_id 0 = local_size_x (default 64); 1 = loss (kFitLoss*).
// Defines:         FIT_MODEL (0 aniso, 1 iso, 2 shared), FIT_LOBES (K): one permutation per
//                  layout, so every parameter loop has a compile-time trip count and unrolls.
// C++ twin:        engine/fit/lm.h (LmBegin, LmAdvance<float, P, true>, internal::Propose,
//                  RaiseDamping, GradientSmall) with the damped system built as
//                  batched_fitter.cc's ProposeLanes builds it, batched_kernel.cc's Kernel (normal
//                  equations), batched_fitter.cc's stage handling (next_stage / finish).
//
// Why a texel buffer for the residuals: each lane reads its own problem's residuals, so the 8
// lanes that lavapipe runs in lock-step read 8 unrelated addresses. lavapipe (Mesa 22.3) loads
// storage buffers lane by lane in a branchy scalar loop, one per component, which cost half of
// the kernel's time here; texel fetches go through its texture path, one vector gather per
// channel (a call into a fetch function that spills every vector register: five fetches per
// four residuals, where one RGBA and one R fetch per residual took eight). On GPUs both are
// ordinary cached loads. Why four residuals per pass of the sample loop: fit_model.glsl's header.
// Descriptors and results move as uvec4s for the same reason: lavapipe runs a scalar loop over
// the 8 lanes for every storage-buffer access, and a uvec4 access moves four words per loop
// (and every access runs each tick, whether a lane takes a problem or not: lavapipe executes
// both sides of every branch under a mask). 5 % of the kernel's time on lavapipe.
//
// Persistent lanes: each invocation is a lane that takes problems from the shared queue
// (atomicAdd on control.next), runs them to the end, writes the result, and takes the next, so a
// lane never idles while problems remain (as the batched CPU path refills its SIMD lanes). A
// problem's LM state lives in registers during a dispatch and in the lane's words of binding 4
// between dispatches.
//
// One tick = at most one Propose pass (one damped factorisation) + stage bookkeeping + at most
// one evaluation of the normal equations (the sample loop). The loops that run are the tick loop
// and the sample loop; every loop over parameters is [[unroll]]ed, so on lavapipe, whose loop
// budget per invocation (engine/gpu/device_info.h) counts every pass through a loop header, a
// dispatch of T ticks over problems of at most Q residual quads (Q = ceil(R / 4) for R residuals)
// takes at most T (Q + 2) + 1 steps —
// the host picks T from that (engine/fit/vulkan_fitter.cc). lm.h's Propose loops until it has a
// proposal; here each pass is one tick, so its retries (failed factorisation, projected step not
// predicted to descend) resume in the next tick with identical state and arithmetic.
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_control_flow_attributes : require

#include "fit/lm_core.glsl"

layout(local_size_x = 64, local_size_x_id = 0) in;

layout(std430, set = 0, binding = 4) buffer Lanes { uint lanes[]; };
layout(push_constant) uniform Push { FitGpuPush push; };

#define LANE_STRIDE REFLCAP_FIT_LANE_STRIDE(FIT_P)

// ---- Lane state in and out of binding 4 -----------------------------------------------------
void LoadLane(uint lane) {
  uint o = lane * uint(LANE_STRIDE);
  s_problem = lanes[o + kFitLaneProblem];
  if (s_problem == kFitNoProblem) return;
  s_stage = lanes[o + kFitLaneStage];
  s_phase = lanes[o + kFitLanePhase];
  s_status = lanes[o + kFitLaneStatus];
  s_free = lanes[o + kFitLaneFreeMask];
  s_iterations = int(lanes[o + kFitLaneIterations]);
  s_failures = int(lanes[o + kFitLaneFailures]);
  s_total = int(lanes[o + kFitLaneTotal]);
  s_lambda = uintBitsToFloat(lanes[o + kFitLaneLambda]);
  s_nu = uintBitsToFloat(lanes[o + kFitLaneNu]);
  s_cost = uintBitsToFloat(lanes[o + kFitLaneCost]);
  s_predicted = uintBitsToFloat(lanes[o + kFitLanePredicted]);
  s_at_cost = uintBitsToFloat(lanes[o + kFitLaneAtCost]);
  uint a = o + kFitLaneArrays;
  [[unroll]] for (int j = 0; j < FIT_P; ++j) {
    s_x[j] = uintBitsToFloat(lanes[a + j]);
    s_x_new[j] = uintBitsToFloat(lanes[a + FIT_P + j]);
    s_jacobi[j] = uintBitsToFloat(lanes[a + 2 * FIT_P + j]);
    s_inv_jacobi[j] = uintBitsToFloat(lanes[a + 3 * FIT_P + j]);
    s_g[j] = uintBitsToFloat(lanes[a + 4 * FIT_P + j]);
  }
  [[unroll]] for (int i = 0; i < FIT_PACKED; ++i) {
    s_a[i] = uintBitsToFloat(lanes[a + 5 * FIT_P + i]);
  }
}

void SaveLane(uint lane) {
  uint o = lane * uint(LANE_STRIDE);
  lanes[o + kFitLaneProblem] = s_problem;
  if (s_problem == kFitNoProblem) return;
  lanes[o + kFitLaneStage] = s_stage;
  lanes[o + kFitLanePhase] = s_phase;
  lanes[o + kFitLaneStatus] = s_status;
  lanes[o + kFitLaneFreeMask] = s_free;
  lanes[o + kFitLaneIterations] = uint(s_iterations);
  lanes[o + kFitLaneFailures] = uint(s_failures);
  lanes[o + kFitLaneTotal] = uint(s_total);
  lanes[o + kFitLaneLambda] = floatBitsToUint(s_lambda);
  lanes[o + kFitLaneNu] = floatBitsToUint(s_nu);
  lanes[o + kFitLaneCost] = floatBitsToUint(s_cost);
  lanes[o + kFitLanePredicted] = floatBitsToUint(s_predicted);
  lanes[o + kFitLaneAtCost] = floatBitsToUint(s_at_cost);
  uint a = o + kFitLaneArrays;
  [[unroll]] for (int j = 0; j < FIT_P; ++j) {
    lanes[a + j] = floatBitsToUint(s_x[j]);
    lanes[a + FIT_P + j] = floatBitsToUint(s_x_new[j]);
    lanes[a + 2 * FIT_P + j] = floatBitsToUint(s_jacobi[j]);
    lanes[a + 3 * FIT_P + j] = floatBitsToUint(s_inv_jacobi[j]);
    lanes[a + 4 * FIT_P + j] = floatBitsToUint(s_g[j]);
  }
  [[unroll]] for (int i = 0; i < FIT_PACKED; ++i) {
    lanes[a + 5 * FIT_P + i] = floatBitsToUint(s_a[i]);
  }
}

// batched_kernel.cc Kernel: J^T W J, J^T W r and the cost of all residuals at s_x_new, four
// residuals per pass (a quad: REFLCAP_FIT_QUAD_TEXELS texels). The host pads a problem's last
// quad with sqrt(w) = 0 and zero geometry, which adds exactly 0 to every sum: the residual and
// every J_sw are 0 and every loss has rho(0) = 0 (the model is finite at base 0: no lobe).
void EvaluateNormalEquations() {
  [[unroll]] for (int i = 0; i < FIT_PACKED; ++i) n_a[i] = 0.0;
  [[unroll]] for (int j = 0; j < FIT_P; ++j) n_g[j] = 0.0;
  precise float cost = 0.0;
  float x[FIT_P];
  [[unroll]] for (int j = 0; j < FIT_P; ++j) x[j] = s_x_new[j];
  int o = int(d_begin);
  uint quads = (d_count + 3u) / 4u;
  for (uint q = 0u; q < quads; ++q, o += REFLCAP_FIT_QUAD_TEXELS) {
    AccumulateQuad(o, q, x, cost);
  }
  n_cost = cost;
}

// ---- Problems in and out --------------------------------------------------------------------
// Takes the next problem from the queue and begins its first stage; false when the queue is
// exhausted (s_problem is then kFitNoProblem).
bool FetchProblem() {
  uint index = atomicAdd(control[0].next, 1u);
  if (index >= push.problem_count) {
    s_problem = kFitNoProblem;
    return false;
  }
  BeginProblem(queue[index]);
  return true;
}

void main() {
  uint lane = gl_GlobalInvocationID.x;
  if (lane >= push.lane_count) return;
  LoadLane(lane);
  bool busy = s_problem != kFitNoProblem;
  if (busy) {
    float x0[FIT_P];  // unused: a resumed problem's x is in its lane state
    LoadDescriptor(x0);
  } else {
    busy = FetchProblem();
  }
  uint evaluations = 0u;
  for (uint tick = 0u; busy && tick < push.ticks; ++tick) {
    if (s_phase == kFitPhasePropose) ProposePass();
    if (s_phase == kFitPhaseDone) {
      // At most two stages: a stage begun with an empty free mask is done at once.
      bool complete = NextStage();
      if (!complete && s_phase == kFitPhaseDone) complete = NextStage();
      if (complete) {
        WriteResult();
        busy = FetchProblem();
      }
    }
    if (busy && (s_phase == kFitPhaseEvaluateStart || s_phase == kFitPhaseEvaluateStep)) {
      evaluations += d_count;
      EvaluateNormalEquations();
      LmAdvance();
    }
  }
  SaveLane(lane);
  if (busy) atomicAdd(control[0].busy, 1u);
  if (evaluations > 0u) atomicAdd(control[0].evaluations, evaluations);
}
