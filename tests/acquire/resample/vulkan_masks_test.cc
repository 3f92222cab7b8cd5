// The Vulkan masks (acquire/resample/vulkan_masks.h) against the Embree path they replace: on a
// small synthetic capture whose relief object shadows itself, the two give the same outcome for
// almost every (texel, image) pair, the disagreements sit at depth discontinuities and shadow
// edges, and the samples both keep carry the same values; `reflcap resample --backend vulkan
// --cross-check` writes a valid store and a report with the device and the agreement. Runs on
// lavapipe in CI; skips only when there is no Vulkan driver at all.
#include "acquire/resample/vulkan_masks.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <map>

#include <nlohmann/json.hpp>

#include "acquire/resample/image_resampler.h"
#include "acquire/resample/mask_agreement.h"
#include "acquire/resample/resample.h"
#include "acquire/synth/synth.h"
#include "engine/gpu/device_info.h"
#include "engine/gpu/vk_context.h"
#include "engine/image/image_io.h"
#include "engine/mesh/mesh_io.h"
#include "engine/mesh/ray_scene.h"
#include "engine/mesh/texel_atlas.h"
#include "tests/acquire/resample/variance_capture.h"
#include "tests/support/test_support.h"

namespace reflcap::resample {
namespace {
namespace fs = std::filesystem;
using Json = nlohmann::json;

// The bar: Embree's rays and the Vulkan masks give the same outcome to at least this
// fraction of the (texel, image) pairs.
constexpr double kMinAgreement = 0.995;
// A distorted camera whose pixels are point samples (the synth's): the camera map lies on the
// undistorted grid, so a tap's visibility and lit flag are those of the map texel nearest its ray
// (up to half a pixel away), while its hit is the pixel's own ray met with that texel's triangle.
// Measured 99.49 % on this capture (99.01 % before the taps met their own rays, 99.57 % when its
// pixels are taken as area samples, where no pair is rejected for the in-texel choice);
// area-filtered or undistorted cameras keep kMinAgreement.
constexpr double kMinAgreementDistortedPointPixels = 0.99;
// Most disagreements must lie near a depth discontinuity or a shadow edge (mask_agreement.h):
// measured 79 % (86 of 109) on this capture. The rest are contact occlusion in the relief's
// grooves: an occluder closer to the receiver plane than the camera-map bias, which the map
// cannot tell from the surface itself (camera_bias_pixels trades these against self-occlusion:
// 0.5 px gives 57 texel-image pairs wrongly occluded, 1 px 39, 2 px 24, while the pairs wrongly
// seen grow 48, 57, 102).
constexpr double kMinNearEdgeFraction = 0.7;
// The comparison has teeth only if the relief shadows itself: cast-shadowed pairs must be at
// least this fraction of the kept samples (measured 2.4 %).
constexpr double kMinShadowedPerKept = 0.02;
// Samples both paths keep (SamplePoint::kPixel, the default: the same pixel's value at its hit's
// geometry): the GPU meets the pixel's own ray with the triangle the rasteriser put under it, so
// its hit is the CPU's to float rounding, except where the two pick different triangles of a
// shared edge (the rasteriser's coverage rule against Embree's test) and the hit lies on the
// neighbour's plane a rounding step beyond its edge: one texel here (its pixel's hit at
// barycentric 0.0013 from the edge), its directions 5.1e-5 apart
// (tangent frames through the neighbour's interpolated normal), values 1.1e-4 relative (lavapipe).
// The rasteriser-interpolated hits used before measured the same here but failed these bounds on
// an NVIDIA H200 (figures not kept; the exact hits are not yet measured there). The tolerance is
// the 1e-3 radiometric floor (kRelativeSigmaFloor) for values, twice that for weights (the square
// of the scale), and 2e-4 for directions.
constexpr double kValueTolerance = 1e-3;
constexpr double kWeightTolerance = 2e-3;
constexpr double kDirectionTolerance = 2e-4;
// Samples both keep from different pixels (two taps' hits at the same distance from the texel
// centre within rounding): measured 0 of 14,881 here, 21 of 765,605 on the seed-11 capture.
constexpr double kMaxOtherPixelShare = 1e-3;

const std::string& NoVulkanReason() {
  static const std::string reason = [] {
    StatusOr<std::vector<gpu::DeviceInfo>> devices = gpu::ListDevices();
    if (!devices.ok() && devices.status().code() == StatusCode::kUnavailable) {
      return "no Vulkan driver or device on this machine: " + devices.status().ToString();
    }
    return std::string();
  }();
  return reason;
}

std::string TestDevice() {
  const char* device = std::getenv("REFLCAP_TEST_VK_DEVICE");
  return device != nullptr ? device : "";
}

// A small capture with cast shadows (the relief object under lights at 20-60° elevation), made
// once for this binary.
testing::ScratchDir* g_dir = nullptr;
class Cleanup : public ::testing::Environment {
 public:
  void TearDown() override {
    delete g_dir;
    g_dir = nullptr;
  }
};
::testing::Environment* const g_cleanup = ::testing::AddGlobalTestEnvironment(new Cleanup);

synth::SynthOptions ShadowCaptureOptions() {
  synth::SynthOptions o;
  o.noise = 0;
  o.texels = 3000;
  o.image_size = 128;
  o.cameras = 2;
  o.lights = 3;
  o.steps = 4;
  return o;
}

struct MaskCase {
  fs::path dir;
  Capture capture;
  TriangleMesh mesh;
  TexelAtlas atlas;
  std::unique_ptr<RayScene> scene;
  MaskAgreement agreement;
  uint64_t embree_shadowed = 0, vulkan_shadowed = 0, embree_kept = 0, vulkan_kept = 0;
};

const fs::path& CaptureDir() {
  static const fs::path dir = [] {
    g_dir = new testing::ScratchDir();
    const fs::path out = *g_dir / "shadow_capture";
    const Status s = synth::WriteSyntheticCapture(ShadowCaptureOptions(), out).status();
    REFLCAP_CHECK(s.ok()) << s.ToString();
    return out;
  }();
  return dir;
}

// Both paths on every image of the capture (train and holdout), compared pair by pair.
const MaskCase& Compared() {
  static MaskCase* c = [] {
    auto* m = new MaskCase();
    m->dir = CaptureDir();
    m->capture = ReadCapture(m->dir).value();
    m->mesh = LoadMesh(m->dir / "mesh.obj").value();
    const Json truth = Json::parse(m->capture.ground_truth_json);
    const int res = truth["atlas"]["width"].get<int>();
    m->atlas = BuildTexelAtlas(m->mesh, res, res).value();
    m->scene = RayScene::Create(m->mesh).value();
    const NoiseModel noise;  // noise-free capture
    auto cpu = ImageResampler::Create(m->capture, m->atlas, m->scene.get(), noise, kDefaultMinCos);
    REFLCAP_CHECK(cpu.ok()) << cpu.status().ToString();
    VulkanMaskOptions options;
    options.device = TestDevice();
    auto gpu = VulkanMasks::Create(m->capture, m->atlas, m->mesh, m->scene->SurfaceOffset(), noise,
                                   kDefaultMinCos, options);
    REFLCAP_CHECK(gpu.ok()) << gpu.status().ToString();
    ImageOutput a, b;
    CameraMapView map;
    for (uint32_t i = 0; i < m->capture.images.size(); ++i) {
      const Image pixels = ReadImageRgb(m->capture.Resolve(m->capture.images[i].file)).value();
      REFLCAP_CHECK((*cpu)->Process(i, pixels, &a).ok());
      const Status s = (*gpu)->Process(i, pixels, &b, &map);
      REFLCAP_CHECK(s.ok()) << s.ToString();
      m->agreement.Add(m->atlas.position, a.outcome, b.outcome, a.kept, b.kept, map);
      for (uint8_t o : a.outcome) m->embree_shadowed += o == uint8_t(Outcome::kShadowed);
      for (uint8_t o : b.outcome) m->vulkan_shadowed += o == uint8_t(Outcome::kShadowed);
      m->embree_kept += a.kept.size();
      m->vulkan_kept += b.kept.size();
    }
    return m;
  }();
  return *c;
}

class VulkanMasksTest : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!NoVulkanReason().empty()) GTEST_SKIP() << NoVulkanReason();
  }
};

