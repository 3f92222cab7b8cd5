// What the render adds to a normal-map capture's direct light: the room's stray light
// (render/reference/stray_light.h) and the photographs' point spread (point_spread.h) — each
// estimated from the train photographs, with its evidence, and the render that applies it.
#include "render/reference/point_spread.h"
#include "render/reference/stray_light.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>

#include <nlohmann/json.hpp>

#include "engine/capture/capture.h"
#include "engine/core/atomic_file.h"
#include "engine/image/exr_io.h"
#include "engine/image/png_io.h"
#include "engine/mesh/height_field.h"
#include "engine/mesh/texel_atlas.h"
#include "engine/texel/brdf_maps.h"
#include "render/reference/render_capture.h"
#include "tests/support/height_scenes.h"
#include "tests/support/test_support.h"

namespace reflcap::render {
namespace {
namespace fs = std::filesystem;

// The room's light in the synthetic photographs: s_c(t) = ρ_c(t) · (e_c · (1, n)), positive for
// every unit normal (the constant exceeds the linear terms' norm), so the environment model of
// stray_light.h holds exactly and both of its estimates can be checked against the truth.
constexpr double kEnvironment[3][4] = {{0.060, 0.010, -0.020, 0.020},
                                       {0.050, -0.015, 0.010, 0.015},
                                       {0.040, 0.005, 0.015, -0.010}};
// Photograph noise (standard deviation, in the photographs' units; lit pixels read ~0.1). The
// faintest stray value, w · s = 0.4 (lamp × exposure) × 0.3 (albedo) × 0.021 (the environment's
// minimum) = 0.0025, then has 0.8 % noise per observation.
constexpr double kNoise = 2e-5;
// A texel's own estimate: least squares over ≥ 2 observations of ≤ 0.8 % noise each — 5 % is
// more than 6σ of the faintest texel's.
constexpr double kOwnRelTolerance = 0.05;
// The environment model: fitted over ~1000 texels' own estimates, so their noise averages out;
// what is left is the ridge (1e-6, negligible). 1 %.
constexpr double kModelRelTolerance = 0.01;

double StrayTruth(const brdf::BrdfParams& p, const Vec3f& n, int c) {
  const double* e = kEnvironment[c];
  return p.rho_d[size_t(c)] * (e[0] + e[1] * n.x() + e[2] * n.y() + e[3] * n.z());
}

struct BallCapture {
  testing::ScratchDir dir;
  Capture capture;
  TexelAtlas atlas;
  BrdfMaps maps;
  fs::path params;
};

// A textured Lambertian sphere cap (normals up to 75° from the view) under 12 directional lights
// of elevations 5–40° around it, every third held out: each light leaves the cap's far side
// unlit, and the texels near its centre face every light (the environment model's). The
// photographs are direct-light renders of the known albedo plus, with `stray`, exposure · I · s,
// plus noise; with `psf_sigma_px` > 0 blurred by that point spread (before the noise).
void MakeBallCapture(BallCapture* b, bool stray, double psf_sigma_px = 0) {
  const int w = 64, h = 60;
  Image normals, mask;
  testing::NormalMapOf(testing::SphereCap(31.5, 29.5, 28, 27), w, h, &normals, &mask);
  auto atlas = BuildNormalMapAtlas(normals, mask);
  ASSERT_TRUE(atlas.ok());
  b->atlas = std::move(*atlas);
  Capture& capture = b->capture;
  capture.json_path = b->dir / "capture.json";
  capture.normal_map = NormalMapGeometry{0, "normals.exr", "mask.png"};
  capture.cameras.push_back(testing::DiligentCamera(w, h));
  b->maps.texels.resize(b->atlas.TexelCount());
  for (size_t t = 0; t < b->atlas.TexelCount(); ++t) {
    int x, y;
    b->atlas.PixelOf(t, &x, &y);
    const float stripe = ((x / 5 + y / 7) % 2) ? 0.25f : 0.0f;
    b->maps.texels[t].rho_d = {0.35f + stripe, 0.45f, 0.55f - stripe};
  }
  b->params = b->dir / "fit/params.exr";
  fs::create_directories(b->dir / "fit");
  ASSERT_TRUE(WriteBrdfMaps(b->params, b->maps, b->atlas).ok());
  fs::create_directories(b->dir / "images");
  for (int l = 0; l < 12; ++l) {
    Light light;
    light.id = StrCat("L", l);
    light.type = LightType::kDirectional;
    const double az = DegToRad(30.0 * l), el = DegToRad(5 + 35.0 * (l % 4) / 3);
    light.direction = Vec3d(std::cos(el) * std::cos(az), std::cos(el) * std::sin(az), std::sin(el));
    light.intensity = Vec3d(0.8 + 0.05 * l, 1.0, 1.2 - 0.03 * l);
    capture.lights.push_back(light);
    CaptureImage image;
    image.file = StrCat("images/", l, ".exr");
    image.light = l;
    image.exposure_s = 0.5 + 0.1 * (l % 3);
    image.split = l % 3 == 2 ? Split::kHoldout : Split::kTrain;
    capture.images.push_back(image);
  }
  ASSERT_TRUE(WriteExr(b->dir / "normals.exr", normals).ok());
  ASSERT_TRUE(WritePng(b->dir / "mask.png", mask).ok());
  ASSERT_TRUE(WriteCapture(capture, capture.json_path).ok());
  // The photographs: the renderer's direct light (its own shadows) + stray light + noise.
  auto fitted = LoadFittedCapture(capture, b->params);
  ASSERT_TRUE(fitted.ok()) << fitted.status().ToString();
  std::mt19937 rng(7);
  std::normal_distribution<double> noise(0.0, kNoise);
  for (size_t i = 0; i < capture.images.size(); ++i) {
    auto direct = RenderCaptureImage(**fitted, i, RenderOptions{});
    ASSERT_TRUE(direct.ok()) << direct.status().ToString();
    Image photo = direct->pixels;
    const CaptureImage& image = capture.images[i];
    const Vec3d lamp = image.exposure_s * capture.lights[image.light].intensity;
    for (size_t t = 0; t < b->atlas.TexelCount() && stray; ++t) {
      int x, y;
      b->atlas.PixelOf(t, &x, &y);
      for (int c = 0; c < 3; ++c) {
        photo.at(x, y, c) +=
            float(lamp[c] * StrayTruth(b->maps.texels[t], b->atlas.shading_normal[t], c));
      }
    }
    if (psf_sigma_px > 0) BlurWithinMask(direct->mask, psf_sigma_px, &photo);
    for (size_t t = 0; t < b->atlas.TexelCount(); ++t) {
      int x, y;
      b->atlas.PixelOf(t, &x, &y);
      for (int c = 0; c < 3; ++c) photo.at(x, y, c) += float(noise(rng));
    }
    ASSERT_TRUE(WriteExr(capture.Resolve(image.file), photo, ExrPixelType::kFloat).ok());
  }
}

TEST(StrayLight, EstimatesEachTexelsOwnAndTheEnvironmentsLight) {
  BallCapture b;
  MakeBallCapture(&b, /*stray=*/true);
  auto fitted = LoadFittedCapture(b.capture, b.params);
  ASSERT_TRUE(fitted.ok());
  const StrayLight stray = EstimateStrayLight(**fitted, true);
  std::printf("stray light: %d images, %zu observations, %zu own, %zu modelled, error "
              "reduction %.4f\n", stray.images, stray.observations, stray.observed_texels,
              stray.modelled_texels, stray.error_reduction);
  EXPECT_EQ(stray.images, 8);  // the train split
  EXPECT_EQ(stray.skipped, 0);
  ASSERT_GE(stray.observed_texels, size_t(500)) << "the scene leaves too few texels unlit";
  ASSERT_GE(stray.modelled_texels, size_t(200)) << "every texel is unlit somewhere";
  EXPECT_TRUE(stray.shows);
  // Held-out folds: only the noise is left (1 % of each observation).
  EXPECT_GT(stray.error_reduction, 0.98);
  for (int c = 0; c < 3; ++c) {
    for (int k = 0; k < 4; ++k) {
      EXPECT_NEAR(stray.environment[size_t(c)][size_t(k)], kEnvironment[c][k],
                  kModelRelTolerance * kEnvironment[c][0])
          << "channel " << c << ", term " << k;
    }
  }
  double worst_own = 0, worst_model = 0;
  for (size_t t = 0; t < b.atlas.TexelCount(); ++t) {
    for (int c = 0; c < 3; ++c) {
      const double truth = StrayTruth(b.maps.texels[t], b.atlas.shading_normal[t], c);
      const double rel = std::abs(stray.per_intensity[t][c] - truth) / truth;
      // A texel with its own estimate differs from the model's value by its noise; the
      // modelled ones equal the model. Which is which is not reported per texel: the bound
      // for the own estimates covers both.
      worst_own = std::max(worst_own, rel);
      const double* e = stray.environment[size_t(c)].data();
      const Vec3f& n = b.atlas.shading_normal[t];
      const double model = b.maps.texels[t].rho_d[size_t(c)] *
                           (e[0] + e[1] * n.x() + e[2] * n.y() + e[3] * n.z());
      if (std::abs(stray.per_intensity[t][c] - model) < 1e-7) {
        worst_model = std::max(worst_model, rel);
      }
    }
  }
  std::printf("worst relative error: %.4f (any texel), %.4f (modelled)\n", worst_own,
              worst_model);
  EXPECT_LT(worst_own, kOwnRelTolerance);
  EXPECT_LT(worst_model, kModelRelTolerance);
}

TEST(StrayLight, PhotographsWithoutItShowNone) {
  BallCapture b;
  MakeBallCapture(&b, /*stray=*/false);
  auto fitted = LoadFittedCapture(b.capture, b.params);
  ASSERT_TRUE(fitted.ok());
  const StrayLight stray = EstimateStrayLight(**fitted, true);
  std::printf("no stray light: %zu observations, error reduction %.4f\n", stray.observations,
              stray.error_reduction);
  EXPECT_GE(stray.observations, kMinStrayEvidenceObservations);
  EXPECT_FALSE(stray.shows);
  // Predicting noise about 0 from the other fold's noise removes none of it.
  EXPECT_LT(stray.error_reduction, 0.05);
}

// `--indirect auto` adds the stray light when the photographs show it, and the holdout renders of
// the true albedo then reproduce the held-out photographs to their noise; `off` leaves it out.
TEST(StrayLight, TheRenderAddsItWhereThePhotographsShowIt) {
  BallCapture b;
  MakeBallCapture(&b, /*stray=*/true);
  for (IndirectMode mode : {IndirectMode::kAuto, IndirectMode::kOff}) {
    CaptureRenderOptions options;
    options.indirect = mode;
    const fs::path out = b.dir / StrCat("render_", IndirectModeName(mode));
    ASSERT_TRUE(RenderCapture(b.capture, b.params, out, options).ok());
    const auto report = nlohmann::json::parse(ReadTextFile(out / "render_report.json").value());
    EXPECT_EQ(report["indirect"]["kind"], "stray_light");
    EXPECT_EQ(report["indirect"]["used"], mode == IndirectMode::kAuto);
    double worst = 0;
    for (const CaptureImage& image : b.capture.images) {
      if (image.split != Split::kHoldout) continue;
      auto photo = ReadExrRgb(b.capture.Resolve(image.file));
      auto rendered = ReadExrRgb(out / RenderPathFor(image.file));
      ASSERT_TRUE(photo.ok() && rendered.ok());
      for (size_t t = 0; t < b.atlas.TexelCount(); ++t) {
        int x, y;
        b.atlas.PixelOf(t, &x, &y);
        for (int c = 0; c < 3; ++c) {
          worst = std::max(worst, double(std::abs(photo->at(x, y, c) - rendered->at(x, y, c))));
        }
      }
    }
    std::printf("%s: worst held-out pixel error %.5f\n", IndirectModeName(mode), worst);
    if (mode == IndirectMode::kAuto) {
      // Noise (≤ 5σ over these pixels) plus the estimate's error (≤ 5 % of ≤ 0.05 · 1.3).
      EXPECT_LT(worst, 5 * kNoise + kOwnRelTolerance * 0.05 * 1.3);
    } else {
      EXPECT_GT(worst, 0.02) << "without the stray light the renders miss it";
    }
  }
}

// Normalised convolution: a constant stays that constant inside the mask up to its border, and
// nothing crosses the border either way.
TEST(PointSpread, BlurKeepsAConstantAndLeaksNothingAcrossTheMask) {
  const int w = 40, h = 30;
  Image mask(w, h, 1, 0.0f), pixels(w, h, 3, 100.0f);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w / 2; ++x) {
      mask.at(x, y) = 1;
      for (int c = 0; c < 3; ++c) pixels.at(x, y, c) = 2.0f + float(c);
    }
  }
  BlurWithinMask(mask, 1.3, &pixels);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      for (int c = 0; c < 3; ++c) {
        const float expected = x < w / 2 ? 2.0f + float(c) : 100.0f;
        ASSERT_NEAR(pixels.at(x, y, c), expected, 1e-5) << x << "," << y;
      }
    }
  }
}

