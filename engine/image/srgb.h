#pragma once
// The sRGB transfer curve of IEC 61966-2-1, the one place reflcap defines it: decoding photographs
// that are sRGB-encoded (calibration boards, the ColorChecker's published values) and encoding
// linear values for display (validation PNGs, glTF base colour).
#include <algorithm>
#include <cmath>

namespace reflcap {

// Encoded value in [0, 1] -> linear. The linear segment below 0.04045 is the standard's.
inline double SrgbToLinear(double v) {
  return v <= 0.04045 ? v / 12.92 : std::pow((v + 0.055) / 1.055, 2.4);
}

// Linear value in [0, 1] -> encoded. Callers clamp: the curve is defined on [0, 1] only.
inline float LinearToSrgb(float x) {
  return x <= 0.0031308f ? 12.92f * x : 1.055f * std::pow(x, 1.0f / 2.4f) - 0.055f;
}

}  // namespace reflcap