TEST_F(VulkanMasksTest, AgreeWithEmbreeRaysOnACaptureWithCastShadows) {
  const MaskCase& c = Compared();
  const MaskAgreement& g = c.agreement;
  std::printf("pairs %llu, agreeing %.4f %%; visible only on vulkan %llu / embree %llu, lit only "
              "on vulkan %llu / embree %llu, footprint ok only on vulkan %llu / embree %llu, "
              "other %llu; near an edge %llu of %llu; shadowed embree %llu vulkan %llu; kept "
              "embree %llu vulkan %llu\n",
              (unsigned long long)g.pairs, 100.0 * g.AgreeingFraction(),
              (unsigned long long)g.visible_only_vulkan, (unsigned long long)g.visible_only_embree,
              (unsigned long long)g.lit_only_vulkan, (unsigned long long)g.lit_only_embree,
              (unsigned long long)g.footprint_only_vulkan,
              (unsigned long long)g.footprint_only_embree, (unsigned long long)g.other,
              (unsigned long long)g.near_edge, (unsigned long long)g.disagreeing(),
              (unsigned long long)c.embree_shadowed, (unsigned long long)c.vulkan_shadowed,
              (unsigned long long)c.embree_kept, (unsigned long long)c.vulkan_kept);
  for (int a = 0; a < kOutcomeCount; ++a) {
    for (int b = 0; b < kOutcomeCount; ++b) {
      const uint64_t n = g.confusion[a * kOutcomeCount + b];
      if (a != b && n > 0) {
        std::printf("  embree %s, vulkan %s: %llu\n", OutcomeName(Outcome(a)),
                    OutcomeName(Outcome(b)), (unsigned long long)n);
      }
    }
  }
  EXPECT_EQ(g.pairs, uint64_t(c.atlas.TexelCount()) * c.capture.images.size());
  EXPECT_GE(g.AgreeingFraction(), kMinAgreement);
  if (g.disagreeing() > 0) {
    EXPECT_GE(double(g.near_edge) / double(g.disagreeing()), kMinNearEdgeFraction);
  }
  // The comparison has teeth: the relief shadows itself, and both paths see it.
  EXPECT_GT(double(c.embree_shadowed), kMinShadowedPerKept * double(c.embree_kept));
  EXPECT_GT(double(c.vulkan_shadowed), kMinShadowedPerKept * double(c.vulkan_kept));
}

