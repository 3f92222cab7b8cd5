// The Vulkan fitter's LM, shared by its two kernels: lm_fit.comp (persistent lanes, one problem
// per invocation: CPU devices such as lavapipe) and lm_fit_cluster.comp (a cluster of invocations
// per problem: GPUs). What is here is the per-problem state machine, identical in both — lm.h's
// LmBegin / LmAdvance / internal::Propose in float, batched_fitter.cc's stage handling — plus one
// residual quad's contribution to the normal equations (batched_kernel.cc's Kernel). The kernels
// differ in how a problem's quads are summed and how problems reach invocations.
//
// Bindings (set 0) used by both kernels:
//   0 FitGpuSettings (read)          bounds and stage settings (shared/fit_gpu.h)
//   1 uvec4 desc[]   (read)          per problem: REFLCAP_FIT_DESC_STRIDE(FIT_P) words
//   2 uint queue[]   (read)          problem indices in the order invocations take them
//   3 samplerBuffer  (RGBA32F texel) residual quads (shared/fit_gpu.h): per four residuals, five
//                                    texels xx, yy, zz, y, sqrt(w) of the four
//   5 uvec4 results[] (write)        per problem: REFLCAP_FIT_OUT_STRIDE(FIT_P) words
//   6 FitGpuControl control[] (atomics) queue heads and counters (one entry per dispatch slot)
// Specialization: constant_id 1 = loss (kFitLoss*). The includer declares local_size and any
// further bindings, push constants and constants.
// C++ twin: engine/fit/lm.h (LmBegin, LmAdvance<float, P, true>, internal::Propose,
// RaiseDamping, GradientSmall) with the damped system built as batched_fitter.cc's ProposeLanes
// builds it, batched_kernel.cc's Kernel (normal equations), batched_fitter.cc's stage handling
// (next_stage / finish).
#ifndef REFLCAP_SHADERS_FIT_LM_CORE_GLSL_
#define REFLCAP_SHADERS_FIT_LM_CORE_GLSL_

#include "fit/fit_model.glsl"

layout(constant_id = 1) const int kLoss = 0;

layout(std430, set = 0, binding = 0) readonly buffer Settings { FitGpuSettings settings; };
layout(std430, set = 0, binding = 1) readonly buffer Descriptors { uvec4 desc[]; };
layout(std430, set = 0, binding = 2) readonly buffer Queue { uint queue[]; };
layout(set = 0, binding = 3) uniform samplerBuffer records;
layout(std430, set = 0, binding = 5) writeonly buffer Results { uvec4 results[]; };
layout(std430, set = 0, binding = 6) buffer Control { FitGpuControl control[]; };

#define DESC_STRIDE REFLCAP_FIT_DESC_STRIDE(FIT_P)
#define OUT_STRIDE REFLCAP_FIT_OUT_STRIDE(FIT_P)
#define DESC_VEC4S (DESC_STRIDE / 4)
#define OUT_VEC4S (OUT_STRIDE / 4)

// ---- A problem's LM state (lm.h LmState, batched_fitter.cc LaneState) -----------------------
uint s_problem;
uint s_stage;
uint s_phase;
uint s_status;
uint s_free;
int s_iterations;
int s_failures;
int s_total;
float s_lambda;
float s_nu;
float s_cost;
float s_predicted;
float s_at_cost;
float s_x[FIT_P];
float s_x_new[FIT_P];
float s_jacobi[FIT_P];
float s_inv_jacobi[FIT_P];
float s_g[FIT_P];
float s_a[FIT_PACKED];
// The problem's descriptor.
uint d_begin;
uint d_block1;
uint d_block2;
uint d_count;
uint d_stages;
uint d_mask0;
uint d_mask1;
float d_loss_scale;
// Normal equations at x_new (the evaluation's output).
float n_a[FIT_PACKED];
float n_g[FIT_P];
float n_cost;

int PackedIndex(int i, int j) { return i * (i + 1) / 2 + j; }
bool IsFree(int j) { return ((s_free >> uint(j)) & 1u) != 0u; }

