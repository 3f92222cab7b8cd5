#pragma once
// Structured-light decoding: per camera pixel, the projector column u and row v it sees.
//
// Gray code with per-pixel thresholds: bit b is 1 where the pattern is brighter than its inverse
// (the inverse is the threshold, so albedo, shading and falloff cancel). Shadow mask: white - black
// below `min_contrast` (the projector does not reach the pixel, or the pixel misses the object).
// Low-contrast mask: the coarse Gray bits' |pattern - inverse| average below
// `min_bit_contrast` of white - black (the code is washed out, e.g. by interreflection).
// Phase shifting (Srinivasan et al. 1984; Zuo et al. 2016 review): for a K-step sequence
// I_k = A + B cos(φ - 2πk/K), φ = atan2(Σ I_k sin(2πk/K), Σ I_k cos(2πk/K)) = 2πx/P (mod 2π). The
// finest period gives the coordinate; it is unwrapped by the Gray code, and, when coarser periods
// exist, temporal unwrapping (coarse to fine; the coarsest is absolute when it spans the projector,
// else Gray-unwrapped) must pick the same fringe (Huntley & Saldner 1993; Sansoni et al. 1999
// combine Gray code and phase the same way). So a Gray code misread by interreflection or blur is
// rejected rather than triangulated to a wrong depth. The sinusoid fit's residual gives each pixel's phase noise, hence a per-pixel
// standard deviation of u and v in projector pixels.
#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "acquire/scan/scan_spec.h"
#include "engine/core/status.h"
#include "engine/image/image.h"

namespace reflcap::scan {

struct DecodeOptions {
  // white - black below this (image units, 1 = full scale) is shadow / background. Default 0.03
  // (8 of 255 levels): well above 8-bit noise, below a dark surface lit obliquely. Range (0, 1).
  double min_contrast = 0.03;
  // Mean |gray - inverse| / (white - black) over the coarse bits below this = low contrast
  // (washed-out code). Default 0.25; a clean code gives ~1, a pixel on a stripe edge ~0.5 in one
  // bit only. Range [0, 1).
  double min_bit_contrast = 0.25;
  // Phase amplitude / ((white - black) / 2) of the finest period below this = low modulation.
  // Default 0.3 (camera blur across a 12-16 px period keeps ~0.95). Range [0, 1).
  double min_modulation = 0.3;
  // |unwrapped phase - Gray code| above this many projector pixels = inconsistent. Default 3: the
  // Gray code is exact to the projector pixel (+-0.5) plus one pixel at a stripe edge, plus blur.
  double max_gray_phase_px = 3.0;
  // A pixel whose phase standard deviation exceeds this (projector px) is rejected. Default 0.5.
  double max_sigma_px = 0.5;
  Status Validate() const;
};

// Why a pixel has no (u, v): the first test it failed.
enum class PixelOutcome : uint8_t {
  kDecoded = 0,
  kShadow,          // white - black < min_contrast
  kLowContrast,     // washed-out Gray code
  kLowModulation,   // phase amplitude too small
  kOutOfRange,      // Gray code beyond the projector's extent
  kInconsistent,    // phase vs Gray / coarser phase disagree
  kNoisy,           // phase standard deviation above max_sigma_px
};
constexpr int kPixelOutcomeCount = 7;
const char* PixelOutcomeName(PixelOutcome outcome);

// The photographs of one angle, in memory (linear, 1 channel, camera size).
struct AxisPhotos {
  std::vector<Image> gray, gray_inverse;       // per bit, MSB first
  std::map<int, std::vector<Image>> phase;     // period (projector px) -> shifts k = 0..K-1
};
struct AnglePhotos {
  Image white, black;
  AxisPhotos col, row;
};

// Reads every photograph of `angle` (grey PNG; colour images are averaged to grey), in parallel.
// Errors name the file (NotFound, DataLoss, InvalidArgument for a size other than width x height).
StatusOr<AnglePhotos> LoadAnglePhotos(const AngleImages& angle, int width, int height);

struct DecodedView {
  int width = 0, height = 0;
  std::vector<float> u, v;              // projector pixel coordinates; NaN where not decoded
  std::vector<float> sigma_u, sigma_v;  // standard deviations, projector px
  std::vector<float> contrast;          // white - black
  std::vector<uint8_t> outcome;         // PixelOutcome
  int64_t counts[kPixelOutcomeCount] = {};
  int64_t Decoded() const { return counts[0]; }
  // Decoded / pixels with white - black >= min_contrast (the lit object), 0 when none is lit.
  double Coverage() const;
};

// Decodes one angle. `projector_width/height` bound the codes. Fails (InvalidArgument) only when
// the photographs' sizes differ; a projector that lights nothing yields counts[kShadow] = all.
StatusOr<DecodedView> DecodeAngle(const AnglePhotos& photos, int projector_width,
                                  int projector_height, const DecodeOptions& options);

}  // namespace reflcap::scan
