#include "engine/mesh/texel_atlas.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <vector>

namespace reflcap {
namespace {

// Positions interpolated in double and stored as float, coordinates <= 1: ~1e-7 rounding.
constexpr float kPositionTolerance = 1e-6f;
// Unit vectors normalised in float, and their dot/cross products: a few ulps of 1.0f.
constexpr float kUnitTolerance = 1e-5f;
// Oracle for coverage: a pixel whose exact overlap with some triangle exceeds this area (in
// pixels^2) must be a texel; one with no overlap at all must not. In between lies the atlas'
// documented rounding tolerance (overlaps thinner than 8 * 2^-24 UV), which the oracle leaves open.
constexpr double kSurelyCoveredArea = 1e-6;

// A planar mesh with xyz = (u, v, 0) and normals +z, one triangle per UV triple.
TriangleMesh PlanarMesh(const std::vector<std::array<Vec2f, 3>>& uv_triangles) {
  TriangleMesh mesh;
  for (const auto& uv : uv_triangles) {
    const uint32_t base = uint32_t(mesh.positions.size());
    for (const Vec2f& p : uv) mesh.positions.push_back(Vec3f(p.x(), p.y(), 0.0f));
    mesh.triangles.push_back({base, base + 1, base + 2});
    mesh.corner_uvs.push_back(uv);
    mesh.corner_normals.push_back({Vec3f::UnitZ(), Vec3f::UnitZ(), Vec3f::UnitZ()});
  }
  return mesh;
}

TriangleMesh UnitSquare() {
  TriangleMesh mesh;
  mesh.positions = {Vec3f(0, 0, 0), Vec3f(1, 0, 0), Vec3f(1, 1, 0), Vec3f(0, 1, 0)};
  mesh.triangles = {{0, 1, 2}, {0, 2, 3}};
  mesh.corner_uvs = {{Vec2f(0, 0), Vec2f(1, 0), Vec2f(1, 1)},
                     {Vec2f(0, 0), Vec2f(1, 1), Vec2f(0, 1)}};
  const std::array<Vec3f, 3> up = {Vec3f::UnitZ(), Vec3f::UnitZ(), Vec3f::UnitZ()};
  mesh.corner_normals = {up, up};
  return mesh;
}

// Exact area of triangle (pixel space) within the unit square of pixel (x, y), by clipping.
double OverlapArea(const std::array<Vec2f, 3>& uv, int width, int height, int x, int y) {
  std::vector<Vec2d> poly;
  for (const Vec2f& p : uv) poly.push_back(Vec2d(p.x() * double(width), (1.0 - p.y()) * height));
  const double bounds[4] = {double(x), double(x + 1), double(y), double(y + 1)};
  for (int side = 0; side < 4; ++side) {
    const int axis = side / 2;
    const bool keep_above = side % 2 == 0;
    auto inside = [&](const Vec2d& p) {
      return keep_above ? p[axis] >= bounds[side] : p[axis] <= bounds[side];
    };
    std::vector<Vec2d> out;
    for (size_t i = 0; i < poly.size(); ++i) {
      const Vec2d& a = poly[i];
      const Vec2d& b = poly[(i + 1) % poly.size()];
      if (inside(a)) out.push_back(a);
      if (inside(a) != inside(b)) {
        const double s = (bounds[side] - a[axis]) / (b[axis] - a[axis]);
        out.push_back(a + s * (b - a));
      }
    }
    poly = out;
    if (poly.empty()) return 0.0;
  }
  double area = 0.0;
  for (size_t i = 0; i < poly.size(); ++i) {
    const Vec2d& a = poly[i];
    const Vec2d& b = poly[(i + 1) % poly.size()];
    area += a.x() * b.y() - a.y() * b.x();
  }
  return std::abs(area) / 2.0;
}

// Texel bookkeeping is consistent: pixel <-> texel maps invert each other, row-major order.
void ExpectConsistentLayout(const TexelAtlas& atlas) {
  ASSERT_EQ(atlas.texel_of_pixel.size(), size_t(atlas.width) * atlas.height);
  for (size_t i = 0; i < atlas.TexelCount(); ++i) {
    ASSERT_EQ(atlas.texel_of_pixel[atlas.pixel_of_texel[i]], int32_t(i));
    if (i > 0) {
      ASSERT_LT(atlas.pixel_of_texel[i - 1], atlas.pixel_of_texel[i]);
    }
  }
  size_t mapped = 0;
  for (int32_t t : atlas.texel_of_pixel) mapped += t >= 0;
  EXPECT_EQ(mapped, atlas.TexelCount());
  EXPECT_EQ(atlas.position.size(), atlas.TexelCount());
  EXPECT_EQ(atlas.tangent.size(), atlas.TexelCount());
  EXPECT_EQ(atlas.triangle.size(), atlas.TexelCount());
}

void ExpectOrthonormalRightHandedFrames(const TexelAtlas& atlas) {
  for (size_t i = 0; i < atlas.TexelCount(); ++i) {
    const Vec3f& t = atlas.tangent[i];
    const Vec3f& b = atlas.bitangent[i];
    const Vec3f& n = atlas.shading_normal[i];
    ASSERT_NEAR(t.norm(), 1.0f, kUnitTolerance) << i;
    ASSERT_NEAR(b.norm(), 1.0f, kUnitTolerance) << i;
    ASSERT_NEAR(n.norm(), 1.0f, kUnitTolerance) << i;
    ASSERT_NEAR(atlas.geometric_normal[i].norm(), 1.0f, kUnitTolerance) << i;
    ASSERT_NEAR(t.dot(n), 0.0f, kUnitTolerance) << i;
    ASSERT_NEAR(t.dot(b), 0.0f, kUnitTolerance) << i;
    ASSERT_NEAR(t.cross(b).dot(n), 1.0f, kUnitTolerance) << i;  // right-handed
  }
}

TEST(BuildTexelAtlas, UnitSquareHasExactlyOneTexelPerPixel) {
  for (int resolution : {1, 7, 64, 100}) {
    StatusOr<TexelAtlas> atlas = BuildTexelAtlas(UnitSquare(), resolution, resolution);
    ASSERT_TRUE(atlas.ok()) << atlas.status().ToString();
    EXPECT_EQ(atlas->TexelCount(), size_t(resolution) * resolution) << resolution;
    ExpectConsistentLayout(*atlas);
    StatusOr<size_t> count = CountAtlasTexels(UnitSquare(), resolution, resolution);
    ASSERT_TRUE(count.ok());
    EXPECT_EQ(*count, size_t(resolution) * resolution);
  }
}

// The texel's side on the surface: a 3 m x 3 m square mapped onto the UV square at 12 x 12 has
// 0.25 m texels; a chart using half the UV range in u for the same square (non-conformal: 0.5 x
// 0.25 m texels) gives their geometric mean; a texel's UV lookup finds the texel itself.
TEST(TexelSidesM, IsTheTexelsSideOnTheSurface) {
  TriangleMesh mesh = UnitSquare();
  for (Vec3f& p : mesh.positions) p *= 3.0f;
  StatusOr<TexelAtlas> atlas = BuildTexelAtlas(mesh, 12, 12);
  ASSERT_TRUE(atlas.ok());
  std::vector<float> sides = TexelSidesM(mesh, *atlas);
  ASSERT_EQ(sides.size(), atlas->TexelCount());
  for (float s : sides) EXPECT_NEAR(s, 0.25f, 1e-6f);
  for (size_t t = 0; t < atlas->TexelCount(); ++t) {
    int x, y;
    atlas->PixelOf(t, &x, &y);
    const Vec2f centre((x + 0.5f) / 12.0f, 1.0f - (y + 0.5f) / 12.0f);
    EXPECT_EQ(atlas->TexelUnderUv(centre), int(t));
  }
  for (auto& tri : mesh.corner_uvs) {
    for (Vec2f& uv : tri) uv.x() *= 0.5f;
  }
  atlas = BuildTexelAtlas(mesh, 12, 12);
  ASSERT_TRUE(atlas.ok());
  sides = TexelSidesM(mesh, *atlas);
  for (float s : sides) EXPECT_NEAR(s, std::sqrt(0.5f * 0.25f), 1e-6f);
  // UVs beyond the chart find the nearest texel of the 3x3 neighbourhood, then none.
  EXPECT_GE(atlas->TexelUnderUv(Vec2f(0.5f + 0.5f / 12.0f, 0.5f)), 0);
  EXPECT_EQ(atlas->TexelUnderUv(Vec2f(0.9f, 0.5f)), -1);
}

TEST(BuildTexelAtlas, TexelPositionIsThePlanarMapOfThePixelCentre) {
  const int width = 64, height = 40;  // non-square on purpose
  StatusOr<TexelAtlas> atlas = BuildTexelAtlas(UnitSquare(), width, height);
  ASSERT_TRUE(atlas.ok()) << atlas.status().ToString();
  ASSERT_EQ(atlas->TexelCount(), size_t(width) * height);
  for (size_t i = 0; i < atlas->TexelCount(); ++i) {
    int x, y;
    atlas->PixelOf(i, &x, &y);
    const Vec3f expected((x + 0.5f) / width, 1.0f - (y + 0.5f) / height, 0.0f);
    ASSERT_LE((atlas->position[i] - expected).cwiseAbs().maxCoeff(), kPositionTolerance)
        << "pixel " << x << "," << y;
    int px, py;
    atlas->PixelOfUv(expected.x(), expected.y(), &px, &py);
    ASSERT_EQ(px, x);
    ASSERT_EQ(py, y);
  }
  // Row 0 is the top of the texture (v = 1).
  EXPECT_GT(atlas->position[0].y(), 1.0f - 1.0f / height);
}

TEST(BuildTexelAtlas, SharedEdgeAssignsEachCoveredPixelToOneTriangle) {
  // A skewed quad split along a diagonal that crosses pixels at odd angles.
  const Vec2f a(0.13f, 0.21f), b(0.81f, 0.17f), c(0.77f, 0.88f), d(0.19f, 0.73f);
  const TriangleMesh mesh = PlanarMesh({{a, b, c}, {a, c, d}});
  const int width = 37, height = 29;
  StatusOr<TexelAtlas> atlas = BuildTexelAtlas(mesh, width, height);
  ASSERT_TRUE(atlas.ok()) << atlas.status().ToString();
  ExpectConsistentLayout(*atlas);
  size_t shared_pixels = 0;
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      const double area0 = OverlapArea(mesh.corner_uvs[0], width, height, x, y);
      const double area1 = OverlapArea(mesh.corner_uvs[1], width, height, x, y);
      const int texel = atlas->TexelAt(x, y);
      if (std::max(area0, area1) > kSurelyCoveredArea) {
        ASSERT_GE(texel, 0) << "covered pixel " << x << "," << y << " has no texel";
        const int t = atlas->triangle[size_t(texel)];
        // The texel's triangle overlaps the pixel.
        EXPECT_GT(t == 0 ? area0 : area1, 0.0) << x << "," << y;
        shared_pixels += area0 > kSurelyCoveredArea && area1 > kSurelyCoveredArea;
        // Its surface point lies on that triangle (within the quad's bounding box here).
        const Vec3f& p = atlas->position[size_t(texel)];
        EXPECT_GE(p.x(), 0.13f - kPositionTolerance);
        EXPECT_LE(p.x(), 0.81f + kPositionTolerance);
      } else if (area0 == 0.0 && area1 == 0.0) {
        EXPECT_EQ(texel, -1) << "uncovered pixel " << x << "," << y << " has a texel";
      }
    }
  }
  EXPECT_GT(shared_pixels, 10u);  // the diagonal really crosses many pixels
}

