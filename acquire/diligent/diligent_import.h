#pragma once
// Importing a DiLiGenT object (Shi et al., CVPR 2016 / TPAMI 2019; ../shared/data/diligent) as a
// capture/1 with normal-map geometry, so the whole pipeline runs on real photographs.
//
// Input folder: filenames.txt (line i names the image lit by light i), light_directions.txt and
// light_intensities.txt (one "x y z" / "r g b" line per light), mask.png, normals.exr and the
// photographs (PNG, 16-bit for ball16, 8-bit for the other crops; linear).
//
// Frames. DiLiGenT uses its camera frame: x right, y up, z towards the camera; normals and light
// directions are given in it. The capture's world frame IS that frame, so normals and light
// directions are copied unchanged. The one camera, "cam0", is orthographic and follows OpenCV
// (+x right, +y down, +z forward = away from the viewer): cam_from_world = [diag(1, -1, -1) |
// (0, 0, 1)], i.e. the camera sits 1 m out along +z looking down -z. So pixel (u, v) lies on world
// x = (u - cx) s, y = -(v - cy) s (row 0 at the top = +y), and the view direction towards the
// camera is +z: a normal (0, 0, 1) gives cos θo = 1. s = pixel_size_m = kNominalPixelSizeM is
// nominal (DiLiGenT gives none; directional lights and a normal map never need it).
//
// Radiometry. Pixel values stay linear: PNG value / 255 (8-bit) or / 65535 (16-bit). DiLiGenT's
// 8-bit crops store 16-bit value / 257 and 257 x 255 = 65535, so both read as the same unit — the
// fraction of the 16-bit full scale — for every object (up to the 8-bit rounding). Light c's
// intensity goes into the light (intensity = light_intensities.txt), exposure_s = 1, so that
// pixel_c / intensity_c = f_c(l, v) max(0, n . l), the benchmark's model (up to its global scale).
//
// Split. Light i (1-based) is holdout when i is a multiple of K (--holdout-every, default
// kDefaultHoldoutEvery = 4: 24 of 96 lights, spread over DiLiGenT's light grid), else train.
// Known-bad photographs are left out of the image list (their lights stay listed, unused):
// bear 1-20, per the dataset's notes.
//
// Output (the caller stages the folder): capture.json, normals.exr (float RGB), mask.png (8-bit
// grey, 255 = object), images/<name>.exr (float RGB), diligent_import.json (provenance: source,
// units, split, exclusions).
#include <filesystem>
#include <string>
#include <vector>

#include "engine/core/status.h"

namespace reflcap::diligent {

// Every 4th light held out: 24 of 96 lights, spread over DiLiGenT's light grid, leaves 72 to fit
// per pixel — far more than the 13 parameters of a one-lobe RGB model.
constexpr int kDefaultHoldoutEvery = 4;
// Metres per pixel of the orthographic camera: nominal (about a 0.1 m object over 500 px).
constexpr double kNominalPixelSizeM = 2e-4;
// The photographs' values are in units of their PNG's full scale, which is where the sensor (or
// the 8-bit crop) clips: images[].saturation.
constexpr double kDiligentFullScale = 1.0;
// Light directions whose length differs from 1 by more than this are reported (then normalised):
// the files give 4 decimals, so a correct direction is within ~1e-4 of unit length.
constexpr double kDirectionLengthTolerance = 1e-2;

struct ImportOptions {
  // Light i (1-based) is holdout when i % holdout_every == 0. Range [2, 1000].
  int holdout_every = kDefaultHoldoutEvery;
  Status Validate() const;
};

struct ImportSummary {
  std::string object;
  int width = 0, height = 0;
  size_t lights = 0;
  size_t images = 0, train = 0, holdout = 0;
  std::vector<int> excluded;  // 1-based light indices of photographs left out
  size_t mask_pixels = 0;
  size_t normal_texels = 0;   // mask pixels with a valid (finite, non-zero) normal
  double seconds = 0;
};

// 1-based indices of the photographs of `object` known to be bad (bear: 1-20), else empty.
std::vector<int> KnownBadImages(const std::string& object);

// Reads `object_dir` and writes the capture into `out_dir` (created if missing). Errors name the
// file and line: "light_directions.txt:17: expected 3 numbers, got 2" (DataLoss), NotFound for a
// missing file, InvalidArgument for inconsistent counts or sizes.
StatusOr<ImportSummary> ImportDiligent(const std::filesystem::path& object_dir,
                                       const std::filesystem::path& out_dir,
                                       const ImportOptions& options);

}  // namespace reflcap::diligent
