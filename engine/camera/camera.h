#pragma once
// Camera models of capture/1: pinhole with the OpenCV distortion model (k1, k2, p1, p2, k3) and
// orthographic. OpenCV frame: +x right, +y down, +z forward; pixel centres at integer (u, v),
// (0, 0) the centre of the top-left pixel.
//
// Pinhole:  x = X/Z, y = Y/Z; r² = x² + y²;
//   x_d = x (1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 x y + p2 (r² + 2x²)
//   y_d = y (1 + k1 r² + k2 r⁴ + k3 r⁶) + p1 (r² + 2y²) + 2 p2 x y
//   (u, v) = (fx x_d + s y_d + cx, fy y_d + cy)   with K = [[fx, s, cx], [0, fy, cy], [0, 0, 1]].
// Orthographic: every pixel looks along +z; (u, v) = (X / pixel_size_m + cx, Y / pixel_size_m + cy)
//   with (cx, cy) the image centre ((width-1)/2, (height-1)/2). K is absent in the file.
//
// Pixel filter (capture/1 `pixel_filter`, optional): what one pixel value measures. "area" (the
// default): radiance integrated over the pixel's footprint, as every sensor and every filtered
// renderer (Cycles' 1.5 px Blackman–Harris, a box over sub-pixel rays) gives it. "point": the
// radiance along the one ray through the pixel centre, as a renderer shooting one ray per pixel
// (`reflcap synth` without --supersample) gives it — each such pixel sees exactly one surface
// point, so the resampler can tell which texel a pixel measured.
#include <array>
#include <string>

#include "engine/geometry/rigid3.h"
#include "engine/math/types.h"

namespace reflcap {

enum class CameraModel { kPinhole, kOrthographic };
enum class PixelFilter { kArea, kPoint };
const char* PixelFilterName(PixelFilter filter);  // "area", "point"

struct Camera {
  std::string id;
  CameraModel model = CameraModel::kPinhole;
  int width = 0;   // pixels
  int height = 0;  // pixels
  Mat3d K = Mat3d::Identity();           // pinhole intrinsics, pixels
  std::array<double, 5> dist{};          // k1, k2, p1, p2, k3 (OpenCV order); zeros when none
  Rigid3 cam_from_world;
  double pixel_size_m = 0;               // orthographic: metres per pixel (0 = not given)
  PixelFilter pixel_filter = PixelFilter::kArea;

  bool HasDistortion() const;
  // Camera centre (pinhole) in the world frame.
  Vec3d CenterInWorld() const { return cam_from_world.Inverse().translation; }
  // Unit viewing axis (+z of the camera) in the world frame.
  Vec3d AxisInWorld() const { return cam_from_world.rotation.row(2).transpose(); }

  // Pixel coordinates of a point in the camera frame. False when the point is not in front of a
  // pinhole camera (Z <= 0). No bounds check against the image.
  bool Project(const Vec3d& p_in_cam, Vec2d* pixel) const;

  // The ray through `pixel`, in the camera frame: origin and unit direction. Pinhole rays start at
  // the centre; orthographic rays start on the plane Z = 0.
  void PixelRay(const Vec2d& pixel, Vec3d* origin_in_cam, Vec3d* dir_in_cam) const;

  // Normalised image coordinates ↔ distorted ones (pinhole). Undistort inverts Distort by
  // fixed-point iteration (kUndistortIterations), accurate to ~1e-10 for the moderate distortion
  // of real lenses; it returns its best estimate otherwise.
  Vec2d Distort(const Vec2d& xy) const;
  Vec2d Undistort(const Vec2d& xy_distorted) const;

  std::string ToString() const;
};

// Enough for |k1| r² up to ~0.3 to converge below 1e-10 (each iteration gains ~|k1 r²| digits).
constexpr int kUndistortIterations = 30;

}  // namespace reflcap
