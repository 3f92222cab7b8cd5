// ColorChecker detection (OpenCV mcc + our refinement), pose, and colour calibration on charts
// rendered analytically in the test (synthetic_brackets.h).
#include "acquire/radiometry/chart.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "acquire/radiometry/brackets.h"
#include "engine/image/exr_io.h"
#include "tests/acquire/radiometry/synthetic_brackets.h"
#include "tests/support/test_support.h"

namespace reflcap::radiometry {
namespace {
using ::testing::HasSubstr;

// Corner accuracy: edges are located by the area under their profile, exact for a symmetric blur
// up to the profile's bilinear sampling; on these 4×4-supersampled renders the corners' mean
// error is < 0.05 px, RMS 0.05–0.08 px, the worst corner 0.17–0.32 px.
constexpr double kCornerRmsTolerancePx = 0.12;
constexpr double kCornerMaxTolerancePx = 0.4;
// Pose: 96 corners at ~0.03 px over a chart ~270 px wide give its normal to ~0.02°.
constexpr double kNormalToleranceDeg = 0.1;
// Gains from the neutral row: limited by the pose's irradiance (cos θ / d²), ~0.05 %.
constexpr double kGainTolerance = 2e-3;

struct Scene {
  reflcap::testing::ScratchDir dir;
  testing::SyntheticBrackets data;
  BracketSet set;
  Image radiance;  // the chart photograph, linear (true RGB)
};

void MakeScene(double tilt_deg, double roll_deg, Scene* s) {
  testing::SyntheticBracketsOptions o;
  o.object_photos = 1;
  o.object_size = 8;
  o.chart_tilt_deg = tilt_deg;
  o.chart_roll_deg = roll_deg;
  o.response = testing::LogLogisticResponse;
  s->data = testing::WriteSyntheticBrackets(s->dir.path(), o);
  auto set = ReadBrackets(s->data.json);
  REFLCAP_CHECK(set.ok()) << set.status().ToString();
  s->set = *set;
  auto radiance = ReadExrRgb(s->dir / "truth/chart.exr");
  REFLCAP_CHECK(radiance.ok());
  s->radiance = *radiance;
}

// Expects every corner of `a` near the same corner of `b` (patch by patch).
void ExpectCornersNear(const ChartCorners& a, const ChartCorners& b) {
  double worst = 0, sum2 = 0;
  for (int i = 0; i < kChartPatches; ++i) {
    for (int k = 0; k < 4; ++k) {
      const double e = (a[size_t(i)][size_t(k)] - b[size_t(i)][size_t(k)]).norm();
      worst = std::max(worst, e);
      sum2 += e * e;
    }
  }
  EXPECT_LT(std::sqrt(sum2 / (4 * kChartPatches)), kCornerRmsTolerancePx);
  EXPECT_LT(worst, kCornerMaxTolerancePx);
}

double NormalErrorDeg(const Rigid3& a, const Rigid3& b) {
  return RadToDeg(std::acos(std::clamp(a.rotation.col(2).dot(b.rotation.col(2)), -1.0, 1.0)));
}

TEST(DetectChart, FindsATiltedChartWithMccAndRefinesItsCorners) {
  Scene s;
  MakeScene(20, 0, &s);
  const Camera& camera = s.set.rig.cameras[1];
  auto d = DetectChart(s.radiance, camera, ChartLayout(), std::nullopt);
  ASSERT_TRUE(d.ok()) << d.status().ToString();
  EXPECT_EQ(d->method, "mcc");
  EXPECT_EQ(d->edges_refined, 96);
  ExpectCornersNear(d->corners_px, s.data.chart_corners);
  EXPECT_LT(NormalErrorDeg(d->world_from_chart, s.data.world_from_chart), kNormalToleranceDeg);
  EXPECT_LT((d->world_from_chart.translation - s.data.world_from_chart.translation).norm(), 1e-3);
}

TEST(DetectChart, FindsAChartUpsideDown) {
  Scene s;
  MakeScene(10, 180, &s);
  auto d = DetectChart(s.radiance, s.set.rig.cameras[1], ChartLayout(), std::nullopt);
  ASSERT_TRUE(d.ok()) << d.status().ToString();
  // Patch 1 (dark skin) is found where it is: at the bottom right of the photograph.
  ExpectCornersNear(d->corners_px, s.data.chart_corners);
  EXPECT_GT(d->corners_px[0][0].y(), s.radiance.height / 2.0);
}

TEST(DetectChart, DeclaredCornersSeedTheRefinementWithoutMcc) {
  Scene s;
  MakeScene(15, 0, &s);
  ChartCorners declared = s.data.chart_corners;
  for (auto& quad : declared) {
    for (Vec2d& p : quad) p += Vec2d(1.5, -1.0);  // a rough declaration
  }
  auto d = DetectChart(s.radiance, s.set.rig.cameras[1], ChartLayout(), declared, /*use_mcc=*/false);
  ASSERT_TRUE(d.ok()) << d.status().ToString();
  EXPECT_EQ(d->method, "declared");
  ExpectCornersNear(d->corners_px, s.data.chart_corners);
}

TEST(DetectChart, NoChartIsNotFound) {
  Scene s;
  MakeScene(0, 0, &s);
  Image empty(s.radiance.width, s.radiance.height, 3, 0.01f);
  for (size_t i = 0; i < empty.data.size(); i += 7) empty.data[i] = 0.02f;
  auto d = DetectChart(empty, s.set.rig.cameras[1], ChartLayout(), std::nullopt);
  ASSERT_FALSE(d.ok());
  EXPECT_EQ(d.status().code(), StatusCode::kNotFound);
  EXPECT_THAT(d.status().message(), HasSubstr("no ColorChecker found"));
}

TEST(CalibrateColour, RecoversTheCameraGainsAndCorrectsTheColours) {
  Scene s;
  MakeScene(20, 0, &s);
  const Camera& camera = s.set.rig.cameras[1];
  const Light& light = s.set.rig.lights[0];
  auto d = DetectChart(s.radiance, camera, ChartLayout(), std::nullopt);
  ASSERT_TRUE(d.ok()) << d.status().ToString();
  const Vec3d gains(1.3, 1.0, 0.7);
  MergedBracket merged;
  merged.value = s.radiance;
  merged.variance = Image(s.radiance.width, s.radiance.height, 3, 1e-8f);
  merged.flags.assign(s.radiance.data.size(), uint8_t(MergeFlag::kMeasured));
  for (size_t i = 0; i < merged.value.data.size(); ++i) merged.value.data[i] *= float(gains[int(i % 3)]);
  const auto pixels = ChartInnerPixels(*d, camera, ChartLayout(), light);
  EXPECT_GT(pixels.size(), 24u * 100u);
  auto cal = CalibrateColour(merged, pixels, light, /*apply_matrix=*/false);
  ASSERT_TRUE(cal.ok()) << cal.status().ToString();
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(cal->gains[c] / gains[c], 1.0, kGainTolerance);
  EXPECT_GT(cal->mean_delta_e_before, 3.0);  // the cast is visible
  EXPECT_LT(cal->mean_delta_e_gains, 0.3);   // and gone after the gains
  EXPECT_LT(cal->mean_delta_e_matrix, 0.3);
  // The matrix of a diagonal cast is its inverse.
  EXPECT_NEAR(cal->matrix(0, 0) * gains[0], 1.0, 0.01);
  EXPECT_NEAR(cal->matrix(0, 1), 0.0, 0.01);
}

}  // namespace
}  // namespace reflcap::radiometry
