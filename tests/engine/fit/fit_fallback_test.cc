// The shared post-processing's Lambert fallback (problem.h: LobeExceedsEvidence, LambertFallback):
// a lobe the data cannot pin down is replaced by the closed-form Lambert-only fit.
#include <gtest/gtest.h>

#include <cmath>

#include "engine/fit/problem.h"

namespace reflcap::fit {
namespace {

TEST(LobeExceedsEvidence, ComparesTheHemisphereSupremumWithTheBrightestSample) {
  const ProblemLayout aniso{LobeModel::kAniso, 1};
  // Mirror lobe C = (-c, -c, c): supremum c^n. 1.1^20 = 6.7 (kept), 1.1^50 = 117 (extrapolated).
  const double kept[] = {0.3, -1.1, -1.1, 1.1, 20};
  const double extrapolated[] = {0.3, -1.1, -1.1, 1.1, 50};
  EXPECT_FALSE(LobeExceedsEvidence(aniso, kept));
  EXPECT_TRUE(LobeExceedsEvidence(aniso, extrapolated));
  // A tangential coefficient larger than Cz is what blows up at grazing angles.
  const double grazing[] = {0.3, -2.0, -0.5, 0.9, 10};
  EXPECT_TRUE(LobeExceedsEvidence(aniso, grazing));
  const ProblemLayout iso{LobeModel::kIso, 1};
  const double iso_kept[] = {0.3, -1.0, 1.0, 300};
  EXPECT_FALSE(LobeExceedsEvidence(iso, iso_kept));
}

TEST(LambertFallback, IsTheWeightedLeastSquaresAlbedoWithTheLobeZeroed) {
  // Three residuals y = rho/pi with weights 1, 1, 2: rho = pi (0.1 + 0.2 + 2 * 0.4) / 4.
  const float zeros[3] = {0, 0, 0};
  const float y[3] = {0.1f, 0.2f, 0.4f};
  const float sw[3] = {1.0f, 1.0f, std::sqrt(2.0f)};
  PreparedProblem q;
  q.layout = {LobeModel::kAniso, 1};
  q.residuals.xx = q.residuals.yy = q.residuals.zz = zeros;
  q.residuals.y = y;
  q.residuals.sw = sw;
  q.residuals.begin[1] = q.residuals.begin[2] = q.residuals.begin[3] = 3;
  q.lower[0] = 0;
  q.upper[0] = 1e3;
  q.x0[4] = 20;
  double x[kMaxParams] = {9, -5, -5, 5, 500};
  const double cost = LambertFallback(q, x);
  const double rho = kPi * (0.1 + 0.2 + 2 * 0.4) / 4;
  EXPECT_NEAR(x[0], rho, 1e-6);
  EXPECT_EQ(x[1], 0.0);
  EXPECT_EQ(x[2], 0.0);
  EXPECT_EQ(x[3], 0.0);
  EXPECT_EQ(x[4], 20.0) << "the exponent returns to its start value";
  const double f = rho / kPi;
  const double expected_cost =
      0.5 * ((f - 0.1) * (f - 0.1) + (f - 0.2) * (f - 0.2) + 2 * (f - 0.4) * (f - 0.4));
  EXPECT_NEAR(cost, expected_cost, 1e-7);
}

}  // namespace
}  // namespace reflcap::fit

