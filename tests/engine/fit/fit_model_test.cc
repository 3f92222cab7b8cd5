// Parameter layouts, bounds, the map to brdf::BrdfParams, and the analytic gradient of every
// lobe model against ceres::Jet automatic differentiation.
#include <gtest/gtest.h>

#include <ceres/jet.h>

#include <Eigen/Dense>
#include <random>

#include "engine/fit/fitter.h"
#include "engine/fit/lm.h"
#include "engine/fit/model.h"
#include "engine/fit/problem.h"
#include "engine/fit/synthetic_samples.h"
#include "shaders/shared/fit_status.h"

namespace reflcap::fit {
namespace {

static_assert(int(FitStatus::kConverged) == 0 && int(FitStatus::kNonFiniteInput) == 5,
              "status codes are shaders/shared/fit_status.h's");
static_assert(kMaxParams == 16 && NumParams(LobeModel::kAniso, 3) == 13 &&
              NumParams(LobeModel::kIso, 3) == 10 && NumParams(LobeModel::kShared, 2) == 15,
              "every layout fits the 16-parameter LM state");

// Every layout the fitter offers.
std::vector<ProblemLayout> AllLayouts() {
  std::vector<ProblemLayout> layouts;
  for (LobeModel m : {LobeModel::kAniso, LobeModel::kIso, LobeModel::kShared}) {
    for (int k = 0; k <= (m == LobeModel::kShared ? kMaxSharedLobes : brdf::kMaxLobes); ++k) {
      layouts.push_back({m, k});
    }
  }
  return layouts;
}

TEST(ProblemLayout, NamesMatchParameterCounts) {
  for (const ProblemLayout& l : AllLayouts()) {
    EXPECT_TRUE(l.Validate().ok());
    EXPECT_EQ(int(l.ParamNames().size()), l.NumParams()) << LobeModelName(l.model) << l.lobes;
    EXPECT_LE(l.NumParams(), kMaxParams);
  }
  EXPECT_EQ((ProblemLayout{LobeModel::kShared, 1}).NumParams(), 9);
  EXPECT_EQ((ProblemLayout{LobeModel::kAniso, 1}).ParamNames(),
            (std::vector<std::string>{"rho", "lobe0.Cx", "lobe0.Cy", "lobe0.Cz", "lobe0.n"}));
  EXPECT_FALSE((ProblemLayout{LobeModel::kShared, 3}).Validate().ok());
  EXPECT_FALSE((ProblemLayout{LobeModel::kAniso, 4}).Validate().ok());
}

TEST(ProblemLayout, BoundsKeepRhoNonNegativeAndExponentInRange) {
  for (const ProblemLayout& l : AllLayouts()) {
    double lo[kMaxParams], hi[kMaxParams];
    ParameterBounds(l, lo, hi);
    EXPECT_EQ(lo[0], 0.0);
    for (int k = 0; k < l.lobes; ++k) {
      EXPECT_EQ(lo[ExponentIndex(l.model, k)], brdf::kMinExponent);
      EXPECT_EQ(hi[ExponentIndex(l.model, k)], brdf::kMaxExponent);
    }
    for (int j = 0; j < l.NumParams(); ++j) {
      EXPECT_TRUE(std::isfinite(lo[j]) && std::isfinite(hi[j]) && lo[j] < hi[j]);
    }
  }
}

// Round trip natural -> normalised -> natural on parameters each model can represent.
TEST(ProblemLayout, BrdfParamsRoundTrip) {
  // float storage of BrdfParams: ~1e-7 relative, amplified by S^(1/n) powers; 1e-5 is ample.
  constexpr double kRoundTripTolerance = 1e-5;
  for (double scale : {1e-4, 1.0, 37.0}) {
    for (const ProblemLayout& l : AllLayouts()) {
      // Isotropic, channel-shared shapes are representable by all three models.
      brdf::BrdfParams truth;
      truth.num_lobes = l.lobes;
      for (int c = 0; c < 3; ++c) {
        truth.rho_d[c] = 0.2f + 0.1f * c;
        for (int k = 0; k < l.lobes; ++k) truth.lobes[k][c] = brdf::MirrorLobe(2.0 + c, 10.0 + 20 * k);
      }
      brdf::BrdfParams back;
      back.num_lobes = l.lobes;
      for (int p = 0; p < ProblemsPerTexel(l.model); ++p) {
        double x[kMaxParams] = {};
        FromBrdfParams(l, truth, scale, p, x);
        ToBrdfParams(l, x, scale, p, &back);
      }
      for (int c = 0; c < 3; ++c) {
        EXPECT_NEAR(back.rho_d[c], truth.rho_d[c], kRoundTripTolerance);
        for (int k = 0; k < l.lobes; ++k) {
          const brdf::LobeParams &a = back.lobes[k][c], &b = truth.lobes[k][c];
          EXPECT_NEAR(a.cx, b.cx, kRoundTripTolerance * std::abs(b.cx)) << LobeModelName(l.model);
          EXPECT_NEAR(a.cy, b.cy, kRoundTripTolerance * std::abs(b.cy));
          EXPECT_NEAR(a.cz, b.cz, kRoundTripTolerance * std::abs(b.cz));
          EXPECT_NEAR(a.n, b.n, kRoundTripTolerance * b.n);
        }
      }
    }
  }
}

// The model in natural units equals brdf::EvalChannel on the mapped parameters.
TEST(EvalModel, MatchesTheBrdfModelAfterMapping) {
  // Both sides in double; the map's pow(S, 1/n) and float storage of BrdfParams: 1e-5 relative.
  constexpr double kTolerance = 1e-5;
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1, 1);
  for (const ProblemLayout& l : AllLayouts()) {
    const brdf::BrdfParams truth = SynthMaterialParams(3);  // anisotropic: Cx != Cy
    const double scale = 3.0;
    for (int p = 0; p < ProblemsPerTexel(l.model); ++p) {
      double x[kMaxParams] = {};
      FromBrdfParams(l, truth, scale, p, x);
      brdf::BrdfParams mapped;
      mapped.num_lobes = l.lobes;
      ToBrdfParams(l, x, scale, p, &mapped);
      for (int trial = 0; trial < 50; ++trial) {
        Vec3d wi(u(rng), u(rng), 1.0), wo(u(rng), u(rng), 1.0);
        wi.normalize();
        wo.normalize();
        for (int c = (l.model == LobeModel::kShared ? 0 : p); c < (l.model == LobeModel::kShared ? 3 : p + 1); ++c) {
          const double f = scale * EvalModelDyn<double>(l, x, wi.x() * wo.x(), wi.y() * wo.y(),
                                                        wi.z() * wo.z(), l.model == LobeModel::kShared ? c : 0, nullptr);
          const auto ch = mapped.Channel(c);
          double params[brdf::kMaxParamsPerChannel];
          for (int j = 0; j < brdf::kMaxParamsPerChannel; ++j) params[j] = ch[j];
          const double expected = brdf::EvalChannel(wi.data(), wo.data(), params, l.lobes);
          EXPECT_NEAR(f, expected, kTolerance * std::max(1.0, std::abs(expected)));
        }
      }
    }
  }
}

// Analytic gradient vs forward-mode automatic differentiation, for every lobe model, at random
// in-bound parameters and directions, including cut-off and saturated lobes.
TEST(EvalModel, GradientMatchesJetForEveryLobeModel) {
  // Both in double with the same formulas reordered: agreement to ~1e-12 relative; 1e-9 leaves
  // room for the b^n cancellation at large n.
  constexpr double kTolerance = 1e-9;
  using Jet = ceres::Jet<double, kMaxParams>;
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-1, 1), coefficient(-1.5, 1.5), exponent(1, 300);
  int cut_off = 0, live = 0;
  for (const ProblemLayout& l : AllLayouts()) {
    for (int trial = 0; trial < 300; ++trial) {
      double x[kMaxParams] = {};
      for (int j = 0; j < l.NumParams(); ++j) x[j] = coefficient(rng);
      for (int c = 0; c < LambertParams(l.model); ++c) x[c] = std::abs(x[c]);
      for (int k = 0; k < l.lobes; ++k) {
        x[ExponentIndex(l.model, k)] = exponent(rng);
        if (l.model == LobeModel::kShared) {
          for (int c = 0; c < 3; ++c) x[LobeOffset(l.model, k) + 3 + c] = std::abs(coefficient(rng));
        }
      }
      Vec3d wi(u(rng), u(rng), 1.0), wo(u(rng), u(rng), 1.0);
      wi.normalize();
      wo.normalize();
      const int channel = trial % 3;
      const double xx = wi.x() * wo.x(), yy = wi.y() * wo.y(), zz = wi.z() * wo.z();
      double grad[kMaxParams] = {};
      const double f = EvalModelDyn<double>(l, x, xx, yy, zz, channel, grad);
      Jet xj[kMaxParams];
      for (int j = 0; j < kMaxParams; ++j) xj[j] = Jet(x[j], j);
      const Jet fj = EvalModelDyn<Jet>(l, xj, Jet(xx), Jet(yy), Jet(zz), channel, nullptr);
      EXPECT_NEAR(f, fj.a, kTolerance * std::max(1.0, std::abs(f)));
      for (int j = 0; j < l.NumParams(); ++j) {
        EXPECT_NEAR(grad[j], fj.v[j], kTolerance * std::max(1.0, std::abs(fj.v[j])))
            << LobeModelName(l.model) << " K=" << l.lobes << " parameter " << j;
      }
      (fj.a > x[0] / kPi + 1e-12 ? live : cut_off) += l.lobes > 0;
    }
  }
  EXPECT_GT(cut_off, 100);  // both regimes were exercised
  EXPECT_GT(live, 100);
}

