#pragma once
// The residual of one planar-board corner seen by a camera with a free pose: projected - detected,
// pixels. Shared by the intrinsics adjustment and the turntable adjustment's board photos.
// Internal to calib/.
#include <ceres/ceres.h>
#include <ceres/rotation.h>

#include "calib/camera_model.h"
#include "engine/math/types.h"

namespace reflcap::calib::internal {

// Parameters: intrinsics (9), cam_from_board (angle-axis, translation).
struct BoardCornerCost {
  BoardCornerCost(const Vec3d& p_board, const Vec2d& observed, double weight)
      : p_(p_board), obs_(observed), weight_(weight) {}
  template <typename T>
  bool operator()(const T* intrinsics, const T* pose, T* residual) const {
    const T p[3] = {T(p_.x()), T(p_.y()), T(p_.z())};
    T q[3];
    ceres::AngleAxisRotatePoint(pose, p, q);
    for (int i = 0; i < 3; ++i) q[i] += pose[3 + i];
    // A board point behind the camera has no pixel: refuse the step.
    if (!(q[2] > T(0))) return false;
    T pixel[2];
    ProjectToPixel(intrinsics, q, pixel);
    residual[0] = T(weight_) * (pixel[0] - T(obs_.x()));
    residual[1] = T(weight_) * (pixel[1] - T(obs_.y()));
    return true;
  }
  // `weight`: reference noise / this corner's noise (1: unweighted).
  static ceres::CostFunction* Create(const Vec3d& p, const Vec2d& obs, double weight = 1) {
    return new ceres::AutoDiffCostFunction<BoardCornerCost, 2, kIntrinsicCount, 6>(new BoardCornerCost(p, obs, weight));
  }
  Vec3d p_;
  Vec2d obs_;
  double weight_;
};

inline Vec2d ProjectBoardCorner(const IntrinsicParams& intr, const double* pose, const Vec3d& p) {
  double q[3];
  const double x[3] = {p.x(), p.y(), p.z()};
  ceres::AngleAxisRotatePoint(pose, x, q);
  for (int i = 0; i < 3; ++i) q[i] += pose[3 + i];
  double pixel[2];
  ProjectToPixel(intr.data(), q, pixel);
  return {pixel[0], pixel[1]};
}

}  // namespace reflcap::calib::internal