TEST(BuildTexelAtlas, PrefersTheTriangleContainingThePixelCentre) {
  // Two triangles share the vertical edge u = 0.55 (pixel 2 of 4 spans [0.5, 0.75], centre
  // 0.625): the right triangle covers the centre, the left one only overlaps the pixel.
  const TriangleMesh mesh = PlanarMesh({{Vec2f(0, 0), Vec2f(0.55f, 0), Vec2f(0.55f, 1)},
                                        {Vec2f(0.55f, 0), Vec2f(1, 0), Vec2f(0.55f, 1)}});
  StatusOr<TexelAtlas> atlas = BuildTexelAtlas(mesh, 4, 1);
  ASSERT_TRUE(atlas.ok()) << atlas.status().ToString();
  ASSERT_EQ(atlas->TexelCount(), 4u);
  EXPECT_EQ(atlas->triangle[size_t(atlas->TexelAt(2, 0))], 1);
  // Pixel 1 ([0.25, 0.5], centre (0.375, 0.5)): triangle 0 contains it.
  EXPECT_EQ(atlas->triangle[size_t(atlas->TexelAt(1, 0))], 0);
}

TEST(BuildTexelAtlas, TriangleInsideOnePixelStillGetsATexel) {
  // Pixel (3, 5) of 8x8 spans u in [0.375, 0.5], v in [0.25, 0.375]; the triangle is a
  // hundredth of a pixel and does not contain the pixel centre (0.4375, 0.3125).
  const Vec2f o(0.38f, 0.26f);
  const float s = 0.125f / 100.0f;
  const TriangleMesh mesh = PlanarMesh({{o, o + Vec2f(s, 0), o + Vec2f(0, s)}});
  StatusOr<TexelAtlas> atlas = BuildTexelAtlas(mesh, 8, 8);
  ASSERT_TRUE(atlas.ok()) << atlas.status().ToString();
  ASSERT_EQ(atlas->TexelCount(), 1u);
  EXPECT_EQ(atlas->TexelAt(3, 5), 0);
  EXPECT_EQ(atlas->triangle[0], 0);
  // The surface point is the triangle's point nearest the pixel centre: its hypotenuse.
  const Vec3f& p = atlas->position[0];
  EXPECT_NEAR(p.x() + p.y(), o.x() + o.y() + s, kPositionTolerance);
  EXPECT_GE(p.x(), o.x() - kPositionTolerance);
  EXPECT_GE(p.y(), o.y() - kPositionTolerance);
  EXPECT_EQ(*CountAtlasTexels(mesh, 8, 8), 1u);
}

