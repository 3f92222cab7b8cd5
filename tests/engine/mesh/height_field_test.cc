#include "engine/mesh/height_field.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include "tests/support/height_scenes.h"

namespace reflcap {
namespace {

using testing::AnalyticHeight;
using testing::DiligentCamera;
using testing::NormalMapOf;

// A quadratic height field has a linear gradient, which the trapezoidal rule integrates exactly:
// what remains is the normals' float storage (~6e-8 relative in each gradient, times the ~50 px
// summed over) and the solver's rounding.
constexpr double kQuadraticTolerancePx = 1e-3;
// Sphere cap of radius 40 px seen to 90 % of it (slopes up to 2.1): the trapezoidal rule's error
// per step is |h'''| / 12, which grows towards the rim; summed along paths and spread by the
// least squares it stays small (measured 0.019 px max, 0.0045 px rms). A sign or axis mistake
// gives errors of tens of pixels.
constexpr double kSphereCapTolerancePx = 0.05;

// Shadow decisions may differ from the truth only where the ray passes within the bias plus
// this of the true surface: the integration error (in the pit 0.40 px at most, at the crease of
// its rim where the slope jumps from 1.5 to 0; 0.08 px rms) and the march's one sample per pixel
// column, which can miss the deepest point of a grazing pass (largest mismatch measured: the
// ray 0.44 px beyond the bias).
constexpr double kMarchErrorPx = 0.6;
// The marched shadow's area against the pixels whose ray passes more than the bias under the
// surface: measured 3.1 % fewer (the same grazing passes at the shadow's thin end).
constexpr double kShadowAreaTolerance = 0.05;

TexelAtlas AtlasOf(const AnalyticHeight& shape, int w, int h) {
  Image normals, mask;
  NormalMapOf(shape, w, h, &normals, &mask);
  auto atlas = BuildNormalMapAtlas(normals, mask);
  EXPECT_TRUE(atlas.ok()) << atlas.status().ToString();
  return std::move(atlas).value();
}

// Largest |h_est - h_true - c| over the texels, c = the mean difference (the free constant).
double WorstHeightError(const HeightField& field, const AnalyticHeight& shape) {
  double mean = 0;
  size_t n = 0;
  for (int y = 0; y < field.height; ++y) {
    for (int x = 0; x < field.width; ++x) {
      if (!field.Inside(x, y)) continue;
      mean += field.At(x, y) - shape.height(x, y);
      ++n;
    }
  }
  mean /= double(n);
  double worst = 0;
  for (int y = 0; y < field.height; ++y) {
    for (int x = 0; x < field.width; ++x) {
      if (!field.Inside(x, y)) continue;
      worst = std::max(worst, std::abs(field.At(x, y) - shape.height(x, y) - mean));
    }
  }
  return worst;
}

TEST(HeightFieldIntegration, SphereCapIntegratesBackToItsHeights) {
  const AnalyticHeight cap = testing::SphereCap(47.5, 45.5, 40, 36);
  const Camera cam = DiligentCamera(96, 92);
  const TexelAtlas atlas = AtlasOf(cap, 96, 92);
  auto field = IntegrateNormalMap(atlas, cam);
  ASSERT_TRUE(field.ok()) << field.status().ToString();
  EXPECT_EQ(field->stats.texels, atlas.TexelCount());
  EXPECT_EQ(field->stats.components, 1u);
  EXPECT_EQ(field->stats.clamped, 0u);
  EXPECT_EQ(field->stats.backfacing, 0u);
  EXPECT_LT(WorstHeightError(*field, cap), kSphereCapTolerancePx) << field->stats.ToString();
  // Heights point towards the camera: the centre is the top.
  EXPECT_NEAR(field->At(47, 45) - field->At(47, 10), cap.height(47, 45) - cap.height(47, 10),
              2 * kSphereCapTolerancePx);
  EXPECT_GT(field->At(47, 45), field->stats.max_height_px - 0.1);
  EXPECT_EQ(field->At(0, 0), kHeightFieldOutside);
  EXPECT_EQ(field->pixel_size_m, cam.pixel_size_m);
}

TEST(HeightFieldIntegration, TiltedParaboloidIsExactInAnyCameraFrame) {
  // h = 0.01 (u - 30)² - 0.02 (v - 20)² + 0.3 u - 0.1 v: a saddle on a tilt, so a swapped or
  // mirrored axis cannot cancel. Seen by a camera whose frame is the world frame (looking down
  // +z: a normal facing it has n_z < 0), n ∝ (-dh/du, -dh/dv, -1) ... in DiLiGenT's camera
  // n_world ∝ (-dh/du, dh/dv, 1); both must integrate to the same heights.
  AnalyticHeight saddle;
  saddle.inside = [](double u, double v) { return (u - 30) * (u - 30) / 900 + (v - 20) * (v - 20) / 300 < 1; };
  saddle.height = [](double u, double v) {
    return 0.01 * (u - 30) * (u - 30) - 0.02 * (v - 20) * (v - 20) + 0.3 * u - 0.1 * v;
  };
  saddle.gradient = [](double u, double v) { return Vec2d(0.02 * (u - 30) + 0.3, -0.04 * (v - 20) - 0.1); };
  const TexelAtlas diligent = AtlasOf(saddle, 61, 41);
  auto a = IntegrateNormalMap(diligent, DiligentCamera(61, 41));
  ASSERT_TRUE(a.ok()) << a.status().ToString();
  EXPECT_LT(WorstHeightError(*a, saddle), kQuadraticTolerancePx);
  EXPECT_LT(a->stats.rms_residual_px, kQuadraticTolerancePx);

  TexelAtlas camera_frame = diligent;
  for (size_t t = 0; t < camera_frame.TexelCount(); ++t) {
    int x, y;
    camera_frame.PixelOf(t, &x, &y);
    const Vec2d g = saddle.gradient(x, y);
    camera_frame.shading_normal[t] = Vec3d(-g.x(), -g.y(), -1).normalized().cast<float>();
  }
  Camera identity = DiligentCamera(61, 41);
  identity.cam_from_world = Rigid3();
  auto b = IntegrateNormalMap(camera_frame, identity);
  ASSERT_TRUE(b.ok()) << b.status().ToString();
  EXPECT_LT(WorstHeightError(*b, saddle), kQuadraticTolerancePx);
}

TEST(HeightFieldIntegration, ComponentsAreIntegratedApartAndSilhouettesClamped) {
  // Two hemispheres (full discs: the rim normals are horizontal) with a gap between them.
  AnalyticHeight two;
  auto left = testing::SphereCap(15, 15, 10, 10.5), right = testing::SphereCap(45, 15, 10, 10.5);
  two.inside = [=](double u, double v) { return left.inside(u, v) || right.inside(u, v); };
  two.height = [=](double u, double v) {
    return left.inside(u, v) ? left.height(u, v) : right.height(u, v);
  };
  two.gradient = [=](double u, double v) {
    const AnalyticHeight& s = left.inside(u, v) ? left : right;
    const double d2 = (u - (u < 30 ? 15 : 45)) * (u - (u < 30 ? 15 : 45)) + (v - 15) * (v - 15);
    if (d2 >= 100) return Vec2d(1e6 * (u - (u < 30 ? 15 : 45)), 1e6 * (v - 15));  // the limb
    return s.gradient(u, v);
  };
  Image normals, mask;
  NormalMapOf(two, 60, 30, &normals, &mask);
  // One back-facing normal (n_z < 0 in the world: facing away from the camera) on the left disc.
  normals.at(15, 6, 0) = 0.0f;
  normals.at(15, 6, 1) = 0.6f;
  normals.at(15, 6, 2) = -0.8f;
  auto atlas = BuildNormalMapAtlas(normals, mask);
  ASSERT_TRUE(atlas.ok());
  auto field = IntegrateNormalMap(*atlas, DiligentCamera(60, 30));
  ASSERT_TRUE(field.ok()) << field.status().ToString();
  EXPECT_EQ(field->stats.components, 2u);
  EXPECT_EQ(field->stats.backfacing, 1u);
  EXPECT_GT(field->stats.clamped, 0u) << "rim normals are (nearly) horizontal";
  for (float h : field->heights_px) ASSERT_TRUE(std::isfinite(h));
  // Each component's boundary averages 0, and both tops stand at the same height (symmetry).
  EXPECT_NEAR(field->At(15, 15), field->At(45, 15), 0.5);
  EXPECT_GT(field->At(15, 15), 3.0);
  EXPECT_LT(field->At(15, 15), 15.0);
}

// A tilted plane whose gradients carry a step of kStepPx at one column in the top quarter of the
// rows only: the field is not integrable (those rows say the right part is kStepPx higher, the
// other three quarters that it is not). Least squares spreads the contradiction over the
// equations around it: the right part bends towards a quarter of the step. L1 takes the
// majority (its optimum is the median-like one): the right part stays on the plane, and the few
// equations of the minority carry the whole contradiction.
TEST(HeightFieldIntegration, L1KeepsAStepSharpWhereLeastSquaresSpreadsIt) {
  constexpr double kStepPx = 4.0;
  constexpr int kW = 60, kH = 40, kStepColumn = 30;
  AnalyticHeight shelf;
  shelf.inside = [](double, double) { return true; };
  shelf.height = [](double u, double) { return 0.5 * u; };
  shelf.gradient = [](double u, double v) {
    // The texel's gradient enters the trapezoid equations on both sides of it: kStepPx in all.
    const bool step = int(u) == kStepColumn && v < kH / 4;
    return Vec2d(0.5 + (step ? kStepPx : 0.0), 0.0);
  };
  const Camera cam = DiligentCamera(kW, kH);
  const TexelAtlas atlas = AtlasOf(shelf, kW, kH);
  HeightFieldOptions l1_options;
  l1_options.integration = HeightFieldIntegration::kL1;
  auto ls = IntegrateNormalMap(atlas, cam);
  auto l1 = IntegrateNormalMap(atlas, cam, l1_options);
  ASSERT_TRUE(ls.ok() && l1.ok());
  std::printf("least squares: %s\nL1: %s\n", ls->stats.ToString().c_str(),
              l1->stats.ToString().c_str());
  EXPECT_EQ(l1->stats.integration, HeightFieldIntegration::kL1);
  EXPECT_GT(l1->stats.reweights, 0);
  // The height across the step column (from 3 px left to 3 px right of it), against the plane's
  // 3 px: what each integration made of the contradiction, in every row.
  auto jump = [&](const HeightField& f, int y) {
    return f.At(kStepColumn + 3, y) - f.At(kStepColumn - 3, y) - 3.0;
  };
  double worst_l1 = 0, least_ls = kStepPx;
  for (int y = kH / 2; y < kH; ++y) {  // the majority's rows, a quarter of the image away
    worst_l1 = std::max(worst_l1, std::abs(jump(*l1, y)));
    least_ls = std::min(least_ls, jump(*ls, y));
  }
  std::printf("jump across the column in the majority's rows: L1 at most %.4f px, least "
              "squares at least %.4f px\n", worst_l1, least_ls);
  // Measured: L1 at most 0.038 px there (the ε-smoothing and the reweighting's stopping point),
  // least squares at least 0.116 px (0.12–0.3 px).
  EXPECT_LT(worst_l1, 0.06);
  EXPECT_GT(least_ls, 0.1);
  EXPECT_GT(least_ls, 3 * worst_l1);
  // The minority's equations are let go: about two per contradicting row.
  EXPECT_GE(l1->stats.discontinuities, size_t(kH / 4));
  EXPECT_EQ(ls->stats.discontinuities, 0u);
  // An integrable field has nothing to let go: L1 integrates the sphere cap as least squares does.
  const AnalyticHeight cap = testing::SphereCap(47.5, 45.5, 40, 36);
  auto cap_l1 = IntegrateNormalMap(AtlasOf(cap, 96, 92), DiligentCamera(96, 92), l1_options);
  ASSERT_TRUE(cap_l1.ok());
  EXPECT_LT(WorstHeightError(*cap_l1, cap), kSphereCapTolerancePx) << cap_l1->stats.ToString();
}

TEST(HeightFieldIntegration, RefusesPinholeCamerasAndMismatchedSizes) {
  const TexelAtlas atlas = AtlasOf(testing::SphereCap(8, 8, 6, 5), 16, 16);
  Camera pinhole = DiligentCamera(16, 16);
  pinhole.model = CameraModel::kPinhole;
  EXPECT_EQ(IntegrateNormalMap(atlas, pinhole).status().code(), StatusCode::kFailedPrecondition);
  EXPECT_EQ(IntegrateNormalMap(atlas, DiligentCamera(17, 16)).status().code(),
            StatusCode::kInvalidArgument);
  HeightFieldOptions bad;
  bad.max_slope = 0;
  EXPECT_EQ(IntegrateNormalMap(atlas, DiligentCamera(16, 16), bad).status().code(),
            StatusCode::kInvalidArgument);
}

// ---- Shadows --------------------------------------------------------------------------------------

// A field built directly (no integration): floor 0 everywhere, and a wall of height `wall` on
// columns [60, 62] of every row (or rows [60, 62] of every column when `horizontal`).
HeightField Wall(double wall, bool horizontal) {
  HeightField f;
  f.width = f.height = 80;
  f.cam_from_world = Vec3d(1, -1, -1).asDiagonal();
  f.heights_px.assign(80 * 80, 0.0f);
  for (int y = 0; y < 80; ++y) {
    for (int x = 0; x < 80; ++x) {
      const int c = horizontal ? y : x;
      if (c >= 60 && c <= 62) f.heights_px[size_t(y) * 80 + x] = float(wall);
    }
  }
  return f;
}

TEST(HeightFieldShadow, WallCastsAShadowOfTheClosedFormLength) {
  // Light at elevation α above the image plane, towards +column (world +x) for the vertical wall,
  // towards the top row (world +y, row 0) for the horizontal one. A floor point d pixels before
  // the wall sees it at ray height d tan α; with the bias, it is shadowed when
  // d tan α + kHeightFieldShadowBiasPx < wall: d < (20 - 1) / 0.45 = 42.2, so 42 pixels per line.
  const double wall = 20, tan_a = 0.45;
  const double cos_a = 1 / std::sqrt(1 + tan_a * tan_a), sin_a = tan_a * cos_a;
  const int expected = int(std::ceil((wall - kHeightFieldShadowBiasPx) / tan_a)) - 1;
  ASSERT_EQ(expected, 42);
  for (bool horizontal : {false, true}) {
    const HeightField f = Wall(wall, horizontal);
    // Vertical wall: light towards +x. Horizontal wall at rows 60-62: light towards the bottom
    // rows (world -y), so the shadow falls on rows above the wall.
    const Vec3d light = horizontal ? Vec3d(0, -cos_a, sin_a) : Vec3d(cos_a, 0, sin_a);
    const HeightFieldMarch march = MakeHeightFieldMarch(f, light);
    ASSERT_GT(march.steps, 0u);
    for (int line = 0; line < 80; line += 7) {
      int shadowed = 0, first = -1;
      for (int i = 0; i < 80; ++i) {
        const int x = horizontal ? line : i, y = horizontal ? i : line;
        if (!HeightFieldShadowed(f.heights_px.data(), march, x, y)) continue;
        ++shadowed;
        if (first < 0) first = i;
      }
      EXPECT_EQ(shadowed, expected) << (horizontal ? "column " : "row ") << line;
      EXPECT_EQ(first, 60 - expected) << "the shadow ends at the wall's foot";
    }
  }
  // The light from the other side shadows the 17 px beyond the wall (columns 63..79): all of them.
  const HeightField f = Wall(wall, false);
  const HeightFieldMarch back = MakeHeightFieldMarch(f, Vec3d(-cos_a, 0, sin_a));
  int behind = 0;
  for (int x = 63; x < 80; ++x) behind += HeightFieldShadowed(f.heights_px.data(), back, x, 5);
  EXPECT_EQ(behind, 17);
  // Straight overhead: no march, nothing shadowed.
  EXPECT_EQ(MakeHeightFieldMarch(f, Vec3d(0, 0, 1)).steps, 0u);
}

TEST(HeightFieldShadow, BowlFromItsNormalMapShadowsWhatTheSphereDoes) {
  // A spherical pit (sphere radius 60 px, rim 50 px, 26.8 px deep) in a plate, integrated from
  // its normal map, under a light 20° above the image plane. Closed form: a pit point P facing the
  // light is in cast shadow when the ray towards it, which crosses the sphere's inside, leaves the
  // sphere below the plate (at Q = P + t L, t = -2 (P - C)·L, with h(Q) < 0). How deep the ray
  // passes under the true surface (its largest penetration, sampled every 0.05 px) says how near
  // the shadow's edge a pixel lies.
  const double cx = 60, cy = 58, r = 60, rim = 50;
  const AnalyticHeight pit = testing::PittedPlate(cx, cy, r, rim);
  const int w = 120, h = 116;
  const TexelAtlas atlas = AtlasOf(pit, w, h);
  auto field = IntegrateNormalMap(atlas, DiligentCamera(w, h));
  ASSERT_TRUE(field.ok()) << field.status().ToString();
  const double el = DegToRad(20), az = DegToRad(30);
  const Vec3d light(std::cos(el) * std::cos(az), std::cos(el) * std::sin(az), std::sin(el));
  const Vec3d l_img(light.x(), -light.y(), light.z());  // (column, row, height)
  const Vec3d centre(cx, cy, std::sqrt(r * r - rim * rim));
  const HeightFieldMarch march = MakeHeightFieldMarch(*field, light);
  int closed_form = 0, deep = 0, found = 0, wrong_far_from_edge = 0, closed_form_disagrees = 0;
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const Vec3d p(x, y, pit.height(x, y));
      const Vec2d g = pit.gradient(x, y);
      if (Vec3d(-g.x(), -g.y(), 1).dot(l_img) <= 0) continue;  // faces away: not a cast shadow
      bool shadowed = false;
      if (pit.height(x, y) < 0) {
        const double t = -2 * (p - centre).dot(l_img);
        shadowed = t > 0 && (p + t * l_img).z() < 0;
      }
      double penetration = -1e9;
      for (double t = 0.05;; t += 0.05) {
        const Vec3d q = p + t * l_img;
        if (q.x() < 0 || q.y() < 0 || q.x() > w - 1 || q.y() > h - 1 || q.z() > 0.5) break;
        penetration = std::max(penetration, pit.height(q.x(), q.y()) - q.z());
      }
      // The sampled penetration resolves the shadow's edge to its 0.05 px step.
      closed_form_disagrees += shadowed != (penetration > 0) && std::abs(penetration) > 0.02;
      const bool marched = HeightFieldShadowed(field->heights_px.data(), march, x, y);
      closed_form += shadowed;
      deep += penetration > kHeightFieldShadowBiasPx;
      found += marched;
      if (marched != shadowed &&
          std::abs(penetration) > kHeightFieldShadowBiasPx + kMarchErrorPx) {
        ++wrong_far_from_edge;
      }
    }
  }
  EXPECT_EQ(closed_form_disagrees, 0) << "the closed form and the sampled ray must agree";
  EXPECT_GT(closed_form, 2000) << "the scene must have a real shadow";
  EXPECT_EQ(wrong_far_from_edge, 0);
  // What the march must find: the shadow whose ray passes more than the bias under the surface.
  EXPECT_NEAR(found, deep, kShadowAreaTolerance * deep) << "closed form " << closed_form;
}

