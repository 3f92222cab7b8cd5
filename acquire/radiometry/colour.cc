// Colour science (see colour.h).
#include "acquire/radiometry/colour.h"

#include <cmath>

namespace reflcap::radiometry {

const std::array<ChartPatchReference, kChartPatches>& ColorCheckerClassic() {
  static const std::array<ChartPatchReference, kChartPatches> kPatches = {{
      {"dark skin", {115, 82, 68}},      {"light skin", {194, 150, 130}},
      {"blue sky", {98, 122, 157}},      {"foliage", {87, 108, 67}},
      {"blue flower", {133, 128, 177}},  {"bluish green", {103, 189, 170}},
      {"orange", {214, 126, 44}},        {"purplish blue", {80, 91, 166}},
      {"moderate red", {193, 90, 99}},   {"purple", {94, 60, 108}},
      {"yellow green", {157, 188, 64}},  {"orange yellow", {224, 163, 46}},
      {"blue", {56, 61, 150}},           {"green", {70, 148, 73}},
      {"red", {175, 54, 60}},            {"yellow", {231, 199, 31}},
      {"magenta", {187, 86, 149}},       {"cyan", {8, 133, 161}},
      {"white 9.5 (.05 D)", {243, 243, 242}},  {"neutral 8 (.23 D)", {200, 200, 200}},
      {"neutral 6.5 (.44 D)", {160, 160, 160}}, {"neutral 5 (.70 D)", {122, 122, 121}},
      {"neutral 3.5 (1.05 D)", {85, 85, 85}},   {"black 2 (1.5 D)", {52, 52, 52}},
  }};
  return kPatches;
}

Vec3d PatchAlbedo(int patch) {
  const auto& p = ColorCheckerClassic()[size_t(patch)];
  return Vec3d(SrgbToLinear(p.srgb8[0] / 255.0), SrgbToLinear(p.srgb8[1] / 255.0),
               SrgbToLinear(p.srgb8[2] / 255.0));
}

Vec3d LinearRgbToXyz(const Vec3d& rgb) {
  // IEC 61966-2-1 (Rec.709 primaries, D65).
  Mat3d m;
  m << 0.4124564, 0.3575761, 0.1804375,  //
      0.2126729, 0.7151522, 0.0721750,   //
      0.0193339, 0.1191920, 0.9503041;
  return m * rgb;
}

Vec3d XyzToLab(const Vec3d& xyz) {
  static const Vec3d white = LinearRgbToXyz(Vec3d::Ones());
  auto f = [](double t) {
    // CIE: cube root above (6/29)³, the linear segment below.
    constexpr double kDelta = 6.0 / 29.0;
    return t > kDelta * kDelta * kDelta ? std::cbrt(t) : t / (3 * kDelta * kDelta) + 4.0 / 29.0;
  };
  const double fx = f(xyz[0] / white[0]), fy = f(xyz[1] / white[1]), fz = f(xyz[2] / white[2]);
  return Vec3d(116 * fy - 16, 500 * (fx - fy), 200 * (fy - fz));
}

Vec3d LinearRgbToLab(const Vec3d& rgb) { return XyzToLab(LinearRgbToXyz(rgb)); }

double DeltaE2000(const Vec3d& lab1, const Vec3d& lab2) {
  const double L1 = lab1[0], a1 = lab1[1], b1 = lab1[2];
  const double L2 = lab2[0], a2 = lab2[1], b2 = lab2[2];
  const double C1 = std::hypot(a1, b1), C2 = std::hypot(a2, b2);
  const double C_bar = 0.5 * (C1 + C2);
  const double C7 = std::pow(C_bar, 7);
  const double G = 0.5 * (1 - std::sqrt(C7 / (C7 + std::pow(25.0, 7))));
  const double a1p = (1 + G) * a1, a2p = (1 + G) * a2;
  const double C1p = std::hypot(a1p, b1), C2p = std::hypot(a2p, b2);
  auto hue = [](double b, double ap) {
    if (b == 0 && ap == 0) return 0.0;
    double h = RadToDeg(std::atan2(b, ap));
    return h < 0 ? h + 360 : h;
  };
  const double h1p = hue(b1, a1p), h2p = hue(b2, a2p);
  const double dLp = L2 - L1, dCp = C2p - C1p;
  double dhp = 0;
  if (C1p * C2p != 0) {
    dhp = h2p - h1p;
    if (dhp > 180) dhp -= 360;
    if (dhp < -180) dhp += 360;
  }
  const double dHp = 2 * std::sqrt(C1p * C2p) * std::sin(DegToRad(dhp / 2));
  const double Lp_bar = 0.5 * (L1 + L2), Cp_bar = 0.5 * (C1p + C2p);
  double hp_bar = h1p + h2p;
  if (C1p * C2p != 0) {
    if (std::abs(h1p - h2p) <= 180) {
      hp_bar = 0.5 * (h1p + h2p);
    } else {
      hp_bar = h1p + h2p < 360 ? 0.5 * (h1p + h2p + 360) : 0.5 * (h1p + h2p - 360);
    }
  }
  const double T = 1 - 0.17 * std::cos(DegToRad(hp_bar - 30)) + 0.24 * std::cos(DegToRad(2 * hp_bar)) +
                   0.32 * std::cos(DegToRad(3 * hp_bar + 6)) - 0.20 * std::cos(DegToRad(4 * hp_bar - 63));
  const double d_theta = 30 * std::exp(-std::pow((hp_bar - 275) / 25, 2));
  const double Cp7 = std::pow(Cp_bar, 7);
  const double RC = 2 * std::sqrt(Cp7 / (Cp7 + std::pow(25.0, 7)));
  const double L50 = (Lp_bar - 50) * (Lp_bar - 50);
  const double SL = 1 + 0.015 * L50 / std::sqrt(20 + L50);
  const double SC = 1 + 0.045 * Cp_bar;
  const double SH = 1 + 0.015 * Cp_bar * T;
  const double RT = -std::sin(DegToRad(2 * d_theta)) * RC;
  const double tl = dLp / SL, tc = dCp / SC, th = dHp / SH;
  return std::sqrt(tl * tl + tc * tc + th * th + RT * tc * th);
}

}  // namespace reflcap::radiometry
