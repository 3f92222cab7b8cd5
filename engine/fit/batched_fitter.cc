// The batched CPU fitter: kLanes problems in lock-step, one per SIMD lane. Each lane runs
// lm.h's state machine (LmAdvance<float>, scalar code per lane: O(P^3) per step), and all lanes'
// normal equations are summed together by batched_kernel.cc (O(samples x P^2) per step, the
// bulk of the work). A lane whose problem finishes is refilled with the next problem at once,
// so lanes never idle while problems remain. All storage lives in the worker's workspace,
// sized before the parallel loop: nothing is allocated per texel.
#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>

#include "engine/fit/batched_kernel.h"
#include "engine/fit/fitter_base.h"

namespace reflcap::fit::internal {
namespace {

struct LaneState {
  std::vector<float> xx, yy, zz, y, sw;  // kLanes x capacity x 3 (SoA, see LaneBatch)
  LaneBatch batch;
  LmState<float> lm[kLanes];
  int problem[kLanes];  // index of the lane's problem, -1 when empty
  int stage[kLanes];
  int iterations[kLanes];
  int count[kLanes][3];  // residuals per block
};

// One pass of lm.h's internal::Propose for every lane in phase kPropose, with the lanes' damped
// systems built, factorised and solved together (structure of arrays, loops over lanes that the
// compiler vectorises). Lanes whose pass ends in a failed factorisation, a non-finite step or a
// projected step that is not predicted to descend take the scalar path's next pass
// (internal::Propose, which repeats the same arithmetic per lane), so the outcome is that of
// LmAdvance<float, P> without deferral.
template <int P>
void ProposeLanes(const LmSettings* settings[kLanes], const float* lower, const float* upper,
                  LmState<float>* lm) {
  constexpr int kPacked = PackedIndex(P, 0);
  bool want[kLanes];
  int wanted = 0;
  for (int l = 0; l < kLanes; ++l) {
    want[l] = lm[l].phase == LmPhase::kPropose;
    if (want[l] && lm[l].iterations >= settings[l]->max_iterations) {
      lm[l].status = FitStatus::kMaxIterations;
      lm[l].phase = LmPhase::kDone;
      want[l] = false;
    }
    wanted += want[l];
  }
  if (wanted == 0) return;
  alignas(64) float m[kPacked][kLanes], z[P][kLanes], d[P][kLanes], fr[P][kLanes];
  alignas(64) float ok[kLanes], lambda[kLanes];
  for (int l = 0; l < kLanes; ++l) {
    const LmState<float>& s = lm[l];
    lambda[l] = s.lambda;
    ok[l] = 1.0f;
    for (int i = 0; i < P; ++i) {
      d[i][l] = s.jacobi[i];
      fr[i][l] = ((s.free_mask >> i) & 1u) ? 1.0f : 0.0f;
      z[i][l] = s.at_x.g[i];
    }
    for (int i = 0; i < kPacked; ++i) m[i][l] = s.at_x.a[i];
  }
  // Damped, Jacobi-scaled system; fixed parameters get an identity row.
  for (int i = 0; i < P; ++i) {
    for (int j = 0; j <= i; ++j) {
      for (int l = 0; l < kLanes; ++l) {
        m[PackedIndex(i, j)][l] *= fr[i][l] * fr[j][l] * d[i][l] * d[j][l];
      }
    }
    for (int l = 0; l < kLanes; ++l) {
      const float mii = m[PackedIndex(i, i)][l];
      const float clamped = std::min(std::max(mii, float(gpu::shared::kLmMinDiagonal)),
                                     float(gpu::shared::kLmMaxDiagonal));
      m[PackedIndex(i, i)][l] = fr[i][l] != 0.0f ? mii + lambda[l] * clamped : 1.0f;
      z[i][l] = -fr[i][l] * d[i][l] * z[i][l];
    }
  }
  // Cholesky with the diagonal kept inverted (as CholeskySolve); a failed pivot marks the lane.
  for (int j = 0; j < P; ++j) {
    for (int l = 0; l < kLanes; ++l) {
      float piv = m[PackedIndex(j, j)][l];
      for (int k = 0; k < j; ++k) piv -= m[PackedIndex(j, k)][l] * m[PackedIndex(j, k)][l];
      const bool good = piv > 0.0f && piv < std::numeric_limits<float>::max();
      ok[l] = good ? ok[l] : 0.0f;
      const float inv = 1.0f / std::sqrt(good ? piv : 1.0f);
      m[PackedIndex(j, j)][l] = inv;
      for (int i = j + 1; i < P; ++i) {
        float v = m[PackedIndex(i, j)][l];
        for (int k = 0; k < j; ++k) v -= m[PackedIndex(i, k)][l] * m[PackedIndex(j, k)][l];
        m[PackedIndex(i, j)][l] = v * inv;
      }
    }
  }
  for (int i = 0; i < P; ++i) {
    for (int l = 0; l < kLanes; ++l) {
      float v = z[i][l];
      for (int k = 0; k < i; ++k) v -= m[PackedIndex(i, k)][l] * z[k][l];
      z[i][l] = v * m[PackedIndex(i, i)][l];
    }
  }
  for (int i = P - 1; i >= 0; --i) {
    for (int l = 0; l < kLanes; ++l) {
      float v = z[i][l];
      for (int k = i + 1; k < P; ++k) v -= m[PackedIndex(k, i)][l] * z[k][l];
      z[i][l] = v * m[PackedIndex(i, i)][l];
    }
  }
  // Per lane: projection, step test, predicted decrease (as internal::Propose).
  for (int l = 0; l < kLanes; ++l) {
    if (!want[l]) continue;
    LmState<float>* s = &lm[l];
    if (ok[l] == 0.0f) {
      if (++s->failures >= gpu::shared::kLmMaxSolveFailures) {
        s->status = FitStatus::kSingular;
        s->phase = LmPhase::kDone;
        continue;
      }
      internal::RaiseDamping(s);
      internal::Propose<float, P>(*settings[l], lower, upper, s);
      continue;
    }
    float dx[P];
    float step_norm2 = 0, x_norm2 = 0;
    bool finite = true;
    for (int j = 0; j < P; ++j) {
      float v = s->x[j];
      if ((s->free_mask >> j) & 1u) {
        const float moved = s->x[j] + s->jacobi[j] * z[j][l];
        finite = finite && moved - moved == 0.0f;
        v = std::min(std::max(moved, lower[j]), upper[j]);
      }
      s->x_new[j] = v;
      dx[j] = v - s->x[j];
      const float scaled_dx = dx[j] * s->inv_jacobi[j];
      const float scaled_x = s->x[j] * s->inv_jacobi[j];
      step_norm2 += scaled_dx * scaled_dx;
      x_norm2 += scaled_x * scaled_x;
    }
    if (!finite) {
      if (++s->failures >= gpu::shared::kLmMaxSolveFailures) {
        s->status = FitStatus::kSingular;
        s->phase = LmPhase::kDone;
        continue;
      }
      internal::RaiseDamping(s);
      internal::Propose<float, P>(*settings[l], lower, upper, s);
      continue;
    }
    s->failures = 0;
    const float tol = float(settings[l]->step_tolerance);
    if (std::sqrt(step_norm2) <= tol * (std::sqrt(x_norm2) + tol)) {
      for (int j = 0; j < P; ++j) s->x_new[j] = s->x[j];
      s->status = FitStatus::kConverged;
      s->phase = LmPhase::kDone;
      continue;
    }
    float g_dx = 0, dx_a_dx = 0;
    for (int i = 0; i < P; ++i) {
      g_dx += s->at_x.g[i] * dx[i];
      float row = 0;
      for (int j = 0; j < i; ++j) row += s->at_x.a[PackedIndex(i, j)] * dx[j];
      dx_a_dx += dx[i] * (2.0f * row + s->at_x.a[PackedIndex(i, i)] * dx[i]);
    }
    s->predicted_decrease = -g_dx - 0.5f * dx_a_dx;
    if (!(s->predicted_decrease > 0.0f)) {
      ++s->iterations;
      internal::RaiseDamping(s);
      internal::Propose<float, P>(*settings[l], lower, upper, s);
      continue;
    }
    s->phase = LmPhase::kEvaluateStep;
  }
}

class BatchedFitter : public FitterBase {
 public:
  explicit BatchedFitter(int threads) : FitterBase(threads) {}
  Backend backend() const override { return Backend::kCpu; }
  std::string device() const override {
    return StrCat("cpu: ", threads(), " threads, ", kLanes, "-lane batches (", LaneKernelIsa(),
                  " kernel)");
  }