// The stage's evaluated-step cap (StageSettings: stage 0 of two gets first_stage_iterations).
int StageMaxIterations() {
  return (d_stages == 2u && s_stage == 0u) ? settings.first_stage_iterations
                                           : settings.max_iterations;
}

// The problem's descriptor: the header into d_*, the start parameters into x0.
void LoadDescriptor(out float x0[FIT_P]) {
  uint w[DESC_STRIDE];
  uint o = s_problem * uint(DESC_VEC4S);
  [[unroll]] for (int k = 0; k < DESC_VEC4S; ++k) {
    uvec4 v = desc[o + k];
    w[4 * k] = v.x;
    w[4 * k + 1] = v.y;
    w[4 * k + 2] = v.z;
    w[4 * k + 3] = v.w;
  }
  d_begin = w[kFitDescBegin];
  d_block1 = w[kFitDescBlock1];
  d_block2 = w[kFitDescBlock2];
  d_count = w[kFitDescCount];
  d_stages = w[kFitDescStages];
  d_mask0 = w[kFitDescMask0];
  d_mask1 = w[kFitDescMask1];
  d_loss_scale = uintBitsToFloat(w[kFitDescLossScale]);
  [[unroll]] for (int j = 0; j < FIT_P; ++j) x0[j] = uintBitsToFloat(w[kFitDescX0 + j]);
}

// ---- lm.h ------------------------------------------------------------------------------------
// LmBegin: starts a stage at s_x with free parameters `free_mask`.
void LmBegin(uint free_mask) {
  s_free = free_mask;
  [[unroll]] for (int j = 0; j < FIT_P; ++j) s_x_new[j] = s_x[j];
  s_lambda = kLmInitialLambda;
  s_nu = 2.0;
  s_cost = 0.0;
  s_predicted = 0.0;
  s_iterations = 0;
  s_failures = 0;
  s_status = uint(kFitStatusConverged);
  s_phase = free_mask != 0u ? kFitPhaseEvaluateStart : kFitPhaseDone;
}

void Finish(int status) {
  s_status = uint(status);
  s_phase = kFitPhaseDone;
}

// RaiseDamping: lambda = min(lambda nu, kLmMaxLambda), nu *= 2 (std::min's comparison order).
void RaiseDamping() {
  float raised = s_lambda * s_nu;
  s_lambda = kLmMaxLambda < raised ? kLmMaxLambda : raised;
  s_nu = s_nu * 2.0;
}

// GradientSmall: max_j |D_j g_j| over free j <= gradient_tolerance (std::max's comparisons).
bool GradientSmall() {
  float max_g = 0.0;
  [[unroll]] for (int j = 0; j < FIT_P; ++j) {
    float v = abs(s_jacobi[j] * s_g[j]);
    if (IsFree(j)) max_g = max_g < v ? v : max_g;
  }
  return max_g <= settings.gradient_tolerance;
}

