#pragma once
// Colour science for chart-based white balance: the ColorChecker Classic reference, linear
// Rec.709 RGB -> CIE XYZ (D65) -> CIELAB, and the CIEDE2000 colour difference.
//
// Reference data: the 24 patches' sRGB values are the widely published X-Rite / BabelColor averages
// (N. Pascale, "RGB coordinates of the Macbeth ColorChecker", 2006), the same table brackets/1
// documents; a patch's linear albedo is the IEC 61966-2-1 decoding of value / 255.
// ΔE00: Sharma, Wu and Dalal, "The CIEDE2000 color-difference formula: implementation notes,
// supplementary test data, and mathematical observations", Color Res. Appl. 30(1), 2005.
#include <array>
#include <string>

#include "engine/image/srgb.h"  // SrgbToLinear (decoding the chart's published sRGB values)
#include "engine/math/types.h"

namespace reflcap::radiometry {

constexpr int kChartPatches = 24;
constexpr int kChartRows = 4;
constexpr int kChartColumns = 6;
// Patches 19..24 (indices 18..23): the neutral row, white to black.
constexpr int kFirstNeutralPatch = 18;

struct ChartPatchReference {
  const char* name;
  int srgb8[3];
};
// Row by row, dark skin (top left) to black (bottom right).
const std::array<ChartPatchReference, kChartPatches>& ColorCheckerClassic();

// Linear albedo of patch i (0-based).
Vec3d PatchAlbedo(int patch);

// Linear Rec.709 RGB (D65 white at RGB = 1) -> XYZ with Y(white) = 1.
Vec3d LinearRgbToXyz(const Vec3d& rgb);
// XYZ -> CIELAB relative to the D65 white XYZ of RGB = (1, 1, 1).
Vec3d XyzToLab(const Vec3d& xyz);
Vec3d LinearRgbToLab(const Vec3d& rgb);
// CIEDE2000 difference (kL = kC = kH = 1).
double DeltaE2000(const Vec3d& lab1, const Vec3d& lab2);

}  // namespace reflcap::radiometry