 protected:
  void Reserve(Workspace* w, const ProblemLayout& layout, size_t max_samples, size_t) override {
    if (!w->backend) w->backend = std::make_shared<LaneState>();
    LaneState& s = *static_cast<LaneState*>(w->backend.get());
    const size_t capacity = std::max<size_t>(1, max_samples);
    if (size_t(s.batch.capacity) < capacity) {
      const size_t n = capacity * 3 * kLanes;
      for (auto* v : {&s.xx, &s.yy, &s.zz, &s.y, &s.sw}) v->assign(n, 0.0f);
      s.batch.capacity = int(capacity);
      s.batch.xx = s.xx.data();
      s.batch.yy = s.yy.data();
      s.batch.zz = s.zz.data();
      s.batch.y = s.y.data();
      s.batch.sw = s.sw.data();
    }
  }

  void Solve(Workspace* w, const FitOptions& options, const LmSettings& settings,
             const PreparedProblem* problems, int count, SolvedProblem* solved) override {
    if (count == 0) return;
    DispatchLayout(problems[0].layout, SolveCall{this, w, options, settings, problems, count, solved});
  }

  struct SolveCall {
    BatchedFitter* self;
    Workspace* w;
    const FitOptions& options;
    const LmSettings& settings;
    const PreparedProblem* problems;
    int count;
    SolvedProblem* solved;
    template <LobeModel M, int K>
    void operator()() const {
      self->SolveLanes<NumParams(M, K)>(w, options, settings, problems, count, solved);
    }
  };

