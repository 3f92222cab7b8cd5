#pragma once
// Synthetic captures: a complete capture/1 dataset with ground truth, rendered by the CPU
// reference renderer — the data every reflcap test and benchmark can make for itself.
//
// The object is a cube-sphere with relief: protruding bumps that cast shadows on their
// surroundings, dimples and a groove (concavities that shadow themselves), and a fine ripple.
// Six charts (one per cube face) laid out in a 3x3 UV grid give a clean, distortion-bounded atlas.
// Ground-truth reflectance is spatially varying, in regions of six materials: matte, glossy,
// sharp highlight (large n), anisotropic, a coloured texture, and a coloured (metal-like) lobe.
// The rig follows the seed paper: cameras on an arc at several elevations, point lights on an arm
// at several elevations and azimuths, turntable steps; the holdout split is every fourth
// turntable angle (starting at the second) plus the last light. Sensor noise is photon
// (signal-dependent) plus read noise, with optional clipping at a saturation level.
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "engine/core/status.h"
#include "engine/mesh/mesh.h"

namespace reflcap::synth {

struct SynthOptions {
  // "small" (tests, demo), "medium", or "million" (>= 1,000,000 texels). Sets the defaults below.
  std::string preset = "small";
  uint64_t seed = 1;
  // Photon noise: standard deviation at pixel value 1 (std = noise * sqrt(value)); read noise has
  // std kReadNoiseRatio * noise. 0 = noise-free. Range [0, 1].
  double noise = 0.01;
  // Pixel value at which the sensor clips (written as images[].saturation). 0 = no clipping.
  double saturation = 0;
  // Overrides of the preset (0 = keep the preset's value).
  int64_t texels = 0;     // target texel count of the ground-truth atlas
  int image_size = 0;     // image width = height, pixels
  int cameras = 0;        // cameras on the arc
  int lights = 0;         // point lights
  int steps = 0;          // turntable steps over 360°
  int supersampling = 1;  // N x N samples per pixel in the renderer
  double pixel_footprint = 1;  // the square (px) those samples cover (RenderOptions)
  // The materials the object's regions draw from, by name (kSynthMaterialNames); empty = all six.
  // A subset makes a capture of only what a test or benchmark needs (e.g. no sharp highlight).
  std::vector<std::string> materials;

  Status Validate() const;
};

// "matte", "glossy", "sharp_highlight", "anisotropic", "coloured_texture", "coloured_lobe".
extern const char* const kSynthMaterialNames[6];

// Read noise relative to photon noise at value 1: a dark pixel (value 0.04) sees equal parts.
constexpr double kReadNoiseRatio = 0.2;

struct SynthSummary {
  int atlas_resolution = 0;
  size_t texels = 0;
  size_t triangles = 0;
  size_t images = 0;
  size_t train_images = 0;
  size_t holdout_images = 0;
  double seconds = 0;
};

// Writes the capture into `out_dir` (created if missing; the caller stages and commits it).
StatusOr<SynthSummary> WriteSyntheticCapture(const SynthOptions& options,
                                             const std::filesystem::path& out_dir);

// The relief object alone: face_resolution x face_resolution quads per cube face, object radius
// about 0.1 m, resting on the turntable plane z = 0, centred on the z axis.
TriangleMesh MakeReliefObject(int face_resolution, uint64_t seed);

}  // namespace reflcap::synth