// One pass of internal::Propose: the iteration cap, the damped Jacobi-scaled system (built as
// ProposeLanes builds it) and its Cholesky solve with the diagonal kept inverted, projection and
// the finiteness check, the relative step test, the predicted decrease. Leaves s_phase at
// kEvaluateStep (x_new proposed), kDone, or kPropose when Propose would loop (failed
// factorisation, non-finite step, or a step not predicted to descend).
void ProposePass() {
  if (s_iterations >= StageMaxIterations()) {
    Finish(kFitStatusMaxIterations);
    return;
  }
  float m[FIT_PACKED];
  float z[FIT_P];
  float fr[FIT_P];
  [[unroll]] for (int i = 0; i < FIT_P; ++i) {
    fr[i] = IsFree(i) ? 1.0 : 0.0;
    z[i] = s_g[i];
  }
  [[unroll]] for (int i = 0; i < FIT_PACKED; ++i) m[i] = s_a[i];
  [[unroll]] for (int i = 0; i < FIT_P; ++i) {
    [[unroll]] for (int j = 0; j < FIT_P; ++j) {
      if (j <= i) m[PackedIndex(i, j)] *= fr[i] * fr[j] * s_jacobi[i] * s_jacobi[j];
    }
    float mii = m[PackedIndex(i, i)];
    float at_least = mii < kLmMinDiagonal ? kLmMinDiagonal : mii;
    float clamped = kLmMaxDiagonal < at_least ? kLmMaxDiagonal : at_least;
    m[PackedIndex(i, i)] = fr[i] != 0.0 ? mii + s_lambda * clamped : 1.0;
    z[i] = -fr[i] * s_jacobi[i] * z[i];
  }
  bool ok = true;
  [[unroll]] for (int j = 0; j < FIT_P; ++j) {
    float piv = m[PackedIndex(j, j)];
    [[unroll]] for (int k = 0; k < FIT_P; ++k) {
      if (k < j) piv -= m[PackedIndex(j, k)] * m[PackedIndex(j, k)];
    }
    bool good = piv > 0.0 && FitIsFinite(piv) && piv < 3.40282347e38;
    ok = ok && good;
    precise float inv = 1.0 / sqrt(good ? piv : 1.0);
    m[PackedIndex(j, j)] = inv;
    // Rows i > j (computed for every i, so the loop has no nested branch around its inner
    // loop and unrolls; rows i <= j read a mirrored in-range entry and keep their value).
    [[unroll]] for (int i = 0; i < FIT_P; ++i) {
      int ij = PackedIndex(max(i, j), min(i, j));
      float v = m[ij];
      [[unroll]] for (int k = 0; k < FIT_P; ++k) {
        if (k < j) v -= m[PackedIndex(max(i, k), min(i, k))] * m[PackedIndex(j, k)];
      }
      if (i > j) m[ij] = v * inv;
    }
  }
  [[unroll]] for (int i = 0; i < FIT_P; ++i) {  // L y = b
    float v = z[i];
    [[unroll]] for (int k = 0; k < FIT_P; ++k) {
      if (k < i) v -= m[PackedIndex(i, k)] * z[k];
    }
    z[i] = v * m[PackedIndex(i, i)];
  }
  [[unroll]] for (int r = 0; r < FIT_P; ++r) {  // L^T z = y, i = P - 1 down to 0
    int i = FIT_P - 1 - r;
    float v = z[i];
    [[unroll]] for (int k = 0; k < FIT_P; ++k) {
      if (k > i) v -= m[PackedIndex(k, i)] * z[k];
    }
    z[i] = v * m[PackedIndex(i, i)];
  }
  if (!ok) {
    if (++s_failures >= kLmMaxSolveFailures) {
      Finish(kFitStatusSingular);
      return;
    }
    RaiseDamping();
    return;  // s_phase stays kPropose: the next tick factorises again
  }
  s_failures = 0;
  // Project, then measure the step actually taken.
  float dx[FIT_P];
  float step_norm2 = 0.0;
  float x_norm2 = 0.0;
  bool finite = true;
  float x_new[FIT_P];
  [[unroll]] for (int j = 0; j < FIT_P; ++j) {
    float v = s_x[j];
    if (IsFree(j)) {
      float moved = s_x[j] + s_jacobi[j] * z[j];
      finite = finite && FitIsFinite(moved);
      float lo = settings.lower[j];
      float hi = settings.upper[j];
      float at_least = moved < lo ? lo : moved;
      v = hi < at_least ? hi : at_least;
    }
    x_new[j] = v;
    dx[j] = v - s_x[j];
    float scaled_dx = dx[j] * s_inv_jacobi[j];
    float scaled_x = s_x[j] * s_inv_jacobi[j];
    step_norm2 += scaled_dx * scaled_dx;
    x_norm2 += scaled_x * scaled_x;
  }
  if (!finite) {  // cannot happen for finite normal equations; treated as a failed solve
    if (++s_failures >= kLmMaxSolveFailures) {
      [[unroll]] for (int j = 0; j < FIT_P; ++j) s_x_new[j] = x_new[j];
      Finish(kFitStatusSingular);
      return;
    }
    [[unroll]] for (int j = 0; j < FIT_P; ++j) s_x_new[j] = x_new[j];
    RaiseDamping();
    return;
  }
  float tol = settings.step_tolerance;
  if (sqrt(step_norm2) <= tol * (sqrt(x_norm2) + tol)) {
    [[unroll]] for (int j = 0; j < FIT_P; ++j) s_x_new[j] = s_x[j];
    Finish(kFitStatusConverged);
    return;
  }
  [[unroll]] for (int j = 0; j < FIT_P; ++j) s_x_new[j] = x_new[j];
  // Predicted decrease of the Gauss–Newton model along the projected step.
  float g_dx = 0.0;
  float dx_a_dx = 0.0;
  [[unroll]] for (int i = 0; i < FIT_P; ++i) {
    g_dx += s_g[i] * dx[i];
    float row = 0.0;  // sum over j < i, counted twice (symmetry), plus the diagonal
    [[unroll]] for (int j = 0; j < FIT_P; ++j) {
      if (j < i) row += s_a[PackedIndex(i, j)] * dx[j];
    }
    dx_a_dx += dx[i] * (2.0 * row + s_a[PackedIndex(i, i)] * dx[i]);
  }
  s_predicted = -g_dx - 0.5 * dx_a_dx;
  if (!(s_predicted > 0.0) || FitIsNan(s_predicted)) {
    // The projection turned the step away from descent: reject it without evaluating.
    ++s_iterations;
    RaiseDamping();
    return;
  }
  s_phase = kFitPhaseEvaluateStep;
}