  // The lane machine for problems of P parameters (P fixed at compile time, so the per-lane
  // dense algebra of LmAdvance unrolls).
  template <int P>
  void SolveLanes(Workspace* w, const FitOptions& options, const LmSettings& settings,
                  const PreparedProblem* problems, int count, SolvedProblem* solved) {
    LaneState& s = *static_cast<LaneState*>(w->backend.get());
    LaneBatch& b = s.batch;
    const ProblemLayout layout = problems[0].layout;
    constexpr int num_params = P;
    const int blocks = layout.Channels();
    float lower[kMaxParams], upper[kMaxParams];
    const LmSettings two_stage_first = StageSettings(settings, 0, 2);
    for (int j = 0; j < kMaxParams; ++j) {
      lower[j] = float(problems[0].lower[j]);
      upper[j] = float(problems[0].upper[j]);
    }
    for (int l = 0; l < kLanes; ++l) s.problem[l] = -1;
    int next = 0;

    // Copies problem p into lane l and starts its first stage.
    auto load = [&](int l, int p) {
      const PreparedProblem& q = problems[p];
      s.problem[l] = p;
      s.stage[l] = 0;
      s.iterations[l] = 0;
      for (int c = 0; c < 3; ++c) {
        const int begin = q.residuals.begin[c], end = c < blocks ? q.residuals.begin[c + 1] : begin;
        s.count[l][c] = end - begin;
        if (c >= blocks) continue;
        for (int i = 0; i < b.capacity; ++i) {
          const size_t o = (size_t(c) * b.capacity + i) * kLanes + l;
          if (i < end - begin) {
            b.xx[o] = q.residuals.xx[begin + i];
            b.yy[o] = q.residuals.yy[begin + i];
            b.zz[o] = q.residuals.zz[begin + i];
            b.y[o] = q.residuals.y[begin + i];
            b.sw[o] = q.residuals.sw[begin + i];
          } else {
            b.sw[o] = 0.0f;
          }
        }
      }
      b.loss_scale[l] = float(q.loss_scale);
      float x0[kMaxParams];
      for (int j = 0; j < kMaxParams; ++j) x0[j] = float(q.x0[j]);
      LmBegin<float>(num_params, q.stage_mask[0], x0, &s.lm[l]);
    };
    // Records lane l's finished problem.
    auto finish = [&](int l) {
      const LmState<float>& lm = s.lm[l];
      SolvedProblem& out = solved[s.problem[l]];
      out = SolvedProblem{};
      for (int j = 0; j < kMaxParams; ++j) out.x[j] = lm.x[j];
      for (int i = 0; i < PackedIndex(num_params, 0); ++i) out.a[i] = lm.at_x.a[i];
      out.cost = lm.at_x.cost;
      out.free_mask = lm.free_mask;
      out.status = lm.status;
      out.iterations = s.iterations[l];
      s.problem[l] = -1;
    };
    // Moves a lane whose stage ended on to its next stage, or finishes it.
    auto next_stage = [&](int l) {
      const PreparedProblem& q = problems[s.problem[l]];
      s.iterations[l] += s.lm[l].iterations;
      if (s.stage[l] + 1 < q.num_stages) {
        ++s.stage[l];
        float x[kMaxParams];
        std::memcpy(x, s.lm[l].x, sizeof x);
        LmBegin<float>(num_params, q.stage_mask[s.stage[l]], x, &s.lm[l]);
        return;
      }
      finish(l);
    };

    while (true) {
      int active = 0;
      for (int l = 0; l < kLanes; ++l) {
        while (s.problem[l] < 0 && next < count) {
          const int p = next++;
          if (problems[p].num_stages == 0) {
            SolvedProblem& out = solved[p];
            out = SolvedProblem{};
            for (int j = 0; j < kMaxParams; ++j) out.x[j] = problems[p].x0[j];
            out.status = FitStatus::kConverged;
            continue;
          }
          load(l, p);
        }
        active += s.problem[l] >= 0;
      }
      if (active == 0) break;
      for (int c = 0; c < 3; ++c) b.block_count[c] = 0;
      for (int l = 0; l < kLanes; ++l) {
        if (s.problem[l] < 0) continue;
        for (int c = 0; c < 3; ++c) b.block_count[c] = std::max(b.block_count[c], s.count[l][c]);
        for (int j = 0; j < num_params; ++j) b.x[j][l] = s.lm[l].x_new[j];
      }
      EvaluateLanes(layout, options.loss, &b);
      const LmSettings* lane_settings[kLanes];
      for (int l = 0; l < kLanes; ++l) {
        lane_settings[l] = &settings;
        if (s.problem[l] < 0) {
          s.lm[l].phase = LmPhase::kDone;  // an empty lane takes no part in the proposal pass
          continue;
        }
        NormalEquations<float> neq;
        const int packed = PackedIndex(num_params, 0);
        for (int i = 0; i < packed; ++i) neq.a[i] = b.a[i][l];
        for (int j = 0; j < num_params; ++j) neq.g[j] = b.g[j][l];
        neq.cost = b.cost[l];
        const bool first_of_two = s.stage[l] == 0 && problems[s.problem[l]].num_stages == 2;
        if (first_of_two) lane_settings[l] = &two_stage_first;
        LmAdvance<float, P, true>(*lane_settings[l], lower, upper, neq, &s.lm[l]);
      }
      ProposeLanes<P>(lane_settings, lower, upper, s.lm);
      for (int l = 0; l < kLanes; ++l) {
        if (s.problem[l] >= 0 && s.lm[l].phase == LmPhase::kDone) next_stage(l);
      }
    }
  }
};

}  // namespace

std::unique_ptr<Fitter> CreateBatchedFitter(int threads) {
  return std::make_unique<BatchedFitter>(threads);
}

}  // namespace reflcap::fit::internal
