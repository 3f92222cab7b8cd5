#include "acquire/synth/synth.h"

#include <gtest/gtest.h>

#include <cmath>
#include <map>

#include <nlohmann/json.hpp>

#include "engine/capture/capture.h"
#include "engine/image/exr_io.h"
#include "engine/mesh/ray_scene.h"
#include "engine/mesh/texel_atlas.h"
#include "tests/support/test_support.h"

namespace reflcap::synth {
namespace {
namespace fs = std::filesystem;

SynthOptions TinyOptions() {
  SynthOptions o;
  o.texels = 4000;
  o.image_size = 64;
  o.cameras = 2;
  o.lights = 4;
  o.steps = 4;
  return o;
}

TEST(ReliefObject, IsClosedAndFullyUvMapped) {
  const TriangleMesh mesh = MakeReliefObject(12, 1);
  // Every undirected edge is shared by exactly two triangles: the welded cube-sphere is closed.
  std::map<std::pair<uint32_t, uint32_t>, int> edges;
  for (const auto& t : mesh.triangles) {
    for (int k = 0; k < 3; ++k) {
      const uint32_t a = t[k], b = t[(k + 1) % 3];
      edges[{std::min(a, b), std::max(a, b)}]++;
    }
  }
  for (const auto& [edge, count] : edges) ASSERT_EQ(count, 2);
  for (const auto& uvs : mesh.corner_uvs) {
    for (const auto& uv : uvs) {
      EXPECT_GE(uv.minCoeff(), 0.0f);
      EXPECT_LE(uv.maxCoeff(), 1.0f);
    }
  }
  EXPECT_NEAR(mesh.Bounds().min().z(), 0.0f, 1e-6f) << "rests on the turntable plane";
}

TEST(ReliefObject, CastsShadowsOnItself) {
  const TriangleMesh mesh = MakeReliefObject(24, 1);
  auto scene = RayScene::Create(mesh);
  ASSERT_TRUE(scene.ok());
  auto atlas = BuildTexelAtlas(mesh, 96, 96);
  ASSERT_TRUE(atlas.ok());
  // Texels facing a low light whose ray to it is blocked by the object itself.
  const Vec3f light(1.0f, 0.2f, 0.3f);
  int facing = 0, shadowed = 0;
  for (size_t t = 0; t < atlas->TexelCount(); ++t) {
    const Vec3f p = atlas->position[t];
    const Vec3f to_light = light - p;
    const Vec3f wi = to_light.normalized();
    if (atlas->geometric_normal[t].dot(wi) <= 0.1f) continue;
    ++facing;
    shadowed += (*scene)->Occluded(p + (*scene)->SurfaceOffset() * atlas->geometric_normal[t], wi,
                                   0, to_light.norm());
  }
  EXPECT_GT(shadowed, facing / 100) << shadowed << " of " << facing << " facing texels";
}

TEST(Synth, WritesAValidCaptureWithGroundTruthAndHoldout) {
  testing::ScratchDir dir;
  auto summary = WriteSyntheticCapture(TinyOptions(), dir.path());
  ASSERT_TRUE(summary.ok()) << summary.status().ToString();
  auto capture = ReadCapture(dir / "capture.json");
  ASSERT_TRUE(capture.ok()) << capture.status().ToString();
  CaptureFilesReport report;
  ASSERT_TRUE(ValidateCaptureFiles(*capture, &report).ok());
  EXPECT_EQ(capture->images.size(), 2u * 4u * 4u);
  EXPECT_GT(capture->CountSplit(Split::kHoldout), 0u);
  EXPECT_GT(capture->CountSplit(Split::kTrain), capture->CountSplit(Split::kHoldout));
  EXPECT_GE(summary->texels, 3000u);
  const auto truth = nlohmann::json::parse(capture->ground_truth_json);
  EXPECT_EQ(truth["params"]["file"], "gt/params.exr");
  EXPECT_EQ(truth["materials"]["list"].size(), 6u);
  for (const auto& m : truth["materials"]["list"]) EXPECT_GT(m["texels"].get<int>(), 0) << m;
  std::vector<std::string> names;
  auto params = ReadExrChannels(dir / "gt/params.exr", &names);
  ASSERT_TRUE(params.ok());
  EXPECT_EQ(params->width, summary->atlas_resolution);
  EXPECT_TRUE(fs::exists(dir / "masks/cam1_090.png"));
}

// The sample variance of (noisy - clean) matches the noise model to this relative tolerance:
// thousands of lit pixels give a standard error of a few percent.
constexpr double kNoiseVarianceTolerance = 0.1;

TEST(Synth, NoiseFollowsThePhotonPlusReadModel) {
  testing::ScratchDir clean_dir, noisy_dir;
  SynthOptions o = TinyOptions();
  o.noise = 0;
  ASSERT_TRUE(WriteSyntheticCapture(o, clean_dir.path()).ok());
  o.noise = 0.05;
  ASSERT_TRUE(WriteSyntheticCapture(o, noisy_dir.path()).ok());
  double sum_sq = 0, expected = 0;
  size_t n = 0;
  for (const char* name : {"images/0000.exr", "images/0001.exr", "images/0002.exr", "images/0005.exr"}) {
    auto clean = ReadExrRgb(clean_dir / name);
    auto noisy = ReadExrRgb(noisy_dir / name);
    ASSERT_TRUE(clean.ok() && noisy.ok());
    for (size_t i = 0; i < clean->data.size(); ++i) {
      const double v = clean->data[i];
      if (v <= 0.01) continue;
      const double d = noisy->data[i] - v;
      sum_sq += d * d;
      expected += o.noise * o.noise * v + std::pow(kReadNoiseRatio * o.noise, 2);
      ++n;
    }
  }
  ASSERT_GT(n, 1000u);
  EXPECT_NEAR(sum_sq / expected, 1.0, kNoiseVarianceTolerance);
}

TEST(Synth, SaturationClipsAndIsRecorded) {
  testing::ScratchDir dir;
  SynthOptions o = TinyOptions();
  o.saturation = 0.05;
  ASSERT_TRUE(WriteSyntheticCapture(o, dir.path()).ok());
  auto capture = ReadCapture(dir / "capture.json");
  ASSERT_TRUE(capture.ok());
  EXPECT_DOUBLE_EQ(capture->images[0].saturation, 0.05);
  auto image = ReadExrRgb(dir / "images/0000.exr");
  ASSERT_TRUE(image.ok());
  for (float v : image->data) ASSERT_LE(v, 0.05f);
}

TEST(Synth, RejectsBadOptions) {
  SynthOptions o;
  o.preset = "huge";
  EXPECT_FALSE(o.Validate().ok());
  o = SynthOptions();
  o.noise = -1;
  EXPECT_FALSE(o.Validate().ok());
  o = SynthOptions();
  o.supersampling = 99;
  EXPECT_FALSE(o.Validate().ok());
  for (const double footprint : {0.5, 4.5, std::nan("")}) {
    o = SynthOptions();
    o.pixel_footprint = footprint;
    const Status bad_footprint = o.Validate();
    EXPECT_NE(bad_footprint.message().find("--pixel-footprint"), std::string::npos)
        << footprint << ": " << bad_footprint.message();
  }
  o = SynthOptions();
  o.materials = {"glossy", "velvet"};
  const Status bad_material = o.Validate();
  EXPECT_FALSE(bad_material.ok());
  EXPECT_NE(bad_material.message().find("velvet"), std::string::npos) << bad_material.message();
}

TEST(Synth, MaterialsSubsetIsAllTheObjectIsMadeOf) {
  testing::ScratchDir dir;
  SynthOptions o = TinyOptions();
  o.steps = 1;
  o.lights = 1;
  o.materials = {"matte", "coloured_texture"};
  auto summary = WriteSyntheticCapture(o, dir / "c");
  ASSERT_TRUE(summary.ok()) << summary.status().ToString();
  std::vector<std::string> names;
  auto material = ReadExrChannels(dir / "c" / "gt" / "material.exr", &names);
  ASSERT_TRUE(material.ok()) << material.status().ToString();
  // Material ids are 1-based in kSynthMaterialNames order (0 = no texel): matte 1, texture 5.
  std::map<int, size_t> seen;
  for (size_t p = 0; p < material->PixelCount(); ++p) ++seen[int(material->data[p * material->channels])];
  seen.erase(0);
  ASSERT_EQ(seen.size(), 2u);
  EXPECT_GT(seen[1], 0u);
  EXPECT_GT(seen[5], 0u);
}

}  // namespace
}  // namespace reflcap::synth
