#pragma once
// A structured-light scan generated in the test: a sphere off the turntable axis, seen by a pinhole
// camera and lit by a pinhole projector (Gray codes with inverses, phase shifts), rendered
// analytically (Lambertian, projector shadow = the sphere's own back side) and written as
// structured_light/1 (8-bit PNGs + scan.json). The exact projector coordinates of every camera
// pixel are kept for the decoder tests.
#include <filesystem>
#include <string>
#include <vector>

#include "engine/camera/camera.h"
#include "engine/geometry/rigid3.h"
#include "engine/math/types.h"

namespace reflcap::scan::testing {

struct SyntheticScan {
  std::filesystem::path json;          // scan.json
  Camera camera, projector;            // projector.cam_from_world = proj_from_world
  Turntable turntable;
  std::vector<double> angles_deg;
  Vec3d sphere_center_object;          // object frame
  double sphere_radius_m = 0;
  // Per angle: exact projector (u, v) per camera pixel (NaN where the pixel misses the sphere or
  // the point is in projector shadow / outside the projector frame).
  std::vector<std::vector<float>> true_u, true_v;
  std::vector<std::vector<float>> true_depth;  // camera z, metres (NaN where missed)
};

struct SyntheticScanOptions {
  int camera_width = 160, camera_height = 120;
  int projector_width = 256, projector_height = 128;
  std::vector<double> angles_deg = {0, 120, 240};
  std::vector<int> col_periods = {256, 32, 8};  // the coarsest spans the projector, as on suzanne
  std::vector<int> row_periods = {128, 16, 8};
  int shifts = 8;
};

// Writes the scan into `dir` (created) and returns its description.
SyntheticScan WriteSyntheticScan(const std::filesystem::path& dir,
                                 const SyntheticScanOptions& options = {});

}  // namespace reflcap::scan::testing