TEST_F(VulkanMasksTest, SamplesBothKeepHaveTheCpuValues) {
  const MaskAgreement& g = Compared().agreement;
  std::printf("kept by both %llu; max relative difference: value %.3g, weight %.3g; max "
              "direction difference %.3g\n",
              (unsigned long long)g.kept_both, g.max_value_rel_diff, g.max_weight_rel_diff,
              g.max_direction_diff);
  ASSERT_GT(g.kept_both, 1000u);
  EXPECT_LE(g.max_value_rel_diff, kValueTolerance);
  EXPECT_LE(g.max_weight_rel_diff, kWeightTolerance);
  EXPECT_LE(g.max_direction_diff, kDirectionTolerance);
  EXPECT_LE(double(g.other_pixel), kMaxOtherPixelShare * double(g.kept_both));
}

// A variance image for photograph `pixels` (images[].variance): 1e-6 + (0.05 p)² per channel
// (5 % noise with a floor), a hundred times that in the right half. It makes the dark pixels of
// the shadowed and grazing parts dark by the variance (the noise-free capture's noise model calls
// only values <= 0 dark) and halves the image's weights by 100: both paths must follow it.
float TestVariance(const Image& pixels, int x, int y, int c) {
  const float p = pixels.at(x, y, c);
  const float var = 1e-6f + 0.0025f * p * p;
  return x >= pixels.width / 2 ? 100 * var : var;
}

Image VarianceImageOf(const Image& pixels) {
  Image variance(pixels.width, pixels.height, 3);
  for (int y = 0; y < pixels.height; ++y) {
    for (int x = 0; x < pixels.width; ++x) {
      for (int c = 0; c < 3; ++c) variance.at(x, y, c) = TestVariance(pixels, x, y, c);
    }
  }
  return variance;
}

// Pairs both paths carried to the pixel tests (kept, invalid, clipped or dark on both) that they
// decided differently: float rounding may flip a value within ~1e-6 of its 3 σ or -5 σ
// threshold (the GPU's bilinear weights come from a float projection), nothing else.
constexpr double kMaxPixelTestFlipFraction = 1e-4;