TEST(BuildTexelAtlas, PixelsOutsideEveryChartGetNoTexel) {
  // Two charts, u in [0, 0.25] and [0.5, 1], at 8 columns: columns 0-1 and 4-7 are covered,
  // columns 2-3 lie in the gap (column 2 merely touches the first chart's border u = 0.25).
  const TriangleMesh mesh = PlanarMesh({{Vec2f(0, 0), Vec2f(0.25f, 0), Vec2f(0.25f, 1)},
                                        {Vec2f(0, 0), Vec2f(0.25f, 1), Vec2f(0, 1)},
                                        {Vec2f(0.5f, 0), Vec2f(1, 0), Vec2f(1, 1)},
                                        {Vec2f(0.5f, 0), Vec2f(1, 1), Vec2f(0.5f, 1)}});
  const int width = 8, height = 5;
  StatusOr<TexelAtlas> atlas = BuildTexelAtlas(mesh, width, height);
  ASSERT_TRUE(atlas.ok()) << atlas.status().ToString();
  EXPECT_EQ(atlas->TexelCount(), size_t(6 * height));
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      EXPECT_EQ(atlas->TexelAt(x, y) >= 0, x < 2 || x >= 4) << x << "," << y;
    }
  }
}

TEST(BuildTexelAtlas, ChartBorderRoundedPastAPixelBorderAddsNoSliverTexels) {
  // 1.0f / 7 rounds up: u * 7 = 1 + 4.5e-8, a sliver of that width into column 1 (or out of
  // column 0, for the chart on the right), which the documented UV tolerance treats as touching.
  const float border = 1.0f / 7.0f;
  ASSERT_GT(double(border) * 7.0, 1.0);
  const int width = 7, height = 3;
  const TriangleMesh left = PlanarMesh({{Vec2f(0, 0), Vec2f(border, 0), Vec2f(border, 1)},
                                        {Vec2f(0, 0), Vec2f(border, 1), Vec2f(0, 1)}});
  const TriangleMesh right = PlanarMesh({{Vec2f(border, 0), Vec2f(1, 0), Vec2f(1, 1)},
                                         {Vec2f(border, 0), Vec2f(1, 1), Vec2f(border, 1)}});
  EXPECT_EQ(*CountAtlasTexels(left, width, height), size_t(1 * height));
  EXPECT_EQ(*CountAtlasTexels(right, width, height), size_t(6 * height));
  StatusOr<TexelAtlas> atlas = BuildTexelAtlas(left, width, height);
  ASSERT_TRUE(atlas.ok()) << atlas.status().ToString();
  EXPECT_EQ(atlas->TexelCount(), size_t(height));
}

