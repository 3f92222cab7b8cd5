#include "engine/mesh/ray_scene.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>

#include <gtest/gtest.h>

namespace reflcap {
namespace {

constexpr float kInf = std::numeric_limits<float>::infinity();
// Embree intersects in float: hit distances and barycentrics of O(1) scenes are good to a few
// float ulps (1.2e-7 each).
constexpr float kHitTol = 1e-6f;

// The unit square in z = 0 as two counter-clockwise triangles (normal +z):
// triangle 0 = (0,0,0) (1,0,0) (1,1,0), triangle 1 = (0,0,0) (1,1,0) (0,1,0).
TriangleMesh UnitSquare() {
  TriangleMesh mesh;
  mesh.positions = {Vec3f(0, 0, 0), Vec3f(1, 0, 0), Vec3f(1, 1, 0), Vec3f(0, 1, 0)};
  mesh.triangles = {{0, 1, 2}, {0, 2, 3}};
  return mesh;
}

// The cube [-1, 1]^3 with outward, counter-clockwise faces: a closed convex surface, so a ray
// leaving any of its points into the outer hemisphere must hit nothing.
TriangleMesh Cube() {
  TriangleMesh mesh;
  for (int i = 0; i < 8; ++i) {
    mesh.positions.emplace_back(i & 1 ? 1.f : -1.f, i & 2 ? 1.f : -1.f, i & 4 ? 1.f : -1.f);
  }
  // Quads as corner indices (bit 0 = x, bit 1 = y, bit 2 = z), counter-clockwise from outside.
  const uint32_t quads[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4},
                                {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
  for (const auto& q : quads) {
    mesh.triangles.push_back({q[0], q[1], q[2]});
    mesh.triangles.push_back({q[0], q[2], q[3]});
  }
  return mesh;
}

// Cube() turned and moved, so that its surface points are not exactly representable in float:
// from such points, rays with tnear = 0 and no origin offset hit their own triangle about half the
// time (measured on Embree 3.13), which is what the offset must prevent.
TriangleMesh TurnedCube() {
  TriangleMesh mesh = Cube();
  const Eigen::Matrix3f rotation =
      Eigen::AngleAxisf(0.7f, Vec3f(1, 2, 3).normalized()).toRotationMatrix();
  for (Vec3f& p : mesh.positions) p = rotation * p + Vec3f(0.5f, -0.3f, 0.2f);
  return mesh;
}

// A latitude-longitude unit sphere above a square floor at z = -1.5: curved surfaces, shared
// edges and vertices, and many triangles for the packet comparison.
TriangleMesh SphereOnFloor() {
  constexpr int kRings = 24;
  constexpr int kSegments = 48;
  TriangleMesh mesh;
  for (int r = 0; r <= kRings; ++r) {
    const double theta = kPi * r / kRings;
    for (int s = 0; s < kSegments; ++s) {
      const double phi = 2 * kPi * s / kSegments;
      mesh.positions.emplace_back(std::sin(theta) * std::cos(phi),
                                  std::sin(theta) * std::sin(phi), std::cos(theta));
    }
  }
  for (int r = 0; r < kRings; ++r) {
    for (int s = 0; s < kSegments; ++s) {
      const uint32_t a = r * kSegments + s;
      const uint32_t b = r * kSegments + (s + 1) % kSegments;
      const uint32_t c = (r + 1) * kSegments + s;
      const uint32_t d = (r + 1) * kSegments + (s + 1) % kSegments;
      // Pole rings collapse to a point: skip the zero-area triangles there, as loaders do.
      if (r != 0) mesh.triangles.push_back({a, c, b});
      if (r != kRings - 1) mesh.triangles.push_back({b, c, d});
    }
  }
  const uint32_t base = mesh.positions.size();
  mesh.positions.insert(mesh.positions.end(), {Vec3f(-3, -3, -1.5f), Vec3f(3, -3, -1.5f),
                                               Vec3f(3, 3, -1.5f), Vec3f(-3, 3, -1.5f)});
  mesh.triangles.push_back({base, base + 1, base + 2});
  mesh.triangles.push_back({base, base + 2, base + 3});
  return mesh;
}

std::unique_ptr<RayScene> MakeScene(const TriangleMesh& mesh) {
  StatusOr<std::unique_ptr<RayScene>> scene = RayScene::Create(mesh);
  EXPECT_TRUE(scene.ok()) << scene.status().ToString();
  return scene.ok() ? std::move(scene).value() : nullptr;
}

Vec3f RandomUnit(std::mt19937* rng) {
  std::normal_distribution<float> normal(0.f, 1.f);
  Vec3f w;
  do {
    w = Vec3f(normal(*rng), normal(*rng), normal(*rng));
  } while (w.norm() < 1e-3f);
  return w.normalized();
}

TEST(RayScene, HitsUnitSquareAtKnownDistanceAndBarycentrics) {
  auto scene = MakeScene(UnitSquare());
  ASSERT_NE(scene, nullptr);
  // Triangle 0: p = (b1 + b2, b2), so (0.25, 0.1) has b1 = 0.15, b2 = 0.1.
  RayHit hit = scene->Intersect(Vec3f(0.25f, 0.1f, 1), Vec3f(0, 0, -1), 0, kInf);
  ASSERT_TRUE(hit.hit);
  EXPECT_EQ(hit.triangle, 0u);
  EXPECT_NEAR(hit.t, 1.0f, kHitTol);
  EXPECT_NEAR(hit.b1, 0.15f, kHitTol);
  EXPECT_NEAR(hit.b2, 0.1f, kHitTol);
  // Triangle 1: p = (b1, b1 + b2), so (0.2, 0.7) has b1 = 0.2, b2 = 0.5; hit from below.
  hit = scene->Intersect(Vec3f(0.2f, 0.7f, -2), Vec3f(0, 0, 1), 0, kInf);
  ASSERT_TRUE(hit.hit);
  EXPECT_EQ(hit.triangle, 1u);
  EXPECT_NEAR(hit.t, 2.0f, kHitTol);
  EXPECT_NEAR(hit.b1, 0.2f, kHitTol);
  EXPECT_NEAR(hit.b2, 0.5f, kHitTol);
}

TEST(RayScene, DistanceIsInUnitsOfDirectionLength) {
  auto scene = MakeScene(UnitSquare());
  ASSERT_NE(scene, nullptr);
  const RayHit hit = scene->Intersect(Vec3f(0.5f, 0.25f, 1), Vec3f(0, 0, -4), 0, kInf);
  ASSERT_TRUE(hit.hit);
  EXPECT_NEAR(hit.t, 0.25f, kHitTol);
}

TEST(RayScene, MissesOutsideAndBeyondRange) {
  auto scene = MakeScene(UnitSquare());
  ASSERT_NE(scene, nullptr);
  EXPECT_FALSE(scene->Intersect(Vec3f(1.5f, 0.5f, 1), Vec3f(0, 0, -1), 0, kInf).hit);
  EXPECT_FALSE(scene->Intersect(Vec3f(0.5f, 0.5f, 1), Vec3f(0, 0, 1), 0, kInf).hit);  // away
  EXPECT_FALSE(scene->Intersect(Vec3f(0.5f, 0.5f, 1), Vec3f(0, 0, -1), 0, 0.9f).hit);
  EXPECT_FALSE(scene->Intersect(Vec3f(0.5f, 0.5f, 1), Vec3f(0, 0, -1), 1.1f, kInf).hit);
}

TEST(RayScene, OccludedOnlyWhenSurfaceLiesWithinRange) {
  auto scene = MakeScene(UnitSquare());
  ASSERT_NE(scene, nullptr);
  const Vec3f origin(0.5f, 0.3f, 1), down(0, 0, -1);
  EXPECT_FALSE(scene->Occluded(origin, down, 0, 0.9f));
  EXPECT_TRUE(scene->Occluded(origin, down, 0, 1.1f));
  EXPECT_FALSE(scene->Occluded(origin, down, 1.1f, kInf));
  EXPECT_FALSE(scene->Occluded(Vec3f(2, 2, 1), down, 0, kInf));
}

TEST(RayScene, SurfaceOffsetIsRelativeToBoundingBoxDiagonal) {
  auto scene = MakeScene(Cube());
  ASSERT_NE(scene, nullptr);
  EXPECT_FLOAT_EQ(scene->SurfaceOffset(), RayScene::kRelativeRayOffset * std::sqrt(12.f));
}

TEST(RayScene, RaysOffsetFromSurfaceDoNotSelfIntersect) {
  const TriangleMesh cube = TurnedCube();
  auto scene = MakeScene(cube);
  ASSERT_NE(scene, nullptr);
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> uniform(0.f, 1.f);
  for (int i = 0; i < 2000; ++i) {
    // A random point on a random triangle (including near its edges), a direction in the outer
    // hemisphere (down to grazing), and the documented offset along the geometric normal.
    const size_t t = i % cube.TriangleCount();
    float b1 = uniform(rng), b2 = uniform(rng);
    if (b1 + b2 > 1) b1 = 1 - b1, b2 = 1 - b2;
    const auto& tri = cube.triangles[t];
    const Vec3f p = (1 - b1 - b2) * cube.positions[tri[0]] + b1 * cube.positions[tri[1]] +
                    b2 * cube.positions[tri[2]];
    const Vec3f n = cube.GeometricNormal(t);
    Vec3f dir = RandomUnit(&rng);
    if (dir.dot(n) < 0) dir -= 2 * dir.dot(n) * n;
    const Vec3f origin = p + scene->SurfaceOffset() * n;
    EXPECT_FALSE(scene->Intersect(origin, dir, 0, kInf).hit) << "triangle " << t;
    EXPECT_FALSE(scene->Occluded(origin, dir, 0, kInf)) << "triangle " << t;
    // Offset inwards and shot inwards, the same ray finds the opposite side of the cube.
    EXPECT_TRUE(scene->Intersect(p - scene->SurfaceOffset() * n, -dir, 0, kInf).hit);
  }
}

TEST(RayScene, PacketsMatchSingleRays) {
  const TriangleMesh mesh = SphereOnFloor();
  auto scene = MakeScene(mesh);
  ASSERT_NE(scene, nullptr);
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> position(-2.f, 2.f);
  std::uniform_real_distribution<float> uniform(0.f, 1.f);
  constexpr int kPackets = 63;  // 1008 rays
  int hits_seen = 0, occluded_seen = 0;
  for (int k = 0; k < kPackets; ++k) {
    std::array<bool, 16> valid;
    std::array<Vec3f, 16> origin, dir;
    std::array<float, 16> tnear, tfar;
    for (int i = 0; i < 16; ++i) {
      valid[i] = uniform(rng) < 0.75f;
      origin[i] = Vec3f(position(rng), position(rng), position(rng));
      dir[i] = RandomUnit(&rng);
      tnear[i] = 0.2f * uniform(rng);
      tfar[i] = uniform(rng) < 0.5f ? kInf : 0.5f + 3 * uniform(rng);
    }
    // Sentinels in every lane: valid lanes must overwrite them, invalid ones keep them.
    RayHit sentinel;
    sentinel.hit = true;
    sentinel.t = -7;
    sentinel.triangle = 12345;
    std::array<RayHit, 16> hits;
    hits.fill(sentinel);
    std::array<bool, 16> occluded;
    for (int i = 0; i < 16; ++i) occluded[i] = (i % 2 == 0);
    const std::array<bool, 16> occluded_before = occluded;
    scene->Intersect16(valid, origin, dir, tnear, tfar, &hits);
    scene->Occluded16(valid, origin, dir, tnear, tfar, &occluded);
    for (int i = 0; i < 16; ++i) {
      if (!valid[i]) {
        EXPECT_TRUE(hits[i].hit);
        EXPECT_EQ(hits[i].t, -7);
        EXPECT_EQ(hits[i].triangle, 12345u);
        EXPECT_EQ(occluded[i], occluded_before[i]);
        continue;
      }
      const RayHit single = scene->Intersect(origin[i], dir[i], tnear[i], tfar[i]);
      ASSERT_EQ(hits[i].hit, single.hit) << "packet " << k << ", lane " << i;
      EXPECT_EQ(occluded[i], scene->Occluded(origin[i], dir[i], tnear[i], tfar[i]));
      EXPECT_EQ(occluded[i], single.hit);
      if (!single.hit) continue;
      ++hits_seen;
      occluded_seen += occluded[i];
      EXPECT_EQ(hits[i].triangle, single.triangle) << "packet " << k << ", lane " << i;
      EXPECT_NEAR(hits[i].t, single.t, kHitTol * std::max(1.f, single.t));
      EXPECT_NEAR(hits[i].b1, single.b1, kHitTol);
      EXPECT_NEAR(hits[i].b2, single.b2, kHitTol);
    }
  }
  EXPECT_GT(hits_seen, 100);  // the comparison saw real hits, not only misses
  EXPECT_EQ(occluded_seen, hits_seen);
}

TEST(RayScene, RejectsEmptyMesh) {
  StatusOr<std::unique_ptr<RayScene>> scene = RayScene::Create(TriangleMesh());
  ASSERT_FALSE(scene.ok());
  EXPECT_EQ(scene.status().code(), StatusCode::kInvalidArgument);
  TriangleMesh no_triangles = UnitSquare();
  no_triangles.triangles.clear();
  EXPECT_EQ(RayScene::Create(no_triangles).status().code(), StatusCode::kInvalidArgument);
}

TEST(RayScene, RejectsNonFinitePositionsBeforeEmbreeSeesThem) {
  TriangleMesh mesh = UnitSquare();
  mesh.positions[2].y() = std::numeric_limits<float>::quiet_NaN();
  StatusOr<std::unique_ptr<RayScene>> scene = RayScene::Create(mesh);
  ASSERT_FALSE(scene.ok());
  EXPECT_EQ(scene.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(scene.status().message().find("position 2"), std::string::npos)
      << scene.status().ToString();
  mesh.positions[2].y() = std::numeric_limits<float>::infinity();
  EXPECT_EQ(RayScene::Create(mesh).status().code(), StatusCode::kInvalidArgument);
}

TEST(RayScene, RejectsOutOfRangeIndices) {
  TriangleMesh mesh = UnitSquare();
  mesh.triangles[1][2] = 4;
  const StatusOr<std::unique_ptr<RayScene>> scene = RayScene::Create(mesh);
  ASSERT_FALSE(scene.ok());
  EXPECT_EQ(scene.status().code(), StatusCode::kInvalidArgument);
}

TEST(RayScene, KeepsACopyOfTheMesh) {
  TriangleMesh mesh = UnitSquare();
  auto scene = MakeScene(mesh);
  ASSERT_NE(scene, nullptr);
  mesh.positions[0] = Vec3f(5, 5, 5);
  EXPECT_EQ(scene->mesh().positions[0], Vec3f(0, 0, 0));
  EXPECT_TRUE(scene->Intersect(Vec3f(0.25f, 0.1f, 1), Vec3f(0, 0, -1), 0, kInf).hit);
}

}  // namespace
}  // namespace reflcap