// LmAdvance<float, P, kDeferProposal = true>: consumes the normal equations at s_x_new; leaves
// s_phase at kPropose or kDone.
void LmAdvance() {
  if (s_phase == kFitPhaseEvaluateStart) {
    // Float overflow at a degenerate start (inputs are finite): nothing can be solved from here.
    if (!FitIsFinite(n_cost)) {
      Finish(kFitStatusSingular);
      return;
    }
    [[unroll]] for (int i = 0; i < FIT_PACKED; ++i) s_a[i] = n_a[i];
    [[unroll]] for (int j = 0; j < FIT_P; ++j) s_g[j] = n_g[j];
    s_at_cost = n_cost;
    s_cost = n_cost;
    [[unroll]] for (int j = 0; j < FIT_P; ++j) {
      float ajj = n_a[PackedIndex(j, j)];
      s_inv_jacobi[j] = 1.0 + sqrt(ajj < 0.0 ? 0.0 : ajj);
      s_jacobi[j] = 1.0 / s_inv_jacobi[j];
    }
    if (GradientSmall()) {
      Finish(kFitStatusConverged);
      return;
    }
    s_phase = kFitPhasePropose;
    return;
  }
  ++s_iterations;
  float cost_new = n_cost;
  float change = s_cost - cost_new;  // not finite when cost_new is not: rejected below
  float gain = change / s_predicted;
  float ftol = settings.cost_tolerance;
  if (FitIsFinite(change) && gain > kLmMinGainRatio) {
    [[unroll]] for (int j = 0; j < FIT_P; ++j) s_x[j] = s_x_new[j];
    [[unroll]] for (int i = 0; i < FIT_PACKED; ++i) s_a[i] = n_a[i];
    [[unroll]] for (int j = 0; j < FIT_P; ++j) s_g[j] = n_g[j];
    s_at_cost = n_cost;
    s_cost = cost_new;
    if (change <= ftol * (s_cost + change)) {
      Finish(kFitStatusConverged);
      return;
    }
    if (GradientSmall()) {
      Finish(kFitStatusConverged);
      return;
    }
    float t = 2.0 * gain - 1.0;
    float shrink = 1.0 - t * t * t;
    float third = 1.0 / 3.0;
    float factor = third < shrink ? shrink : third;
    float lowered = s_lambda * factor;
    s_lambda = lowered < kLmMinLambda ? kLmMinLambda : lowered;
    s_nu = 2.0;
  } else {
    if (FitIsFinite(change) && abs(change) <= ftol * s_cost) {
      [[unroll]] for (int j = 0; j < FIT_P; ++j) s_x_new[j] = s_x[j];
      Finish(kFitStatusConverged);
      return;
    }
    RaiseDamping();
  }
  s_phase = kFitPhasePropose;
}

