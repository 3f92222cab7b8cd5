#include "engine/camera/camera.h"

#include <cmath>
#include <sstream>

namespace reflcap {

const char* PixelFilterName(PixelFilter filter) {
  return filter == PixelFilter::kPoint ? "point" : "area";
}

bool Camera::HasDistortion() const {
  for (double d : dist) {
    if (d != 0.0) return true;
  }
  return false;
}

Vec2d Camera::Distort(const Vec2d& xy) const {
  const double x = xy.x(), y = xy.y();
  const double r2 = x * x + y * y;
  const double radial = 1 + r2 * (dist[0] + r2 * (dist[1] + r2 * dist[4]));
  const double p1 = dist[2], p2 = dist[3];
  return {x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
          y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y};
}

Vec2d Camera::Undistort(const Vec2d& xy_distorted) const {
  if (!HasDistortion()) return xy_distorted;
  // Fixed point of xy = xy_d - (Distort(xy) - xy): converges for the contraction real lenses give.
  Vec2d xy = xy_distorted;
  for (int i = 0; i < kUndistortIterations; ++i) {
    const Vec2d next = xy - (Distort(xy) - xy_distorted);
    if ((next - xy).squaredNorm() < 1e-24) return next;
    xy = next;
  }
  return xy;
}

bool Camera::Project(const Vec3d& p_in_cam, Vec2d* pixel) const {
  if (model == CameraModel::kOrthographic) {
    const double cx = 0.5 * (width - 1), cy = 0.5 * (height - 1);
    *pixel = {p_in_cam.x() / pixel_size_m + cx, p_in_cam.y() / pixel_size_m + cy};
    return true;
  }
  if (!(p_in_cam.z() > 0)) return false;
  const Vec2d xy = Distort({p_in_cam.x() / p_in_cam.z(), p_in_cam.y() / p_in_cam.z()});
  *pixel = {K(0, 0) * xy.x() + K(0, 1) * xy.y() + K(0, 2), K(1, 1) * xy.y() + K(1, 2)};
  return true;
}

void Camera::PixelRay(const Vec2d& pixel, Vec3d* origin_in_cam, Vec3d* dir_in_cam) const {
  if (model == CameraModel::kOrthographic) {
    const double cx = 0.5 * (width - 1), cy = 0.5 * (height - 1);
    *origin_in_cam = {(pixel.x() - cx) * pixel_size_m, (pixel.y() - cy) * pixel_size_m, 0};
    *dir_in_cam = Vec3d::UnitZ();
    return;
  }
  const double yd = (pixel.y() - K(1, 2)) / K(1, 1);
  const double xd = (pixel.x() - K(0, 2) - K(0, 1) * yd) / K(0, 0);
  const Vec2d xy = Undistort({xd, yd});
  *origin_in_cam = Vec3d::Zero();
  *dir_in_cam = Vec3d(xy.x(), xy.y(), 1).normalized();
}

std::string Camera::ToString() const {
  std::ostringstream out;
  out << "Camera(" << id << ", "
      << (model == CameraModel::kPinhole ? "pinhole" : "orthographic") << ", " << width << "x"
      << height;
  if (model == CameraModel::kPinhole) {
    out << ", f=(" << K(0, 0) << "," << K(1, 1) << "), c=(" << K(0, 2) << "," << K(1, 2) << ")";
  } else {
    out << ", pixel_size_m=" << pixel_size_m;
  }
  if (pixel_filter != PixelFilter::kArea) {
    out << ", " << PixelFilterName(pixel_filter) << " pixels";
  }
  out << ")";
  return out.str();
}

}  // namespace reflcap
