#include "engine/gpu/vk_view.h"

#include <cmath>

namespace reflcap::gpu {

shared::vec4 V4(const Vec3d& v, double w) {
  return {float(v.x()), float(v.y()), float(v.z()), float(w)};
}

void SetRows(const Mat4d& m, shared::vec4 rows[4]) {
  for (int r = 0; r < 4; ++r) {
    rows[r] = {float(m(r, 0)), float(m(r, 1)), float(m(r, 2)), float(m(r, 3))};
  }
}

Mat4d Homogeneous(const Rigid3& t) {
  Mat4d m = Mat4d::Identity();
  m.topLeftCorner<3, 3>() = t.rotation;
  m.topRightCorner<3, 1>() = t.translation;
  return m;
}

Mat4d PinholeClipFromCam(double fx, double fy, double s, double cx, double cy, int w, int h,
                         double near, double far) {
  Mat4d p = Mat4d::Zero();
  p(0, 0) = 2 * fx / w;
  p(0, 1) = 2 * s / w;
  p(0, 2) = 2 * (cx + 0.5) / w - 1;
  p(1, 1) = 2 * fy / h;
  p(1, 2) = 2 * (cy + 0.5) / h - 1;
  p(2, 2) = far / (far - near);
  p(2, 3) = -far * near / (far - near);
  p(3, 2) = 1;
  return p;
}

Mat4d OrthoClipFromCam(double pixel_m, int w, int h, double near, double far) {
  Mat4d p = Mat4d::Zero();
  p(0, 0) = 2 / (pixel_m * w);
  p(1, 1) = 2 / (pixel_m * h);
  p(2, 2) = 1 / (far - near);
  p(2, 3) = -near / (far - near);
  p(3, 3) = 1;
  return p;
}

void Basis(const Vec3d& forward, Vec3d* right, Vec3d* up) {
  // Any axis not nearly parallel to `forward` works; z unless forward is close to it.
  const Vec3d helper = std::abs(forward.z()) < 0.9 ? Vec3d::UnitZ() : Vec3d::UnitX();
  *right = forward.cross(helper).normalized();
  *up = forward.cross(*right).normalized();
}

Mat4d ViewMatrix(const Vec3d& origin, const Vec3d& forward, const Vec3d& right, const Vec3d& up) {
  Mat4d view = Mat4d::Identity();
  view.block<1, 3>(0, 0) = right.transpose();
  view.block<1, 3>(1, 0) = up.transpose();
  view.block<1, 3>(2, 0) = forward.transpose();
  view.block<3, 1>(0, 3) = -(view.topLeftCorner<3, 3>() * origin);
  return view;
}

}  // namespace reflcap::gpu
