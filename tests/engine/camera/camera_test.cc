#include "engine/camera/camera.h"

#include <gtest/gtest.h>

#include <random>

namespace reflcap {
namespace {

// Round trips in double precision: Undistort converges to ~1e-12 and projection adds rounding.
constexpr double kPixelRoundTripTolerance = 1e-7;

Camera MakePinhole() {
  Camera cam;
  cam.width = 640;
  cam.height = 480;
  cam.K << 500, 0.5, 320, 0, 510, 240, 0, 0, 1;
  cam.dist = {-0.2, 0.05, 0.001, -0.002, 0.01};
  return cam;
}

TEST(Camera, PixelRayProjectsBackToItsPixel) {
  Camera cam = MakePinhole();
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(0, 639), v(0, 479), depth(0.5, 5);
  for (int i = 0; i < 200; ++i) {
    const Vec2d pixel(u(rng), v(rng));
    Vec3d origin, dir;
    cam.PixelRay(pixel, &origin, &dir);
    EXPECT_NEAR(dir.norm(), 1, 1e-12);
    Vec2d back;
    ASSERT_TRUE(cam.Project(origin + depth(rng) * dir, &back));
    EXPECT_NEAR((back - pixel).norm(), 0, kPixelRoundTripTolerance);
  }
}

TEST(Camera, DistortionMatchesOpenCvFormula) {
  Camera cam = MakePinhole();
  const double x = 0.3, y = -0.2, r2 = x * x + y * y;
  const auto& d = cam.dist;
  const double radial = 1 + d[0] * r2 + d[1] * r2 * r2 + d[4] * r2 * r2 * r2;
  const Vec2d expected(x * radial + 2 * d[2] * x * y + d[3] * (r2 + 2 * x * x),
                       y * radial + d[2] * (r2 + 2 * y * y) + 2 * d[3] * x * y);
  EXPECT_NEAR((cam.Distort({x, y}) - expected).norm(), 0, 1e-15);
}

TEST(Camera, PointBehindPinholeDoesNotProject) {
  Camera cam = MakePinhole();
  Vec2d pixel;
  EXPECT_FALSE(cam.Project({0, 0, -1}, &pixel));
  EXPECT_FALSE(cam.Project({0, 0, 0}, &pixel));
}

TEST(Camera, OrthographicRaysAreParallelAndMetric) {
  Camera cam;
  cam.model = CameraModel::kOrthographic;
  cam.width = 101;
  cam.height = 51;
  cam.pixel_size_m = 0.01;
  Vec3d origin, dir;
  cam.PixelRay({60, 25}, &origin, &dir);
  EXPECT_EQ(dir, Vec3d::UnitZ());
  EXPECT_NEAR(origin.x(), 0.1, 1e-12);
  EXPECT_NEAR(origin.y(), 0.0, 1e-12);
  Vec2d pixel;
  ASSERT_TRUE(cam.Project(origin + 3 * dir, &pixel));
  EXPECT_NEAR((pixel - Vec2d(60, 25)).norm(), 0, 1e-9);
}

}  // namespace
}  // namespace reflcap
