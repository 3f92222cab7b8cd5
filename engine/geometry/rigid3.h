#pragma once
// Rigid3: a proper rigid transform b_from_a, x_b = rotation * x_a + translation. Names follow
// COLMAP: `cam_from_world * p_in_world` gives p_in_cam.
#include <string>

#include "engine/math/types.h"

namespace reflcap {

struct Rigid3 {
  Mat3d rotation = Mat3d::Identity();
  Vec3d translation = Vec3d::Zero();

  Vec3d operator*(const Vec3d& p) const { return rotation * p + translation; }
  // (c_from_b * b_from_a) = c_from_a.
  Rigid3 operator*(const Rigid3& b_from_a) const {
    return {rotation * b_from_a.rotation, rotation * b_from_a.translation + translation};
  }
  Rigid3 Inverse() const {
    const Mat3d rt = rotation.transpose();
    return {rt, -(rt * translation)};
  }
  Mat4d ToMatrix() const;
  static Rigid3 FromMatrix(const Mat4d& m);
  std::string ToString() const;
};

// The OpenCV-convention camera pose (+x right, +y down, +z forward) of a camera at `eye` looking at
// `target`, with `up` (world) pointing up in the image. eye != target; up not parallel to the view.
Rigid3 CamFromWorldLookAt(const Vec3d& eye, const Vec3d& target, const Vec3d& up = Vec3d::UnitZ());

// Rotation by angle_rad about the unit `axis`, right-hand rule.
Mat3d AxisAngleRotation(const Vec3d& axis, double angle_rad);

// The turntable of a capture: it spins about `axis` (unit, world frame) through `point`. The
// object frame coincides with the world at 0 degrees; at angle θ the object is posed by
// world_from_object = Rot(axis, θ) about `point` (capture/1, "Frames and units").
struct Turntable {
  Vec3d axis = Vec3d::UnitZ();
  Vec3d point = Vec3d::Zero();

  Rigid3 WorldFromObject(double angle_deg) const;
};

}  // namespace reflcap
