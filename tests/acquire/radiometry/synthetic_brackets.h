#pragma once
// Synthetic brackets/1 data made in the test, with a known camera: raw = g · t · L + n (n ~
// N(0, read²)), code = round(255 · f(clip(raw, 0, 1))) — the brackets/1 camera model. Object
// photos are smooth random radiance fields spanning ~6 decades (so every code is hit at some
// exposure); the chart photo is a ColorChecker Classic rendered analytically (Lambertian patches
// and a black frame of albedo 0.01 under one point light, 4×4 supersampled pixels) through its own
// camera. Every file a brackets/1 reader and `reflcap hdr` need is written: brackets.json (with a
// ground_truth block and the linear photos as source_hdr), the PNGs, a chart geometry file
// (corners_px, world_from_chart), and a minimal source capture with a one-triangle mesh.
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include "acquire/radiometry/chart.h"
#include "engine/math/types.h"

namespace reflcap::radiometry::testing {

struct SyntheticBracketsOptions {
  int object_size = 48;          // object photos are object_size² pixels
  int object_photos = 6;
  int chart_width = 320, chart_height = 240;
  std::vector<double> exposures = {0.125, 0.5, 2.0, 8.0, 32.0};
  // Response f: raw in [0, 1] -> [0, 1], increasing, f(0) = 0, f(1) = 1.
  std::function<double(double)> response;
  Vec3d gains = Vec3d(1.25, 1.0, 0.8);
  double read_sigma = 0.001;
  bool chart = true;
  double chart_tilt_deg = 10;    // rotation of the chart about its vertical axis, away from frontal
  double chart_roll_deg = 0;     // in-plane rotation (180: upside down in the photograph)
  uint64_t seed = 1;
};

struct SyntheticBrackets {
  std::filesystem::path json;  // brackets.json
  std::vector<double> x_of_code;  // the true inverse response f⁻¹(k / 255)
  ChartCorners chart_corners{};   // true patch corners in the chart photograph
  Rigid3 world_from_chart;
};

// The brackets/1 camera's log-logistic response with the shared data's parameters (a = 1.4, k = 0.3).
double LogLogisticResponse(double x);
// A response outside every parametric family of response.h: a gamma-2.2-like curve with a
// sinusoidal ripple of 2 % in log (a sensor's non-linearity no family models).
double RippledResponse(double x);

// Writes everything into `dir` (created).
SyntheticBrackets WriteSyntheticBrackets(const std::filesystem::path& dir,
                                         const SyntheticBracketsOptions& options);

}  // namespace reflcap::radiometry::testing
