// Resampling a normal-map capture with cast shadows from its height field
// (ResampleOptions::height_shadows, image_resampler.h).
#include <gtest/gtest.h>

#include <cmath>
#include <set>
#include <utility>

#include <nlohmann/json.hpp>

#include "acquire/resample/resample.h"
#include "engine/capture/capture.h"
#include "engine/image/exr_io.h"
#include "engine/image/png_io.h"
#include "engine/mesh/height_field.h"
#include "engine/mesh/texel_atlas.h"
#include "engine/texel/sample_store.h"
#include "tests/support/height_scenes.h"
#include "tests/support/test_support.h"

namespace reflcap::resample {
namespace {
namespace fs = std::filesystem;
using Json = nlohmann::json;

// Light that reaches a shadowed pixel anyway in the synthetic photographs (interreflection, as
// real shadows have): 30 % of the direct value, far above the dark floor, so without the height
// field those samples are kept and only the shadow test can reject them.
constexpr double kIndirectShare = 0.3;

struct PitCapture {
  testing::ScratchDir dir;
  Capture capture;
  TexelAtlas atlas;
  HeightField field;
};

// A Lambertian plate with a spherical pit (tests/support/height_scenes.h), seen by DiLiGenT's
// orthographic camera under four low directional lights; photographs rendered with the pit's
// own height-field shadows at kIndirectShare.
void MakePitCapture(PitCapture* c) {
  const int w = 72, h = 68;
  const testing::AnalyticHeight pit = testing::PittedPlate(36, 33, 36, 30);  // 16 px deep
  Image normals, mask;
  testing::NormalMapOf(pit, w, h, &normals, &mask);
  auto atlas = BuildNormalMapAtlas(normals, mask);
  ASSERT_TRUE(atlas.ok());
  c->atlas = std::move(*atlas);
  Capture& capture = c->capture;
  capture.json_path = c->dir / "capture.json";
  capture.normal_map = NormalMapGeometry{0, "normals.exr", "mask.png"};
  capture.cameras.push_back(testing::DiligentCamera(w, h));
  auto field = IntegrateNormalMap(c->atlas, capture.cameras[0]);
  ASSERT_TRUE(field.ok()) << field.status().ToString();
  c->field = std::move(*field);
  const Vec3d albedo(0.6, 0.5, 0.4);
  fs::create_directories(c->dir / "images");
  for (int l = 0; l < 4; ++l) {
    Light light;
    light.id = StrCat("L", l);
    light.type = LightType::kDirectional;
    const double az = DegToRad(20 + 90.0 * l), el = DegToRad(18 + 4 * l);
    light.direction = Vec3d(std::cos(el) * std::cos(az), std::cos(el) * std::sin(az), std::sin(el));
    light.intensity = Vec3d(1, 1, 1);
    capture.lights.push_back(light);
    CaptureImage image;
    image.file = StrCat("images/", l, ".exr");
    image.light = l;
    capture.images.push_back(image);
    const HeightFieldMarch march = MakeHeightFieldMarch(c->field, light.direction);
    Image pixels(w, h, 3, 0.0f);
    for (size_t t = 0; t < c->atlas.TexelCount(); ++t) {
      int x, y;
      c->atlas.PixelOf(t, &x, &y);
      const double cos_i = c->atlas.shading_normal[t].cast<double>().dot(light.direction);
      if (cos_i <= 0) continue;
      const double share =
          HeightFieldShadowed(c->field.heights_px.data(), march, x, y) ? kIndirectShare : 1.0;
      for (int ch = 0; ch < 3; ++ch) pixels.at(x, y, ch) = float(share * albedo[ch] / kPi * cos_i);
    }
    ASSERT_TRUE(WriteExr(c->dir / image.file, pixels).ok());
  }
  ASSERT_TRUE(WriteExr(c->dir / "normals.exr", normals).ok());
  ASSERT_TRUE(WritePng(c->dir / "mask.png", mask).ok());
  ASSERT_TRUE(WriteCapture(capture, capture.json_path).ok());
}

// (texel, image) pairs of a sample store.
std::set<std::pair<uint32_t, uint32_t>> KeptPairs(const fs::path& store) {
  std::set<std::pair<uint32_t, uint32_t>> pairs;
  auto reader = SampleStoreReader::Open(store);
  EXPECT_TRUE(reader.ok());
  if (!reader.ok()) return pairs;
  for (uint32_t k = 0; k < (*reader)->info().chunks; ++k) {
    auto chunk = (*reader)->ReadChunk(k);
    EXPECT_TRUE(chunk.ok());
    if (!chunk.ok()) return pairs;
    for (uint32_t i = 0; i < chunk->texel_count; ++i) {
      for (uint64_t s = chunk->offsets[i]; s < chunk->offsets[i + 1]; ++s) {
        pairs.insert({chunk->first_texel + i, chunk->samples[s].image});
      }
    }
  }
  return pairs;
}

TEST(ResampleHeightShadows, RejectsExactlyTheTexelsInTheHeightFieldsShadow) {
  PitCapture c;
  MakePitCapture(&c);
  // Expected: every pair whose cosines pass min_cos, minus those the march shadows.
  std::set<std::pair<uint32_t, uint32_t>> lit, shadowed;
  for (uint32_t i = 0; i < c.capture.images.size(); ++i) {
    const Light& light = c.capture.lights[c.capture.images[i].light];
    const HeightFieldMarch march = MakeHeightFieldMarch(c.field, light.direction);
    for (uint32_t t = 0; t < c.atlas.TexelCount(); ++t) {
      const Vec3f& n = c.atlas.shading_normal[t];
      if (!(n.z() > float(kDefaultMinCos)) ||
          !(n.dot(light.direction.cast<float>()) > float(kDefaultMinCos))) {
        continue;
      }
      int x, y;
      c.atlas.PixelOf(t, &x, &y);
      (HeightFieldShadowed(c.field.heights_px.data(), march, x, y) ? shadowed : lit).insert({t, i});
    }
  }
  ASSERT_GT(shadowed.size(), 200u) << "the scene must cast real shadows";

  ResampleOptions options;
  options.split = SplitSelection::kAll;
  testing::ScratchDir on, off;
  auto with = ResampleCapture(c.capture.json_path, options, on.path());
  ASSERT_TRUE(with.ok()) << with.status().ToString();
  const Json report = Json::parse(with->report_json);
  EXPECT_EQ(report["samples_rejected"]["shadowed"].get<uint64_t>(), shadowed.size());
  EXPECT_EQ(report["height_field"]["cast_shadows"], "on");
  EXPECT_EQ(report["height_field"]["components"].get<uint64_t>(), 1u);
  EXPECT_NE(report["visibility"].get<std::string>().find("height field"), std::string::npos);
  EXPECT_EQ(KeptPairs(on.path()), lit);

  options.height_shadows = false;
  auto without = ResampleCapture(c.capture.json_path, options, off.path());
  ASSERT_TRUE(without.ok()) << without.status().ToString();
  const Json off_report = Json::parse(without->report_json);
  EXPECT_EQ(off_report["samples_rejected"]["shadowed"].get<uint64_t>(), 0u);
  EXPECT_NE(off_report["visibility"].get<std::string>().find("not tested"), std::string::npos);
  EXPECT_EQ(without->samples_kept, lit.size() + shadowed.size())
      << "off, the shadowed samples are kept (they are lit by the indirect share)";
}

TEST(ResampleHeightShadows, PinholeNormalMapsSkipTheTestAndSaySo) {
  PitCapture c;
  MakePitCapture(&c);
  Camera& cam = c.capture.cameras[0];
  cam.model = CameraModel::kPinhole;
  cam.K << 200, 0, 35.5, 0, 200, 33.5, 0, 0, 1;
  ASSERT_TRUE(WriteCapture(c.capture, c.capture.json_path).ok());
  testing::ScratchDir out;
  ResampleOptions options;
  options.split = SplitSelection::kAll;
  auto summary = ResampleCapture(c.capture.json_path, options, out.path());
  ASSERT_TRUE(summary.ok()) << summary.status().ToString();
  const Json report = Json::parse(summary->report_json);
  EXPECT_EQ(report["samples_rejected"]["shadowed"].get<uint64_t>(), 0u);
  EXPECT_NE(report["height_field"]["cast_shadows"].get<std::string>().find("not orthographic"),
            std::string::npos);
}

}  // namespace
}  // namespace reflcap::resample
