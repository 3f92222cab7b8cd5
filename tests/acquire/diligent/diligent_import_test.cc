// `reflcap import-diligent` on a DiLiGenT-like folder made here (a Lambertian sphere under 8
// lights), and on the real objects in ../shared/data/diligent when present.
#include "acquire/diligent/diligent_import.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <sstream>

#include "engine/capture/capture.h"
#include "engine/core/atomic_file.h"
#include "engine/image/exr_io.h"
#include "engine/image/png_io.h"
#include "engine/mesh/texel_atlas.h"
#include "engine/texel/brdf_maps.h"
#include "render/reference/render_capture.h"
#include "tests/support/test_support.h"

namespace reflcap::diligent {
namespace {
namespace fs = std::filesystem;

// 16-bit photographs quantise to 1/65535; the renderer computes in float (~1e-7 relative of values
// <= 1): 0.5/65535 + 1e-6.
constexpr double kSixteenBitTolerance = 0.5 / 65535 + 1e-6;
// cos θ from float normals and directions.
constexpr double kCosTolerance = 1e-5;

constexpr int kSize = 41;
constexpr double kRadiusPx = 18;
const Vec3d kAlbedo(0.7, 0.5, 0.3);

// The DiLiGenT-frame normal (x right, y up, z towards the camera) of pixel (x, y), or zero off the
// sphere.
Vec3d SphereNormal(int x, int y) {
  const double c = 0.5 * (kSize - 1);
  const double nx = (x - c) / kRadiusPx, ny = -(y - c) / kRadiusPx, rr = nx * nx + ny * ny;
  if (rr >= 1) return Vec3d::Zero();
  return Vec3d(nx, ny, std::sqrt(1 - rr));
}

struct FakeObject {
  std::vector<Vec3d> directions, intensities;
};

// Writes a DiLiGenT-like object folder: Lambertian sphere, `lights` lights, 16-bit PNGs
// (pixel = I_c rho_c / pi max(0, n.l)). Light 0 points along the normal of pixel (27, 12).
FakeObject WriteFakeObject(const fs::path& dir, int lights) {
  FakeObject object;
  fs::create_directories(dir);
  std::ostringstream names, dirs, ints;
  for (int i = 0; i < lights; ++i) {
    const double a = 2 * kPi * i / lights;
    Vec3d l = i == 0 ? SphereNormal(27, 12).normalized()
                     : Vec3d(0.5 * std::cos(a), 0.5 * std::sin(a), 0.8).normalized();
    const Vec3d intensity(1.2 + 0.01 * i, 1.5, 2.0 - 0.02 * i);
    object.directions.push_back(l);
    object.intensities.push_back(intensity);
    char name[16];
    std::snprintf(name, sizeof name, "%03d.png", i + 1);
    names << name << "\n";
    char line[128];
    std::snprintf(line, sizeof line, "%.9f %.9f %.9f\n", l.x(), l.y(), l.z());
    dirs << line;
    std::snprintf(line, sizeof line, "%.4f %.4f %.4f\n", intensity.x(), intensity.y(), intensity.z());
    ints << line;
    Image photo(kSize, kSize, 3, 0.0f);
    for (int y = 0; y < kSize; ++y) {
      for (int x = 0; x < kSize; ++x) {
        const Vec3d n = SphereNormal(x, y);
        if (n.isZero()) continue;
        for (int c = 0; c < 3; ++c) {
          photo.at(x, y, c) = float(intensity[c] * kAlbedo[c] / kPi * std::max(0.0, n.dot(l)));
        }
      }
    }
    REFLCAP_CHECK(WritePng(dir / name, photo, 16).ok());
  }
  testing::WriteText(dir / "filenames.txt", names.str());
  testing::WriteText(dir / "light_directions.txt", dirs.str());
  testing::WriteText(dir / "light_intensities.txt", ints.str());
  Image normals(kSize, kSize, 3, 0.0f), mask(kSize, kSize, 3, 0.0f);
  for (int y = 0; y < kSize; ++y) {
    for (int x = 0; x < kSize; ++x) {
      const Vec3d n = SphereNormal(x, y);
      if (n.isZero()) continue;
      for (int c = 0; c < 3; ++c) {
        normals.at(x, y, c) = float(n[c]);
        mask.at(x, y, c) = 1;
      }
    }
  }
  REFLCAP_CHECK(WriteExr(dir / "normals.exr", normals).ok());
  REFLCAP_CHECK(WritePng(dir / "mask.png", mask).ok());
  return object;
}

TEST(ImportDiligent, SyntheticObjectGivesACaptureThatInfoValidates) {
  testing::ScratchDir dir;
  const FakeObject object = WriteFakeObject(dir / "sphere", 8);
  auto summary = ImportDiligent(dir / "sphere", dir / "capture", {});
  ASSERT_TRUE(summary.ok()) << summary.status().ToString();
  EXPECT_EQ(summary->object, "sphere");
  EXPECT_EQ(summary->lights, 8u);
  EXPECT_EQ(summary->images, 8u);
  EXPECT_EQ(summary->holdout, 2u);  // lights 4 and 8
  EXPECT_EQ(summary->mask_pixels, summary->normal_texels);

  auto capture = ReadCapture(dir / "capture");
  ASSERT_TRUE(capture.ok()) << capture.status().ToString();
  CaptureFilesReport files;
  ASSERT_TRUE(ValidateCaptureFiles(*capture, &files).ok());
  EXPECT_EQ(files.normal_map_texels, summary->mask_pixels);
  ASSERT_TRUE(capture->normal_map.has_value());
  ASSERT_EQ(capture->cameras.size(), 1u);
  const Camera& cam = capture->cameras[0];
  EXPECT_EQ(cam.model, CameraModel::kOrthographic);
  EXPECT_EQ(cam.pixel_size_m, kNominalPixelSizeM);
  // OpenCV camera: looks along world -z (DiLiGenT's z points at the viewer), image y = -world y.
  EXPECT_LT((cam.AxisInWorld() - Vec3d(0, 0, -1)).norm(), 1e-15);
  EXPECT_NEAR(cam.cam_from_world.rotation.determinant(), 1, 1e-15);
  EXPECT_FALSE(capture->turntable.has_value());
  for (size_t i = 0; i < capture->lights.size(); ++i) {
    const Light& light = capture->lights[i];
    EXPECT_EQ(light.type, LightType::kDirectional);
    EXPECT_LT((light.direction - object.directions[i]).norm(), 1e-8);
    EXPECT_LT((light.intensity - object.intensities[i]).norm(), 1e-12);
  }
  EXPECT_EQ(capture->images[3].split, Split::kHoldout);
  EXPECT_EQ(capture->images[2].split, Split::kTrain);
  EXPECT_EQ(capture->images[0].file, "images/001.exr");
  EXPECT_EQ(capture->images[0].exposure_s, 1.0);
  // The PNG's full scale clips: every photograph says so.
  for (const CaptureImage& image : capture->images) EXPECT_EQ(image.saturation, 1.0);
}

TEST(ImportDiligent, RenderingTheKnownAlbedoReproducesTheImages) {
  testing::ScratchDir dir;
  WriteFakeObject(dir / "sphere", 8);
  ASSERT_TRUE(ImportDiligent(dir / "sphere", dir / "capture", {}).ok());
  auto capture = ReadCapture(dir / "capture");
  ASSERT_TRUE(capture.ok());
  // The fit: Lambert with the known albedo, in the normal-map layout.
  auto normals = ReadExrRgb(dir / "capture/normals.exr");
  auto mask = ReadPng(dir / "capture/mask.png");
  ASSERT_TRUE(normals.ok() && mask.ok());
  auto atlas = BuildNormalMapAtlas(*normals, *mask);
  ASSERT_TRUE(atlas.ok());
  BrdfMaps maps;
  brdf::BrdfParams p;
  p.rho_d = {float(kAlbedo[0]), float(kAlbedo[1]), float(kAlbedo[2])};
  maps.texels.assign(atlas->TexelCount(), p);
  fs::create_directories(dir / "fit");
  ASSERT_TRUE(WriteBrdfMaps(dir / "fit/params.exr", maps, *atlas).ok());
  render::CaptureRenderOptions options;
  options.split = render::SplitSelection::kAll;
  auto rendered = render::RenderCapture(*capture, dir / "fit/params.exr", dir / "renders", options);
  ASSERT_TRUE(rendered.ok()) << rendered.status().ToString();
  double max_diff = 0;
  for (const CaptureImage& image : capture->images) {
    auto photo = ReadExrRgb(capture->Resolve(image.file));
    auto render = ReadExrRgb(dir / "renders" / render::RenderPathFor(image.file));
    ASSERT_TRUE(photo.ok() && render.ok());
    for (size_t i = 0; i < photo->data.size(); ++i) {
      max_diff = std::max(max_diff, std::abs(double(photo->data[i]) - render->data[i]));
    }
  }
  std::printf("imported Lambertian sphere: render from the known albedo vs 16-bit images: max "
              "|diff| %.3g (tolerance %.3g)\n", max_diff, kSixteenBitTolerance);
  EXPECT_LE(max_diff, kSixteenBitTolerance);
  // Frames: the centre pixel faces the camera (cos θo = 1); light 0 points along the normal of
  // pixel (27, 12) (cos θi = 1 there).
  std::vector<std::string> names;
  auto aux = ReadExrChannels(dir / "renders" / render::AuxPathFor(capture->images[0].file), &names);
  ASSERT_TRUE(aux.ok());
  ASSERT_EQ(names, render::AuxChannelNames());
  EXPECT_NEAR(aux->at(20, 20, render::kAuxCosThetaO), 1.0, kCosTolerance);
  EXPECT_NEAR(aux->at(27, 12, render::kAuxCosThetaI), 1.0, kCosTolerance);
}

TEST(ImportDiligent, ErrorsNameTheFileAndLine) {
  testing::ScratchDir dir;
  WriteFakeObject(dir / "sphere", 4);
  testing::WriteText(dir / "sphere/light_directions.txt", "0 0 1\n0 0 1\n0 1\n0 0 1\n");
  auto r = ImportDiligent(dir / "sphere", dir / "out1", {});
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("light_directions.txt:3: expected 3 numbers, got 2"),
            std::string::npos) << r.status().message();
  testing::WriteText(dir / "sphere/light_directions.txt", "0 0 1\n0 0 1\n0 0 1\n");
  r = ImportDiligent(dir / "sphere", dir / "out2", {});
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(r.status().message().find("light_directions.txt: 3 lights"), std::string::npos)
      << r.status().message();
  testing::WriteText(dir / "sphere/light_directions.txt", "0 0 1\n0 0 1\n0 0 1\n0 0 1\n");
  testing::WriteText(dir / "sphere/light_intensities.txt", "1 1 1\n1 x 1\n1 1 1\n1 1 1\n");
  r = ImportDiligent(dir / "sphere", dir / "out3", {});
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("light_intensities.txt:2: \"x\""), std::string::npos)
      << r.status().message();
  testing::WriteText(dir / "sphere/light_intensities.txt", "1 1 1\n1 1 1\n1 1 1\n1 1 1\n");
  fs::remove(dir / "sphere/normals.exr");
  r = ImportDiligent(dir / "sphere", dir / "out4", {});
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), StatusCode::kNotFound);
  EXPECT_NE(r.status().message().find("normals.exr"), std::string::npos) << r.status().message();
  ImportOptions bad;
  bad.holdout_every = 1;
  EXPECT_EQ(ImportDiligent(dir / "sphere", dir / "out5", bad).status().code(),
            StatusCode::kInvalidArgument);
}

