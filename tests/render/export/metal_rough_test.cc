// The metallic-roughness approximation (render/export/metal_rough.h): the glTF model it fits, and
// the fits of texels whose best approximation is known.
#include "render/export/metal_rough.h"

#include <gtest/gtest.h>

#include <cmath>

namespace reflcap::render {
namespace {

// A Lambert texel is a glTF dielectric of roughness 1 up to the Fresnel terms (the (1 - F_d)
// diffuse factor and the 4 % specular layer): its relative error stays below this.
constexpr float kLambertError = 0.08f;

brdf::BrdfParams Lambert(float r, float g, float b) {
  brdf::BrdfParams p;
  p.rho_d = {r, g, b};
  return p;
}

TEST(MetalRough, GltfBrdfOfARoughDielectricIsNearLambert) {
  const Vec3f wi = Vec3f(0.3f, 0.1f, 1.0f).normalized(), wo = Vec3f(-0.2f, 0.4f, 1.0f).normalized();
  const float f = GltfBrdf(0.5f, 0, 1, wi, wo);
  EXPECT_NEAR(f, 0.5f / float(kPi), 0.1f * 0.5f / float(kPi));
  EXPECT_TRUE(std::isfinite(GltfBrdf(1, 1, kMinRoughness, wi, Vec3f(-wi.x(), -wi.y(), wi.z()))));
}

TEST(MetalRough, LambertTexelIsAMatchingDielectric) {
  const MetalRoughFitter fitter;
  const MetalRough m = fitter.Fit(Lambert(0.6f, 0.4f, 0.2f));
  EXPECT_EQ(m.metallic, 0.0f);
  EXPECT_FLOAT_EQ(m.base_color[0], 0.6f);
  EXPECT_FLOAT_EQ(m.base_color[2], 0.2f);
  EXPECT_GT(m.roughness, 0.5f);
  EXPECT_LT(m.error, kLambertError) << "roughness " << m.roughness;
}

TEST(MetalRough, BlackTexelHasNoErrorAndNothingNonFinite) {
  const MetalRoughFitter fitter;
  MetalRough m = fitter.Fit(Lambert(0, 0, 0));
  EXPECT_EQ(m.error, 0.0f);
  brdf::BrdfParams bad = Lambert(NAN, 0.5f, INFINITY);
  m = fitter.Fit(bad);
  EXPECT_TRUE(m.base_color.allFinite());
  EXPECT_TRUE(std::isfinite(m.error));
}

TEST(MetalRough, NarrowerLobesGetSmootherSurfaces) {
  const MetalRoughFitter fitter;
  float previous = 2;
  for (double n : {10.0, 50.0, 250.0}) {
    brdf::BrdfParams p = Lambert(0.3f, 0.3f, 0.3f);
    p.num_lobes = 1;
    for (int c = 0; c < 3; ++c) p.lobes[0][c] = brdf::MirrorLobe(0.05 * n, n);
    const MetalRough m = fitter.Fit(p);
    EXPECT_LT(m.roughness, previous) << "n " << n;
    previous = m.roughness;
  }
}

}  // namespace
}  // namespace reflcap::render
