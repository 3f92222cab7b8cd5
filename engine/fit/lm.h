#pragma once
// The per-problem Levenberg–Marquardt solver shared by every backend: a fixed-size state
// (at most kMaxParams = 16 parameters, no allocation), normal equations accumulated over the
// samples, a small dense Cholesky, and a damping update — after Ceres' tiny_solver.h and
// Madsen, Nielsen and Tingleff, "Methods for non-linear least squares problems" (2004), §3.2.
//
// Why this shape: the Vulkan fitter runs exactly this iteration per texel, and a GPU invocation
// cannot loop for long (lavapipe cuts an invocation off after 65,535 loop iterations), so the
// solver is a resumable state machine. LmState is everything that must survive between two
// dispatches: parameters x, the proposal x_new, Jacobi scaling, damping lambda and its growth
// factor nu, cost, iteration count, phase and status. A step is
//   1. evaluate the normal equations (J^T J, J^T r, cost) at x_new   — EvaluateNormalEquations
//      here (scalar), the SIMD lanes of batched_kernel.cc, or the shader;
//   2. LmAdvance: accept or reject x_new, test for convergence, update the damping, and solve
//      for the next x_new.
// The same LmAdvance<float> runs for every lane of the batched CPU path (which only solves the
// lanes' damped systems together, following internal::Propose), so the scalar and the batched
// paths differ in how they sum and in float rounding, not in any decision rule.
//
// The iteration, in normalised units (model.h), with P free parameters of mask `free`:
//   Jacobi scaling   D_j = 1 / (1 + sqrt(A_jj)), fixed at the first evaluation of a stage
//                    (TinySolver; the 1 regularises parameters without influence).
//   damped system    (D A D + lambda diag(clamp((D A D)_jj, kLmMinDiagonal, kLmMaxDiagonal)))
//                    dz = -D g, step dx = D dz; fixed parameters get an identity row.
//   projection       x_new = clamp(x + dx, lower, upper) (the bounds of model.h).
//   gain ratio       rho = (cost - cost_new) / (-g.dx' - dx'.A.dx' / 2), dx' = x_new - x the
//                    projected step; a projected step that is not predicted to descend is
//                    rejected without evaluation.
//   accept           rho > kLmMinGainRatio: lambda *= max(1/3, 1 - (2 rho - 1)^3), nu = 2.
//   reject           lambda *= nu, nu *= 2 (Nielsen's schedule); lambda stays in
//                    [kLmMinLambda, kLmMaxLambda].
//   failed Cholesky  (a pivot <= 0 or not finite) raises the damping (as a rejection, without
//                    counting an iteration); kLmMaxSolveFailures in a row end the stage as
//                    kSingular.
// Stopping tests (each ends the stage as converged):
//   relative step    ||dx' / D|| <= step_tolerance (||x / D|| + step_tolerance), tested on the
//                    proposal before it is evaluated. In Jacobi-scaled coordinates, because the
//                    plain ||x|| is dominated by n (up to 1e4) and would stop C's early.
//   cost decrease    accepted step with cost - cost_new <= cost_tolerance cost, or a rejected
//                    one with |cost - cost_new| <= cost_tolerance cost (no change at working
//                    precision: the float path reaches this where double would go on).
//   gradient         max_j |D_j g_j| <= gradient_tolerance (free j).
// Iteration cap: max_iterations evaluated steps per stage → kMaxIterations.
// The non-finite guard: a non-finite cost is a rejected step; a non-finite start cost (float
// overflow at a degenerate start; inputs are sanitised) ends the stage as kSingular.
#include <cmath>
#include <cstdint>
#include <limits>

#include "engine/fit/fitter.h"
#include "engine/fit/model.h"
#include "shaders/shared/fit_status.h"

