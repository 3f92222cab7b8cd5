// The Ceres reference backend: every prepared problem (problem.h: same residuals, start, stages
// and bounds as the batched path) becomes one small ceres::Problem with one automatically
// differentiated residual block per (sample, channel) — so a robust loss applies per residual,
// as in the batched path — solved by Ceres' Levenberg–Marquardt with the same tolerances and
// iteration cap. The final normal equations for the rank test and the standard deviations are
// recomputed with lm.h in double, so every backend reports them alike.
#include <ceres/ceres.h>

#include <vector>

#include "engine/fit/fitter_base.h"

namespace reflcap::fit::internal {
namespace {

template <LobeModel M, int K>
struct OneResidual {
  float xx, yy, zz, y, sw;
  int channel;
  template <typename T>
  bool operator()(const T* x, T* residual) const {
    const T f = EvalModel<M, K, T>(x, T(xx), T(yy), T(zz), channel, nullptr);
    residual[0] = T(sw) * (f - T(y));
    return true;
  }
};

FitStatus FromCeres(const ceres::Solver::Summary& summary) {
  switch (summary.termination_type) {
    case ceres::CONVERGENCE: return FitStatus::kConverged;
    case ceres::NO_CONVERGENCE: return FitStatus::kMaxIterations;
    default: return FitStatus::kSingular;
  }
}

struct CeresSolve {
  const PreparedProblem& q;
  const FitOptions& options;
  const LmSettings& settings;

  template <LobeModel M, int K>
  SolvedProblem operator()() const {
    constexpr int P = NumParams(M, K);
    SolvedProblem out;
    double x[kMaxParams];
    for (int j = 0; j < kMaxParams; ++j) x[j] = q.x0[j];
    for (int stage = 0; stage < q.num_stages; ++stage) {
      ceres::Problem::Options problem_options;
      problem_options.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
      ceres::Problem problem(problem_options);
      std::unique_ptr<ceres::LossFunction> loss;
      if (options.loss == LossKind::kHuber) loss = std::make_unique<ceres::HuberLoss>(q.loss_scale);
      if (options.loss == LossKind::kCauchy) loss = std::make_unique<ceres::CauchyLoss>(q.loss_scale);
      const ResidualView& r = q.residuals;
      for (int c = 0; c < 3; ++c) {
        for (int i = r.begin[c]; i < r.begin[c + 1]; ++i) {
          auto* cost = new ceres::AutoDiffCostFunction<OneResidual<M, K>, 1, P>(
              new OneResidual<M, K>{r.xx[i], r.yy[i], r.zz[i], r.y[i], r.sw[i], c});
          problem.AddResidualBlock(cost, loss.get(), x);
        }
      }
      for (int j = 0; j < P; ++j) {
        problem.SetParameterLowerBound(x, j, q.lower[j]);
        problem.SetParameterUpperBound(x, j, q.upper[j]);
      }
      const uint32_t mask = q.stage_mask[stage];
      std::vector<int> fixed;
      for (int j = 0; j < P; ++j) {
        if (!((mask >> j) & 1u)) fixed.push_back(j);
      }
      if (int(fixed.size()) == P) continue;
      if (!fixed.empty()) problem.SetManifold(x, new ceres::SubsetManifold(P, fixed));
      ceres::Solver::Options solver;
      solver.minimizer_type = ceres::TRUST_REGION;
      solver.trust_region_strategy_type = ceres::LEVENBERG_MARQUARDT;
      solver.linear_solver_type = ceres::DENSE_QR;
      solver.max_num_iterations = StageSettings(settings, stage, q.num_stages).max_iterations;
      solver.function_tolerance = settings.cost_tolerance;
      solver.parameter_tolerance = settings.step_tolerance;
      solver.gradient_tolerance = settings.gradient_tolerance;
      solver.initial_trust_region_radius = 1.0 / double(gpu::shared::kLmInitialLambda);
      solver.num_threads = 1;
      solver.logging_type = ceres::SILENT;
      ceres::Solver::Summary summary;
      ceres::Solve(solver, &problem, &summary);
      out.iterations += std::max(0, int(summary.iterations.size()) - 1);
      out.status = FromCeres(summary);
      out.free_mask = mask;
    }
    for (int j = 0; j < kMaxParams; ++j) out.x[j] = x[j];
    if (q.num_stages > 0) {
      NormalEquations<double> neq;
      EvaluateNormalEquations<M, K, double>(q.residuals, x, options.loss, q.loss_scale, &neq);
      for (int i = 0; i < kMaxPacked; ++i) out.a[i] = i < PackedIndex(P, 0) ? neq.a[i] : 0.0;
      out.cost = neq.cost;
    }
    return out;
  }
};

class CeresFitter : public FitterBase {
 public:
  explicit CeresFitter(int threads) : FitterBase(threads) {}
  Backend backend() const override { return Backend::kCeres; }
  std::string device() const override {
    return StrCat("ceres ", CERES_VERSION_STRING, " (one problem per fit, autodiff), ", threads(),
                  " threads");
  }

 protected:
  void Solve(Workspace*, const FitOptions& options, const LmSettings& settings,
             const PreparedProblem* problems, int count, SolvedProblem* solved) override {
    for (int i = 0; i < count; ++i) {
      solved[i] = DispatchLayout(problems[i].layout, CeresSolve{problems[i], options, settings});
    }
  }
};

}  // namespace

std::unique_ptr<Fitter> CreateCeresFitter(int threads) {
  return std::make_unique<CeresFitter>(threads);
}

}  // namespace reflcap::fit::internal