// With a variance image, masks.comp takes each sample's noise from it as the CPU does (the
// twins MeasuredVariance, MeasuredInvalid, MeasuredDark, MeasuredPixelVariance): the same
// outcomes, the pixel tests included, and the same weights.
TEST_F(VulkanMasksTest, VarianceImageGivesTheCpuOutcomesAndWeights) {
  const MaskCase& c = Compared();
  auto cpu =
      ImageResampler::Create(c.capture, c.atlas, c.scene.get(), NoiseModel(), kDefaultMinCos);
  VulkanMaskOptions options;
  options.device = TestDevice();
  auto gpu = VulkanMasks::Create(c.capture, c.atlas, c.mesh, c.scene->SurfaceOffset(), NoiseModel(),
                                 kDefaultMinCos, options);
  ASSERT_TRUE(cpu.ok() && gpu.ok());
  MaskAgreement agreement;
  uint64_t dark_cpu = 0, dark_gpu = 0, dark_model = 0, pixel_tested = 0, pixel_flips = 0;
  double max_weight_change = 0;  // largest |w_variance / w_model - 1| of the GPU's samples
  auto pixel_test = [](uint8_t o) {
    return o == uint8_t(Outcome::kKept) || o == uint8_t(Outcome::kDark) ||
           o == uint8_t(Outcome::kInvalid) || o == uint8_t(Outcome::kClipped);
  };
  for (uint32_t i = 0; i < 8; ++i) {
    const Image pixels = ReadImageRgb(c.capture.Resolve(c.capture.images[i].file)).value();
    const Image variance = VarianceImageOf(pixels);
    ImageOutput a, b, model;
    CameraMapView map;
    ASSERT_TRUE((*cpu)->Process(i, pixels, &a, &variance).ok());
    const Status s = (*gpu)->Process(i, pixels, &b, &map, &variance);
    ASSERT_TRUE(s.ok()) << s.ToString();
    ASSERT_TRUE((*gpu)->Process(i, pixels, &model).ok());
    agreement.Add(c.atlas.position, a.outcome, b.outcome, a.kept, b.kept, map);
    for (size_t t = 0; t < a.outcome.size(); ++t) {
      dark_cpu += a.outcome[t] == uint8_t(Outcome::kDark);
      dark_gpu += b.outcome[t] == uint8_t(Outcome::kDark);
      dark_model += model.outcome[t] == uint8_t(Outcome::kDark);
      if (pixel_test(a.outcome[t]) && pixel_test(b.outcome[t])) {
        ++pixel_tested;
        pixel_flips += a.outcome[t] != b.outcome[t];
      }
    }
    std::map<uint32_t, const BrdfSample*> by_texel;
    for (const TexelSample& k : model.kept) by_texel[k.texel] = &k.sample;
    for (const TexelSample& k : b.kept) {
      auto it = by_texel.find(k.texel);
      if (it == by_texel.end()) continue;
      for (int ch = 0; ch < 3; ++ch) {
        max_weight_change = std::max(
            max_weight_change, std::abs(double(k.sample.weight[ch]) / it->second->weight[ch] - 1));
      }
    }
  }
  std::printf("with a variance image: agreeing %.4f %% of %llu pairs; kept by both %llu, max "
              "relative difference value %.3g, weight %.3g; dark cpu %llu gpu %llu (noise model "
              "%llu); pixel-test flips %llu of %llu\n",
              100.0 * agreement.AgreeingFraction(), (unsigned long long)agreement.pairs,
              (unsigned long long)agreement.kept_both, agreement.max_value_rel_diff,
              agreement.max_weight_rel_diff, (unsigned long long)dark_cpu,
              (unsigned long long)dark_gpu, (unsigned long long)dark_model,
              (unsigned long long)pixel_flips, (unsigned long long)pixel_tested);
  EXPECT_GE(agreement.AgreeingFraction(), kMinAgreement);
  ASSERT_GT(agreement.kept_both, 1000u);
  EXPECT_LE(agreement.max_value_rel_diff, kValueTolerance);
  EXPECT_LE(agreement.max_weight_rel_diff, kWeightTolerance);
  EXPECT_LE(double(pixel_flips), kMaxPixelTestFlipFraction * double(pixel_tested));
  // Teeth: the variance image changed the GPU's pixel tests and weights, not just the CPU's.
  EXPECT_GT(dark_gpu, dark_model + 100);
  EXPECT_GT(max_weight_change, 0.5);
}

