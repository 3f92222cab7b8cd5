#include "render/reference/indirect_light.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "engine/brdf/lafortune.h"
#include "tests/support/shapes.h"

namespace reflcap::render {
namespace {

constexpr double kPi = 3.14159265358979323846;
// Inside a sphere every texel sends the same radiance, so every gathered ray that finds a texel
// adds the same value and the estimate is exact; what remains is the tessellation (texel centres
// on chords, nearer the centre than R: E higher by up to 0.15 % at 96 x 48). One lost ray of 64
// would be 1.6 % (a ray dropped below the geometric surface instead of mirrored did that).
constexpr double kSphereRelTolerance = 0.005;

// A UV sphere seen from inside: winding reversed and normals turned inwards.
TriangleMesh InwardSphere(float radius) {
  TriangleMesh m = testing::MakeUvSphere(radius, 96, 48);
  for (size_t t = 0; t < m.TriangleCount(); ++t) {
    std::swap(m.triangles[t][1], m.triangles[t][2]);
    std::swap(m.corner_uvs[t][1], m.corner_uvs[t][2]);
    std::swap(m.corner_normals[t][1], m.corner_normals[t][2]);
    for (Vec3f& n : m.corner_normals[t]) n = -n;
  }
  return m;
}

struct SphereScene {
  TriangleMesh mesh;
  std::unique_ptr<RayScene> rays;
  TexelAtlas atlas;
  BrdfMaps maps;
};

SphereScene MakeSphereScene(float radius, float albedo) {
  SphereScene s;
  s.mesh = InwardSphere(radius);
  auto rays = RayScene::Create(s.mesh);
  REFLCAP_CHECK(rays.ok()) << rays.status().ToString();
  s.rays = std::move(rays).value();
  auto atlas = BuildTexelAtlas(s.mesh, 128, 128);
  REFLCAP_CHECK(atlas.ok()) << atlas.status().ToString();
  s.atlas = std::move(atlas).value();
  brdf::BrdfParams p;
  p.rho_d = {albedo, albedo, albedo};
  s.maps.texels.assign(s.atlas.TexelCount(), p);
  return s;
}

// Inside a sphere of radius R, every surface element sees every other under the same form factor
// dA / (4 π R²), so with a point light of intensity I at the centre (E = I / R² everywhere):
//   L0 = ρ I / (π R²), L_ind,1 = ρ L0 = ρ² I / (π R²), L_ind,2 = ρ³ I / (π R²).
TEST(IndirectLight, InsideASphereEachBounceMultipliesByTheAlbedo) {
  const float radius = 0.5f, albedo = 0.6f;
  const SphereScene s = MakeSphereScene(radius, albedo);
  auto table = IndirectLight::Build(*s.rays, s.atlas, 64);
  ASSERT_TRUE(table.ok()) << table.status().ToString();
  Light light;
  light.type = LightType::kPoint;
  light.position = Vec3d::Zero();
  light.intensity = Vec3d(2.0, 1.0, 0.5);
  size_t misses = 0;
  for (size_t t = 0; t < s.atlas.TexelCount(); ++t) {
    for (int r = 0; r < table->rays(); ++r) misses += table->HitTexel(t, r) < 0;
  }
  // Every ray from inside a closed sphere hits it; only seam rounding may lose a texel.
  EXPECT_LT(double(misses), 1e-3 * double(s.atlas.TexelCount()) * table->rays());
  for (int bounces : {1, 2}) {
    const std::vector<Vec3f> radiance = table->TexelRadiance(
        *s.rays, s.atlas, s.maps, light, Rigid3(), bounces, /*cast_shadows=*/true);
    ASSERT_EQ(radiance.size(), s.atlas.TexelCount());
    const double rho = albedo;
    const double factor = (bounces == 1 ? rho * rho : rho * rho + rho * rho * rho) /
                          (kPi * double(radius) * radius);
    double worst = 0;
    for (const Vec3f& l : radiance) {
      for (int c = 0; c < 3; ++c) {
        const double expected = factor * light.intensity[c];
        worst = std::max(worst, std::abs(double(l[c]) - expected) / expected);
      }
    }
    EXPECT_LT(worst, kSphereRelTolerance) << bounces << " bounce(s)";
  }
}

// Nothing bounces off the outside of a convex object: a sphere seen from outside sends no ray
// back to itself, and the indirect light is exactly 0.
TEST(IndirectLight, AConvexObjectGetsNoIndirectLight) {
  TriangleMesh mesh = testing::MakeUvSphere(0.5f, 48, 24);
  auto rays = RayScene::Create(mesh);
  ASSERT_TRUE(rays.ok());
  auto atlas = BuildTexelAtlas(mesh, 64, 64);
  ASSERT_TRUE(atlas.ok());
  BrdfMaps maps;
  brdf::BrdfParams p;
  p.rho_d = {0.9f, 0.9f, 0.9f};
  maps.texels.assign(atlas->TexelCount(), p);
  auto table = IndirectLight::Build(**rays, *atlas, 16);
  ASSERT_TRUE(table.ok());
  Light light;
  light.position = Vec3d(2, 0, 0);
  const std::vector<Vec3f> radiance =
      table->TexelRadiance(**rays, *atlas, maps, light, Rigid3(), 3, true);
  for (const Vec3f& l : radiance) ASSERT_EQ(l, Vec3f::Zero());
}

// Non-finite parameters (a texel the fit could not use) neither send nor receive: no NaN spreads
// to the texels that gather from it.
TEST(IndirectLight, NonFiniteTexelsNeitherSendNorReceive) {
  SphereScene s = MakeSphereScene(0.5f, 0.5f);
  s.maps.texels[0].rho_d[1] = std::nanf("");
  s.maps.texels[1].rho_d[0] = std::numeric_limits<float>::infinity();
  auto table = IndirectLight::Build(*s.rays, s.atlas, 16);
  ASSERT_TRUE(table.ok());
  Light light;
  light.position = Vec3d::Zero();
  const std::vector<Vec3f> radiance =
      table->TexelRadiance(*s.rays, s.atlas, s.maps, light, Rigid3(), 2, true);
  EXPECT_EQ(radiance[0], Vec3f::Zero());
  EXPECT_EQ(radiance[1], Vec3f::Zero());
  for (const Vec3f& l : radiance) ASSERT_TRUE(l.allFinite());
}

TEST(IndirectLight, RefusesBadRayCountsAndNormalMapAtlases) {
  const SphereScene s = MakeSphereScene(0.5f, 0.5f);
  EXPECT_EQ(IndirectLight::Build(*s.rays, s.atlas, 0).status().code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(IndirectLight::Build(*s.rays, s.atlas, kMaxIndirectRays + 1).status().code(),
            StatusCode::kInvalidArgument);
  TexelAtlas normal_map = s.atlas;
  normal_map.triangle[3] = -1;
  const auto refused = IndirectLight::Build(*s.rays, normal_map, 4);
  EXPECT_EQ(refused.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(refused.status().message().find("texel 3"), std::string::npos)
      << refused.status().message();
}

}  // namespace
}  // namespace reflcap::render
