// The Vulkan renderer against the CPU reference renderer and closed forms on small analytic
// scenes: Lambertian plane and sphere (to ~1e-4 relative away from silhouettes), a known occluder
// under each kind of shadow map, supersampling, an orthographic camera, back faces, and a
// normal-map capture.
#include "render/vulkan/vulkan_renderer.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <utility>
#include <vector>

#include "engine/brdf/lafortune.h"
#include "engine/core/status.h"
#include "engine/mesh/height_field.h"
#include "engine/mesh/ray_scene.h"
#include "tests/render/vulkan/vulkan_test_util.h"
#include "tests/support/height_scenes.h"
#include "tests/support/shapes.h"

namespace reflcap::render {
namespace {

using testing::Agreement;
using testing::Compare;
using testing::kMinPsnrDb;

// Both renderers shade in float from the same float inputs at the same surface point: the GPU
// intersects each sample's exact ray with the triangle the rasteriser found
// (shaders/render/surface_hit.glsl), as Embree does, so the point agrees to float rounding (~1e-6
// relative of the distance) whatever the device's sub-pixel precision (interpolated attributes
// carried its snapping: up to 3.6e-4 relative on an NVIDIA H100, subPixelPrecisionBits 8). 1e-4
// is the bar. Measured worst interior error: plane 6.1e-7 on the H100 / 5.7e-7 on
// lavapipe, sphere 1.7e-6 / 2.1e-6; the renderers' exp/log are precise_math twins, not the
// device's, so transcendental accuracy does not enter.
constexpr double kRelTolerance = 1e-4;
// |Δ cos θ| of the aux buffers: the same exact points and normals; measured at most 8.5e-7 (H100)
// and 7.7e-7 (lavapipe) on these scenes (2.7e-5 on the H100 with interpolated attributes).
constexpr double kAuxCosTolerance = 1e-5;
// Values below this fraction of the image's peak are compared in absolute terms.
constexpr double kAbsFloorFraction = 1e-3;
// Sphere pixels compared only where both cosines exceed this (as the CPU closed-form test).
constexpr double kSphereMinCos = 0.3;

Camera LookAtCamera(const Vec3d& eye, const Vec3d& target, int w, int h, double f) {
  Camera cam;
  cam.id = "cam";
  cam.width = w;
  cam.height = h;
  cam.K << f, 0, 0.5 * (w - 1), 0, f, 0.5 * (h - 1), 0, 0, 1;
  cam.cam_from_world = CamFromWorldLookAt(eye, target);
  return cam;
}

struct Scene {
  TriangleMesh mesh;
  std::unique_ptr<RayScene> rays;
  TexelAtlas atlas;
  BrdfMaps maps;
  ShadedScene shaded() const { return {rays.get(), &atlas, &maps}; }
};

// A scene of `mesh` whose texels all carry `params`, or a checkerboard of `params` and `other`
// (by texel parity) when `checker`.
Scene MakeScene(TriangleMesh mesh, const brdf::BrdfParams& params, int atlas_res,
                const brdf::BrdfParams* other = nullptr) {
  Scene s;
  s.mesh = std::move(mesh);
  auto rays = RayScene::Create(s.mesh);
  REFLCAP_CHECK(rays.ok()) << rays.status().ToString();
  s.rays = std::move(rays).value();
  auto atlas = BuildTexelAtlas(s.mesh, atlas_res, atlas_res);
  REFLCAP_CHECK(atlas.ok()) << atlas.status().ToString();
  s.atlas = std::move(atlas).value();
  s.maps.num_lobes = params.num_lobes;
  s.maps.texels.assign(s.atlas.TexelCount(), params);
  if (other != nullptr) {
    for (size_t t = 0; t < s.atlas.TexelCount(); ++t) {
      int x, y;
      s.atlas.PixelOf(t, &x, &y);
      if ((x / 2 + y / 2) % 2) s.maps.texels[t] = *other;
    }
  }
  return s;
}

brdf::BrdfParams Lambert(const Vec3f& albedo) {
  brdf::BrdfParams p;
  p.num_lobes = 0;
  p.rho_d = {albedo.x(), albedo.y(), albedo.z()};
  return p;
}

brdf::BrdfParams Glossy(const Vec3f& albedo, double n) {
  brdf::BrdfParams p = Lambert(albedo);
  p.num_lobes = 1;
  for (int c = 0; c < 3; ++c) p.lobes[0][c] = brdf::MirrorLobe(0.8 + 0.3 * c, n);
  return p;
}

RenderOptions WithAux(int supersampling = 1) {
  RenderOptions o;
  o.aux_buffers = true;
  o.supersampling = supersampling;
  return o;
}

// Pixels where both renders have the object and every 8-neighbour has it in both (away from
// silhouettes), compared to kRelTolerance relative (absolute below the floor).
struct RelativeCheck {
  size_t compared = 0, failed = 0;
  double worst = 0;
};
RelativeCheck CompareInterior(const RenderResult& cpu, const RenderResult& gpu,
                              const Image* skip = nullptr) {
  RelativeCheck r;
  double peak = 0;
  for (float v : cpu.pixels.data) peak = std::max(peak, double(v));
  const int w = cpu.pixels.width, h = cpu.pixels.height;
  for (int y = 1; y + 1 < h; ++y) {
    for (int x = 1; x + 1 < w; ++x) {
      bool interior = true;
      for (int dy = -1; dy <= 1; ++dy) {
        for (int dx = -1; dx <= 1; ++dx) {
          interior =
              interior && cpu.mask.at(x + dx, y + dy) > 0.5f && gpu.mask.at(x + dx, y + dy) > 0.5f;
        }
      }
      if (!interior || (skip != nullptr && skip->at(x, y) > 0.5f)) continue;
      ++r.compared;
      for (int c = 0; c < 3; ++c) {
        const double a = cpu.pixels.at(x, y, c), b = gpu.pixels.at(x, y, c);
        const double scale = std::max(std::abs(a), kAbsFloorFraction * peak);
        const double rel = std::abs(b - a) / scale;
        r.worst = std::max(r.worst, rel);
        if (rel > kRelTolerance) {
          if (r.failed < 5) {
            ADD_FAILURE() << "pixel " << x << "," << y << " channel " << c << ": cpu " << a
                          << " vulkan " << b << " (rel " << rel << ")";
          }
          ++r.failed;
        }
      }
    }
  }
  return r;
}

class VulkanRendererScenes : public testing::VulkanRendererTest {};

TEST_F(VulkanRendererScenes, LambertianPlaneMatchesCpuAndClosedForm) {
  const Vec3f albedo(0.5f, 0.3f, 0.2f);
  Scene s = MakeScene(reflcap::testing::MakeGridPlane(2, 2, 4, 4), Lambert(albedo), 64);
  ASSERT_TRUE(renderer().SetScene(s.shaded()).ok());
  Camera cam = LookAtCamera({0.3, 0.2, 2.0}, {0, 0, 0}, 64, 48, 40);
  Light light;
  light.position = {0.5, -0.4, 1.5};
  light.intensity = {2, 3, 4};
  for (bool distorted : {false, true}) {
    SCOPED_TRACE(distorted ? "distorted" : "pinhole");
    cam.dist = {};
    if (distorted) cam.dist = {-0.05, 0.01, 0.001, 0.0005, 0};
    auto cpu = RenderImage(s.shaded(), cam, light, Rigid3(), 0.5, WithAux());
    auto gpu = renderer().RenderImage(cam, light, Rigid3(), 0.5, WithAux());
    ASSERT_TRUE(cpu.ok() && gpu.ok()) << gpu.status().ToString();
    const RelativeCheck r = CompareInterior(*cpu, *gpu);
    EXPECT_GT(r.compared, 1000u);
    EXPECT_EQ(r.failed, 0u) << "worst relative error " << r.worst;
    const Agreement a = Compare(*cpu, *gpu);
    std::printf("[ vulkan   ] plane%s: %s; worst interior rel %.2g\n",
                distorted ? " (distorted)" : "", a.ToString().c_str(), r.worst);
    EXPECT_EQ(a.mask_mismatches, 0u);
    EXPECT_GE(a.psnr_db, kMinPsnrDb);
  }
}

TEST_F(VulkanRendererScenes, LambertianSphereMatchesCpu) {
  const Vec3f albedo(0.8f, 0.6f, 0.4f);
  Scene s = MakeScene(reflcap::testing::MakeUvSphere(0.5f, 360, 180), Lambert(albedo), 256);
  ASSERT_TRUE(renderer().SetScene(s.shaded()).ok());
  const Camera cam = LookAtCamera({3, 0.5, 1}, {0, 0, 0}, 96, 96, 150);
  Light light;
  light.position = {1.5, 2.0, 2.5};
  light.intensity = {5, 5, 5};
  auto cpu = RenderImage(s.shaded(), cam, light, Rigid3(), 1.0, WithAux());
  ASSERT_TRUE(cpu.ok());
  // Only where both cosines exceed kSphereMinCos (the CPU closed-form test's region).
  Image skip(cam.width, cam.height, 1, 0.0f);
  for (int y = 0; y < cam.height; ++y) {
    for (int x = 0; x < cam.width; ++x) {
      if (cpu->aux.at(x, y, kAuxCosThetaI) < kSphereMinCos ||
          cpu->aux.at(x, y, kAuxCosThetaO) < kSphereMinCos) {
        skip.at(x, y) = 1;
      }
    }
  }
  // Both ways of shading a pinhole camera. The sphere's pole fans put many slivers in a pixel:
  // the resolve's walk from the visibility image's triangle once stopped short there (8 steps:
  // 0.2 % error on the H200 and lavapipe).
  for (CameraShading shading : {CameraShading::kFragment, CameraShading::kResolve}) {
    const bool resolve = shading == CameraShading::kResolve;
    SCOPED_TRACE(resolve ? "resolve" : "per-fragment");
    VulkanRenderOptions vo;
    vo.camera_shading = shading;
    const char* device = std::getenv("REFLCAP_TEST_VK_DEVICE");
    auto renderer = VulkanRenderer::Create(device ? device : "", vo);
    ASSERT_TRUE(renderer.ok()) << renderer.status().ToString();
    ASSERT_TRUE((*renderer)->SetScene(s.shaded()).ok());
    auto gpu = (*renderer)->RenderImage(cam, light, Rigid3(), 1.0, WithAux());
    ASSERT_TRUE(gpu.ok()) << gpu.status().ToString();
    EXPECT_EQ((*renderer)->last_stats().distortion_resolve, resolve);
    const RelativeCheck r = CompareInterior(*cpu, *gpu, &skip);
    EXPECT_GT(r.compared, 800u);
    EXPECT_EQ(r.failed, 0u) << "worst relative error " << r.worst;
    const Agreement a = Compare(*cpu, *gpu);
    std::printf("[ vulkan   ] sphere, %s: %s; worst rel (cos > %.1f) %.2g\n",
                resolve ? "resolve" : "per-fragment", a.ToString().c_str(), kSphereMinCos,
                r.worst);
    EXPECT_GE(a.psnr_db, kMinPsnrDb);
    EXPECT_EQ(a.mask_mismatches, 0u);
  }
}

// Ground plane, a square occluder above it with its own UV island, checkerboard glossy material.
Scene MakeOccluderScene() {
  TriangleMesh mesh = reflcap::testing::MakeGridPlane(2, 2, 8, 8, 0);
  TriangleMesh occluder = reflcap::testing::MakeGridPlane(0.4f, 0.4f, 2, 2, 0.3f);
  for (auto& uv : occluder.corner_uvs) {
    for (auto& c : uv) c = Vec2f(0.75f, 0.75f) + 0.2f * c;
  }
  for (auto& uv : mesh.corner_uvs) {
    for (auto& c : uv) c *= 0.5f;
  }
  reflcap::testing::AppendMesh(occluder, &mesh);
  const brdf::BrdfParams a = Glossy({0.5f, 0.4f, 0.3f}, 30), b = Lambert({0.2f, 0.6f, 0.3f});
  return MakeScene(std::move(mesh), a, 64, &b);
}

TEST_F(VulkanRendererScenes, KnownOccluderUnderEveryShadowMapMatchesCpu) {
  Scene s = MakeOccluderScene();
  const Camera cam = LookAtCamera({0.1, -1.2, 2.2}, {0, 0, 0}, 120, 120, 90);
  struct Case {
    const char* name;
    LightType type;
    Vec3d where;  // point light position or directional light direction
    ShadowMapKind kind;
    bool resolve;  // CameraShading::kResolve: visibility image + exact rays
    const char* expect_map;
  };
  const Vec3d inside(0.2, 0.1, 1.0), outside(0.3, -0.3, 1.9);
  const Case cases[] = {
      {"point light inside the bounds", LightType::kPoint, inside, ShadowMapKind::kAuto, false,
       "cube"},
      {"point light outside the bounds", LightType::kPoint, outside, ShadowMapKind::kAuto, false,
       "fitted"},
      {"point light outside the bounds, cube map", LightType::kPoint, outside, ShadowMapKind::kCube,
       false, "cube"},
      {"directional light", LightType::kDirectional, Vec3d(0.3, 0.2, 1).normalized(),
       ShadowMapKind::kAuto, false, "orthographic"},
      {"point light inside the bounds, resolve path", LightType::kPoint, inside,
       ShadowMapKind::kAuto, true, "cube"},
  };
  for (const auto& [c, raster] :
       [&] {
         std::vector<std::pair<Case, ShadowRaster>> all;
         for (const Case& c : cases) {
           for (ShadowRaster r : {ShadowRaster::kGraphics, ShadowRaster::kCompute}) {
             all.push_back({c, r});
           }
         }
         return all;
       }()) {
    SCOPED_TRACE(StrCat(c.name, raster == ShadowRaster::kCompute ? ", compute-drawn map" : ""));
    VulkanRenderOptions vo;
    vo.shadow_map = c.kind;
    vo.camera_shading = c.resolve ? CameraShading::kResolve : CameraShading::kFragment;
    vo.shadow_raster = raster;
    const char* device = std::getenv("REFLCAP_TEST_VK_DEVICE");
    auto r = VulkanRenderer::Create(device ? device : "", vo);
    ASSERT_TRUE(r.ok()) << r.status().ToString();
    ASSERT_TRUE((*r)->SetScene(s.shaded()).ok());
    Light light;
    light.type = c.type;
    light.intensity = {1.5, 1.5, 1.5};
    if (c.type == LightType::kPoint)
      light.position = c.where;
    else
      light.direction = c.where;
    auto cpu = RenderImage(s.shaded(), cam, light, Rigid3(), 1.0, WithAux());
    auto gpu = (*r)->RenderImage(cam, light, Rigid3(), 1.0, WithAux());
    ASSERT_TRUE(cpu.ok() && gpu.ok()) << gpu.status().ToString();
    EXPECT_EQ((*r)->last_stats().shadow_map, c.expect_map);
    EXPECT_EQ((*r)->last_stats().shadow_map_computed, raster == ShadowRaster::kCompute);
    const Agreement a = Compare(*cpu, *gpu);
    size_t cpu_shadow = 0;
    for (int y = 0; y < cam.height; ++y) {
      for (int x = 0; x < cam.width; ++x) cpu_shadow += cpu->aux.at(x, y, kAuxCastShadow) > 0.5f;
    }
    std::printf("[ vulkan   ] occluder, %s (%s %d px%s): %s; CPU shadow px %zu\n", c.name,
                (*r)->last_stats().shadow_map.c_str(), (*r)->last_stats().shadow_resolution,
                raster == ShadowRaster::kCompute ? ", compute" : "",
                a.ToString().c_str(), cpu_shadow);
    EXPECT_GT(cpu_shadow, 80u);
    EXPECT_GE(a.psnr_db, kMinPsnrDb);
    EXPECT_EQ(a.shadow_mismatches, 0u);
    EXPECT_EQ(a.mask_mismatches, 0u);
    EXPECT_LT(a.max_aux_cos_error, kAuxCosTolerance);
  }
}

// Shadow edges are the CPU's to the pixel: with a deliberately coarse shadow map (64 texels per
// side for a 160 px image) the map alone flips pixels along the occluder's shadow between lit
// and shadowed; the pixels it cannot decide (VulkanRenderOptions::exact_shadow_edges) are shaded
// with rays on the host, and then every pixel, the edge band included, agrees — at one ray per
// pixel, 2 x 2 supersampled, and through the distortion path.
TEST_F(VulkanRendererScenes, ShadowEdgesAreTheCpusWithACoarseShadowMap) {
  Scene s = MakeOccluderScene();
  const Camera cam = LookAtCamera({0.1, -1.2, 2.2}, {0, 0, 0}, 160, 160, 120);
  Light light;
  light.position = {0.3, -0.3, 1.9};
  light.intensity = {1.5, 1.5, 1.5};
  struct Case {
    const char* name;
    int supersampling;
    bool resolve;  // CameraShading::kResolve
    ShadowRaster raster;
  };
  for (const Case c : {Case{"1 ray", 1, false, ShadowRaster::kGraphics},
                       Case{"2 x 2 rays", 2, false, ShadowRaster::kGraphics},
                       Case{"resolve path", 1, true, ShadowRaster::kGraphics},
                       Case{"1 ray, compute-drawn map", 1, false, ShadowRaster::kCompute},
                       Case{"resolve path, compute-drawn map", 1, true,
                            ShadowRaster::kCompute}}) {
    SCOPED_TRACE(c.name);
    auto cpu = RenderImage(s.shaded(), cam, light, Rigid3(), 1.0, WithAux(c.supersampling));
    ASSERT_TRUE(cpu.ok());
    size_t mismatches_map_alone = 0;
    for (const bool exact : {false, true}) {
      VulkanRenderOptions vo;
      vo.shadow_resolution = 64;
      vo.camera_shading = c.resolve ? CameraShading::kResolve : CameraShading::kFragment;
      vo.shadow_raster = c.raster;
      vo.exact_shadow_edges = exact;
      const char* device = std::getenv("REFLCAP_TEST_VK_DEVICE");
      auto r = VulkanRenderer::Create(device ? device : "", vo);
      ASSERT_TRUE(r.ok()) << r.status().ToString();
      ASSERT_TRUE((*r)->SetScene(s.shaded()).ok());
      auto gpu = (*r)->RenderImage(cam, light, Rigid3(), 1.0, WithAux(c.supersampling));
      ASSERT_TRUE(gpu.ok()) << gpu.status().ToString();
      // Every pixel: no band around edges is left out.
      const Agreement a = Compare(*cpu, *gpu, 0.0);
      std::printf("[ vulkan   ] coarse shadow map, %s, exact edges %s: %s; host-shaded %zu px\n",
                  c.name, exact ? "on" : "off", a.ToString().c_str(),
                  (*r)->last_batch_stats().shadow_edge_pixels);
      if (!exact) {
        mismatches_map_alone = a.shadow_mismatches;
        EXPECT_EQ((*r)->last_batch_stats().shadow_edge_pixels, 0u);
        continue;
      }
      EXPECT_GT((*r)->last_batch_stats().shadow_edge_pixels, 0u);
      EXPECT_EQ(a.shadow_mismatches, 0u);
      EXPECT_EQ(a.mask_mismatches, 0u);
      EXPECT_GE(a.psnr_db, kMinPsnrDb);
    }
    // Teeth: the coarse map alone gets edge pixels wrong.
    EXPECT_GT(mismatches_map_alone, 10u);
  }
}

// Compute-drawn shadow maps on a device that stops long loops silently (lavapipe: 65,000 steps an
// invocation) refuse a triangle whose box of map texels is too large for one workgroup, instead of
// drawing part of it; a device without that limit draws it (and matches the CPU). Likewise a map
// too large for one storage-buffer binding.
TEST_F(VulkanRendererScenes, ComputeShadowMapsRefuseWhatTheDeviceCannotDraw) {
  // Two triangles over a whole 4096² map: ~8 M texels each, 262,144 per invocation of 32.
  Scene s = MakeScene(reflcap::testing::MakeGridPlane(2, 2, 1, 1), Lambert({0.5f, 0.5f, 0.5f}),
                      16);
  const Camera cam = LookAtCamera({0.1, -1.2, 2.2}, {0, 0, 0}, 48, 48, 40);
  Light light;
  light.position = {0.3, -0.3, 1.9};
  light.intensity = {1.5, 1.5, 1.5};
  VulkanRenderOptions vo;
  vo.shadow_raster = ShadowRaster::kCompute;
  vo.shadow_resolution = 4096;
  const char* device = std::getenv("REFLCAP_TEST_VK_DEVICE");
  auto r = VulkanRenderer::Create(device ? device : "", vo);
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  ASSERT_TRUE((*r)->SetScene(s.shaded()).ok());
  auto gpu = (*r)->RenderImage(cam, light, Rigid3(), 1.0, WithAux());
  if (gpu::MaxLoopIterationsPerInvocation((*r)->device()) == gpu::kNoLoopIterationLimit) {
    ASSERT_TRUE(gpu.ok()) << gpu.status().ToString();
    auto cpu = RenderImage(s.shaded(), cam, light, Rigid3(), 1.0, WithAux());
    ASSERT_TRUE(cpu.ok());
    EXPECT_GE(Compare(*cpu, *gpu).psnr_db, kMinPsnrDb);
  } else {
    EXPECT_EQ(gpu.status().code(), StatusCode::kUnavailable) << gpu.status().ToString();
    EXPECT_NE(gpu.status().message().find("ShadowRaster::kGraphics"), std::string::npos)
        << gpu.status().ToString();
    // The renderer recovers: a map it can draw renders.
    vo.shadow_resolution = 256;
    auto small = VulkanRenderer::Create(device ? device : "", vo);
    ASSERT_TRUE(small.ok());
    ASSERT_TRUE((*small)->SetScene(s.shaded()).ok());
    EXPECT_TRUE((*small)->RenderImage(cam, light, Rigid3(), 1.0, WithAux()).ok());
  }
  // A map whose raster buffer exceeds one storage-buffer binding is refused the same way (small
  // triangles, so the loop limit is not what stops it).
  Scene fine = MakeScene(reflcap::testing::MakeGridPlane(2, 2, 64, 64),
                         Lambert({0.5f, 0.5f, 0.5f}), 16);
  vo.shadow_resolution = 8192;  // 256 MiB of raster buffer
  auto big = VulkanRenderer::Create(device ? device : "", vo);
  ASSERT_TRUE(big.ok()) << big.status().ToString();
  ASSERT_TRUE((*big)->SetScene(fine.shaded()).ok());
  auto rendered = (*big)->RenderImage(cam, light, Rigid3(), 1.0, WithAux());
  if ((*big)->device().max_storage_buffer_range < (uint64_t{256} << 20)) {
    EXPECT_EQ(rendered.status().code(), StatusCode::kUnavailable) << rendered.status().ToString();
    EXPECT_NE(rendered.status().message().find("maxStorageBufferRange"), std::string::npos)
        << rendered.status().ToString();
  } else {
    EXPECT_TRUE(rendered.ok()) << rendered.status().ToString();
  }
}

// The view of MakeOccluderScene that the supersampling tests share: the occluder's shadow and
// silhouette edges fill a 64 px image.
Camera OccluderSceneCamera() { return LookAtCamera({0.1, -1.2, 2.2}, {0, 0, 0}, 64, 64, 48); }
Light OccluderSceneLight() {
  Light light;
  light.position = {1.5, -2.0, 4.0};
  light.intensity = {2, 2, 2};
  return light;
}

TEST_F(VulkanRendererScenes, SupersamplingMatchesCpu) {
  Scene s = MakeOccluderScene();
  ASSERT_TRUE(renderer().SetScene(s.shaded()).ok());
  Camera cam = OccluderSceneCamera();
  const Light light = OccluderSceneLight();
  for (bool distorted : {false, true}) {
    SCOPED_TRACE(distorted ? "distorted" : "pinhole");
    if (distorted) cam.dist = {-0.08, 0.02, 0.0005, -0.0005, 0};
    // The resolve at the largest N too: its walks shrink with N to stay inside lavapipe's loop
    // steps per invocation (distort_resolve.comp WalkSteps).
    for (int n : distorted ? std::vector<int>{2, 3, kMaxSupersampling} : std::vector<int>{2, 3}) {
      auto cpu = RenderImage(s.shaded(), cam, light, Rigid3(), 1.0, WithAux(n));
      auto gpu = renderer().RenderImage(cam, light, Rigid3(), 1.0, WithAux(n));
      ASSERT_TRUE(cpu.ok() && gpu.ok()) << gpu.status().ToString();
      const Agreement a = Compare(*cpu, *gpu);
      std::printf("[ vulkan   ] supersampling %dx%d%s: %s\n", n, n, distorted ? " (distorted)" : "",
                  a.ToString().c_str());
      if (a.psnr_db < kMinPsnrDb) {
        testing::PrintWorstPixels(*cpu, *gpu, a, 8);
        testing::DumpRenders("supersampling" + std::to_string(n) + (distorted ? "_distorted" : ""),
                             *cpu, *gpu);
      }
      EXPECT_GE(a.psnr_db, kMinPsnrDb) << n;
      EXPECT_EQ(a.mask_mismatches, 0u) << n;
    }
  }
}

// A footprint wider than the pixel (RenderOptions::pixel_footprint): the samples leave the
// supersampled pass's grid, so the resolve takes them by their exact rays on every device (the
// per-fragment default of lavapipe included) and matches the CPU's, pinhole and distorted. The
// footprint shows: the same render with the pixel's own square differs at the occluder's edges.
// Orthographic cameras (rasterised on the pixel grid) and forced per-fragment shading refuse it.
TEST_F(VulkanRendererScenes, PixelFootprintMatchesCpu) {
  Scene s = MakeOccluderScene();
  ASSERT_TRUE(renderer().SetScene(s.shaded()).ok());
  Camera cam = OccluderSceneCamera();
  const Light light = OccluderSceneLight();
  RenderOptions wide = WithAux(4);
  wide.pixel_footprint = 1.5;
  for (bool distorted : {false, true}) {
    SCOPED_TRACE(distorted ? "distorted" : "pinhole");
    if (distorted) cam.dist = {-0.08, 0.02, 0.0005, -0.0005, 0};
    auto cpu = RenderImage(s.shaded(), cam, light, Rigid3(), 1.0, wide);
    auto gpu = renderer().RenderImage(cam, light, Rigid3(), 1.0, wide);
    ASSERT_TRUE(cpu.ok() && gpu.ok()) << gpu.status().ToString();
    EXPECT_TRUE(renderer().last_stats().distortion_resolve);
    const Agreement a = Compare(*cpu, *gpu);
    std::printf("[ vulkan   ] footprint 1.5 px, 4x4%s: %s\n", distorted ? " (distorted)" : "",
                a.ToString().c_str());
    if (a.psnr_db < kMinPsnrDb) {
      testing::PrintWorstPixels(*cpu, *gpu, a, 8);
      testing::DumpRenders(std::string("footprint") + (distorted ? "_distorted" : ""), *cpu, *gpu);
    }
    EXPECT_GE(a.psnr_db, kMinPsnrDb);
    EXPECT_EQ(a.mask_mismatches, 0u);
    auto own_square = RenderImage(s.shaded(), cam, light, Rigid3(), 1.0, WithAux(4));
    ASSERT_TRUE(own_square.ok());
    const Agreement narrow = Compare(*own_square, *gpu);
    std::printf("[ vulkan   ]   against the CPU's 1 px footprint: %s\n", narrow.ToString().c_str());
    EXPECT_LT(narrow.psnr_db, kMinPsnrDb) << "the footprint must change the render";
  }
  Camera ortho = LookAtCamera({0.4, -1.0, 2.0}, {0, 0, 0}, 80, 64, 1);
  ortho.model = CameraModel::kOrthographic;
  ortho.pixel_size_m = 0.03;
  EXPECT_EQ(renderer().RenderImage(ortho, light, Rigid3(), 1.0, wide).status().code(),
            StatusCode::kInvalidArgument);
  VulkanRenderOptions vo;
  vo.camera_shading = CameraShading::kFragment;
  const char* device = std::getenv("REFLCAP_TEST_VK_DEVICE");
  auto fragment = VulkanRenderer::Create(device ? device : "", vo);
  ASSERT_TRUE(fragment.ok()) << fragment.status().ToString();
  ASSERT_TRUE((*fragment)->SetScene(s.shaded()).ok());
  EXPECT_EQ((*fragment)->RenderImage(cam, light, Rigid3(), 1.0, wide).status().code(),
            StatusCode::kInvalidArgument);
}

TEST_F(VulkanRendererScenes, OrthographicCameraMatchesCpu) {
  Scene s = MakeOccluderScene();
  ASSERT_TRUE(renderer().SetScene(s.shaded()).ok());
  Camera cam = LookAtCamera({0.4, -1.0, 2.0}, {0, 0, 0}, 80, 64, 1);
  cam.model = CameraModel::kOrthographic;
  cam.pixel_size_m = 0.03;
  Light light;
  light.type = LightType::kDirectional;
  light.direction = Vec3d(-0.2, 0.4, 1).normalized();
  light.intensity = {2, 2, 2};
  for (int n : {1, 2}) {
    auto cpu = RenderImage(s.shaded(), cam, light, Rigid3(), 1.0, WithAux(n));
    auto gpu = renderer().RenderImage(cam, light, Rigid3(), 1.0, WithAux(n));
    ASSERT_TRUE(cpu.ok() && gpu.ok()) << gpu.status().ToString();
    const Agreement a = Compare(*cpu, *gpu);
    std::printf("[ vulkan   ] orthographic, %dx%d samples: %s\n", n, n, a.ToString().c_str());
    if (a.psnr_db < kMinPsnrDb) {
      testing::PrintWorstPixels(*cpu, *gpu, a, 8);
      testing::DumpRenders("orthographic" + std::to_string(n), *cpu, *gpu);
    }
    EXPECT_GE(a.psnr_db, kMinPsnrDb) << n;
    EXPECT_EQ(a.mask_mismatches, 0u) << n;
    EXPECT_GT(a.compared_pixels, 1500u) << n;
  }
}

TEST_F(VulkanRendererScenes, BackFacesAreBlackAndMasked) {
  // The plane seen from below: every object pixel is a back face, black but in the mask.
  Scene s = MakeScene(reflcap::testing::MakeGridPlane(2, 2, 2, 2), Lambert({1, 1, 1}), 16);
  ASSERT_TRUE(renderer().SetScene(s.shaded()).ok());
  const Camera cam = LookAtCamera({0.2, 0.1, -2.0}, {0, 0, 0}, 32, 32, 20);
  Light light;
  light.position = {0, 0, -1};
  auto gpu = renderer().RenderImage(cam, light, Rigid3(), 1.0, WithAux());
  ASSERT_TRUE(gpu.ok()) << gpu.status().ToString();
  size_t masked = 0;
  for (int y = 0; y < 32; ++y) {
    for (int x = 0; x < 32; ++x) {
      if (gpu->mask.at(x, y) < 0.5f) continue;
      ++masked;
      for (int c = 0; c < 3; ++c) ASSERT_EQ(gpu->pixels.at(x, y, c), 0.0f);
    }
  }
  EXPECT_GT(masked, 300u);
}

TEST_F(VulkanRendererScenes, NormalMapCaptureMatchesCpu) {
  // An orthographic view of a hemisphere as a normal map, glossy, directional light.
  const int size = 48;
  Image normals(size, size, 3, 0.0f), mask(size, size, 1, 0.0f);
  for (int y = 0; y < size; ++y) {
    for (int x = 0; x < size; ++x) {
      const double u = (x - 23.5) / 20, v = (y - 23.5) / 20;
      if (u * u + v * v >= 1) continue;
      const Vec3d n(u, -v, std::sqrt(1 - u * u - v * v));  // world: +z towards the camera
      for (int c = 0; c < 3; ++c) normals.at(x, y, c) = float(n[c]);
      mask.at(x, y) = 1;
    }
  }
  auto atlas = BuildNormalMapAtlas(normals, mask);
  ASSERT_TRUE(atlas.ok()) << atlas.status().ToString();
  BrdfMaps maps;
  maps.num_lobes = 1;
  maps.texels.assign(atlas->TexelCount(), Glossy({0.4f, 0.3f, 0.2f}, 20));
  Camera cam;
  cam.id = "ortho";
  cam.model = CameraModel::kOrthographic;
  cam.width = cam.height = size;
  cam.pixel_size_m = 1e-3;
  Mat3d r;
  r << 1, 0, 0, 0, -1, 0, 0, 0, -1;  // looking down -z, image y = -world y
  cam.cam_from_world = {r, Vec3d(0, 0, 1)};
  Light light;
  light.type = LightType::kDirectional;
  light.direction = Vec3d(0.3, 0.2, 1).normalized();
  light.intensity = {3, 3, 3};
  ASSERT_TRUE(renderer().SetNormalMapScene(*atlas, maps, cam).ok());
  for (CameraModel model : {CameraModel::kOrthographic, CameraModel::kPinhole}) {
    cam.model = model;
    cam.K << 60, 0, 23.5, 0, 60, 23.5, 0, 0, 1;
    cam.dist = {};
    if (model == CameraModel::kPinhole) cam.dist = {-0.1, 0.02, 0, 0, 0};
    auto cpu = RenderNormalMapImage(*atlas, maps, cam, light, 0.7, WithAux());
    auto gpu = renderer().RenderNormalMapImage(cam, light, 0.7, WithAux());
    ASSERT_TRUE(cpu.ok() && gpu.ok()) << gpu.status().ToString();
    const RelativeCheck rc = CompareInterior(*cpu, *gpu);
    EXPECT_EQ(rc.failed, 0u) << "worst " << rc.worst;
    for (size_t i = 0; i < cpu->aux.data.size(); ++i) {
      ASSERT_NEAR(gpu->aux.data[i], cpu->aux.data[i], kAuxCosTolerance) << "aux value " << i;
    }
    EXPECT_EQ(gpu->mask.data, cpu->mask.data);
  }
}

TEST_F(VulkanRendererScenes, NormalMapHeightFieldShadowsMatchCpu) {
  // A glossy plate with a spherical pit, its height field integrated from the normal map, under
  // low lights from several azimuths (diagonal ones march between pixel centres, through the
  // bilinear taps). The march is float arithmetic in the same order on both sides (no fused
  // multiply-add), so every pixel's shadow decision must agree exactly; the shading elsewhere to
  // kRelTolerance as in NormalMapCaptureMatchesCpu.
  const int w = 96, h = 90;
  Image normals, mask;
  reflcap::testing::NormalMapOf(reflcap::testing::PittedPlate(47, 44, 44, 37), w, h, &normals,
                                &mask);
  auto atlas = BuildNormalMapAtlas(normals, mask);
  ASSERT_TRUE(atlas.ok()) << atlas.status().ToString();
  const Camera cam = reflcap::testing::DiligentCamera(w, h);
  auto field = IntegrateNormalMap(*atlas, cam);
  ASSERT_TRUE(field.ok()) << field.status().ToString();
  BrdfMaps maps;
  maps.num_lobes = 1;
  maps.texels.assign(atlas->TexelCount(), Glossy({0.4f, 0.3f, 0.2f}, 20));
  ASSERT_TRUE(renderer().SetNormalMapScene(*atlas, maps, cam, &*field).ok());
  for (int az = 0; az < 360; az += 45) {
    SCOPED_TRACE(StrCat("azimuth ", az));
    Light light;
    light.type = LightType::kDirectional;
    const double el = DegToRad(15 + az / 45 * 2);
    light.direction = Vec3d(std::cos(el) * std::cos(DegToRad(az)),
                            std::cos(el) * std::sin(DegToRad(az)), std::sin(el));
    light.intensity = {3, 3, 3};
    auto cpu = RenderNormalMapImage(*atlas, maps, cam, light, 0.7, WithAux(), &*field);
    auto gpu = renderer().RenderNormalMapImage(cam, light, 0.7, WithAux());
    ASSERT_TRUE(cpu.ok() && gpu.ok()) << gpu.status().ToString();
    size_t shadowed = 0, differ = 0;
    for (int y = 0; y < h; ++y) {
      for (int x = 0; x < w; ++x) {
        const float c = cpu->aux.at(x, y, kAuxCastShadow), g = gpu->aux.at(x, y, kAuxCastShadow);
        shadowed += c > 0.5f;
        differ += (c > 0.5f) != (g > 0.5f);
        if (c > 0.5f) {
          ASSERT_EQ(gpu->pixels.at(x, y, 0), 0.0f) << "shadowed pixels are black";
        }
      }
    }
    EXPECT_GT(shadowed, 300u) << "the pit must shadow itself under a low light";
    EXPECT_EQ(differ, 0u) << "shadow decisions differ (of " << shadowed << " shadowed)";
    const RelativeCheck rc = CompareInterior(*cpu, *gpu);
    EXPECT_EQ(rc.failed, 0u) << "worst " << rc.worst;
    EXPECT_EQ(gpu->mask.data, cpu->mask.data);
  }
  // cast_shadows off: no march on either side.
  Light light;
  light.type = LightType::kDirectional;
  light.direction = Vec3d(0.9, 0, 0.3).normalized();
  RenderOptions off = WithAux();
  off.cast_shadows = false;
  auto gpu = renderer().RenderNormalMapImage(cam, light, 1, off);
  auto cpu = RenderNormalMapImage(*atlas, maps, cam, light, 1, off, &*field);
  ASSERT_TRUE(cpu.ok() && gpu.ok());
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      ASSERT_EQ(gpu->aux.at(x, y, kAuxCastShadow), 0.0f);
      ASSERT_EQ(cpu->aux.at(x, y, kAuxCastShadow), 0.0f);
    }
  }
  EXPECT_EQ(CompareInterior(*cpu, *gpu).failed, 0u);
}

TEST_F(VulkanRendererScenes, RefusesWhatTheCpuRefuses) {
  Scene s = MakeScene(reflcap::testing::MakeGridPlane(2, 2, 1, 1), Lambert({1, 1, 1}), 8);
  ASSERT_TRUE(renderer().SetScene(s.shaded()).ok());
  Camera cam = LookAtCamera({0, -0.5, 2}, {0, 0, 0}, 16, 16, 10);
  cam.model = CameraModel::kOrthographic;  // without pixel_size_m
  EXPECT_EQ(renderer().RenderImage(cam, Light{}, Rigid3(), 1, RenderOptions{}).status().code(),
            StatusCode::kInvalidArgument);
  RenderOptions bad;
  bad.supersampling = 0;
  cam.model = CameraModel::kPinhole;
  EXPECT_FALSE(renderer().RenderImage(cam, Light{}, Rigid3(), 1, bad).ok());
  EXPECT_EQ(renderer().RenderNormalMapImage(cam, Light{}, 1, RenderOptions{}).status().code(),
            StatusCode::kFailedPrecondition);
}

}  // namespace
}  // namespace reflcap::render
