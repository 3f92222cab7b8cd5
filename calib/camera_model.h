#pragma once
// The camera model calibration estimates, as a Scalar template (double and ceres::Jet): pinhole
// with OpenCV's distortion (k1, k2, p1, p2, k3) and zero skew — capture/1's model, the same
// formula as engine/camera/camera.h's Camera::Project.
//
// Intrinsics travel as 9 numbers in the order of IntrinsicIndex; poses as 6 numbers, an angle-axis
// rotation (radians, |r| = angle) and a translation or a centre (metres), as documented where used.
#include <array>
#include <string>
#include <vector>

#include "engine/core/status.h"

#include "engine/camera/camera.h"
#include "engine/math/types.h"

namespace reflcap::calib {

enum IntrinsicIndex { kFx = 0, kFy, kCx, kCy, kK1, kK2, kP1, kP2, kK3, kIntrinsicCount };
using IntrinsicParams = std::array<double, kIntrinsicCount>;

// "fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3".
const char* IntrinsicName(int index);

IntrinsicParams ToIntrinsicParams(const Mat3d& K, const std::array<double, 5>& dist);
Mat3d KFromParams(const IntrinsicParams& p);
std::array<double, 5> DistFromParams(const IntrinsicParams& p);

// Distorts normalised coordinates (x, y) = (X/Z, Y/Z) and maps them to pixels.
template <typename T>
void DistortToPixel(const T* intrinsics, const T& x, const T& y, T* pixel) {
  const T r2 = x * x + y * y;
  const T radial = T(1) + r2 * (intrinsics[kK1] + r2 * (intrinsics[kK2] + r2 * intrinsics[kK3]));
  const T p1 = intrinsics[kP1], p2 = intrinsics[kP2];
  const T xd = x * radial + T(2) * p1 * x * y + p2 * (r2 + T(2) * x * x);
  const T yd = y * radial + p1 * (r2 + T(2) * y * y) + T(2) * p2 * x * y;
  pixel[0] = intrinsics[kFx] * xd + intrinsics[kCx];
  pixel[1] = intrinsics[kFy] * yd + intrinsics[kCy];
}

// Pixel of a point in the camera frame (Z > 0 expected; callers reject points behind).
template <typename T>
void ProjectToPixel(const T* intrinsics, const T* p_cam, T* pixel) {
  const T x = p_cam[0] / p_cam[2];
  const T y = p_cam[1] / p_cam[2];
  DistortToPixel(intrinsics, x, y, pixel);
}

// Rodrigues rotation of v about the unit axis a by angle (radians), right-hand rule.
template <typename T>
void RotateAboutAxis(const T* a, const T& angle, const T* v, T* out) {
  const T c = cos(angle), s = sin(angle);
  const T dot = a[0] * v[0] + a[1] * v[1] + a[2] * v[2];
  const T cross[3] = {a[1] * v[2] - a[2] * v[1], a[2] * v[0] - a[0] * v[2], a[0] * v[1] - a[1] * v[0]};
  for (int i = 0; i < 3; ++i) out[i] = v[i] * c + cross[i] * s + a[i] * dot * (T(1) - c);
}

// Which intrinsics an adjustment estimates: a subset of the nine, the rest held at their start;
// with tie_focal, fx and fy take one common step (square pixels: start them equal).
struct IntrinsicsModel {
  std::vector<int> free = {kFx, kFy, kCx, kCy, kK1, kK2, kP1, kP2};  // IntrinsicIndex values
  bool tie_focal = false;

  // "fx,fy,cx,cy,k1,k2,p1,p2"; "f" stands for fx and fy tied. InvalidArgument names a bad item.
  static StatusOr<IntrinsicsModel> Parse(const std::string& list);
  std::string ToString() const;
  bool IsFree(int index) const;
  int TangentSize() const { return int(free.size()) - (tie_focal ? 1 : 0); }
  // kIntrinsicCount x TangentSize(): how a step in the free parameters moves the nine.
  Eigen::MatrixXd Basis() const;
  Status Validate() const;
};

// A Camera (capture/1) with these intrinsics and pose.
Camera MakeCamera(const std::string& id, int width, int height, const IntrinsicParams& p,
                  const Rigid3& cam_from_world);

// Rigid3 <-> 6 numbers (angle-axis, translation).
std::array<double, 6> PoseToParams(const Rigid3& t);
Rigid3 ParamsToPose(const double* p);

}  // namespace reflcap::calib
