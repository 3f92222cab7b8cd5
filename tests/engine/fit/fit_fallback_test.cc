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
