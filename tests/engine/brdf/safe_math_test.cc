#include "engine/math/safe_math.h"

#include <cmath>
#include <limits>

#include <ceres/jet.h>
#include <gtest/gtest.h>

namespace reflcap {
namespace {

using Jet = ceres::Jet<double, 2>;

TEST(SafePow, ZeroToTheZeroIsZeroUnlikeC) {
  // C's pow(0, 0) is 1; GLSL leaves it undefined and lavapipe gives 0. The twins agree on 0.
  EXPECT_EQ(SafePow(0.0, 0.0), 0.0);
  EXPECT_EQ(SafePow(0.0f, 0.0f), 0.0f);
}

TEST(SafePow, NonPositiveBaseIsZero) {
  EXPECT_EQ(SafePow(-0.5, 2.5), 0.0);
  EXPECT_EQ(SafePow(-2.0, 2.0), 0.0);  // even for an integer exponent, where C would give 4
  EXPECT_EQ(SafePow(0.0, 3.0), 0.0);
  EXPECT_EQ(SafePow(kPowBaseMin, 1.0), 0.0);
  EXPECT_EQ(SafePow(-1.0f, 2.5f), 0.0f);
}

TEST(SafePow, MatchesStdPowAboveCutOff) {
  for (double b : {1e-29, 1e-5, 0.3, 1.0, 2.0}) {
    for (double n : {0.5, 1.0, 7.25, 100.0}) {
      EXPECT_EQ(SafePow(b, n), std::pow(b, n)) << b << "^" << n;
    }
  }
}

TEST(SafePow, JetDerivativesAreZeroBelowAndExactAbove) {
  const Jet zero_base = SafePow(Jet(-0.25, 0), Jet(3.0, 1));
  EXPECT_EQ(zero_base.a, 0.0);
  EXPECT_EQ(zero_base.v[0], 0.0);
  EXPECT_EQ(zero_base.v[1], 0.0);
  const Jet p = SafePow(Jet(0.5, 0), Jet(3.0, 1));
  EXPECT_DOUBLE_EQ(p.a, 0.125);
  EXPECT_DOUBLE_EQ(p.v[0], 3.0 * 0.25);              // n b^(n-1)
  EXPECT_DOUBLE_EQ(p.v[1], 0.125 * std::log(0.5));  // b^n log b
}

TEST(SafeSqrt, ClampsRoundingNoiseBelowZero) {
  EXPECT_EQ(SafeSqrt(-1e-9), 0.0);
  EXPECT_EQ(SafeSqrt(0.0f), 0.0f);
  EXPECT_DOUBLE_EQ(SafeSqrt(2.25), 1.5);
  const Jet at_zero = SafeSqrt(Jet(0.0, 0));
  EXPECT_EQ(at_zero.a, 0.0);
  EXPECT_TRUE(std::isfinite(at_zero.v[0]));
  EXPECT_TRUE(std::isnan(SafeSqrt(std::numeric_limits<double>::quiet_NaN())));
}

TEST(SafeAcos, ClampsToUnitInterval) {
  EXPECT_EQ(SafeAcos(1.0 + 1e-7), 0.0);
  EXPECT_DOUBLE_EQ(SafeAcos(-1.0 - 1e-7), kPi);
  EXPECT_DOUBLE_EQ(SafeAcos(0.5), std::acos(0.5));
  const Jet at_one = SafeAcos(Jet(1.0, 0));
  EXPECT_EQ(at_one.a, 0.0);
  EXPECT_TRUE(std::isfinite(at_one.v[0]));
}

TEST(SafeDiv, ZeroDenominatorGivesFallback) {
  EXPECT_EQ(SafeDiv(1.0, 0.0, -3.0), -3.0);
  EXPECT_EQ(SafeDiv(1.0f, -0.0f, 7.0f), 7.0f);
  EXPECT_DOUBLE_EQ(SafeDiv(1.0, 4.0, -3.0), 0.25);
  EXPECT_DOUBLE_EQ(SafeDiv(1.0, 1e-300, 0.0), 1e300);  // only an exact zero falls back
}

TEST(SafeLog, ClampsTinyAndNonPositiveArguments) {
  const double log_tiny = std::log(kTiny);
  EXPECT_EQ(SafeLog(0.0), log_tiny);
  EXPECT_EQ(SafeLog(-1.0), log_tiny);
  EXPECT_EQ(SafeLog(1e-40), log_tiny);
  EXPECT_FLOAT_EQ(SafeLog(0.0f), static_cast<float>(log_tiny));
  EXPECT_DOUBLE_EQ(SafeLog(2.0), std::log(2.0));
  const Jet clamped = SafeLog(Jet(0.0, 0));
  EXPECT_EQ(clamped.v[0], 0.0);
}

TEST(Clamp, LimitsToRangeAndPassesInterior) {
  EXPECT_EQ(Clamp(-1.0, 0.0, 1.0), 0.0);
  EXPECT_EQ(Clamp(2.0f, 0.0f, 1.0f), 1.0f);
  EXPECT_EQ(Clamp(0.25, 0.0, 1.0), 0.25);
  const Jet clamped = Clamp(Jet(2.0, 0), Jet(0.0), Jet(1.0));
  EXPECT_EQ(clamped.a, 1.0);
  EXPECT_EQ(clamped.v[0], 0.0);
  const Jet interior = Clamp(Jet(0.5, 0), Jet(0.0), Jet(1.0));
  EXPECT_EQ(interior.v[0], 1.0);
}

}  // namespace
}  // namespace reflcap