TEST(HeightFieldShadow, ConvexSurfacesNeverShadowThemselves) {
  // A sphere cap lit from every direction in front of its surface: a lit-facing texel (n·l > 0)
  // of a convex surface is never in cast shadow.
  const AnalyticHeight cap = testing::SphereCap(40, 40, 34, 33);
  const TexelAtlas atlas = AtlasOf(cap, 80, 80);
  auto field = IntegrateNormalMap(atlas, DiligentCamera(80, 80));
  ASSERT_TRUE(field.ok());
  for (int el = 5; el <= 85; el += 20) {
    for (int az = 0; az < 360; az += 45) {
      const Vec3d light(std::cos(DegToRad(el)) * std::cos(DegToRad(az)),
                        std::cos(DegToRad(el)) * std::sin(DegToRad(az)), std::sin(DegToRad(el)));
      const HeightFieldMarch march = MakeHeightFieldMarch(*field, light);
      int wrong = 0;
      for (size_t t = 0; t < atlas.TexelCount(); ++t) {
        int x, y;
        atlas.PixelOf(t, &x, &y);
        if (atlas.shading_normal[t].cast<double>().dot(light) <= 0) continue;
        wrong += HeightFieldShadowed(field->heights_px.data(), march, x, y);
      }
      EXPECT_EQ(wrong, 0) << "elevation " << el << ", azimuth " << az;
    }
  }
}