TEST(BuildTexelAtlas, CoverageMatchesExactClippingOnRandomTriangles) {
  std::mt19937 rng(12345);
  std::uniform_real_distribution<float> unit(0.0f, 1.0f);
  std::uniform_real_distribution<float> size(0.002f, 0.08f);
  std::vector<std::array<Vec2f, 3>> triangles;
  for (int i = 0; i < 300; ++i) {
    const Vec2f o(unit(rng), unit(rng));
    triangles.push_back(
        {o, o + Vec2f(size(rng), size(rng) - 0.04f), o + Vec2f(size(rng) - 0.04f, size(rng))});
  }
  const TriangleMesh mesh = PlanarMesh(triangles);
  const int width = 96, height = 80;
  StatusOr<TexelAtlas> atlas = BuildTexelAtlas(mesh, width, height);
  ASSERT_TRUE(atlas.ok()) << atlas.status().ToString();
  ExpectConsistentLayout(*atlas);
  std::vector<double> max_area(size_t(width) * height, 0.0);
  for (const auto& tri : triangles) {
    // Pixels within the triangle's bounding box, one pixel of margin (others have no overlap).
    const Vec2f lo = tri[0].cwiseMin(tri[1]).cwiseMin(tri[2]);
    const Vec2f hi = tri[0].cwiseMax(tri[1]).cwiseMax(tri[2]);
    const int x0 = std::max(0, int(lo.x() * width) - 1);
    const int x1 = std::min(width, int(hi.x() * width) + 2);
    const int y0 = std::max(0, int((1.0f - hi.y()) * height) - 1);
    const int y1 = std::min(height, int((1.0f - lo.y()) * height) + 2);
    for (int y = y0; y < y1; ++y) {
      for (int x = x0; x < x1; ++x) {
        double& area = max_area[size_t(y) * width + x];
        area = std::max(area, OverlapArea(tri, width, height, x, y));
      }
    }
  }
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      const double area = max_area[size_t(y) * width + x];
      const int texel = atlas->TexelAt(x, y);
      if (area > kSurelyCoveredArea) {
        EXPECT_GE(texel, 0) << x << "," << y;
      }
      if (area == 0.0) {
        EXPECT_EQ(texel, -1) << x << "," << y;
      }
      if (texel >= 0) {
        const int t = atlas->triangle[size_t(texel)];
        EXPECT_GT(OverlapArea(triangles[size_t(t)], width, height, x, y), 0.0) << x << "," << y;
      }
    }
  }
  StatusOr<size_t> count = CountAtlasTexels(mesh, width, height);
  ASSERT_TRUE(count.ok());
  EXPECT_EQ(*count, atlas->TexelCount());
  // Deterministic: a second build gives the same assignment.
  StatusOr<TexelAtlas> again = BuildTexelAtlas(mesh, width, height);
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(again->texel_of_pixel, atlas->texel_of_pixel);
  EXPECT_EQ(again->triangle, atlas->triangle);
}

