// The resampler's variance path (images[].variance, written by `reflcap hdr`): a sample's
// noise is the interpolated variance Σ w_k² var_k of its pixel taps plus the relative floor; it
// sets the weight and decides the dark and invalid tests. Photographs without a variance image
// keep the noise model, bit for bit; bad variance files stop `reflcap resample` with exit 2
// naming the file and the field. (CPU against Vulkan with a variance image: vulkan_masks_test.cc.)
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <map>

#include <nlohmann/json.hpp>

#include "acquire/resample/image_resampler.h"
#include "acquire/resample/resample.h"
#include "acquire/synth/synth.h"
#include "engine/core/atomic_file.h"
#include "engine/image/exr_io.h"
#include "engine/image/image_io.h"
#include "engine/mesh/mesh_io.h"
#include "engine/mesh/ray_scene.h"
#include "engine/mesh/texel_atlas.h"
#include "engine/texel/sample_store.h"
#include "tests/acquire/resample/plane_scene.h"
#include "tests/acquire/resample/variance_capture.h"
#include "tests/engine/capture/raw_exr.h"
#include "tests/support/shapes.h"
#include "tests/support/test_support.h"

namespace reflcap::resample {
namespace {
namespace fs = std::filesystem;
using Json = nlohmann::json;

// Float evaluation in the resampler against double expectations here: a few ulps, plus bilinear
// weights from float fractions of the projection (~1e-7 relative).
constexpr double kFloatRelTolerance = 1e-5;
// A projection within rounding of a pixel centre's row or column may include a tap of weight
// ~1e-8 or not, depending on the last bit: such texels are not classified.
constexpr double kTapRounding = 1e-6;

// ---- An exact plane: weights and pixel tests from a variance image -----------------------------

TEST(ResampleVariance, PlaneWeightsFollowTheInterpolatedVarianceWhichDecidesDarkAndInvalid) {
  testing::PlaneScene plane = testing::MakePlaneScene();
  const std::unique_ptr<RayScene>* scene = &plane.scene;
  const TexelAtlas* atlas = &plane.atlas;
  Capture& capture = plane.capture;
  CaptureImage image;
  image.file = "a.exr";
  image.variance = "a_var.exr";
  image.exposure_s = 2;
  capture.images = {image};
  NoiseModel noise;  // read sigma 0.01: dark at or below 0.03, invalid below -0.05
  noise.photon_sigma_at_1 = 0.02;
  noise.read_sigma = 0.01;
  auto resampler = ImageResampler::Create(capture, *atlas, scene->get(), noise, kDefaultMinCos);
  ASSERT_TRUE(resampler.ok()) << resampler.status().ToString();
  // The interpolation's variance Σ w_k² var_k is what this test checks: bilinear taps.
  (*resampler)->SetSamplePoint(SamplePoint::kTexel);

  // Pixels (0.2, 0.3, 0.4) with a variance that changes from pixel to pixel and channel to
  // channel (so Σ w_k² var_k is checked tap by tap), and three patches where the variance image
  // and the noise model disagree (bilinear interpolation divides a pixel's σ by up to 2):
  //   A: value 0.05, σ = 0.05   -> dark by the variance (0.05 <= 3 x 0.025), kept by the model
  //                                (> 0.03)
  //   B: red -0.02, σ = 0.001   -> invalid by the variance (< -0.005), kept by the model (> -0.05)
  //   C: value 0.02, σ = 1e-4   -> kept by the variance (> 3e-4), dark by the model (<= 0.03)
  Image pixels(64, 64, 3), variance(64, 64, 3);
  for (int y = 0; y < 64; ++y) {
    for (int x = 0; x < 64; ++x) {
      for (int c = 0; c < 3; ++c) {
        pixels.at(x, y, c) = 0.2f + 0.1f * float(c);
        variance.at(x, y, c) = 1e-5f * float(1 + (x + 3 * y + c) % 7);
      }
    }
  }
  struct Patch {
    int x0, y0;
    float value[3];
    float sigma;
  };
  const Patch patches[] = {{40, 10, {0.05f, 0.05f, 0.05f}, 0.05f},
                           {20, 40, {-0.02f, 0.3f, 0.4f}, 0.001f},
                           {10, 12, {0.02f, 0.02f, 0.02f}, 1e-4f}};
  for (const Patch& patch : patches) {
    for (int y = patch.y0; y < patch.y0 + 6; ++y) {
      for (int x = patch.x0; x < patch.x0 + 6; ++x) {
        for (int c = 0; c < 3; ++c) {
          pixels.at(x, y, c) = patch.value[c];
          variance.at(x, y, c) = patch.sigma * patch.sigma;
        }
      }
    }
  }
  ImageOutput measured, modelled;
  ASSERT_TRUE((*resampler)->Process(0, pixels, &measured, &variance).ok());
  ASSERT_TRUE((*resampler)->Process(0, pixels, &modelled).ok());
  std::vector<int> kept_index(atlas->TexelCount(), -1);
  for (size_t k = 0; k < measured.kept.size(); ++k) kept_index[measured.kept[k].texel] = int(k);

  const Camera& cam = capture.cameras[0];
  const Vec3d l = capture.lights[0].direction;
  std::map<Outcome, int> counts;
  int dark_by_variance_only = 0, invalid_by_variance_only = 0, kept_by_variance_only = 0;
  int weights_checked = 0;
  for (uint32_t t = 0; t < atlas->TexelCount(); ++t) {
    const Outcome outcome = Outcome(measured.outcome[t]);
    if (outcome != Outcome::kKept && outcome != Outcome::kDark && outcome != Outcome::kInvalid) {
      continue;  // geometry (the square's border): not this test's subject
    }
    Vec2d px;
    ASSERT_TRUE(cam.Project(cam.cam_from_world * atlas->position[t].cast<double>(), &px));
    const int x0 = int(std::floor(px.x())), y0 = int(std::floor(px.y()));
    const double fx = px.x() - x0, fy = px.y() - y0;
    if (std::min(fx, 1 - fx) < kTapRounding || std::min(fy, 1 - fy) < kTapRounding) continue;
    const double w[4] = {(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy};
    Vec3d value = Vec3d::Zero(), var = Vec3d::Zero();
    for (int k = 0; k < 4; ++k) {
      const int tx = x0 + (k & 1), ty = y0 + (k >> 1);
      for (int c = 0; c < 3; ++c) {
        value[c] += w[k] * pixels.at(tx, ty, c);
        var[c] += w[k] * w[k] * variance.at(tx, ty, c);
      }
    }
    // Expected outcome from the measured noise; texels within rounding of a threshold are left
    // out (the resampler decides them in float).
    bool invalid = false, dark = true, borderline = false;
    for (int c = 0; c < 3; ++c) {
      const double sigma = std::sqrt(var[c]);
      invalid |= value[c] < -kInvalidSigmas * sigma;
      dark &= value[c] <= kDarkSigmas * sigma;
      borderline |= std::abs(value[c] + kInvalidSigmas * sigma) < kFloatRelTolerance * sigma ||
                    std::abs(value[c] - kDarkSigmas * sigma) < kFloatRelTolerance * sigma;
    }
    if (borderline) continue;
    const Outcome expected = invalid ? Outcome::kInvalid : dark ? Outcome::kDark : Outcome::kKept;
    ASSERT_EQ(outcome, expected) << "texel " << t << " at " << px.transpose();
    ++counts[outcome];
    const Outcome model_outcome = Outcome(modelled.outcome[t]);
    dark_by_variance_only += outcome == Outcome::kDark && model_outcome == Outcome::kKept;
    invalid_by_variance_only += outcome == Outcome::kInvalid && model_outcome == Outcome::kKept;
    kept_by_variance_only += outcome == Outcome::kKept && model_outcome == Outcome::kDark;
    if (outcome != Outcome::kKept) continue;
    const TexelSample& s = measured.kept[size_t(kept_index[t])];
    const double floor = kRelativeSigmaFloor * value.maxCoeff();
    for (int c = 0; c < 3; ++c) {
      const double scale = image.exposure_s * capture.lights[0].intensity[c] * l.z();
      const double expected_value = value[c] / scale;
      EXPECT_NEAR(s.sample.value[c], expected_value, kFloatRelTolerance * std::abs(expected_value));
      const double weight = scale * scale / (var[c] + floor * floor);
      EXPECT_NEAR(s.sample.weight[c], weight, kFloatRelTolerance * weight) << "texel " << t;
    }
    ++weights_checked;
  }
  std::printf("kept %d, dark %d, invalid %d; by the variance only: dark %d, invalid %d, kept %d\n",
              counts[Outcome::kKept], counts[Outcome::kDark], counts[Outcome::kInvalid],
              dark_by_variance_only, invalid_by_variance_only, kept_by_variance_only);
  EXPECT_GT(weights_checked, 800) << "of 1600 texels";
  // Each patch changed outcomes against the noise model, in the direction its noise says.
  EXPECT_GT(dark_by_variance_only, 0) << "patch A";
  EXPECT_GT(invalid_by_variance_only, 0) << "patch B";
  EXPECT_GT(kept_by_variance_only, 0) << "patch C";
}

// A normal-map capture takes the texel's own pixel (tap weight 1): its variance is that pixel's.
TEST(ResampleVariance, NormalMapTexelsTakeTheirPixelsVariance) {
  const int size = 8;
  Image normals(size, size, 3), mask(size, size, 1, 1.0f);
  for (size_t p = 0; p < normals.PixelCount(); ++p) normals.data[p * 3 + 2] = 1;
  auto atlas = BuildNormalMapAtlas(normals, mask);
  ASSERT_TRUE(atlas.ok());
  Capture capture;
  capture.json_path = "flat/capture.json";
  capture.normal_map = NormalMapGeometry{0, "normals.exr", "mask.png"};
  Camera cam = testing::DownCamera(Vec3d(0, 0, 1), size, 1);
  cam.model = CameraModel::kOrthographic;
  cam.pixel_size_m = 0.001;
  capture.cameras.push_back(cam);
  Light light;
  light.id = "L";
  light.type = LightType::kDirectional;
  light.direction = Vec3d(0.6, 0, 0.8);
  light.intensity = Vec3d(1, 0.5, 2);
  capture.lights.push_back(light);
  CaptureImage image;
  image.file = "0.exr";
  image.variance = "0_var.exr";
  image.exposure_s = 0.5;
  capture.images.push_back(image);
  auto resampler = ImageResampler::Create(capture, *atlas, nullptr, NoiseModel(), kDefaultMinCos);
  ASSERT_TRUE(resampler.ok()) << resampler.status().ToString();
  Image pixels(size, size, 3, 0.3f), variance(size, size, 3);
  for (int y = 0; y < size; ++y) {
    for (int x = 0; x < size; ++x) {
      for (int c = 0; c < 3; ++c) variance.at(x, y, c) = 1e-5f * float(1 + x + size * y + c);
    }
  }
  ImageOutput out;
  ASSERT_TRUE((*resampler)->Process(0, pixels, &out, &variance).ok());
  ASSERT_EQ(out.kept.size(), atlas->TexelCount());
  const double floor = kRelativeSigmaFloor * 0.3f;
  for (const TexelSample& s : out.kept) {
    int x, y;
    atlas->PixelOf(s.texel, &x, &y);
    for (int c = 0; c < 3; ++c) {
      const double scale = image.exposure_s * light.intensity[c] * light.direction.z();
      const double weight = scale * scale / (variance.at(x, y, c) + floor * floor);
      EXPECT_NEAR(s.sample.weight[c], weight, kFloatRelTolerance * weight) << x << ", " << y;
    }
  }
}

// ---- A synthetic capture with variance images -------------------------------------------------

// Variance of the synthetic tests' images: kBaseVariance everywhere (σ = 3.2e-3, about the
// capture's own noise at its typical pixel values, so few samples turn dark), times
// kRegionFactor in the right half of every photograph.
constexpr float kBaseVariance = 1e-5f;
constexpr float kRegionFactor = 100;
// Texels whose taps lie within this many pixels of the region boundary are not classified (the
// resampler's float projection may put a tap on the other side).
constexpr int kBoundaryMarginPx = 1;
// The median weight ratio (high region / uniform) must be within this of 1 / kRegionFactor: the
// relative floor (1e-3 x max channel)² adds the same term to both variances, at most a few % of
// the base variance at the capture's pixel values.
constexpr double kMedianRatioTolerance = 0.05;

struct VarianceCase {
  testing::ScratchDir dir;
  fs::path plain, uniform, region, half;  // capture JSON files (photographs shared)
};

VarianceCase* g_case = nullptr;
// Removes the case's folder after the last test.
class Cleanup : public ::testing::Environment {
 public:
  void TearDown() override {
    delete g_case;
    g_case = nullptr;
  }
};
::testing::Environment* const g_cleanup = ::testing::AddGlobalTestEnvironment(new Cleanup);

// The small synth rig (2 cameras x 3 lights x 4 steps, 96 px, ~2,500 texels, photon noise 1 %)
// as plain (no variance), uniform (kBaseVariance), region (x kRegionFactor in the right half)
// and half (the region's images on every other photograph only).
const VarianceCase& Case() {
  static VarianceCase* c = [] {
    auto* v = g_case = new VarianceCase();
    synth::SynthOptions o;
    o.texels = 2500;
    o.image_size = 96;
    o.cameras = 2;
    o.lights = 3;
    o.steps = 4;
    const fs::path capture = v->dir / "synth";
    const Status s = synth::WriteSyntheticCapture(o, capture).status();
    REFLCAP_CHECK(s.ok()) << s.ToString();
    v->plain = capture / "capture.json";
    const testing::VarianceOf uniform = [](const Image&, int, int, int) { return kBaseVariance; };
    v->uniform =
        testing::AddVarianceImages(capture, "capture_uniform.json", "variance_uniform", uniform);
    const testing::VarianceOf region = [](const Image& p, int x, int, int) {
      return x >= p.width / 2 ? kRegionFactor * kBaseVariance : kBaseVariance;
    };
    v->region =
        testing::AddVarianceImages(capture, "capture_region.json", "variance_region", region);
    v->half = testing::AddVarianceImages(capture, "capture_half.json", "variance_half", region,
                                         [](size_t i) { return i % 2 == 0; });
    return v;
  }();
  return *c;
}

TEST(ResampleVariance, RegionWithAHundredTimesTheVarianceGetsAHundredthOfTheWeight) {
  const VarianceCase& c = Case();
  const Capture uniform = ReadCapture(c.uniform).value();
  const Capture region = ReadCapture(c.region).value();
  const TriangleMesh mesh = LoadMesh(uniform.Resolve(uniform.mesh)).value();
  const int res = Json::parse(uniform.ground_truth_json)["atlas"]["width"].get<int>();
  const TexelAtlas atlas = BuildTexelAtlas(mesh, res, res).value();
  const auto scene = RayScene::Create(mesh).value();
  NoiseModel noise;  // unused by these photographs: every one has a variance image
  auto resampler = ImageResampler::Create(region, atlas, scene.get(), noise, kDefaultMinCos);
  ASSERT_TRUE(resampler.ok()) << resampler.status().ToString();
  // The expected ratios below follow the bilinear taps' Σ w_k²: SamplePoint::kTexel.
  (*resampler)->SetSamplePoint(SamplePoint::kTexel);
  std::vector<double> high_ratios;
  size_t low = 0, high_checked = 0;
  for (uint32_t i = 0; i < 8; ++i) {
    const Image pixels = ReadImageRgb(region.Resolve(region.images[i].file)).value();
    const Image var_uniform = ReadVarianceImage(uniform, i).value();
    const Image var_region = ReadVarianceImage(region, i).value();
    ImageOutput a, b;
    ASSERT_TRUE((*resampler)->Process(i, pixels, &a, &var_uniform).ok());
    ASSERT_TRUE((*resampler)->Process(i, pixels, &b, &var_region).ok());
    std::map<uint32_t, const BrdfSample*> by_texel;
    for (const TexelSample& s : a.kept) by_texel[s.texel] = &s.sample;
    const CaptureImage& image = region.images[i];
    const Camera& cam = region.cameras[image.camera];
    const Rigid3 cam_from_object = cam.cam_from_world * region.WorldFromObject(image);
    const int boundary = cam.width / 2;
    for (const TexelSample& s : b.kept) {
      auto it = by_texel.find(s.texel);
      if (it == by_texel.end()) continue;
      Vec2d px;
      ASSERT_TRUE(cam.Project(cam_from_object * atlas.position[s.texel].cast<double>(), &px));
      const int x0 = int(std::floor(px.x())), y0 = int(std::floor(px.y()));
      const double fx = px.x() - x0, fy = px.y() - y0;
      if (std::min(fx, 1 - fx) < kTapRounding || std::min(fy, 1 - fy) < kTapRounding) continue;
      if (x0 + 1 < boundary - kBoundaryMarginPx) {
        // Low region: the same variance in both images, so the same weight, bit for bit.
        for (int ch = 0; ch < 3; ++ch) EXPECT_EQ(s.sample.weight[ch], it->second->weight[ch]);
        ++low;
      } else if (x0 >= boundary + kBoundaryMarginPx) {
        // High region: var = F v0 S + f² against v0 S + f² (S = Σ w_k², f the relative floor).
        const double w[4] = {(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy};
        double sum_w2 = 0, max_channel = 0;
        for (int k = 0; k < 4; ++k) sum_w2 += w[k] * w[k];
        for (int ch = 0; ch < 3; ++ch) {
          double v = 0;
          for (int k = 0; k < 4; ++k) v += w[k] * pixels.at(x0 + (k & 1), y0 + (k >> 1), ch);
          max_channel = std::max(max_channel, v);
        }
        const double f2 = std::pow(kRelativeSigmaFloor * max_channel, 2);
        const double expected =
            (kBaseVariance * sum_w2 + f2) / (kRegionFactor * kBaseVariance * sum_w2 + f2);
        for (int ch = 0; ch < 3; ++ch) {
          const double ratio = double(s.sample.weight[ch]) / double(it->second->weight[ch]);
          EXPECT_NEAR(ratio, expected, 10 * kFloatRelTolerance * expected) << "texel " << s.texel;
          high_ratios.push_back(ratio);
        }
        ++high_checked;
      }
    }
  }
  ASSERT_GT(low, 200u);
  ASSERT_GT(high_checked, 200u);
  const auto middle = high_ratios.begin() + ptrdiff_t(high_ratios.size() / 2);
  std::nth_element(high_ratios.begin(), middle, high_ratios.end());
  const double median = *middle;
  std::printf("high-variance region: %zu samples, median weight ratio %.5f (1/%g = %.5f); "
              "low: %zu\n",
              high_checked, median, double(kRegionFactor), 1.0 / kRegionFactor, low);
  EXPECT_NEAR(median * kRegionFactor, 1.0, kMedianRatioTolerance);
}

// The bytes of every chunk file of a store.
std::vector<std::string> ChunkBytes(const fs::path& store) {
  std::vector<std::string> chunks;
  for (uint32_t i = 0; fs::exists(store / SampleChunkFileName(i)); ++i) {
    chunks.push_back(ReadTextFile(store / SampleChunkFileName(i)).value());
  }
  return chunks;
}

// (texel, image) -> the sample's record, for a whole store.
std::map<std::pair<uint32_t, uint32_t>, BrdfSample> SamplesOf(const fs::path& store) {
  std::map<std::pair<uint32_t, uint32_t>, BrdfSample> out;
  auto reader = SampleStoreReader::Open(store);
  REFLCAP_CHECK(reader.ok()) << reader.status().ToString();
  for (uint32_t i = 0; i < (*reader)->info().chunks; ++i) {
    const TexelSampleChunk chunk = (*reader)->ReadChunk(i).value();
    for (uint32_t t = 0; t < chunk.texel_count; ++t) {
      for (uint64_t k = 0; k < chunk.SampleCount(t); ++k) {
        const BrdfSample& s = chunk.SamplesOf(t)[k];
        out[{chunk.first_texel + t, s.image}] = s;
      }
    }
  }
  return out;
}

Json Resample(const fs::path& capture, const fs::path& out, bool use_variance = true) {
  ResampleOptions options;
  options.use_variance = use_variance;
  fs::create_directories(out);
  auto summary = ResampleCapture(capture, options, out);
  REFLCAP_CHECK(summary.ok()) << summary.status().ToString();
  return Json::parse(summary->report_json);
}

TEST(ResampleVariance, WithoutVarianceTheNoiseModelIsUsedBitForBit) {
  const VarianceCase& c = Case();
  testing::ScratchDir dir;
  const Json plain = Resample(c.plain, dir / "plain");
  const Json ignored = Resample(c.region, dir / "ignored", /*use_variance=*/false);
  const Json region = Resample(c.region, dir / "region");
  const Json half = Resample(c.half, dir / "half");
  // Variance files present but not used: the noise model's store, byte for byte.
  const std::vector<std::string> plain_chunks = ChunkBytes(dir / "plain");
  ASSERT_FALSE(plain_chunks.empty());
  EXPECT_TRUE(plain_chunks == ChunkBytes(dir / "ignored"));
  EXPECT_EQ(plain["noise_model"]["variance_images"], 0);
  EXPECT_EQ(ignored["noise_model"]["variance_images"], 0);
  EXPECT_GT(ignored["noise_model"]["variance_images_ignored"].get<int>(), 0);
  const int images = region["images"].get<int>();
  EXPECT_EQ(region["noise_model"]["variance_images"], images);
  // Variance on every other photograph: those take the variance run's samples, the others the
  // noise model's, record for record.
  const auto a = SamplesOf(dir / "plain");
  const auto b = SamplesOf(dir / "region");
  const auto h = SamplesOf(dir / "half");
  const Capture half_capture = ReadCapture(c.half).value();
  size_t with = 0, without = 0, differing = 0;
  for (const auto& [key, sample] : h) {
    const bool has_variance = !half_capture.images[key.second].variance.empty();
    const auto& reference = has_variance ? b : a;
    auto it = reference.find(key);
    ASSERT_NE(it, reference.end()) << "texel " << key.first << " image " << key.second;
    EXPECT_EQ(std::memcmp(&it->second, &sample, sizeof(BrdfSample)), 0)
        << "texel " << key.first << " image " << key.second;
    (has_variance ? with : without) += 1;
    if (has_variance) differing += a.count(key) == 0 || a.at(key).weight[1] != sample.weight[1];
  }
  auto has_variance = [&](const auto& entry) {
    return !half_capture.images[entry.first.second].variance.empty();
  };
  size_t expected_total = 0;
  for (const auto& entry : a) expected_total += !has_variance(entry);
  for (const auto& entry : b) expected_total += has_variance(entry);
  EXPECT_EQ(h.size(), expected_total) << "no sample lost or added";
  EXPECT_GT(with, 1000u);
  EXPECT_GT(without, 1000u);
  EXPECT_GT(differing, with / 2) << "the variance images change the weights";
  int train_with_variance = 0;
  for (const CaptureImage& image : half_capture.images) {
    train_with_variance += image.split == Split::kTrain && !image.variance.empty();
  }
  EXPECT_EQ(half["noise_model"]["variance_images"].get<int>(), train_with_variance);
  EXPECT_LT(train_with_variance, images);
}

// ---- Bad variance files: exit 2 naming the file and the field, nothing written ----------------

TEST(ResampleVarianceCli, BadVarianceFilesExitTwoNamingFileAndField) {
  const VarianceCase& c = Case();
  const fs::path folder = c.region.parent_path();
  const Capture region = ReadCapture(c.region).value();
  // The first train photograph: the one resample reads.
  size_t k = 0;
  while (region.images[k].split != Split::kTrain) ++k;
  const Camera& cam = region.cameras[region.images[k].camera];
  fs::create_directories(folder / "variance_bad");
  const Image small(cam.width - 1, cam.height, 3, 1e-5f), grey(cam.width, cam.height, 1, 1e-5f);
  ASSERT_TRUE(WriteExr(folder / "variance_bad/small.exr", small).ok());
  ASSERT_TRUE(WriteExr(folder / "variance_bad/grey.exr", grey).ok());
  const std::string small_reason = StrCat("is ", small.width, "x", small.height, " but camera");
  Image nan(cam.width, cam.height, 3, 1e-5f);
  nan.at(7, 5, 2) = std::nanf("");
  testing::WriteRawExr(folder / "variance_bad/nan.exr", nan);
  Image negative(cam.width, cam.height, 3, 1e-5f);
  negative.at(3, 2, 0) = -1e-5f;
  testing::WriteRawExr(folder / "variance_bad/negative.exr", negative);
  struct Case {
    const char* file;
    std::string reason;
  };
  const Case cases[] = {{"variance_bad/missing.exr", "cannot open"},
                        {"variance_bad/small.exr", small_reason},
                        {"variance_bad/grey.exr", "has 1 channel (Y)"},
                        {"variance_bad/nan.exr", "pixel (7, 5) channel B is NaN"},
                        {"variance_bad/negative.exr", "pixel (3, 2) channel R is negative"}};
  const std::string field = StrCat("images[", k, "].variance");
  for (const Case& bad : cases) {
    Json json = Json::parse(ReadTextFile(c.region).value());
    json["images"][k]["variance"] = bad.file;
    const fs::path path = folder / "capture_bad.json";
    testing::WriteText(path, json.dump(2));
    testing::ScratchDir dir;
    const fs::path out = dir / "samples";
    const testing::CliResult r = testing::RunCommand(
        REFLCAP_BINARY, "resample " + path.string() + " --variance-weights --out " + out.string(), dir);
    EXPECT_EQ(r.exit_code, 2) << bad.file << ": " << r.err;
    for (const std::string& needle : {path.string(), field, std::string(bad.file), bad.reason}) {
      EXPECT_NE(r.err.find(needle), std::string::npos) << "'" << needle << "' not in: " << r.err;
    }
    EXPECT_FALSE(fs::exists(out)) << bad.file << ": nothing may be written";
    for (const auto& e : fs::directory_iterator(dir.path())) {
      EXPECT_EQ(e.path().filename().string().find(".tmp"), std::string::npos) << e.path();
    }
  }
}

TEST(ResampleVarianceCli, SaysWhichPhotographsTheVarianceWeights) {
  const VarianceCase& c = Case();
  testing::ScratchDir dir;
  const testing::CliResult r = testing::RunCommand(
      REFLCAP_BINARY, "resample " + c.half.string() + " --variance-weights --out " + (dir / "s").string(), dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("weights: per-pixel variance (images[].variance) for "), std::string::npos)
      << r.out;
  EXPECT_NE(r.out.find("noise model for the rest"), std::string::npos) << r.out;
}

// The variance weights are opt-in (README, "Per-pixel variance": they lost up to 0.57 dB on the
// merged suzanne captures): without the flag every photograph takes the noise model and the
// summary points at the flag.
TEST(ResampleVarianceCli, WithoutTheFlagTheNoiseModelWeightsEveryPhotograph) {
  const VarianceCase& c = Case();
  testing::ScratchDir dir;
  const testing::CliResult r = testing::RunCommand(
      REFLCAP_BINARY, "resample " + c.half.string() + " --out " + (dir / "s").string(), dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("weights: per-pixel variance (images[].variance) for 0 of "),
            std::string::npos)
      << r.out;
  EXPECT_NE(r.out.find("--variance-weights uses them"), std::string::npos) << r.out;
}

}  // namespace
}  // namespace reflcap::resample