// Adds quad q of the problem (its first texel at `o`) to the normal equations n_a, n_g and to
// `cost` at x: batched_kernel.cc Kernel's per-residual terms, four residuals at a time.
void AccumulateQuad(int o, uint q, float x[FIT_P], inout precise float cost) {
  vec4 xx = texelFetch(records, o);
  vec4 yy = texelFetch(records, o + 1);
  vec4 zz = texelFetch(records, o + 2);
  vec4 y = texelFetch(records, o + 3);
  vec4 sw = texelFetch(records, o + 4);
#if FIT_MODEL == 2
  uvec4 i = uvec4(4u * q) + uvec4(0u, 1u, 2u, 3u);
  ivec4 channel = ivec4(greaterThanEqual(i, uvec4(d_block1))) +
                  ivec4(greaterThanEqual(i, uvec4(d_block2)));
#else
  ivec4 channel = ivec4(0);
#endif
  vec4 grad[FIT_P];
  vec4 f = FitEvalModel(x, xx, yy, zz, channel, grad);
  vec4 res = sw * (f - y);
  vec4 rho, rho1;
  FitRobustLoss(kLoss, res * res, d_loss_scale, rho, rho1);
  cost += 0.5 * ((rho.x + rho.y) + (rho.z + rho.w));
  vec4 j_sw[FIT_P];
  [[unroll]] for (int j = 0; j < FIT_P; ++j) j_sw[j] = sw * grad[j];
  vec4 rho1_res = rho1 * res;
  [[unroll]] for (int p = 0; p < FIT_P; ++p) {
    n_g[p] += dot(rho1_res, j_sw[p]);
    vec4 wp = rho1 * j_sw[p];
    [[unroll]] for (int r = 0; r < FIT_P; ++r) {
      if (r <= p) n_a[PackedIndex(p, r)] += dot(wp, j_sw[r]);
    }
  }
}

// ---- Problems in and out --------------------------------------------------------------------
// Begins problem `problem` (a batch problem index): its descriptor, zero normal equations (the
// scalar path starts every problem with them; a stage that ends before its first evaluation keeps
// them) and its first stage.
void BeginProblem(uint problem) {
  s_problem = problem;
  LoadDescriptor(s_x);
  [[unroll]] for (int i = 0; i < FIT_PACKED; ++i) s_a[i] = 0.0;
  [[unroll]] for (int j = 0; j < FIT_P; ++j) {
    s_g[j] = 0.0;
    s_jacobi[j] = 0.0;
    s_inv_jacobi[j] = 0.0;
  }
  s_at_cost = 0.0;
  s_stage = 0u;
  s_total = 0;
  LmBegin(d_mask0);
}

void WriteResult() {
  uint w[OUT_STRIDE];
  [[unroll]] for (int k = 0; k < OUT_STRIDE; ++k) w[k] = 0u;  // padding
  w[kFitOutStatus] = s_status;
  w[kFitOutFreeMask] = s_free;
  w[kFitOutIterations] = uint(s_total);
  w[kFitOutCost] = floatBitsToUint(s_at_cost);
  [[unroll]] for (int j = 0; j < FIT_P; ++j) w[kFitOutX + j] = floatBitsToUint(s_x[j]);
  [[unroll]] for (int i = 0; i < FIT_PACKED; ++i) w[kFitOutX + FIT_P + i] = floatBitsToUint(s_a[i]);
  uint o = s_problem * uint(OUT_VEC4S);
  [[unroll]] for (int k = 0; k < OUT_VEC4S; ++k) {
    results[o + k] = uvec4(w[4 * k], w[4 * k + 1], w[4 * k + 2], w[4 * k + 3]);
  }
}

// batched_fitter.cc next_stage for a stage that ended (s_phase == kDone): counts its steps and
// begins the next stage at the current x, or reports the problem complete (true).
bool NextStage() {
  s_total += s_iterations;
  if (s_stage + 1u < d_stages) {
    ++s_stage;
    LmBegin(s_stage == 1u ? d_mask1 : d_mask0);
    return false;
  }
  return true;
}

#endif  // REFLCAP_SHADERS_FIT_LM_CORE_GLSL_