TEST(EvalModel, SaturatesInsteadOfOverflowing) {
  const ProblemLayout l{LobeModel::kAniso, 1};
  const double x[5] = {0.5, 0, 0, 50, brdf::kMaxExponent};  // base 50, n = 1e4
  double grad[5];
  const float xf[5] = {0.5f, 0, 0, 50, float(brdf::kMaxExponent)};
  float gradf[5];
  EXPECT_EQ(EvalModelDyn<double>(l, x, 0.0, 0.0, 1.0, 0, grad), 0.5 / kPi + kMaxFitLobeValue);
  EXPECT_TRUE(std::isfinite(EvalModelDyn<float>(l, xf, 0.f, 0.f, 1.f, 0, gradf)));
  for (int j = 1; j < 5; ++j) EXPECT_EQ(grad[j], 0.0);
}

TEST(FitOptions, ValidateRejectsOutOfRangeValues) {
  EXPECT_TRUE(FitOptions{}.Validate().ok());
  FitOptions o;
  o.lobes = 4;
  EXPECT_FALSE(o.Validate().ok());
  o = FitOptions{};
  o.max_iterations = 0;
  EXPECT_FALSE(o.Validate().ok());
  o = FitOptions{};
  o.loss_scale = -1;
  EXPECT_FALSE(o.Validate().ok());
  o = FitOptions{};
  o.start_exponent = 0.5;
  EXPECT_FALSE(o.Validate().ok());
  o = FitOptions{};
  o.lobe_model = LobeModel::kShared;
  o.lobes = 3;
  EXPECT_FALSE(o.Validate().ok());
  EXPECT_FALSE(ParseBackend("gpu").ok());
  EXPECT_EQ(ParseLossKind("cauchy").value(), LossKind::kCauchy);
}