// The same through ResampleCapture (the variance read beside each photograph and bound for the
// GPU), cross-checked against Embree on every photograph.
TEST_F(VulkanMasksTest, ResampleWithVarianceImagesAgreesWithEmbree) {
  const fs::path json =
      testing::AddVarianceImages(CaptureDir(), "capture_variance.json", "variance", TestVariance);
  testing::ScratchDir dir;
  ResampleOptions options;
  options.backend = Backend::kVulkan;
  options.device = TestDevice();
  options.cross_check = true;
  options.use_variance = true;
  auto summary = ResampleCapture(json, options, dir.path());
  ASSERT_TRUE(summary.ok()) << summary.status().ToString();
  const Json report = Json::parse(summary->report_json);
  EXPECT_EQ(report["backend"], "vulkan");
  EXPECT_EQ(report["noise_model"]["variance_images"], report["images"]);
  const Json& agreement = report["mask_agreement"];
  EXPECT_GE(agreement["agreeing_fraction"].get<double>(), kMinAgreement);
  EXPECT_GT(agreement["kept_by_both"].get<uint64_t>(), 1000u);
  EXPECT_LE(agreement["max_weight_relative_difference"].get<double>(), kWeightTolerance);
  EXPECT_LE(agreement["max_value_relative_difference"].get<double>(), kValueTolerance);
}

// The other light and camera kinds the synthetic rig does not use: a point light inside the
// object's bounding sphere (cube light map), a directional light (orthographic light map), an
// orthographic camera, and a pinhole camera with lens distortion (camera map on the undistorted
// grid). Visibility and shadow do not depend on the pixels, so every photograph is a constant
// grey that passes the pixel tests on both paths, and all of the outcome is the masks'.
TEST_F(VulkanMasksTest, AgreeWithEmbreeForCubeOrthographicAndDistortedSetups) {
  const MaskCase& c = Compared();
  const Eigen::AlignedBox3f box = c.mesh.Bounds();
  const Vec3d centre = box.center().cast<double>(), half = (box.sizes() / 2).cast<double>();
  double radius = 0;  // of the bounding sphere about the box centre, as VulkanMasks measures it
  for (const Vec3f& p : c.mesh.positions) radius = std::max(radius, (p.cast<double>() - centre).norm());
  enum Kind { kCubeLight, kDirectionalLight, kOrthographicCamera, kDistortedCamera };
  for (Kind kind : {kCubeLight, kDirectionalLight, kOrthographicCamera, kDistortedCamera}) {
    Capture capture = c.capture;
    for (Light& light : capture.lights) {
      if (kind == kCubeLight) {
        // On the turntable axis, above the top face and inside the bounding sphere: halfway
        // between the top (half.z <= radius) and 1.05 radii, where the cube map takes over.
        light.position = centre + Vec3d(0.0, 0.0, 0.5 * (half.z() + 1.05 * radius));
      } else if (kind == kDirectionalLight) {
        light.type = LightType::kDirectional;
        light.direction = Vec3d(0.3, -0.4, 0.8).normalized();
      }
    }
    for (Camera& camera : capture.cameras) {
      if (kind == kOrthographicCamera) {
        camera.model = CameraModel::kOrthographic;
        camera.pixel_size_m = 2.4 * half.norm() / camera.width;
      } else if (kind == kDistortedCamera) {
        camera.dist = {-0.15, 0.05, 0.002, -0.002, 0.0};
      }
    }
    auto cpu = ImageResampler::Create(capture, c.atlas, c.scene.get(), NoiseModel(), kDefaultMinCos);
    VulkanMaskOptions options;
    options.device = TestDevice();
    auto gpu = VulkanMasks::Create(capture, c.atlas, c.mesh, c.scene->SurfaceOffset(), NoiseModel(),
                                   kDefaultMinCos, options);
    ASSERT_TRUE(cpu.ok()) << cpu.status().ToString();
    ASSERT_TRUE(gpu.ok()) << gpu.status().ToString();
    MaskAgreement agreement;
    uint64_t shadowed = 0, kept = 0;
    std::string light_map;
    const uint32_t images = std::min<uint32_t>(8, uint32_t(capture.images.size()));
    for (uint32_t i = 0; i < images; ++i) {
      const Camera& camera = capture.cameras[capture.images[i].camera];
      const Image grey(camera.width, camera.height, 3, 0.5f);
      ImageOutput a, b;
      CameraMapView map;
      ASSERT_TRUE((*cpu)->Process(i, grey, &a).ok());
      const Status s = (*gpu)->Process(i, grey, &b, &map);
      ASSERT_TRUE(s.ok()) << s.ToString();
      agreement.Add(c.atlas.position, a.outcome, b.outcome, a.kept, b.kept, map);
      for (uint8_t o : a.outcome) shadowed += o == uint8_t(Outcome::kShadowed);
      kept += a.kept.size();
      light_map = (*gpu)->last_stats().light_map;
    }
    std::printf("setup %d (light map %s): agreeing %.4f %% of %llu pairs, %llu near an edge of "
                "%llu; Embree shadowed %llu, kept %llu\n",
                int(kind), light_map.c_str(), 100.0 * agreement.AgreeingFraction(),
                (unsigned long long)agreement.pairs, (unsigned long long)agreement.near_edge,
                (unsigned long long)agreement.disagreeing(), (unsigned long long)shadowed,
                (unsigned long long)kept);
    const bool point_pixels = capture.cameras[0].pixel_filter == PixelFilter::kPoint;
    EXPECT_GE(agreement.AgreeingFraction(), kind == kDistortedCamera && point_pixels
                                                ? kMinAgreementDistortedPointPixels
                                                : kMinAgreement)
        << "setup " << int(kind);
    // Each setup keeps samples at all (the light just above the top face lights little else).
    EXPECT_GT(kept, agreement.pairs / 100) << "setup " << int(kind);
    EXPECT_GT(shadowed, 0u) << "setup " << int(kind);
    if (kind == kCubeLight) {
      EXPECT_EQ(light_map, "cube");
    }
    if (kind == kDirectionalLight) {
      EXPECT_EQ(light_map, "orthographic");
    }
  }
}