TEST(BuildTexelAtlas, TangentFollowsIncreasingUOnPlanarAndMirroredCharts) {
  StatusOr<TexelAtlas> atlas = BuildTexelAtlas(UnitSquare(), 16, 16);
  ASSERT_TRUE(atlas.ok()) << atlas.status().ToString();
  ExpectOrthonormalRightHandedFrames(*atlas);
  for (size_t i = 0; i < atlas->TexelCount(); ++i) {
    ASSERT_LE((atlas->tangent[i] - Vec3f::UnitX()).norm(), kUnitTolerance);
    ASSERT_LE((atlas->bitangent[i] - Vec3f::UnitY()).norm(), kUnitTolerance);
    ASSERT_LE((atlas->shading_normal[i] - Vec3f::UnitZ()).norm(), kUnitTolerance);
    ASSERT_LE((atlas->geometric_normal[i] - Vec3f::UnitZ()).norm(), kUnitTolerance);
  }
  // Mirrored chart: x = 1 - u, so dP/du = -x; the geometric normal is -z.
  TriangleMesh mirrored = UnitSquare();
  for (Vec3f& p : mirrored.positions) p.x() = 1.0f - p.x();
  for (auto& corners : mirrored.corner_normals) corners.fill(-Vec3f::UnitZ());
  atlas = BuildTexelAtlas(mirrored, 16, 16);
  ASSERT_TRUE(atlas.ok()) << atlas.status().ToString();
  ExpectOrthonormalRightHandedFrames(*atlas);
  for (size_t i = 0; i < atlas->TexelCount(); ++i) {
    ASSERT_LE((atlas->tangent[i] + Vec3f::UnitX()).norm(), kUnitTolerance);
    ASSERT_LE((atlas->bitangent[i] - Vec3f::UnitY()).norm(), kUnitTolerance);  // = dP/dv
    ASSERT_LE((atlas->geometric_normal[i] + Vec3f::UnitZ()).norm(), kUnitTolerance);
  }
}