namespace reflcap::fit {
namespace {

// Three aniso K = 1 channel problems of 100 residuals, fitted in two stages, with `scale` as
// their normalisation and the given LM costs (normalised units, all 5 parameters free).
struct ThreeChannels {
  PreparedProblem q[3];
  SolvedProblem solved[3];
  ThreeChannels(const double (&cost)[3], const double (&scale)[3]) {
    for (int c = 0; c < 3; ++c) {
      q[c].layout = {LobeModel::kAniso, 1};
      q[c].problem = c;
      q[c].residuals.begin[1] = q[c].residuals.begin[2] = q[c].residuals.begin[3] = 100;
      q[c].scale = scale[c];
      q[c].num_stages = 2;
      for (int j = 0; j < 5; ++j) {
        q[c].lower[j] = j == 4 ? 1 : -1e3;
        q[c].upper[j] = j == 4 ? 1e4 : 1e3;
      }
      q[c].x0[0] = 0.1 * (c + 1);
      q[c].x0[4] = 20;
      const double x[5] = {0.3, -0.9, -0.9, 0.9, 100};  // within the evidence: 0.9^100
      std::copy(x, x + 5, solved[c].x);
      solved[c].cost = cost[c];
      solved[c].free_mask = 0x1F;
      solved[c].status = FitStatus::kConverged;
    }
  }
};

TEST(ChannelRetry, RetriesOnlyChannelsFarWorseThanTheBestFromItsLobe) {
  // Reduced costs 2 S^2 cost / 95 (natural noise units): 1.05, 1.16, 21 (S = 0.5) -> only
  // channel 2 exceeds 4 x max(1.05, 1).
  ThreeChannels t({50, 55, 4000}, {1, 1, 0.5});
  t.solved[0].x[4] = 200;
  PreparedProblem retry[3];
  int channel[3];
  ASSERT_EQ(PrepareChannelRetries(t.q, t.solved, 3, retry, channel), 1);
  EXPECT_EQ(channel[0], 2);
  // Channel 0's lobe in channel 2's normalisation (S 1 vs 0.5: the same natural lobe is twice as
  // tall there): C x 2^(1/200), n kept; the start rho stays channel 2's own.
  const double f = std::pow(2.0, 1.0 / 200);
  EXPECT_DOUBLE_EQ(retry[0].x0[0], 0.3);
  EXPECT_NEAR(retry[0].x0[1], -0.9 * f, 1e-12);
  EXPECT_NEAR(retry[0].x0[3], 0.9 * f, 1e-12);
  EXPECT_DOUBLE_EQ(retry[0].x0[4], 200);
  EXPECT_EQ(retry[0].problem, 2);

  // Within 4x of the best: no retry.
  ThreeChannels close({50, 150, 180}, {1, 1, 1});
  EXPECT_EQ(PrepareChannelRetries(close.q, close.solved, 3, retry, channel), 0);
  // The reference must have converged with a lobe inside the evidence: with channel 0 singular,
  // channel 1 (1.16) is the reference, channel 2 is retried from its lobe (n = 100, S 1 vs 0.5),
  // and channel 0 (1.05) is not.
  t.solved[0].status = FitStatus::kSingular;
  ASSERT_EQ(PrepareChannelRetries(t.q, t.solved, 3, retry, channel), 1);
  EXPECT_EQ(channel[0], 2);
  EXPECT_DOUBLE_EQ(retry[0].x0[4], 100);
  EXPECT_NEAR(retry[0].x0[3], 0.9 * std::pow(2.0, 1.0 / 100), 1e-12);
  // Channel 1 with |Cx| = 1.5 at n = 1000 (supremum 1.5^1000, beyond kMaxLobeSupremum): no
  // reference at all.
  t.solved[1].x[4] = 1000;
  t.solved[1].x[1] = t.solved[1].x[2] = -1.5;
  EXPECT_EQ(PrepareChannelRetries(t.q, t.solved, 3, retry, channel), 0);
}

TEST(ChannelRetry, NothingToRetryWithoutPerChannelLobes) {
  ThreeChannels t({50, 55, 1000}, {1, 1, 1});
  PreparedProblem retry[3];
  int channel[3];
  for (PreparedProblem& q : t.q) q.lambert_only = true;
  EXPECT_EQ(PrepareChannelRetries(t.q, t.solved, 3, retry, channel), 0);
  EXPECT_EQ(PrepareChannelRetries(t.q, t.solved, 1, retry, channel), 0);  // shared: one problem
}

TEST(ChannelRetry, KeepsTheLowerCostAndNeverANan) {
  SolvedProblem solved[3], retried[2];
  solved[1].cost = 10;
  solved[2].cost = 10;
  retried[0].cost = 12;  // worse: channel 1 keeps its own
  retried[1].cost = std::nan("");
  const int channel[2] = {1, 2};
  EXPECT_EQ(AdoptChannelRetries(retried, channel, 2, solved), 0);
  EXPECT_EQ(solved[1].cost, 10);
  retried[1].cost = 3;
  EXPECT_EQ(AdoptChannelRetries(retried, channel, 2, solved), 1);
  EXPECT_EQ(solved[2].cost, 3);
}

}  // namespace
}  // namespace reflcap::fit
