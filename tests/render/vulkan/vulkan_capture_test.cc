// The Vulkan renderer against the CPU reference renderer on a synthetic capture (the relief
// object, which shadows itself, with the six ground-truth materials), through the capture-level
// API both backends of `reflcap render` use: the criterion — PSNR >= 50 dB between the two
// renders excluding pixels within 2 px of cast-shadow edges and silhouettes — per image, with the
// excluded fraction printed; under point lights (fitted frustum and cube map), directional lights,
// supersampling, and cameras with real lens distortion.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <vector>

#include "acquire/synth/synth.h"
#include "render/reference/render_capture.h"
#include "render/vulkan/vulkan_render_capture.h"
#include "tests/render/vulkan/vulkan_test_util.h"
#include "tests/support/test_support.h"

namespace reflcap::render {
namespace {
namespace fs = std::filesystem;

using testing::Agreement;
using testing::Compare;
using testing::kMinPsnrDb;

// A small noise-free synthetic capture: 2 cameras x 3 point lights x 4 turntable steps, 96 px.
struct SynthCapture {
  reflcap::testing::ScratchDir dir;
  Capture capture;
  std::unique_ptr<FittedCapture> fitted;
};

const SynthCapture& Synth() {
  static SynthCapture* s = [] {
    auto* sc = new SynthCapture();
    // Its folder removed after the last test: ctest runs each test in a process of its own.
    reflcap::testing::ReleaseBeforeExit([sc] { delete sc; });
    synth::SynthOptions o;
    o.noise = 0;
    o.texels = 4000;
    o.image_size = 96;
    o.cameras = 2;
    o.lights = 3;
    o.steps = 4;
    auto summary = synth::WriteSyntheticCapture(o, sc->dir / "capture");
    REFLCAP_CHECK(summary.ok()) << summary.status().ToString();
    auto capture = ReadCapture(sc->dir / "capture");
    REFLCAP_CHECK(capture.ok()) << capture.status().ToString();
    sc->capture = std::move(capture).value();
    auto fitted = LoadFittedCapture(sc->capture, sc->dir / "capture/gt/params.exr");
    REFLCAP_CHECK(fitted.ok()) << fitted.status().ToString();
    sc->fitted = std::move(fitted).value();
    return sc;
  }();
  return *s;
}

// Renders every image of `fitted` (whose capture may have been modified) with both renderers and
// returns the pooled agreement; each image must reach kMinPsnrDb on its own.
Agreement CompareAllImages(VulkanRenderer& renderer, const FittedCapture& fitted,
                           const RenderOptions& options, const char* label) {
  EXPECT_TRUE(SetFittedScene(renderer, fitted).ok());
  Agreement pooled;
  double worst_psnr = 1e9;
  size_t images_with_shadows = 0;
  for (size_t i = 0; i < fitted.capture->images.size(); ++i) {
    auto cpu = RenderCaptureImage(fitted, i, options);
    auto gpu = RenderCaptureImageVulkan(renderer, fitted, i, options);
    EXPECT_TRUE(cpu.ok() && gpu.ok()) << gpu.status().ToString();
    if (!cpu.ok() || !gpu.ok()) return pooled;
    const Agreement a = Compare(*cpu, *gpu);
    EXPECT_GE(a.psnr_db, kMinPsnrDb) << label << ", image " << i << ": " << a.ToString();
    if (a.psnr_db < kMinPsnrDb) {
      testing::PrintWorstPixels(*cpu, *gpu, a, 8);
      testing::DumpRenders(std::string(label) + "_image" + std::to_string(i), *cpu, *gpu);
    }
    worst_psnr = std::min(worst_psnr, a.psnr_db);
    size_t shadowed = 0;
    for (int y = 0; y < cpu->aux.height; ++y) {
      for (int x = 0; x < cpu->aux.width; ++x) shadowed += cpu->aux.at(x, y, kAuxCastShadow) > 0.5f;
    }
    images_with_shadows += shadowed > 0;
    pooled.Add(a);
  }
  std::printf(
      "[ vulkan   ] %s: %zu images (%zu with cast shadows), worst image PSNR %.1f dB; pooled %s\n",
      label, fitted.capture->images.size(), images_with_shadows, worst_psnr,
      pooled.ToString().c_str());
  EXPECT_GT(images_with_shadows, fitted.capture->images.size() / 2) << label;
  return pooled;
}

RenderOptions WithAux(int supersampling = 1) {
  RenderOptions o;
  o.aux_buffers = true;
  o.supersampling = supersampling;
  return o;
}

// Own renderer with non-default options, on the test device.
std::unique_ptr<VulkanRenderer> MakeRenderer(const VulkanRenderOptions& options) {
  const char* device = std::getenv("REFLCAP_TEST_VK_DEVICE");
  auto r = VulkanRenderer::Create(device ? device : "", options);
  EXPECT_TRUE(r.ok()) << r.status().ToString();
  return r.ok() ? std::move(r).value() : nullptr;
}

class VulkanCapture : public testing::VulkanRendererTest {};

TEST_F(VulkanCapture, GroundTruthRendersMatchCpuUnderPointLights) {
  const Agreement a =
      CompareAllImages(renderer(), *Synth().fitted, WithAux(), "synth, point lights");
  EXPECT_GE(a.psnr_db, kMinPsnrDb);
  EXPECT_EQ(renderer().last_stats().shadow_map, "fitted");
  EXPECT_LT(a.ExcludedFraction(), 0.5);
}

TEST_F(VulkanCapture, CubeShadowMapMatchesCpu) {
  VulkanRenderOptions vo;
  vo.shadow_map = ShadowMapKind::kCube;
  std::unique_ptr<VulkanRenderer> r = MakeRenderer(vo);
  ASSERT_NE(r, nullptr);
  const Agreement a = CompareAllImages(*r, *Synth().fitted, WithAux(), "synth, cube shadow map");
  EXPECT_GE(a.psnr_db, kMinPsnrDb);
  EXPECT_EQ(r->last_stats().shadow_map, "cube");
}

TEST_F(VulkanCapture, DirectionalLightsMatchCpu) {
  // The same capture with each point light replaced by a directional one from where it stood.
  Capture capture = Synth().capture;
  for (Light& light : capture.lights) {
    light.type = LightType::kDirectional;
    light.direction = light.position.normalized();
    light.intensity *= 2;  // E = I cos, not I cos / d² with d = 1 m
  }
  auto fitted = LoadFittedCapture(capture, Synth().dir / "capture/gt/params.exr");
  ASSERT_TRUE(fitted.ok()) << fitted.status().ToString();
  const Agreement a =
      CompareAllImages(renderer(), **fitted, WithAux(), "synth, directional lights");
  EXPECT_GE(a.psnr_db, kMinPsnrDb);
  EXPECT_EQ(renderer().last_stats().shadow_map, "orthographic");
}

TEST_F(VulkanCapture, DistortedCamerasMatchCpu) {
  // Real lens distortion (barrel, as a short lens has, with decentring): the CPU traces exact
  // rays through the distorted pixels; the Vulkan renderer resolves them through its visibility
  // image.
  Capture capture = Synth().capture;
  capture.cameras[0].dist = {-0.18, 0.09, 0.0012, -0.0008, -0.015};
  capture.cameras[1].dist = {0.06, -0.02, -0.0005, 0.0009, 0.0};
  auto fitted = LoadFittedCapture(capture, Synth().dir / "capture/gt/params.exr");
  ASSERT_TRUE(fitted.ok()) << fitted.status().ToString();
  const Agreement a = CompareAllImages(renderer(), **fitted, WithAux(), "synth, distorted cameras");
  EXPECT_GE(a.psnr_db, kMinPsnrDb);
  EXPECT_TRUE(renderer().last_stats().distortion_resolve);
}

TEST_F(VulkanCapture, SupersampledRendersMatchCpu) {
  Capture capture = Synth().capture;
  capture.images.resize(6);  // a few images suffice: the supersampling path is the same for all
  capture.cameras[1].dist = {-0.1, 0.03, 0, 0, 0};
  auto fitted = LoadFittedCapture(capture, Synth().dir / "capture/gt/params.exr");
  ASSERT_TRUE(fitted.ok()) << fitted.status().ToString();
  const Agreement a =
      CompareAllImages(renderer(), **fitted, WithAux(3), "synth, 3x3 supersampling");
  EXPECT_GE(a.psnr_db, kMinPsnrDb);
}

}  // namespace
}  // namespace reflcap::render
