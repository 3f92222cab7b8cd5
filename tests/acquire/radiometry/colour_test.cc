// Colour science: sRGB decoding, CIELAB and CIEDE2000 against published test data.
#include "acquire/radiometry/colour.h"

#include <gtest/gtest.h>

namespace reflcap::radiometry {
namespace {

// Sharma, Wu & Dalal (2005) list ΔE00 to 4 decimals; half a unit in the last place.
constexpr double kDeltaETableTolerance = 5e-5;
// IEC 61966-2-1 values quoted to 5 significant digits.
constexpr double kSrgbTolerance = 1e-5;

struct DeltaECase {
  Vec3d lab1, lab2;
  double expected;
};

TEST(DeltaE2000, MatchesSharmaWuDalalTestData) {
  const DeltaECase cases[] = {
      {{50.0000, 2.6772, -79.7751}, {50.0000, 0.0000, -82.7485}, 2.0425},
      {{50.0000, 3.1571, -77.2803}, {50.0000, 0.0000, -82.7485}, 2.8615},
      {{50.0000, 2.8361, -74.0200}, {50.0000, 0.0000, -82.7485}, 3.4412},
      {{50.0000, -1.3802, -84.2814}, {50.0000, 0.0000, -82.7485}, 1.0000},
      {{50.0000, 0.0000, 0.0000}, {50.0000, -1.0000, 2.0000}, 2.3669},
      {{50.0000, -1.0000, 2.0000}, {50.0000, 0.0000, 0.0000}, 2.3669},
      {{50.0000, 2.5000, 0.0000}, {73.0000, 25.0000, -18.0000}, 27.1492},
      {{50.0000, 2.5000, 0.0000}, {61.0000, -5.0000, 29.0000}, 22.8977},
      {{50.0000, 2.5000, 0.0000}, {56.0000, -27.0000, -3.0000}, 31.9030},
      {{50.0000, 2.5000, 0.0000}, {58.0000, 24.0000, 15.0000}, 19.4535},
      {{60.2574, -34.0099, 36.2677}, {60.4626, -34.1751, 39.4387}, 1.2644},
      {{63.0109, -31.0961, -5.8663}, {62.8187, -29.7946, -4.0864}, 1.2630},
      {{2.0776, 0.0795, -1.1350}, {0.9033, -0.0636, -0.5514}, 0.9082},
  };
  for (const DeltaECase& c : cases) {
    EXPECT_NEAR(DeltaE2000(c.lab1, c.lab2), c.expected, kDeltaETableTolerance)
        << c.lab1.transpose() << " vs " << c.lab2.transpose();
  }
}

TEST(Colour, SrgbDecodingAndWhite) {
  EXPECT_NEAR(SrgbToLinear(0.5), 0.21404, kSrgbTolerance);
  EXPECT_NEAR(SrgbToLinear(0.04045), 0.0031308, kSrgbTolerance);
  EXPECT_DOUBLE_EQ(SrgbToLinear(1.0), 1.0);
  const Vec3d white = LinearRgbToLab(Vec3d::Ones());
  EXPECT_NEAR(white[0], 100, 1e-9);
  EXPECT_NEAR(white[1], 0, 1e-9);
  EXPECT_NEAR(white[2], 0, 1e-9);
  // Neutral patches are neutral: a* and b* within the 8-bit rounding of their sRGB values.
  for (int i = kFirstNeutralPatch; i < kChartPatches; ++i) {
    const Vec3d lab = LinearRgbToLab(PatchAlbedo(i));
    EXPECT_LT(std::abs(lab[1]) + std::abs(lab[2]), 1.0) << ColorCheckerClassic()[size_t(i)].name;
  }
  EXPECT_EQ(std::string(ColorCheckerClassic()[0].name), "dark skin");
  EXPECT_EQ(std::string(ColorCheckerClassic()[23].name), "black 2 (1.5 D)");
}

}  // namespace
}  // namespace reflcap::radiometry