// Inside a full mask the blur of one bright pixel is the Gaussian: neighbours in the ratio
// exp(-d² / 2σ²) to the centre, and the light is conserved (the weights sum to 1 away from the
// image's border).
TEST(PointSpread, BlurOfAPointIsTheGaussian) {
  const int w = 31, h = 31;
  const double sigma = 0.7;
  Image mask(w, h, 1, 1.0f), pixels(w, h, 1, 0.0f);
  pixels.at(15, 15) = 1;
  BlurWithinMask(mask, sigma, &pixels);
  const double centre = pixels.at(15, 15);
  EXPECT_NEAR(pixels.at(16, 15) / centre, std::exp(-1 / (2 * sigma * sigma)), 1e-6);
  EXPECT_NEAR(pixels.at(16, 17) / centre, std::exp(-5 / (2 * sigma * sigma)), 1e-6);
  EXPECT_EQ(pixels.at(15 + 4, 15), 0.0f) << "beyond 3 sigma (2.1 px -> 3 taps) nothing";
  double sum = 0;
  for (float v : pixels.data) sum += v;
  EXPECT_NEAR(sum, 1.0, 1e-6);
}

// The auto decision finds the spread the photographs were made with (among the candidates) and
// none in sharp photographs; the render then reproduces the held-out blurred photographs.
TEST(PointSpread, TheEvidenceFindsThePhotographsSpread) {
  constexpr double kTrueSigma = 0.7;  // one of kPsfCandidatesPx
  BallCapture sharp, blurred;
  MakeBallCapture(&sharp, /*stray=*/false);
  MakeBallCapture(&blurred, /*stray=*/false, kTrueSigma);
  auto sharp_fit = LoadFittedCapture(sharp.capture, sharp.params);
  auto blurred_fit = LoadFittedCapture(blurred.capture, blurred.params);
  ASSERT_TRUE(sharp_fit.ok() && blurred_fit.ok());
  const PsfEvidence none = MeasurePsfEvidence(**sharp_fit, true, nullptr);
  const PsfEvidence found = MeasurePsfEvidence(**blurred_fit, true, nullptr);
  std::printf("sharp photographs: sigma %.2f, reduction %.4f; blurred (%.2f px): sigma %.2f, "
              "reduction %.4f\n", none.sigma_px, none.reduction, kTrueSigma, found.sigma_px,
              found.reduction);
  EXPECT_EQ(none.sigma_px, 0.0);
  EXPECT_LT(none.reduction, kMinPsfErrorReduction);
  EXPECT_EQ(found.images, kPsfEvidenceImages);
  EXPECT_EQ(found.sigma_px, kTrueSigma);
  // What is left is the noise: the sharp render's error is the blur's (terminator, shadow edges).
  EXPECT_GT(found.reduction, 0.9);

  CaptureRenderOptions options;
  ASSERT_TRUE(RenderCapture(blurred.capture, blurred.params, blurred.dir / "render", options).ok());
  const auto report =
      nlohmann::json::parse(ReadTextFile(blurred.dir / "render/render_report.json").value());
  EXPECT_EQ(report["pixel_model"]["psf"]["sigma_px"], kTrueSigma);
  double worst = 0;
  for (const CaptureImage& image : blurred.capture.images) {
    if (image.split != Split::kHoldout) continue;
    auto photo = ReadExrRgb(blurred.capture.Resolve(image.file));
    auto rendered = ReadExrRgb(blurred.dir / "render" / RenderPathFor(image.file));
    ASSERT_TRUE(photo.ok() && rendered.ok());
    for (size_t i = 0; i < photo->data.size(); ++i) {
      worst = std::max(worst, double(std::abs(photo->data[i] - rendered->data[i])));
    }
  }
  std::printf("worst held-out pixel error with the found spread: %.6f\n", worst);
  EXPECT_LT(worst, 6 * kNoise);  // the photographs' noise only (6σ over ~10^4 values)
}

