#include "engine/geometry/rigid3.h"

#include <sstream>

namespace reflcap {

Mat4d Rigid3::ToMatrix() const {
  Mat4d m = Mat4d::Identity();
  m.topLeftCorner<3, 3>() = rotation;
  m.topRightCorner<3, 1>() = translation;
  return m;
}

Rigid3 Rigid3::FromMatrix(const Mat4d& m) {
  return {m.topLeftCorner<3, 3>(), m.topRightCorner<3, 1>()};
}

std::string Rigid3::ToString() const {
  std::ostringstream out;
  out << "Rigid3(R=[" << rotation.row(0) << "; " << rotation.row(1) << "; " << rotation.row(2)
      << "], t=[" << translation.transpose() << "])";
  return out.str();
}

Rigid3 CamFromWorldLookAt(const Vec3d& eye, const Vec3d& target, const Vec3d& up) {
  const Vec3d z = (target - eye).normalized();
  const Vec3d x = z.cross(up).normalized();  // image right
  const Vec3d y = z.cross(x);                // image down
  Mat3d r;
  r.row(0) = x.transpose();
  r.row(1) = y.transpose();
  r.row(2) = z.transpose();
  return {r, -(r * eye)};
}

Mat3d AxisAngleRotation(const Vec3d& axis, double angle_rad) {
  return Eigen::AngleAxisd(angle_rad, axis.normalized()).toRotationMatrix();
}

Rigid3 Turntable::WorldFromObject(double angle_deg) const {
  // x_world = R (x_object - point) + point.
  const Mat3d r = AxisAngleRotation(axis, DegToRad(angle_deg));
  return {r, point - r * point};
}

}  // namespace reflcap