TEST(CreateFitter, VulkanIsAvailableOrSaysWhyNot) {
  // Built without Vulkan, or on a machine without a Vulkan device: Unavailable, naming Vulkan
  // (fit_vulkan_test.cc tests the backend itself).
  auto fitter = CreateFitter(Backend::kVulkan);
  if (fitter.ok()) {
    EXPECT_EQ((*fitter)->backend(), Backend::kVulkan);
  } else {
    EXPECT_EQ(fitter.status().code(), StatusCode::kUnavailable) << fitter.status().ToString();
    EXPECT_NE(fitter.status().message().find("Vulkan"), std::string::npos);
  }
}

TEST(CholeskySolve, SolvesAndRejectsIndefiniteMatrices) {
  double a[6] = {4, 2, 3, 1, 0.5, 2};  // [[4,2,1],[2,3,.5],[1,.5,2]] packed lower
  double b[3] = {1, 2, 3};
  ASSERT_TRUE(CholeskySolve(3, a, b));
  // Solution of the system above (by hand / numpy): x = A^-1 b.
  EXPECT_NEAR(4 * b[0] + 2 * b[1] + 1 * b[2], 1, 1e-12);
  EXPECT_NEAR(2 * b[0] + 3 * b[1] + 0.5 * b[2], 2, 1e-12);
  EXPECT_NEAR(1 * b[0] + 0.5 * b[1] + 2 * b[2], 3, 1e-12);
  double bad[3] = {1, 2, 1};  // [[1,2],[2,1]]: indefinite
  double rhs[2] = {1, 1};
  EXPECT_FALSE(CholeskySolve(2, bad, rhs));
}