// Atlases beyond one storage-buffer binding (2 M texels on lavapipe) are dispatched in chunks:
// forced here to 1024-texel chunks, the outcomes and samples are those of one dispatch.
TEST_F(VulkanMasksTest, ChunkedDispatchGivesTheSameResult) {
  const MaskCase& c = Compared();
  ASSERT_GT(c.atlas.TexelCount(), 2048u);  // at least three chunks
  VulkanMaskOptions whole, chunked;
  whole.device = chunked.device = TestDevice();
  chunked.max_chunk_texels = 1024;
  auto a = VulkanMasks::Create(c.capture, c.atlas, c.mesh, c.scene->SurfaceOffset(), NoiseModel(),
                               kDefaultMinCos, whole);
  auto b = VulkanMasks::Create(c.capture, c.atlas, c.mesh, c.scene->SurfaceOffset(), NoiseModel(),
                               kDefaultMinCos, chunked);
  ASSERT_TRUE(a.ok() && b.ok());
  for (uint32_t i = 0; i < 2; ++i) {
    const Image pixels = ReadImageRgb(c.capture.Resolve(c.capture.images[i].file)).value();
    ImageOutput oa, ob;
    ASSERT_TRUE((*a)->Process(i, pixels, &oa).ok());
    ASSERT_TRUE((*b)->Process(i, pixels, &ob).ok());
    EXPECT_EQ(oa.outcome, ob.outcome);
    ASSERT_EQ(oa.kept.size(), ob.kept.size());
    for (size_t k = 0; k < oa.kept.size(); ++k) {
      EXPECT_EQ(oa.kept[k].texel, ob.kept[k].texel);
      EXPECT_EQ(oa.kept[k].sample.value[1], ob.kept[k].sample.value[1]);
    }
  }
}