TEST(HeightFieldShadow, MarchIsBoundedAndSkipsBackground) {
  // A field wider than the march cap: the step count stays at kMaxHeightFieldMarchSteps.
  HeightField wide;
  wide.width = int(kMaxHeightFieldMarchSteps) + 100;
  wide.height = 1;
  wide.heights_px.assign(size_t(wide.width), 0.0f);
  EXPECT_EQ(MakeHeightFieldMarch(wide, Vec3d(1, 0, 0.1)).steps, kMaxHeightFieldMarchSteps);
  // A pillar outside the mask (background pixels between) still shadows; background never does.
  HeightField f;
  f.width = 20;
  f.height = 1;
  f.cam_from_world = Vec3d(1, -1, -1).asDiagonal();
  f.heights_px.assign(20, kHeightFieldOutside);
  f.heights_px[2] = 0;
  f.heights_px[10] = 30;
  const HeightFieldMarch m = MakeHeightFieldMarch(f, Vec3d(1, 0, 1));
  EXPECT_TRUE(HeightFieldShadowed(f.heights_px.data(), m, 2, 0));
  f.heights_px[10] = kHeightFieldOutside;
  f.heights_px[11] = 5;  // 9 px away, where the ray is 9 px high: below it
  EXPECT_FALSE(HeightFieldShadowed(f.heights_px.data(), MakeHeightFieldMarch(f, Vec3d(1, 0, 1)), 2, 0));
}

}  // namespace
}  // namespace reflcap