// FinishProblem's standard deviations are Cov = s^2 (J^T J)^-1 over the free parameters, pushed
// through the map to natural units: checked against a dense inverse (Eigen) of a random
// well-conditioned J^T J, with every parameter free and with the exponent held fixed.
TEST(FinishProblem, StandardDeviationsAreTheFreeBlocksCovariance) {
  const ProblemLayout layout{LobeModel::kAniso, 1};  // rho, Cx, Cy, Cz, n
  constexpr int n = 5;
  constexpr int kResiduals = 40;
  std::vector<float> zeros(kResiduals, 0.0f);
  std::mt19937 rng(7);
  std::normal_distribution<double> normal;
  Eigen::Matrix<double, n, n> jtj;
  {
    Eigen::Matrix<double, 2 * n, n> j;
    for (int r = 0; r < 2 * n; ++r) {
      for (int c = 0; c < n; ++c) j(r, c) = normal(rng) * (1 + c);  // columns of unequal size
    }
    jtj = j.transpose() * j;
  }
  for (const double scale : {1.0, 3.0}) {
    for (const uint32_t free_mask : {0x1Fu, 0x0Fu}) {  // all free; n (parameter 4) fixed
      PreparedProblem q;
      q.layout = layout;
      q.scale = scale;
      q.samples = kResiduals;
      q.num_stages = 2;
      q.residuals.xx = q.residuals.yy = q.residuals.zz = q.residuals.y = q.residuals.sw =
          zeros.data();
      q.residuals.begin[1] = q.residuals.begin[2] = q.residuals.begin[3] = kResiduals;
      ParameterBounds(layout, q.lower, q.upper);
      SolvedProblem solved;
      const double x[n] = {0.4, -0.5, -0.5, 0.9, 10.0};  // peak 0.9^10: within the evidence
      for (int j = 0; j < n; ++j) solved.x[j] = x[j];
      for (int r = 0; r < n; ++r) {
        for (int c = 0; c <= r; ++c) solved.a[PackedIndex(r, c)] = jtj(r, c);
      }
      solved.cost = 7;
      solved.free_mask = free_mask;
      TexelFit fit;
      BeginTexel(1, &fit);
      FinishProblem(q, solved, &fit);
      ASSERT_EQ(fit.status, FitStatus::kConverged);

      const int m = free_mask == 0x1Fu ? 5 : 4;  // the free block is the leading m x m one
      const Eigen::MatrixXd inv = jtj.topLeftCorner(m, m).inverse();
      const double variance = 2 * solved.cost / (kResiduals - m);
      // d(natural)/d(normalised): rho = S rho'; C = C' r, r = S^(1/n); dC/dn = -C' r log S / n^2.
      const double r = std::pow(scale, 1.0 / x[4]);
      const double dr_dn = -r * std::log(scale) / (x[4] * x[4]);
      auto expected = [&](int param, double d_param, double d_n) {
        Eigen::VectorXd g = Eigen::VectorXd::Zero(m);
        g(param) = d_param;
        if (m == 5) g(4) += d_n;
        return std::sqrt(variance * g.dot(inv * g));
      };
      // Relative 1e-6: float outputs (1e-7) of a double computation on a well-conditioned matrix.
      constexpr double kRel = 1e-6;
      const brdf::LobeParams& s = fit.sigma.lobes[0][0];
      EXPECT_NEAR(fit.sigma.rho_d[0], expected(0, scale, 0), kRel * expected(0, scale, 0));
      const float* c_sigma[3] = {&s.cx, &s.cy, &s.cz};
      for (int f = 0; f < 3; ++f) {
        const bool depends_on_fixed_n = m == 4 && dr_dn != 0;
        if (depends_on_fixed_n) {
          EXPECT_EQ(*c_sigma[f], -1.0f) << "C depends on the fixed exponent when S != 1";
        } else {
          const double e = expected(1 + f, r, x[1 + f] * dr_dn);
          EXPECT_NEAR(*c_sigma[f], e, kRel * e) << "scale " << scale << " mask " << free_mask;
        }
      }
      if (m == 5) {
        EXPECT_NEAR(s.n, expected(4, 0, 1), kRel * expected(4, 0, 1));
      } else {
        EXPECT_EQ(s.n, -1.0f) << "the fixed exponent has no standard deviation";
      }
    }
  }
}

}  // namespace
}  // namespace reflcap::fit
