#pragma once
// Normal-map scenes from analytic height fields, for the tests of height-field integration, its
// shadows, resampling and rendering of normal-map captures. Header-only (engine types only).
//
// Frames as `reflcap import-diligent` writes them: world = x right, y up, z towards the camera;
// the camera is orthographic with cam_from_world = [diag(1, -1, -1) | (0, 0, 1)], so pixel (u, v)
// is world (u - cx, -(v - cy)) and the height h(u, v) towards the camera is world z. The normal of
// h is n_world ∝ (-dh/du, +dh/dv, 1) (rows run along -y).
#include <cmath>
#include <functional>

#include "engine/camera/camera.h"
#include "engine/image/image.h"
#include "engine/math/types.h"

namespace reflcap::testing {

// An orthographic camera looking down -z at a size_x x size_y image, DiLiGenT's frame.
inline Camera DiligentCamera(int size_x, int size_y, double pixel_size_m = 1e-3) {
  Camera cam;
  cam.id = "cam0";
  cam.model = CameraModel::kOrthographic;
  cam.width = size_x;
  cam.height = size_y;
  cam.pixel_size_m = pixel_size_m;
  cam.cam_from_world.rotation = Vec3d(1, -1, -1).asDiagonal();
  cam.cam_from_world.translation = Vec3d(0, 0, 1);
  return cam;
}

// A height field h(u, v) (pixels) with its gradient, on the pixels where `inside` holds.
struct AnalyticHeight {
  std::function<bool(double u, double v)> inside;
  std::function<double(double u, double v)> height;
  std::function<Vec2d(double u, double v)> gradient;  // (dh/du, dh/dv)
};

// World normals (3 channels) and mask (1 channel, 1 = object) of `shape` at pixel centres.
inline void NormalMapOf(const AnalyticHeight& shape, int size_x, int size_y, Image* normals,
                        Image* mask) {
  *normals = Image(size_x, size_y, 3, 0.0f);
  *mask = Image(size_x, size_y, 1, 0.0f);
  for (int y = 0; y < size_y; ++y) {
    for (int x = 0; x < size_x; ++x) {
      if (!shape.inside(x, y)) continue;
      const Vec2d g = shape.gradient(x, y);
      const Vec3d n = Vec3d(-g.x(), g.y(), 1).normalized();
      for (int c = 0; c < 3; ++c) normals->at(x, y, c) = float(n[c]);
      mask->at(x, y) = 1;
    }
  }
}

// A sphere of radius r about (cx, cy) in the image, seen up to rim radius `rim` (< r).
inline AnalyticHeight SphereCap(double cx, double cy, double r, double rim) {
  AnalyticHeight s;
  s.inside = [=](double u, double v) {
    return (u - cx) * (u - cx) + (v - cy) * (v - cy) < rim * rim;
  };
  s.height = [=](double u, double v) {
    return std::sqrt(r * r - (u - cx) * (u - cx) - (v - cy) * (v - cy));
  };
  s.gradient = [=](double u, double v) {
    const double h = std::sqrt(r * r - (u - cx) * (u - cx) - (v - cy) * (v - cy));
    return Vec2d(-(u - cx) / h, -(v - cy) / h);
  };
  return s;
}

// A square plate of side `size` (all pixels) at height 0 with a spherical pit: the part of a
// sphere of radius r below the plate, of rim radius `rim` (< r) about (cx, cy), depth
// r - sqrt(r² - rim²). A bowl: under a low light its far wall shadows its near floor.
inline AnalyticHeight PittedPlate(double cx, double cy, double r, double rim) {
  AnalyticHeight s;
  const double below = std::sqrt(r * r - rim * rim);  // sphere centre height: + below
  s.inside = [](double, double) { return true; };
  s.height = [=](double u, double v) {
    const double d2 = (u - cx) * (u - cx) + (v - cy) * (v - cy);
    return d2 < rim * rim ? below - std::sqrt(r * r - d2) : 0.0;
  };
  s.gradient = [=](double u, double v) {
    const double d2 = (u - cx) * (u - cx) + (v - cy) * (v - cy);
    if (d2 >= rim * rim) return Vec2d(0, 0);
    const double root = std::sqrt(r * r - d2);
    return Vec2d((u - cx) / root, (v - cy) / root);
  };
  return s;
}

}  // namespace reflcap::testing