// The render's height field (HeightFieldChoice::kAuto): a flat plate whose normal map says, in
// its top quarter of rows only, that the right half stands kShelfStepPx higher — not integrable.
// Least squares lifts the right half of those rows by most of the step (and the rest a little):
// under light from the right it casts shadows to the left of the step; L1 keeps the plate flat.
// Photographs rendered with either field's shadows choose that field.
TEST(HeightFieldChoice, TheTrainPhotographsPickTheFieldWhoseShadowsTheyShow) {
  constexpr double kShelfStepPx = 4.0;
  constexpr int kW = 64, kH = 48, kColumn = 32;
  testing::AnalyticHeight shelf;
  shelf.inside = [](double, double) { return true; };
  shelf.height = [](double, double) { return 0.0; };
  shelf.gradient = [](double u, double v) {
    return Vec2d(int(u) == kColumn && v < kH / 4 ? kShelfStepPx : 0.0, 0.0);
  };
  for (const bool truth_l1 : {true, false}) {
    testing::ScratchDir dir;
    Image normals, mask;
    testing::NormalMapOf(shelf, kW, kH, &normals, &mask);
    auto atlas = BuildNormalMapAtlas(normals, mask);
    ASSERT_TRUE(atlas.ok());
    Capture capture;
    capture.json_path = dir / "capture.json";
    capture.normal_map = NormalMapGeometry{0, "normals.exr", "mask.png"};
    capture.cameras.push_back(testing::DiligentCamera(kW, kH));
    BrdfMaps maps;
    brdf::BrdfParams p;
    p.rho_d = {0.5f, 0.5f, 0.5f};
    maps.texels.assign(atlas->TexelCount(), p);
    fs::create_directories(dir / "fit");
    fs::create_directories(dir / "images");
    ASSERT_TRUE(WriteBrdfMaps(dir / "fit/params.exr", maps, *atlas).ok());
    ASSERT_TRUE(WriteExr(dir / "normals.exr", normals).ok());
    ASSERT_TRUE(WritePng(dir / "mask.png", mask).ok());
    HeightFieldOptions truth_options;
    truth_options.integration =
        truth_l1 ? HeightFieldIntegration::kL1 : HeightFieldIntegration::kLeastSquares;
    auto truth = IntegrateNormalMap(*atlas, capture.cameras[0], truth_options);
    ASSERT_TRUE(truth.ok());
    for (int l = 0; l < 10; ++l) {
      Light light;
      light.id = StrCat("L", l);
      light.type = LightType::kDirectional;
      // From the right (+x, the image's +u), low: the raised right half shadows the left.
      const double az = DegToRad(-20 + 4.0 * l), el = DegToRad(10 + 1.5 * l);
      light.direction = Vec3d(std::cos(el) * std::cos(az), std::cos(el) * std::sin(az), std::sin(el));
      capture.lights.push_back(light);
      CaptureImage image;
      image.file = StrCat("images/", l, ".exr");
      image.light = l;
      image.split = l % 5 == 4 ? Split::kHoldout : Split::kTrain;
      capture.images.push_back(image);
      auto photo = RenderNormalMapImage(*atlas, maps, capture.cameras[0], light, 1.0,
                                        RenderOptions{}, &*truth);
      ASSERT_TRUE(photo.ok());
      ASSERT_TRUE(WriteExr(dir / image.file, photo->pixels, ExrPixelType::kFloat).ok());
    }
    ASSERT_TRUE(WriteCapture(capture, capture.json_path).ok());
    auto fitted = LoadFittedCapture(capture, dir / "fit/params.exr");
    ASSERT_TRUE(fitted.ok());
    HeightFieldOptions l1_options;
    l1_options.integration = HeightFieldIntegration::kL1;
    auto l1_field = IntegrateNormalMap(*atlas, capture.cameras[0], l1_options);
    ASSERT_TRUE(l1_field.ok());
    const HeightFieldEvidence evidence = MeasureHeightFieldEvidence(**fitted, *l1_field);
    std::printf("photographs with %s shadows: %zu pixels of differing shadow, reduction %.3f\n",
                truth_l1 ? "L1" : "least-squares", evidence.pixels_differing, evidence.reduction);
    EXPECT_GE(evidence.pixels_differing, kMinHeightFieldEvidencePixels);
    EXPECT_EQ(evidence.l1, truth_l1);
    // The photographs are one field's renders: where the shadows differ, that field's render
    // is exact and the other's is all error.
    if (truth_l1) {
      EXPECT_EQ(evidence.error_l1, 0.0);
      EXPECT_NEAR(evidence.reduction, 1.0, 1e-12);
    } else {
      EXPECT_EQ(evidence.error_ls, 0.0);
      EXPECT_GT(evidence.error_l1, 0.0);
      EXPECT_LE(evidence.reduction, 0.0);
    }

    CaptureRenderOptions options;
    ASSERT_TRUE(RenderCapture(capture, dir / "fit/params.exr", dir / "render", options).ok());
    const auto report =
        nlohmann::json::parse(ReadTextFile(dir / "render/render_report.json").value());
    EXPECT_EQ(report["height_field"]["mode"], "auto");
    EXPECT_EQ(report["height_field"]["integration"], truth_l1 ? "l1" : "ls");
  }
}

}  // namespace
}  // namespace reflcap::render