TEST(ImportDiligent, BearLeavesOutItsFirstTwentyImages) {
  testing::ScratchDir dir;
  WriteFakeObject(dir / "bear", 24);
  auto summary = ImportDiligent(dir / "bear", dir / "capture", {});
  ASSERT_TRUE(summary.ok()) << summary.status().ToString();
  EXPECT_EQ(summary->lights, 24u);
  EXPECT_EQ(summary->images, 4u);   // 21..24
  EXPECT_EQ(summary->holdout, 1u);  // 24
  EXPECT_EQ(summary->excluded.size(), 20u);
  auto capture = ReadCapture(dir / "capture");
  ASSERT_TRUE(capture.ok());
  EXPECT_EQ(capture->images[0].file, "images/021.exr");
  EXPECT_EQ(capture->lights[size_t(capture->images[0].light)].id, "L021");
}

// The real data: counts, and that the frames agree with the photographs — in a Lambertian-ish
// object the pixel / intensity correlates with max(0, n . l) computed in our frames.
TEST(ImportDiligent, RealObjectsImportWithTheirCountsAndFrames) {
  const auto shared = testing::SharedDataDir();
  if (!shared || !fs::is_directory(*shared / "diligent")) {
    GTEST_SKIP() << "../shared/data/diligent is absent: skipping the real DiLiGenT import";
  }
  testing::ScratchDir dir;
  // ball16 is the smallest (158 x 158, 16-bit); bear checks the exclusion.
  for (const char* name : {"ball16", "bear"}) {
    auto summary = ImportDiligent(*shared / "diligent" / name, dir / name, {});
    ASSERT_TRUE(summary.ok()) << summary.status().ToString();
    const bool bear = std::string(name) == "bear";
    EXPECT_EQ(summary->lights, 96u);
    EXPECT_EQ(summary->images, bear ? 76u : 96u);
    EXPECT_EQ(summary->holdout, bear ? 19u : 24u);
    auto capture = ReadCapture(dir / name);
    ASSERT_TRUE(capture.ok());
    CaptureFilesReport files;
    ASSERT_TRUE(ValidateCaptureFiles(*capture, &files).ok());
    EXPECT_GT(files.normal_map_texels, 1000u);
    std::printf("DiLiGenT %s: %dx%d, %zu texels, %zu images (holdout %zu)\n", name, summary->width,
                summary->height, summary->normal_texels, summary->images, summary->holdout);
    if (bear) continue;
    // ball16: correlation of pixel / intensity with max(0, n . l) over lit mask pixels, per image.
    auto normals = ReadExrRgb(dir / name / "normals.exr");
    auto mask = ReadPng(dir / name / "mask.png");
    ASSERT_TRUE(normals.ok() && mask.ok());
    double worst = 1;
    for (size_t k = 0; k < capture->images.size(); k += 8) {
      const CaptureImage& image = capture->images[k];
      const Light& light = capture->lights[size_t(image.light)];
      auto photo = ReadExrRgb(capture->Resolve(image.file));
      ASSERT_TRUE(photo.ok());
      double sx = 0, sy = 0, sxx = 0, syy = 0, sxy = 0, n = 0;
      for (int y = 0; y < photo->height; ++y) {
        for (int x = 0; x < photo->width; ++x) {
          if (mask->at(x, y, 0) < 0.5f) continue;
          const Vec3d nrm(normals->at(x, y, 0), normals->at(x, y, 1), normals->at(x, y, 2));
          const double a = std::max(0.0, nrm.dot(light.direction));
          const double b = photo->at(x, y, 1) / light.intensity[1];
          sx += a, sy += b, sxx += a * a, syy += b * b, sxy += a * b, n += 1;
        }
      }
      const double corr = (sxy - sx * sy / n) /
                          std::sqrt((sxx - sx * sx / n) * (syy - sy * sy / n));
      worst = std::min(worst, corr);
    }
    std::printf("ball16: worst correlation of pixel/intensity with max(0, n.l): %.3f\n", worst);
    EXPECT_GT(worst, 0.8) << "normals, lights and image rows disagree on the frame";
  }
}

}  // namespace
}  // namespace reflcap::diligent
