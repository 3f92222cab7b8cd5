#include "engine/geometry/rigid3.h"

#include <gtest/gtest.h>

namespace reflcap {
namespace {

TEST(Rigid3, InverseComposesToIdentity) {
  Rigid3 a{AxisAngleRotation(Vec3d(1, 2, 3).normalized(), 0.7), Vec3d(0.1, -2, 3)};
  const Rigid3 id = a * a.Inverse();
  EXPECT_LT((id.rotation - Mat3d::Identity()).norm(), 1e-12);
  EXPECT_LT(id.translation.norm(), 1e-12);
  const Vec3d p(1, 2, 3);
  EXPECT_LT(((a * a.Inverse()) * p - p).norm(), 1e-12);
  EXPECT_EQ(Rigid3::FromMatrix(a.ToMatrix()).ToMatrix(), a.ToMatrix());
}

TEST(Turntable, RotatesRightHandedAboutItsPoint) {
  Turntable t{Vec3d::UnitZ(), Vec3d(1, 0, 0)};
  const Rigid3 w = t.WorldFromObject(90);
  // The point on the axis stays put; +x from it turns to +y (right-hand rule about +z).
  EXPECT_LT((w * Vec3d(1, 0, 5) - Vec3d(1, 0, 5)).norm(), 1e-12);
  EXPECT_LT((w * Vec3d(2, 0, 0) - Vec3d(1, 1, 0)).norm(), 1e-12);
  EXPECT_LT((t.WorldFromObject(0).ToMatrix() - Mat4d::Identity()).norm(), 1e-15);
}

TEST(CamFromWorldLookAt, LooksAtTargetWithUpUpInTheImage) {
  const Vec3d eye(2, 1, 0.5), target(0, 0, 0.2);
  const Rigid3 cam_from_world = CamFromWorldLookAt(eye, target);
  EXPECT_LT((cam_from_world * eye).norm(), 1e-12);
  const Vec3d t = cam_from_world * target;
  EXPECT_NEAR(t.x(), 0, 1e-12);
  EXPECT_NEAR(t.y(), 0, 1e-12);
  EXPECT_GT(t.z(), 0);
  // A point above the target appears above it in the image (smaller y, OpenCV +y down).
  EXPECT_LT((cam_from_world * (target + Vec3d::UnitZ())).y(), 0);
  EXPECT_NEAR(cam_from_world.rotation.determinant(), 1, 1e-12);
}

}  // namespace
}  // namespace reflcap