TEST_F(VulkanMasksTest, RejectsWhatItCannotUse) {
  const MaskCase& c = Compared();
  VulkanMaskOptions options;
  options.device = TestDevice();
  EXPECT_EQ(VulkanMasks::Create(c.capture, c.atlas, c.mesh, c.scene->SurfaceOffset(), NoiseModel(),
                                1.0, options)
                .status()
                .code(),
            StatusCode::kInvalidArgument);
  options.light_bias_texels = -1;
  EXPECT_EQ(options.Validate().code(), StatusCode::kInvalidArgument);
  options = VulkanMaskOptions();
  options.device = TestDevice();
  auto masks = VulkanMasks::Create(c.capture, c.atlas, c.mesh, c.scene->SurfaceOffset(),
                                   NoiseModel(), kDefaultMinCos, options);
  ASSERT_TRUE(masks.ok()) << masks.status().ToString();
  EXPECT_FALSE((*masks)->device_name().empty());
  // What `reflcap run` asks before resampling on the fit's device: the same device's kind.
  const StatusOr<bool> on_gpu = VulkanMasksOnGpu(TestDevice());
  ASSERT_TRUE(on_gpu.ok()) << on_gpu.status().ToString();
  EXPECT_EQ(*on_gpu, !(*masks)->software_device());
  EXPECT_FALSE(VulkanMasksOnGpu("no-such-device").ok());
  EXPECT_EQ(*VulkanMasksOnGpu(TestDevice(), &c.capture), *on_gpu);
  // Photographs larger than any storage-buffer binding (at most 4 GiB): Process would refuse them.
  Capture huge = c.capture;
  huge.cameras[0].width = huge.cameras[0].height = 65536;
  const StatusOr<bool> too_large = VulkanMasksOnGpu(TestDevice(), &huge);
  EXPECT_EQ(too_large.status().code(), StatusCode::kUnavailable);
  EXPECT_NE(too_large.status().message().find("cameras[0]"), std::string::npos)
      << too_large.status().message();
  ImageOutput out;
  EXPECT_EQ((*masks)->Process(0, Image(3, 3, 3), &out).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ((*masks)->Process(uint32_t(c.capture.images.size()), Image(3, 3, 3), &out).code(),
            StatusCode::kInvalidArgument);
}

TEST_F(VulkanMasksTest, CliWritesAStoreAndAReportWithDeviceAndAgreement) {
  testing::ScratchDir dir;
  const fs::path out = dir / "samples";
  std::string args = "resample " + CaptureDir().string() + " --out " + out.string() +
                     " --backend vulkan --cross-check";
  if (!TestDevice().empty()) args += " --device " + TestDevice();
  testing::CliResult r = testing::RunCommand(REFLCAP_BINARY, args, dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("mask agreement"), std::string::npos) << r.out;
  ASSERT_TRUE(fs::exists(out / "store.json"));
  ASSERT_TRUE(fs::exists(out / "chunk_00000.rcs"));
  std::FILE* f = std::fopen((out / "resample_report.json").c_str(), "rb");
  ASSERT_NE(f, nullptr);
  std::string text;
  char buf[4096];
  for (size_t n; (n = std::fread(buf, 1, sizeof buf, f)) > 0;) text.append(buf, n);
  std::fclose(f);
  const Json report = Json::parse(text);
  EXPECT_EQ(report["backend"], "vulkan");
  EXPECT_FALSE(report["device"].get<std::string>().empty());
  const Json& agreement = report["mask_agreement"];
  EXPECT_GE(agreement["agreeing_fraction"].get<double>(), kMinAgreement);
  EXPECT_EQ(agreement["pairs_compared"].get<uint64_t>(), report["pairs"].get<uint64_t>());
  EXPECT_GT(report["samples_kept"].get<uint64_t>(), 0u);
  // The store is the Vulkan path's: kept + rejected = pairs still holds.
  EXPECT_EQ(report["samples_kept"].get<uint64_t>() + report["samples_rejected_total"].get<uint64_t>(),
            report["pairs"].get<uint64_t>());
}

// Without any Vulkan driver, --backend vulkan exits 3 with a message naming Vulkan; the CPU
// backend is unaffected. In a child process, so the environment change cannot leak.
TEST(VulkanMasksWithoutDriver, BackendVulkanIsUnavailable) {
  GTEST_FLAG_SET(death_test_style, "threadsafe");
  EXPECT_EXIT(
      {
        setenv("VK_ICD_FILENAMES", "/nonexistent/reflcap_no_icd.json", 1);
        setenv("VK_DRIVER_FILES", "/nonexistent/reflcap_no_icd.json", 1);
        const Status s = BackendAvailable(Backend::kVulkan);
        const bool ok = s.code() == StatusCode::kUnavailable &&
                        s.message().find("Vulkan") != std::string::npos &&
                        BackendAvailable(Backend::kCpu).ok();
        std::fprintf(stderr, "%s\n", s.ToString().c_str());
        std::exit(ok ? 0 : 1);
      },
      ::testing::ExitedWithCode(0), "");
}

}  // namespace
}  // namespace reflcap::resample