TEST(BuildTexelAtlas, FramesOnACylinderAreOrthonormalAndFollowU) {
  // Open cylinder of radius 1: u = angle / (2 pi) * 0.9 (no seam), v = height; outward normals.
  constexpr int kSegments = 24, kRings = 4;
  constexpr double kAngleSpan = 0.9 * 2.0 * kPi;
  TriangleMesh mesh;
  for (int j = 0; j <= kRings; ++j) {
    for (int i = 0; i <= kSegments; ++i) {
      const double angle = kAngleSpan * i / kSegments;
      mesh.positions.push_back(Vec3f(std::cos(angle), std::sin(angle), float(j) / kRings));
    }
  }
  auto id = [](int i, int j) { return uint32_t(j * (kSegments + 1) + i); };
  auto uv = [](int i, int j) { return Vec2f(0.9f * i / kSegments, float(j) / kRings); };
  auto normal = [&](int i) {
    const double angle = kAngleSpan * i / kSegments;
    return Vec3f(std::cos(angle), std::sin(angle), 0.0f);
  };
  for (int j = 0; j < kRings; ++j) {
    for (int i = 0; i < kSegments; ++i) {
      mesh.triangles.push_back({id(i, j), id(i + 1, j), id(i + 1, j + 1)});
      mesh.corner_uvs.push_back({uv(i, j), uv(i + 1, j), uv(i + 1, j + 1)});
      mesh.corner_normals.push_back({normal(i), normal(i + 1), normal(i + 1)});
      mesh.triangles.push_back({id(i, j), id(i + 1, j + 1), id(i, j + 1)});
      mesh.corner_uvs.push_back({uv(i, j), uv(i + 1, j + 1), uv(i, j + 1)});
      mesh.corner_normals.push_back({normal(i), normal(i + 1), normal(i)});
    }
  }
  StatusOr<TexelAtlas> atlas = BuildTexelAtlas(mesh, 64, 32);
  ASSERT_TRUE(atlas.ok()) << atlas.status().ToString();
  ExpectOrthonormalRightHandedFrames(*atlas);
  // Cosine between the tangent and the circumferential direction, which dP/du follows; the
  // faceted surface and interpolated normals tilt it by at most half a segment (7.5 degrees).
  constexpr float kMinTangentCosine = 0.99f;
  for (size_t i = 0; i < atlas->TexelCount(); ++i) {
    const Vec3f& p = atlas->position[i];
    const Vec3f around = Vec3f(-p.y(), p.x(), 0.0f).normalized();
    ASSERT_GT(atlas->tangent[i].dot(around), kMinTangentCosine) << i;
    ASSERT_GT(atlas->bitangent[i].z(), kMinTangentCosine) << i;
    ASSERT_GT(atlas->geometric_normal[i].dot(Vec3f(p.x(), p.y(), 0).normalized()),
              kMinTangentCosine)
        << i;
  }
  StatusOr<size_t> count = CountAtlasTexels(mesh, 64, 32);
  ASSERT_TRUE(count.ok());
  EXPECT_EQ(*count, atlas->TexelCount());
}