namespace reflcap::fit {

// Packed index of symmetric-matrix entry (i, j), j <= i.
constexpr int PackedIndex(int i, int j) { return i * (i + 1) / 2 + j; }

// Settings of one stage in normalised units, the same for all problems of a fit.
struct LmSettings {
  int max_iterations = 100;
  int first_stage_iterations = 3;  // the cap of stage 0 of a two-stage plan
  double step_tolerance = 1e-5;
  double cost_tolerance = 1e-5;
  double gradient_tolerance = 1e-10;
};
LmSettings MakeLmSettings(const FitOptions& options);
// The settings of stage `stage` of a plan of `num_stages` stages (stage 0 of two gets the
// first-stage cap).
LmSettings StageSettings(const LmSettings& settings, int stage, int num_stages);

template <typename T>
struct NormalEquations {
  T a[kMaxPacked];  // J^T W J, packed lower triangle (robust weights included)
  T g[kMaxParams];  // J^T W r
  T cost;           // 1/2 sum rho(r^2)
};

// Copies the entries of an n-parameter problem (the rest is never read).
template <typename T>
REFLCAP_FIT_INLINE void CopyNormalEquations(int n, const NormalEquations<T>& from,
                                            NormalEquations<T>* to) {
  for (int i = 0; i < PackedIndex(n, 0); ++i) to->a[i] = from.a[i];
  for (int j = 0; j < n; ++j) to->g[j] = from.g[j];
  to->cost = from.cost;
}

enum class LmPhase : int {
  kEvaluateStart = 0,  // x_new == x: evaluate the stage's start point
  kEvaluateStep = 1,   // x_new is a proposed step
  kDone = 2,
  kPropose = 3,        // LmAdvance<..., kDeferProposal>: the next step is still to be solved for
};

template <typename T>
struct LmState {
  int num_params = 0;
  uint32_t free_mask = 0;
  T x[kMaxParams];
  T x_new[kMaxParams];
  T jacobi[kMaxParams];
  T inv_jacobi[kMaxParams];  // 1 / jacobi
  T lambda;
  T nu;
  T cost;                // at x
  T predicted_decrease;  // of x_new
  int iterations = 0;    // evaluated steps in this stage
  int failures = 0;      // consecutive failed factorisations
  LmPhase phase = LmPhase::kDone;
  FitStatus status = FitStatus::kConverged;
  NormalEquations<T> at_x;  // the normal equations at x
};

// Robust loss value rho(s) and slope rho'(s) at s = r^2 (FitOptions' LossKind), scale a > 0.
template <typename T>
REFLCAP_FIT_INLINE void RobustLoss(LossKind loss, const T& s, const T& a, T* rho, T* rho1) {
  using std::log;
  using std::sqrt;
  if (loss == LossKind::kHuber) {
    // Conditions restated in each Select (see LobeValueAndSlopes in model.h).
    const T root = sqrt(Select(s > a * a, s, T(1)));
    *rho = Select(s > a * a, T(2) * a * root - a * a, s);
    *rho1 = Select(s > a * a, a / root, T(1));
  } else if (loss == LossKind::kCauchy) {
    const T u = T(1) + s / (a * a);
    *rho = a * a * log(u);
    *rho1 = T(1) / u;
  } else {
    *rho = s;
    *rho1 = T(1);
  }
}

// Solves (M) z = b for a symmetric positive definite M given as packed lower triangle of size
// n, in place (Cholesky, no pivoting). False when a pivot is <= 0 or not finite. N > 0 fixes n
// at compile time (the fitters' fast path); N = 0 takes it from the argument.
template <typename T, int N = 0>
inline bool CholeskySolve(int n_dynamic, T* packed, T* b) {
  const int n = N > 0 ? N : n_dynamic;
  using std::sqrt;
  for (int j = 0; j < n; ++j) {
    T d = packed[PackedIndex(j, j)];
    for (int k = 0; k < j; ++k) d -= packed[PackedIndex(j, k)] * packed[PackedIndex(j, k)];
    if (!(d > T(0)) || !(d < std::numeric_limits<T>::max())) return false;
    const T l = sqrt(d);
    const T inv_l = T(1) / l;
    packed[PackedIndex(j, j)] = inv_l;  // the diagonal is kept inverted for the solves
    for (int i = j + 1; i < n; ++i) {
      T s = packed[PackedIndex(i, j)];
      for (int k = 0; k < j; ++k) s -= packed[PackedIndex(i, k)] * packed[PackedIndex(j, k)];
      packed[PackedIndex(i, j)] = s * inv_l;
    }
  }
  for (int i = 0; i < n; ++i) {  // L y = b
    T s = b[i];
    for (int k = 0; k < i; ++k) s -= packed[PackedIndex(i, k)] * b[k];
    b[i] = s * packed[PackedIndex(i, i)];
  }
  for (int i = n - 1; i >= 0; --i) {  // L^T z = y
    T s = b[i];
    for (int k = i + 1; k < n; ++k) s -= packed[PackedIndex(k, i)] * b[k];
    b[i] = s * packed[PackedIndex(i, i)];
  }
  return true;
}

// Starts a stage at x with free parameters `free_mask`.
template <typename T>
void LmBegin(int num_params, uint32_t free_mask, const T* x, LmState<T>* s) {
  s->num_params = num_params;
  s->free_mask = free_mask;
  for (int j = 0; j < num_params; ++j) s->x[j] = s->x_new[j] = x[j];
  for (int j = num_params; j < kMaxParams; ++j) s->x[j] = s->x_new[j] = T(0);
  s->lambda = T(gpu::shared::kLmInitialLambda);
  s->nu = T(2);
  s->cost = T(0);
  s->predicted_decrease = T(0);
  s->iterations = 0;
  s->failures = 0;
  s->status = FitStatus::kConverged;
  s->phase = free_mask ? LmPhase::kEvaluateStart : LmPhase::kDone;
}

namespace internal {

template <typename T>
bool IsFree(const LmState<T>& s, int j) {
  return (s.free_mask >> j) & 1u;
}

template <typename T>
void Finish(LmState<T>* s, FitStatus status) {
  s->status = status;
  s->phase = LmPhase::kDone;
}

template <typename T>
void RaiseDamping(LmState<T>* s) {
  s->lambda = std::min(s->lambda * s->nu, T(gpu::shared::kLmMaxLambda));
  s->nu = s->nu * T(2);
}

// Solves the damped system at x and stores the projected proposal in x_new; ends the stage
// when the step test fires, when factorisation keeps failing, or at the iteration cap.
template <typename T, int N>
void Propose(const LmSettings& settings, const T* lower, const T* upper, LmState<T>* s) {
  const int n = N > 0 ? N : s->num_params;
  while (true) {
    if (s->iterations >= settings.max_iterations) return Finish(s, FitStatus::kMaxIterations);
    T m[kMaxPacked];
    T z[kMaxParams];
    for (int i = 0; i < n; ++i) {
      for (int j = 0; j <= i; ++j) {
        const bool both = IsFree(*s, i) && IsFree(*s, j);
        m[PackedIndex(i, j)] =
            both ? s->jacobi[i] * s->at_x.a[PackedIndex(i, j)] * s->jacobi[j] : T(0);
      }
      if (IsFree(*s, i)) {
        const T d = std::min(std::max(m[PackedIndex(i, i)], T(gpu::shared::kLmMinDiagonal)),
                             T(gpu::shared::kLmMaxDiagonal));
        m[PackedIndex(i, i)] += s->lambda * d;
        z[i] = -s->jacobi[i] * s->at_x.g[i];
      } else {
        m[PackedIndex(i, i)] = T(1);
        z[i] = T(0);
      }
    }
    if (!CholeskySolve<T, N>(n, m, z)) {
      if (++s->failures >= gpu::shared::kLmMaxSolveFailures) return Finish(s, FitStatus::kSingular);
      RaiseDamping(s);
      continue;
    }
    s->failures = 0;
    // Project, then measure the step actually taken.
    T dx[kMaxParams];
    T step_norm2 = T(0), x_norm2 = T(0);
    bool finite = true;
    for (int j = 0; j < n; ++j) {
      T v = s->x[j];
      if (IsFree(*s, j)) {
        const T moved = s->x[j] + s->jacobi[j] * z[j];
        finite = finite && moved - moved == T(0);  // false for NaN and +-Inf
        v = std::min(std::max(moved, lower[j]), upper[j]);
      }
      s->x_new[j] = v;
      dx[j] = v - s->x[j];
      const T scaled_dx = dx[j] * s->inv_jacobi[j];
      const T scaled_x = s->x[j] * s->inv_jacobi[j];
      step_norm2 += scaled_dx * scaled_dx;
      x_norm2 += scaled_x * scaled_x;
    }
    if (!finite) {  // cannot happen for finite normal equations; treated as a failed solve
      if (++s->failures >= gpu::shared::kLmMaxSolveFailures) return Finish(s, FitStatus::kSingular);
      RaiseDamping(s);
      continue;
    }
    const T tol = T(settings.step_tolerance);
    if (std::sqrt(step_norm2) <= tol * (std::sqrt(x_norm2) + tol)) {
      for (int j = 0; j < n; ++j) s->x_new[j] = s->x[j];
      return Finish(s, FitStatus::kConverged);
    }
    // Predicted decrease of the Gauss–Newton model along the projected step.
    T g_dx = T(0), dx_a_dx = T(0);
    for (int i = 0; i < n; ++i) {
      g_dx += s->at_x.g[i] * dx[i];
      T row = T(0);  // sum over j < i, counted twice (symmetry), plus the diagonal
      for (int j = 0; j < i; ++j) row += s->at_x.a[PackedIndex(i, j)] * dx[j];
      dx_a_dx += dx[i] * (T(2) * row + s->at_x.a[PackedIndex(i, i)] * dx[i]);
    }
    s->predicted_decrease = -g_dx - T(0.5) * dx_a_dx;
    if (!(s->predicted_decrease > T(0))) {
      // The projection turned the step away from descent: reject it without evaluating.
      ++s->iterations;
      RaiseDamping(s);
      continue;
    }
    s->phase = LmPhase::kEvaluateStep;
    return;
  }
}

template <typename T>
bool GradientSmall(const LmSettings& settings, const LmState<T>& s) {
  T max_g = T(0);
  for (int j = 0; j < s.num_params; ++j) {
    if (IsFree(s, j)) max_g = std::max(max_g, std::abs(s.jacobi[j] * s.at_x.g[j]));
  }
  return max_g <= T(settings.gradient_tolerance);
}

}  // namespace internal

// Consumes the normal equations evaluated at s->x_new (phase kEvaluateStart or kEvaluateStep).
// Afterwards s->phase is kDone (s->status says why) or kEvaluateStep with the next x_new.
// N > 0 must equal s->num_params and unrolls the small dense algebra (N = 0: dynamic).
// kDeferProposal: stop before solving for the next step and leave phase kPropose, so that the
// batched path can solve all lanes' damped systems together (it then follows internal::Propose
// step for step, see batched_fitter.cc).
template <typename T, int N = 0, bool kDeferProposal = false>
void LmAdvance(const LmSettings& settings, const T* lower, const T* upper,
               const NormalEquations<T>& at_x_new, LmState<T>* s) {
  using internal::Finish;
  const int n = N > 0 ? N : s->num_params;
  if (s->phase == LmPhase::kEvaluateStart) {
    // Float overflow at a degenerate start (inputs are finite): nothing can be solved from here.
    if (!std::isfinite(at_x_new.cost)) return Finish(s, FitStatus::kSingular);
    CopyNormalEquations(n, at_x_new, &s->at_x);
    s->cost = at_x_new.cost;
    for (int j = 0; j < n; ++j) {
      s->inv_jacobi[j] = T(1) + std::sqrt(std::max(at_x_new.a[PackedIndex(j, j)], T(0)));
      s->jacobi[j] = T(1) / s->inv_jacobi[j];
    }
    if (internal::GradientSmall(settings, *s)) return Finish(s, FitStatus::kConverged);
    if (kDeferProposal) {
      s->phase = LmPhase::kPropose;
      return;
    }
    return internal::Propose<T, N>(settings, lower, upper, s);
  }
  ++s->iterations;
  const T cost_new = at_x_new.cost;
  const T change = s->cost - cost_new;  // NaN when cost_new is: rejected below
  const T gain = change / s->predicted_decrease;
  const T ftol = T(settings.cost_tolerance);
  if (gain > T(gpu::shared::kLmMinGainRatio)) {
    for (int j = 0; j < n; ++j) s->x[j] = s->x_new[j];
    CopyNormalEquations(n, at_x_new, &s->at_x);
    s->cost = cost_new;
    if (change <= ftol * (s->cost + change)) return Finish(s, FitStatus::kConverged);
    if (internal::GradientSmall(settings, *s)) return Finish(s, FitStatus::kConverged);
    const T t = T(2) * gain - T(1);
    s->lambda = std::max(s->lambda * std::max(T(1) / T(3), T(1) - t * t * t),
                         T(gpu::shared::kLmMinLambda));
    s->nu = T(2);
  } else {
    if (std::abs(change) <= ftol * s->cost) {
      for (int j = 0; j < n; ++j) s->x_new[j] = s->x[j];
      return Finish(s, FitStatus::kConverged);
    }
    internal::RaiseDamping(s);
  }
  if (kDeferProposal) {
    s->phase = LmPhase::kPropose;
    return;
  }
  internal::Propose<T, N>(settings, lower, upper, s);
}

// A problem's residuals in normalised units (problem.h fills them): residual i has channel
// block c with begin[c] <= i < begin[c + 1], directions products xx, yy, zz, value y and
// sqrt(weight) sw.
struct ResidualView {
  const float* xx = nullptr;
  const float* yy = nullptr;
  const float* zz = nullptr;
  const float* y = nullptr;
  const float* sw = nullptr;
  int begin[4] = {0, 0, 0, 0};  // channel blocks; aniso/iso use block 0 only
  int count() const { return begin[3]; }
};

// Accumulates the normal equations of all residuals at x (the scalar path's step 1).
template <LobeModel M, int K, typename T>
void EvaluateNormalEquations(const ResidualView& r, const T* x, LossKind loss, T loss_scale,
                             NormalEquations<T>* out) {
  constexpr int P = NumParams(M, K);
  for (int i = 0; i < PackedIndex(P, 0); ++i) out->a[i] = T(0);
  for (int j = 0; j < P; ++j) out->g[j] = T(0);
  T cost = T(0);
  for (int c = 0; c < 3; ++c) {
    for (int i = r.begin[c]; i < r.begin[c + 1]; ++i) {
      T grad[P > 0 ? P : 1];
      const T f = EvalModel<M, K, T>(x, T(r.xx[i]), T(r.yy[i]), T(r.zz[i]), c, grad);
      const T sw = T(r.sw[i]);
      const T res = sw * (f - T(r.y[i]));
      T rho, rho1;
      RobustLoss(loss, res * res, loss_scale, &rho, &rho1);
      cost += T(0.5) * rho;
      for (int a = 0; a < P; ++a) {
        const T ja = sw * grad[a];
        out->g[a] += rho1 * res * ja;
        const T wa = rho1 * ja;
        for (int b = 0; b <= a; ++b) out->a[PackedIndex(a, b)] += wa * sw * grad[b];
      }
    }
  }
  out->cost = cost;
}

}  // namespace reflcap::fit