TEST(BuildTexelAtlas, RejectsBadSizesAndMeshesWithoutUvs) {
  EXPECT_EQ(BuildTexelAtlas(UnitSquare(), 0, 8).status().code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(CountAtlasTexels(UnitSquare(), 8, -1).status().code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(BuildTexelAtlas(UnitSquare(), 1 << 16, 1 << 16).status().code(),
            StatusCode::kInvalidArgument);
  TriangleMesh no_uv = UnitSquare();
  no_uv.corner_uvs.clear();
  StatusOr<TexelAtlas> atlas = BuildTexelAtlas(no_uv, 8, 8);
  ASSERT_FALSE(atlas.ok());
  EXPECT_EQ(atlas.status().code(), StatusCode::kFailedPrecondition);
  EXPECT_NE(atlas.status().message().find("has no UV coordinates"), std::string::npos);
  TriangleMesh bad_index = UnitSquare();
  bad_index.triangles[1][2] = 9;
  EXPECT_EQ(BuildTexelAtlas(bad_index, 8, 8).status().code(), StatusCode::kInvalidArgument);
}

TEST(BuildTexelAtlas, IgnoresTrianglesWithZeroUvAreaOrOutsideTheLayout) {
  const TriangleMesh mesh =
      PlanarMesh({{Vec2f(0.1f, 0.1f), Vec2f(0.9f, 0.9f), Vec2f(0.5f, 0.5f)},  // collinear
                  {Vec2f(1.0f, 0.0f), Vec2f(2.0f, 0.0f), Vec2f(2.0f, 1.0f)},  // touches u = 1
                  {Vec2f(0, 0), Vec2f(0.5f, 0), Vec2f(0, 0.5f)}});
  StatusOr<TexelAtlas> atlas = BuildTexelAtlas(mesh, 4, 4);
  ASSERT_TRUE(atlas.ok()) << atlas.status().ToString();
  // Only the third triangle covers anything: 3 of the lower-left 2x2 pixels, since its
  // hypotenuse u + v = 0.5 merely touches pixel (1, 2) at a corner.
  for (size_t i = 0; i < atlas->TexelCount(); ++i) EXPECT_EQ(atlas->triangle[i], 2);
  EXPECT_EQ(atlas->TexelCount(), 3u);
  EXPECT_EQ(atlas->TexelAt(1, 2), -1);
}

TEST(PixelOfUv, ClampsToTheLayout) {
  TexelAtlas atlas;
  atlas.width = 10;
  atlas.height = 5;
  int x, y;
  atlas.PixelOfUv(0.0f, 1.0f, &x, &y);
  EXPECT_EQ(x, 0);
  EXPECT_EQ(y, 0);
  atlas.PixelOfUv(1.0f, 0.0f, &x, &y);
  EXPECT_EQ(x, 9);
  EXPECT_EQ(y, 4);
  atlas.PixelOfUv(0.55f, 0.5f, &x, &y);
  EXPECT_EQ(x, 5);
  EXPECT_EQ(y, 2);
  atlas.PixelOfUv(-3.0f, 7.0f, &x, &y);
  EXPECT_EQ(x, 0);
  EXPECT_EQ(y, 0);
  atlas.PixelOfUv(std::numeric_limits<float>::quiet_NaN(), 0.5f, &x, &y);
  EXPECT_EQ(x, 0);
}

TEST(PixelOfUv, DecidesATexelBoundaryTheSameWayFromEitherSideOfIt) {
  // A boundary UV (0.3 of 10 texels) as two implementations compute it: one float ulp below and
  // above. Without kTexelTieOffset floor() puts them in texels 2 and 3.
  TexelAtlas atlas;
  atlas.width = 10;
  atlas.height = 10;
  const float below = std::nextafter(0.3f, 0.0f), above = std::nextafter(0.3f, 1.0f);
  int x_below, x_above, y;
  atlas.PixelOfUv(below, 0.5f, &x_below, &y);
  atlas.PixelOfUv(above, 0.5f, &x_above, &y);
  EXPECT_EQ(x_below, 3);
  EXPECT_EQ(x_above, 3);
  // Rows count from v = 1: 1 - v = 0.7 is the boundary of rows 6 and 7.
  int x, y_below, y_above;
  atlas.PixelOfUv(0.5f, std::nextafter(0.3f, 0.0f), &x, &y_below);
  atlas.PixelOfUv(0.5f, std::nextafter(0.3f, 1.0f), &x, &y_above);
  EXPECT_EQ(y_below, 7);
  EXPECT_EQ(y_above, 7);
  // A point clearly inside a texel is not moved.
  atlas.PixelOfUv(0.3f - 0.02f, 0.5f, &x, &y);
  EXPECT_EQ(x, 2);
}

TEST(BuildNormalMapAtlas, KeepsMaskedPixelsWithUsableNormals) {
  const int width = 4, height = 3;
  Image normals(width, height, 3, 0.0f);
  Image mask(width, height, 2, 0.0f);  // extra channels are ignored
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      const Vec3f n = Vec3f(x - 1.5f, y - 1.0f, 2.0f).normalized();
      for (int c = 0; c < 3; ++c) normals.at(x, y, c) = n[c];
      mask.at(x, y, 0) = x >= 1 ? 1.0f : 0.0f;  // column 0 is outside the object
      mask.at(x, y, 1) = 1.0f;
    }
  }
  normals.at(2, 1, 1) = std::numeric_limits<float>::quiet_NaN();  // masked, but NaN
  for (int c = 0; c < 3; ++c) normals.at(3, 2, c) = 0.0f;         // masked, but no normal
  normals.at(1, 0, 0) = 0.0f;                                     // masked, length 2:
  normals.at(1, 0, 1) = 0.0f;                                     // normalised
  normals.at(1, 0, 2) = -2.0f;
  StatusOr<TexelAtlas> atlas = BuildNormalMapAtlas(normals, mask);
  ASSERT_TRUE(atlas.ok()) << atlas.status().ToString();
  EXPECT_EQ(atlas->width, width);
  EXPECT_EQ(atlas->height, height);
  EXPECT_EQ(atlas->TexelCount(), size_t(3 * height - 2));
  ExpectConsistentLayout(*atlas);
  ExpectOrthonormalRightHandedFrames(*atlas);
  EXPECT_EQ(atlas->TexelAt(0, 0), -1);
  EXPECT_EQ(atlas->TexelAt(2, 1), -1);
  EXPECT_EQ(atlas->TexelAt(3, 2), -1);
  const size_t down = size_t(atlas->TexelAt(1, 0));
  EXPECT_LE((atlas->shading_normal[down] + Vec3f::UnitZ()).norm(), kUnitTolerance);
  for (size_t i = 0; i < atlas->TexelCount(); ++i) {
    EXPECT_EQ(atlas->position[i], Vec3f::Zero());
    EXPECT_EQ(atlas->geometric_normal[i], atlas->shading_normal[i]);
    EXPECT_EQ(atlas->triangle[i], -1);
  }
}

TEST(BuildNormalMapAtlas, RejectsMismatchedImages) {
  EXPECT_EQ(BuildNormalMapAtlas(Image(4, 3, 3), Image(4, 2, 1)).status().code(),
            StatusCode::kInvalidArgument);
  EXPECT_EQ(BuildNormalMapAtlas(Image(4, 3, 1), Image(4, 3, 1)).status().code(),
            StatusCode::kInvalidArgument);
  EXPECT_EQ(BuildNormalMapAtlas(Image(4, 3, 3), Image(4, 3, 0)).status().code(),
            StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace reflcap
