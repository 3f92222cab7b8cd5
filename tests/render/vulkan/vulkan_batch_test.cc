// The Vulkan renderer's batches (VulkanRenderer::RenderImages): the same bits as rendering each
// image alone (one image per submission, waited for, every shadow map drawn afresh) for many
// images over several batches and submissions in flight — mixed image sizes, pinhole,
// distorted and orthographic cameras, point lights inside and outside the object's bounds and
// directional lights, turntable poses, supersampling, kept shadow maps redrawn while images of
// the same batch still sample them, pass targets released mid-stream — and normal-map scenes;
// errors found before anything renders (naming the image) or raised by the caller's sink;
// `reflcap render`'s capture path refusing a bad camera before writing any file; and the auto
// settings' evidence rendered on the device deciding as the CPU reference's.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "acquire/synth/synth.h"
#include "engine/core/atomic_file.h"
#include "engine/image/exr_io.h"
#include "engine/mesh/ray_scene.h"
#include "render/reference/indirect_light.h"
#include "render/reference/render_capture.h"
#include "render/vulkan/vulkan_render_capture.h"
#include "render/vulkan/vulkan_renderer.h"
#include "tests/render/vulkan/vulkan_test_util.h"
#include "tests/support/shapes.h"
#include "tests/support/test_support.h"

namespace reflcap::render {
namespace {
namespace fs = std::filesystem;

// Fixed shadow-map resolution of these tests: small maps keep lavapipe fast; the batching logic
// does not depend on the size.
constexpr int kShadowResolution = 256;

std::string Device() {
  const char* device = std::getenv("REFLCAP_TEST_VK_DEVICE");
  return device ? device : "";
}

// The per-image path: one image per submission, waited for, no kept shadow maps.
VulkanRenderOptions OneByOne() {
  VulkanRenderOptions o;
  o.shadow_resolution = kShadowResolution;
  o.batch_images = 1;
  o.batches_in_flight = 1;
  o.shadow_cache_mib = 0;
  return o;
}

VulkanRenderOptions Batched(int images, int in_flight, int shadow_cache_mib) {
  VulkanRenderOptions o = OneByOne();
  o.batch_images = images;
  o.batches_in_flight = in_flight;
  o.shadow_cache_mib = shadow_cache_mib;
  return o;
}

Camera LookAt(const std::string& id, const Vec3d& eye, int w, int h, double f) {
  Camera cam;
  cam.id = id;
  cam.width = w;
  cam.height = h;
  cam.K << f, 0, 0.5 * (w - 1), 0, f, 0.5 * (h - 1), 0, 0, 1;
  cam.cam_from_world = CamFromWorldLookAt(eye, Vec3d::Zero());
  return cam;
}

brdf::BrdfParams Material(const Vec3f& albedo, int lobes) {
  brdf::BrdfParams p;
  p.num_lobes = lobes;
  p.rho_d = {albedo.x(), albedo.y(), albedo.z()};
  for (int c = 0; c < 3 && lobes > 0; ++c) p.lobes[0][c] = brdf::MirrorLobe(0.8 + 0.3 * c, 30);
  return p;
}

// Ground plane with a square occluder above it (its own UV island), checkerboard material.
struct OccluderScene {
  TriangleMesh mesh;
  std::unique_ptr<RayScene> rays;
  TexelAtlas atlas;
  BrdfMaps maps;
  ShadedScene shaded() const { return {rays.get(), &atlas, &maps}; }
};

std::unique_ptr<OccluderScene> MakeOccluderScene() {
  auto s = std::make_unique<OccluderScene>();
  s->mesh = reflcap::testing::MakeGridPlane(2, 2, 8, 8, 0);
  TriangleMesh occluder = reflcap::testing::MakeGridPlane(0.4f, 0.4f, 2, 2, 0.3f);
  for (auto& uv : occluder.corner_uvs) {
    for (auto& c : uv) c = Vec2f(0.75f, 0.75f) + 0.2f * c;
  }
  for (auto& uv : s->mesh.corner_uvs) {
    for (auto& c : uv) c *= 0.5f;
  }
  reflcap::testing::AppendMesh(occluder, &s->mesh);
  auto rays = RayScene::Create(s->mesh);
  REFLCAP_CHECK(rays.ok()) << rays.status().ToString();
  s->rays = std::move(rays).value();
  auto atlas = BuildTexelAtlas(s->mesh, 64, 64);
  REFLCAP_CHECK(atlas.ok()) << atlas.status().ToString();
  s->atlas = std::move(atlas).value();
  s->maps.num_lobes = 1;
  const brdf::BrdfParams a = Material({0.5f, 0.4f, 0.3f}, 1), b = Material({0.2f, 0.6f, 0.3f}, 0);
  s->maps.texels.assign(s->atlas.TexelCount(), a);
  for (size_t t = 0; t < s->atlas.TexelCount(); ++t) {
    int x, y;
    s->atlas.PixelOf(t, &x, &y);
    if ((x / 2 + y / 2) % 2) s->maps.texels[t] = b;
  }
  return s;
}

// Cameras of several sizes and models, lights of every shadow-map kind, turntable poses.
struct Rig {
  std::vector<Camera> cameras;
  std::vector<Light> lights;
  std::vector<Rigid3> poses;
};

Rig MakeRig() {
  Rig rig;
  rig.cameras.push_back(LookAt("pinhole", {0.1, -1.2, 2.2}, 64, 48, 45));
  Camera distorted = LookAt("distorted", {-0.6, -0.9, 2.0}, 56, 56, 40);
  distorted.dist = {-0.08, 0.02, 0.0005, -0.0005, 0};
  rig.cameras.push_back(distorted);
  Camera ortho = LookAt("orthographic", {0.4, -1.0, 2.0}, 48, 40, 1);
  ortho.model = CameraModel::kOrthographic;
  ortho.pixel_size_m = 0.05;
  rig.cameras.push_back(ortho);
  rig.cameras.push_back(LookAt("pinhole_b", {0.9, 0.5, 1.8}, 64, 48, 50));  // pinhole's size
  Light inside, outside, directional;
  inside.id = "inside";
  inside.position = {0.2, 0.1, 1.0};
  inside.intensity = {1.5, 1.5, 1.5};
  outside.id = "outside";
  outside.position = {0.3, -0.3, 1.9};
  outside.intensity = {2, 2, 2};
  directional.id = "directional";
  directional.type = LightType::kDirectional;
  directional.direction = Vec3d(0.3, 0.2, 1).normalized();
  directional.intensity = {2, 2, 2};
  rig.lights = {inside, outside, directional};
  for (double deg : {0.0, 40.0}) {
    Rigid3 pose;
    pose.rotation = Eigen::AngleAxisd(deg * M_PI / 180, Vec3d::UnitZ()).toRotationMatrix();
    rig.poses.push_back(pose);
  }
  return rig;
}

// Every (pose, camera, light), in turntable-capture order: pose, then camera, then light, so an
// image shares its light map with the image of the next camera three requests later.
std::vector<RenderRequest> AllRequests(const Rig& rig) {
  std::vector<RenderRequest> requests;
  for (size_t p = 0; p < rig.poses.size(); ++p) {
    for (const Camera& cam : rig.cameras) {
      for (const Light& light : rig.lights) {
        RenderRequest q;
        q.camera = &cam;
        q.light = &light;
        q.world_from_object = rig.poses[p];
        q.exposure_s = 0.5 + 0.25 * double(p);
        requests.push_back(q);
      }
    }
  }
  return requests;
}

// Bit-for-bit equality of two renders; names the first difference.
::testing::AssertionResult SameBits(const RenderResult& a, const RenderResult& b) {
  const std::pair<const Image*, const Image*> images[] = {
      {&a.pixels, &b.pixels}, {&a.mask, &b.mask}, {&a.aux, &b.aux}};
  const char* names[] = {"pixels", "mask", "aux"};
  for (int k = 0; k < 3; ++k) {
    const Image& x = *images[k].first;
    const Image& y = *images[k].second;
    if (x.width != y.width || x.height != y.height || x.channels != y.channels) {
      return ::testing::AssertionFailure() << names[k] << ": shapes differ";
    }
    for (size_t i = 0; i < x.data.size(); ++i) {
      if (std::memcmp(&x.data[i], &y.data[i], sizeof(float)) != 0) {
        return ::testing::AssertionFailure()
               << names[k] << " value " << i << " (pixel " << i / size_t(x.channels) << "): "
               << x.data[i] << " vs " << y.data[i];
      }
    }
  }
  return ::testing::AssertionSuccess();
}

class VulkanBatch : public testing::VulkanRendererTest {
 protected:
  // Renders `requests` one by one on the per-image path.
  std::vector<RenderResult> OneByOneResults(const ShadedScene& scene,
                                            const std::vector<RenderRequest>& requests,
                                            const RenderOptions& options,
                                            const VulkanRenderOptions& one_by_one = OneByOne()) {
    auto r = VulkanRenderer::Create(Device(), one_by_one);
    EXPECT_TRUE(r.ok()) << r.status().ToString();
    if (!r.ok()) return {};
    EXPECT_TRUE((*r)->SetScene(scene).ok());
    std::vector<RenderResult> results;
    for (const RenderRequest& q : requests) {
      auto result =
          (*r)->RenderImage(*q.camera, *q.light, q.world_from_object, q.exposure_s, options);
      EXPECT_TRUE(result.ok()) << result.status().ToString();
      if (!result.ok()) return {};
      results.push_back(std::move(result).value());
    }
    return results;
  }
};

TEST_F(VulkanBatch, ManyImagesInBatchesMatchOneByOneBitForBit) {
  const auto scene = MakeOccluderScene();
  const Rig rig = MakeRig();
  const std::vector<RenderRequest> requests = AllRequests(rig);
  ASSERT_EQ(requests.size(), 24u);
  struct Config {
    const char* name;
    VulkanRenderOptions options;
  };
  // 3 images per submission, 2 in flight (the ring wraps 4 times); a 1 MiB shadow cache holds
  // four 256² maps and one cube map, so maps are redrawn while earlier images of the same batch
  // still sample them. Then every image in one submission with a large cache.
  const Config configs[] = {{"3 per batch, 2 in flight, 1 MiB kept maps", Batched(3, 2, 1)},
                            {"one batch, 64 MiB kept maps", Batched(64, 1, 64)},
                            {"automatic", [] {
                               VulkanRenderOptions o;
                               o.shadow_resolution = kShadowResolution;
                               return o;
                             }()}};
  for (int supersampling : {1, 2}) {
    RenderOptions options;
    options.aux_buffers = true;
    options.supersampling = supersampling;
    const std::vector<RenderResult> expected = OneByOneResults(scene->shaded(), requests, options);
    ASSERT_EQ(expected.size(), requests.size());
    for (const Config& config : configs) {
      SCOPED_TRACE(StrCat(config.name, ", supersampling ", supersampling));
      auto r = VulkanRenderer::Create(Device(), config.options);
      ASSERT_TRUE(r.ok()) << r.status().ToString();
      ASSERT_TRUE((*r)->SetScene(scene->shaded()).ok());
      std::vector<size_t> order;
      auto status = (*r)->RenderImages(requests, options, [&](size_t i, RenderResult&& result) {
        order.push_back(i);
        EXPECT_TRUE(SameBits(result, expected[i])) << "image " << i;
        return OkStatus();
      });
      ASSERT_TRUE(status.ok()) << status.ToString();
      ASSERT_EQ(order.size(), requests.size());
      for (size_t i = 0; i < order.size(); ++i) EXPECT_EQ(order[i], i) << "delivery order";
      const VulkanBatchStats& stats = (*r)->last_batch_stats();
      std::printf("[ vulkan   ] batches (%s, %dx%d samples): %s\n", config.name, supersampling,
                  supersampling, stats.ToString().c_str());
      EXPECT_EQ(stats.images, requests.size());
      EXPECT_EQ(stats.shadow_maps_drawn + stats.shadow_maps_reused, requests.size());
      if (config.options.batch_images == 3) {
        EXPECT_EQ(stats.submissions, 8u);
      }
      // Four cameras share each (pose, light) map: a large cache draws each map once.
      if (config.options.shadow_cache_mib == 64) {
        EXPECT_EQ(stats.shadow_maps_drawn, rig.poses.size() * rig.lights.size());
      }
    }
  }
}

// The paths a GPU takes by default (compute-drawn shadow maps, pinhole cameras shaded by the
// resolve pass) batch as the rasterised ones do: bit for bit the one-by-one renders, with maps
// redrawn while earlier images of the batch still sample them.
TEST_F(VulkanBatch, ComputeShadowMapsAndResolvedCamerasBatchBitForBit) {
  const auto scene = MakeOccluderScene();
  const Rig rig = MakeRig();
  const std::vector<RenderRequest> requests = AllRequests(rig);
  auto gpu_paths = [](VulkanRenderOptions o) {
    o.shadow_raster = ShadowRaster::kCompute;
    o.camera_shading = CameraShading::kResolve;
    return o;
  };
  RenderOptions options;
  options.aux_buffers = true;
  const std::vector<RenderResult> expected =
      OneByOneResults(scene->shaded(), requests, options, gpu_paths(OneByOne()));
  ASSERT_EQ(expected.size(), requests.size());
  auto r = VulkanRenderer::Create(Device(), gpu_paths(Batched(3, 2, 1)));
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  ASSERT_TRUE((*r)->SetScene(scene->shaded()).ok());
  size_t delivered = 0;
  auto status = (*r)->RenderImages(requests, options, [&](size_t i, RenderResult&& result) {
    ++delivered;
    EXPECT_TRUE(SameBits(result, expected[i])) << "image " << i;
    return OkStatus();
  });
  ASSERT_TRUE(status.ok()) << status.ToString();
  EXPECT_EQ(delivered, requests.size());
  const VulkanBatchStats& stats = (*r)->last_batch_stats();
  std::printf("[ vulkan   ] batches (compute maps, resolve shading): %s\n",
              stats.ToString().c_str());
  EXPECT_TRUE((*r)->last_stats().shadow_map_computed);
  EXPECT_TRUE((*r)->last_stats().distortion_resolve);
  EXPECT_GT(stats.shadow_maps_drawn, rig.poses.size() * rig.lights.size());  // redrawn
}

TEST_F(VulkanBatch, ManyImageSizesReleaseKeptTargetsWithoutChangingResults) {
  // Twelve image sizes: more than the renderer keeps, so targets are released mid-stream (after
  // the submissions using them have finished).
  const auto scene = MakeOccluderScene();
  std::vector<Camera> cameras;
  for (int k = 0; k < 12; ++k) {
    cameras.push_back(LookAt("c" + std::to_string(k), {0.1 + 0.05 * k, -1.2, 2.2}, 24 + 4 * k,
                             20 + 3 * k, 20 + 3 * k));
  }
  Light light;
  light.position = {0.3, -0.3, 1.9};
  light.intensity = {2, 2, 2};
  std::vector<RenderRequest> requests;
  for (const Camera& cam : cameras) {
    RenderRequest q;
    q.camera = &cam;
    q.light = &light;
    requests.push_back(q);
  }
  RenderOptions options;
  options.aux_buffers = true;
  const std::vector<RenderResult> expected = OneByOneResults(scene->shaded(), requests, options);
  ASSERT_EQ(expected.size(), requests.size());
  auto r = VulkanRenderer::Create(Device(), Batched(5, 2, 16));
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  ASSERT_TRUE((*r)->SetScene(scene->shaded()).ok());
  for (int pass = 0; pass < 2; ++pass) {  // the second pass starts from released targets
    auto results = (*r)->RenderImages(requests, options);
    ASSERT_TRUE(results.ok()) << results.status().ToString();
    for (size_t i = 0; i < requests.size(); ++i) {
      EXPECT_TRUE(SameBits((*results)[i], expected[i])) << "pass " << pass << ", image " << i;
    }
  }
}

TEST_F(VulkanBatch, NormalMapScenesBatchToo) {
  const int size = 40;
  Image normals(size, size, 3, 0.0f), mask(size, size, 1, 0.0f);
  for (int y = 0; y < size; ++y) {
    for (int x = 0; x < size; ++x) {
      const double u = (x - 19.5) / 17, v = (y - 19.5) / 17;
      if (u * u + v * v >= 1) continue;
      const Vec3d n(u, -v, std::sqrt(1 - u * u - v * v));
      for (int c = 0; c < 3; ++c) normals.at(x, y, c) = float(n[c]);
      mask.at(x, y) = 1;
    }
  }
  auto atlas = BuildNormalMapAtlas(normals, mask);
  ASSERT_TRUE(atlas.ok()) << atlas.status().ToString();
  BrdfMaps maps;
  maps.num_lobes = 1;
  maps.texels.assign(atlas->TexelCount(), Material({0.4f, 0.3f, 0.2f}, 1));
  Camera ortho;
  ortho.id = "ortho";
  ortho.model = CameraModel::kOrthographic;
  ortho.width = ortho.height = size;
  ortho.pixel_size_m = 1e-3;
  Mat3d rot;
  rot << 1, 0, 0, 0, -1, 0, 0, 0, -1;
  ortho.cam_from_world = {rot, Vec3d(0, 0, 1)};
  ortho.K << 60, 0, 19.5, 0, 60, 19.5, 0, 0, 1;
  Camera pinhole = ortho;
  pinhole.model = CameraModel::kPinhole;
  pinhole.dist = {-0.1, 0.02, 0, 0, 0};
  std::vector<Light> lights(3);
  for (int k = 0; k < 3; ++k) {
    lights[k].type = LightType::kDirectional;
    lights[k].direction = Vec3d(0.3 - 0.2 * k, 0.2, 1).normalized();
    lights[k].intensity = {3, 3, 3};
  }
  std::vector<RenderRequest> requests;
  for (const Camera* cam : {&ortho, &pinhole}) {
    for (const Light& light : lights) {
      RenderRequest q;
      q.camera = cam;
      q.light = &light;
      q.exposure_s = 0.7;
      requests.push_back(q);
    }
  }
  RenderOptions options;
  options.aux_buffers = true;
  auto single = VulkanRenderer::Create(Device(), OneByOne());
  auto batched = VulkanRenderer::Create(Device(), Batched(4, 2, 0));
  ASSERT_TRUE(single.ok() && batched.ok());
  ASSERT_TRUE((*single)->SetNormalMapScene(*atlas, maps, ortho).ok());
  ASSERT_TRUE((*batched)->SetNormalMapScene(*atlas, maps, ortho).ok());
  auto results = (*batched)->RenderImages(requests, options);
  ASSERT_TRUE(results.ok()) << results.status().ToString();
  for (size_t i = 0; i < requests.size(); ++i) {
    auto expected = (*single)->RenderNormalMapImage(*requests[i].camera, *requests[i].light,
                                                    requests[i].exposure_s, options);
    ASSERT_TRUE(expected.ok()) << expected.status().ToString();
    EXPECT_TRUE(SameBits((*results)[i], *expected)) << "image " << i;
  }
}

TEST_F(VulkanBatch, ABadImageFailsTheCallBeforeAnythingRenders) {
  const auto scene = MakeOccluderScene();
  const Rig rig = MakeRig();
  std::vector<RenderRequest> requests = AllRequests(rig);
  Camera no_pixel_size = rig.cameras[2];  // orthographic without its pixel size
  no_pixel_size.id = "broken";
  no_pixel_size.pixel_size_m = 0;
  Camera fisheye = rig.cameras[1];  // distortion far beyond what a pinhole raster covers
  fisheye.id = "fisheye";
  fisheye.dist = {-0.5, 0, 0, 0, 0};  // r (1 - r²/2) peaks at r_d 0.54: corners have no inverse
  auto r = VulkanRenderer::Create(Device(), Batched(3, 2, 1));
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  ASSERT_TRUE((*r)->SetScene(scene->shaded()).ok());
  RenderOptions options;
  options.aux_buffers = true;
  struct Case {
    size_t index;
    const Camera* camera;
    std::string label;
    std::string expect_in_message;
  };
  const Case cases[] = {{7, &no_pixel_size, "", "requests[7]"},
                        {13, &fisheye, "capture.json: images[42]", "capture.json: images[42]"}};
  for (const Case& c : cases) {
    SCOPED_TRACE(c.expect_in_message);
    std::vector<RenderRequest> bad = requests;
    bad[c.index].camera = c.camera;
    bad[c.index].label = c.label;
    size_t delivered = 0;
    const Status s = (*r)->RenderImages(bad, options, [&](size_t, RenderResult&&) {
      ++delivered;
      return OkStatus();
    });
    EXPECT_EQ(s.code(), StatusCode::kInvalidArgument) << s.ToString();
    EXPECT_NE(s.message().find(c.expect_in_message), std::string::npos) << s.message();
    EXPECT_NE(s.message().find(c.camera->id), std::string::npos) << s.message();
    EXPECT_EQ(delivered, 0u) << "no image is handed over when a request is bad";
    EXPECT_EQ((*r)->last_batch_stats().submissions, 0u);
  }
  std::vector<RenderRequest> missing = requests;
  missing[3].light = nullptr;
  EXPECT_EQ((*r)->RenderImages(missing, options).status().code(), StatusCode::kInvalidArgument);
  auto unset = VulkanRenderer::Create(Device(), Batched(3, 2, 1));
  ASSERT_TRUE(unset.ok());
  EXPECT_EQ((*unset)->RenderImages(requests, options).status().code(),
            StatusCode::kFailedPrecondition);
  // Still a working renderer after the refusals.
  auto results = (*r)->RenderImages(requests, options);
  ASSERT_TRUE(results.ok()) << results.status().ToString();
  EXPECT_EQ(results->size(), requests.size());
}

TEST_F(VulkanBatch, ASinkErrorStopsTheCallAndTheRendererRecovers) {
  const auto scene = MakeOccluderScene();
  const Rig rig = MakeRig();
  const std::vector<RenderRequest> requests = AllRequests(rig);
  RenderOptions options;
  options.aux_buffers = true;
  const std::vector<RenderResult> expected = OneByOneResults(scene->shaded(), requests, options);
  ASSERT_EQ(expected.size(), requests.size());
  auto r = VulkanRenderer::Create(Device(), Batched(3, 3, 1));
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  ASSERT_TRUE((*r)->SetScene(scene->shaded()).ok());
  std::vector<size_t> seen;
  const Status s = (*r)->RenderImages(requests, options, [&](size_t i, RenderResult&&) {
    seen.push_back(i);
    if (i == 4) return InternalError("disk full writing image ", i);
    return OkStatus();
  });
  EXPECT_EQ(s.code(), StatusCode::kInternal);
  EXPECT_NE(s.message().find("disk full writing image 4"), std::string::npos) << s.message();
  EXPECT_EQ(seen, (std::vector<size_t>{0, 1, 2, 3, 4}));
  // Whatever was in flight finished; kept shadow maps were forgotten; the next call is exact.
  auto results = (*r)->RenderImages(requests, options);
  ASSERT_TRUE(results.ok()) << results.status().ToString();
  for (size_t i = 0; i < requests.size(); ++i) {
    EXPECT_TRUE(SameBits((*results)[i], expected[i])) << "image " << i;
  }
}

TEST(VulkanBatchOptions, ValidateNamesTheField) {
  const std::pair<const char*, VulkanRenderOptions> cases[] = {
      {"batch_images", [] { VulkanRenderOptions o; o.batch_images = -1; return o; }()},
      {"batch_images",
       [] { VulkanRenderOptions o; o.batch_images = kMaxBatchImages + 1; return o; }()},
      {"batch_readback_mib", [] { VulkanRenderOptions o; o.batch_readback_mib = 0; return o; }()},
      {"batches_in_flight", [] { VulkanRenderOptions o; o.batches_in_flight = 0; return o; }()},
      {"batches_in_flight", [] { VulkanRenderOptions o; o.batches_in_flight = 9; return o; }()},
      {"shadow_cache_mib", [] { VulkanRenderOptions o; o.shadow_cache_mib = -1; return o; }()},
  };
  for (const auto& [field, options] : cases) {
    const Status s = options.Validate();
    EXPECT_EQ(s.code(), StatusCode::kInvalidArgument) << field;
    EXPECT_NE(s.message().find(field), std::string::npos) << s.message();
  }
  EXPECT_TRUE(VulkanRenderOptions{}.Validate().ok());
}

// A small synthetic capture: 2 cameras, 2 lights, 4 turntable steps.
synth::SynthOptions SmallCapture(double noise, int texels, int image_size) {
  synth::SynthOptions o;
  o.noise = noise;
  o.texels = texels;
  o.image_size = image_size;
  o.cameras = 2;
  o.lights = 2;
  o.steps = 4;
  return o;
}

TEST_F(VulkanBatch, CaptureWithABadCameraWritesNoFileAndNamesTheImage) {
  reflcap::testing::ScratchDir dir;
  ASSERT_TRUE(synth::WriteSyntheticCapture(SmallCapture(0, 2000, 40), dir / "capture").ok());
  auto capture = ReadCapture(dir / "capture");
  ASSERT_TRUE(capture.ok()) << capture.status().ToString();
  // Camera 1 becomes orthographic without a pixel size: its images cannot render.
  capture->cameras[1].model = CameraModel::kOrthographic;
  capture->cameras[1].pixel_size_m = 0;
  size_t first_bad = capture->images.size();
  for (size_t i = 0; i < capture->images.size(); ++i) {
    if (capture->images[i].split == Split::kHoldout && capture->images[i].camera == 1) {
      first_bad = i;
      break;
    }
  }
  ASSERT_LT(first_bad, capture->images.size());
  CaptureRenderOptions options;
  const Status s = RenderCaptureVulkan(*capture, dir / "capture/gt/params.exr", dir / "renders",
                                       options, renderer())
                       .status();
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument) << s.ToString();
  EXPECT_NE(s.message().find(StrCat("images[", first_bad, "]")), std::string::npos)
      << s.message();
  size_t files = 0;
  if (fs::exists(dir / "renders")) {
    for (const auto& entry : fs::recursive_directory_iterator(dir / "renders")) {
      files += entry.is_regular_file();
    }
  }
  EXPECT_EQ(files, 0u) << "every image is checked before the first renders";
}

// The interreflection gather table of a fitted capture (16 rays per texel, as the tests of
// render_capture use).
std::unique_ptr<IndirectLight> table_of(const FittedCapture& fitted) {
  auto table = IndirectLight::Build(*fitted.scene, fitted.atlas, 16);
  REFLCAP_CHECK(table.ok()) << table.status().ToString();
  return std::make_unique<IndirectLight>(std::move(table).value());
}

// The auto settings' evidence (pixel model, interreflection) rendered on the device — a GPU's
// default (CaptureRenderBackend::renders_evidence), forced here on lavapipe — decides as the CPU
// reference renderer's: on photographs taken at the pixel centre or averaged over the pixel,
// without and with interreflection. The two renderers differ at shadow edges (shadow
// maps against rays), so the sums differ slightly.
TEST_F(VulkanBatch, EvidenceRenderedOnTheDeviceDecidesAsTheCpus) {
  // |reduction(device) - reduction(cpu)| relative to max(1, |reduction(cpu)|): measured 1.9e-3
  // (point-sampled photographs, -296.35 against -295.79), 0 to 1e-5 otherwise (the decision
  // margins are 0.02 for the pixel model, 0.25 for interreflection).
  constexpr double kReductionAgreement = 0.01;
  const auto agree = [](double device, double cpu) {
    return std::abs(device - cpu) <= kReductionAgreement * std::max(1.0, std::abs(cpu));
  };
  reflcap::testing::ScratchDir dir;
  struct Case {
    int photo_supersampling;
    bool interreflection;
  };
  for (const Case c : {Case{1, false}, Case{3, false}, Case{1, true}, Case{3, true}}) {
    const std::string name =
        StrCat("capture_", c.photo_supersampling, c.interreflection ? "_indirect" : "");
    SCOPED_TRACE(name);
    const fs::path cap_dir = dir / name;
    synth::SynthOptions o = SmallCapture(0.01, 4000, 64);
    o.supersampling = c.photo_supersampling;
    ASSERT_TRUE(synth::WriteSyntheticCapture(o, cap_dir).ok());
    auto capture = ReadCapture(cap_dir);
    ASSERT_TRUE(capture.ok());
    const fs::path gt = cap_dir / "gt/params.exr";
    if (c.interreflection) {
      // Every photograph rendered with interreflection (CPU) and written over it.
      CaptureRenderOptions on;
      on.split = SplitSelection::kAll;
      on.indirect = IndirectMode::kOn;
      on.indirect_rays = 16;
      on.supersampling = c.photo_supersampling;
      ASSERT_TRUE(RenderCapture(*capture, gt, cap_dir / "with_indirect", on).ok());
      for (const CaptureImage& image : capture->images) {
        auto lit = ReadExrRgb(cap_dir / "with_indirect" / RenderPathFor(image.file));
        ASSERT_TRUE(lit.ok());
        ASSERT_TRUE(WriteExr(capture->Resolve(image.file), *lit, ExrPixelType::kFloat).ok());
      }
    }
    auto fitted = LoadFittedCapture(*capture, gt);
    ASSERT_TRUE(fitted.ok()) << fitted.status().ToString();
    ASSERT_TRUE(SetFittedScene(renderer(), **fitted).ok());
    const EvidenceRender on_device = [&](size_t index, const RenderOptions& options) {
      return RenderCaptureImageVulkan(renderer(), **fitted, index, options);
    };
    const PixelEvidence cpu = MeasurePixelEvidence(**fitted, true);
    const PixelEvidence gpu = MeasurePixelEvidence(**fitted, true, on_device);
    const int pixel_model = cpu.box ? kAutoBoxSupersampling : 1;
    const std::unique_ptr<IndirectLight> table = table_of(**fitted);
    const IndirectEvidence icpu = MeasureIndirectEvidence(**fitted, *table, 2, true, pixel_model);
    const IndirectEvidence igpu =
        MeasureIndirectEvidence(**fitted, *table, 2, true, pixel_model, on_device);
    std::printf("%s: pixel-model reduction cpu %.5f, device %.5f; interreflection: %zu / %zu "
                "unlit pixels, error reduction cpu %.5f, device %.5f\n",
                name.c_str(), cpu.reduction, gpu.reduction, icpu.pixels, igpu.pixels,
                icpu.error_reduction, igpu.error_reduction);
    EXPECT_EQ(gpu.images, cpu.images);
    EXPECT_EQ(gpu.pixels, cpu.pixels);
    EXPECT_EQ(cpu.box, c.photo_supersampling > 1);  // the cases have teeth
    EXPECT_EQ(gpu.box, cpu.box);
    // With interreflection the photographs are the CPU renderer's own noise-free output: its
    // point error is the indirect light alone, the device's adds its shadow-edge differences, and
    // the ratio (-1.2e4 against -1.1e4) says only "not a box" on both.
    if (!c.interreflection) {
      EXPECT_TRUE(agree(gpu.reduction, cpu.reduction));
    }
    // The other way of shading pinhole cameras (whichever kAuto did not pick on this device)
    // decides alike: the point-sampled evidence is where the resolve once missed silhouette
    // pixels (-193 against -296 before its visibility image was aligned with the pixel grid).
    {
      VulkanRenderOptions other;
      other.camera_shading = renderer().resolves_pinhole_cameras() ? CameraShading::kFragment
                                                                   : CameraShading::kResolve;
      auto r = VulkanRenderer::Create(Device(), other);
      ASSERT_TRUE(r.ok()) << r.status().ToString();
      ASSERT_TRUE(SetFittedScene(**r, **fitted).ok());
      const PixelEvidence alt =
          MeasurePixelEvidence(**fitted, true, [&](size_t index, const RenderOptions& options) {
            return RenderCaptureImageVulkan(**r, **fitted, index, options);
          });
      std::printf("%s: pixel-model reduction, %s shading: %.5f\n", name.c_str(),
                  (*r)->resolves_pinhole_cameras() ? "resolve" : "per-fragment", alt.reduction);
      EXPECT_EQ(alt.box, cpu.box);
      if (!c.interreflection) {
        EXPECT_TRUE(agree(alt.reduction, cpu.reduction));
      }
    }
    EXPECT_EQ(icpu.shows, c.interreflection);
    EXPECT_EQ(igpu.shows, icpu.shows);
    EXPECT_TRUE(agree(igpu.error_reduction, icpu.error_reduction));
    // The footprint's evidence (with a box): every width rendered by the resolve on the device,
    // with the interreflection when the photographs hold it. Same choice; without interreflection
    // (the photographs then differ from every candidate at edges by more than the renderers
    // do) the same error for every width.
    if (cpu.box) {
      const IndirectLight* bounced = c.interreflection ? table.get() : nullptr;
      const FootprintEvidence fcpu =
          MeasureFootprintEvidence(**fitted, true, kAutoBoxSupersampling, bounced, 2);
      const FootprintEvidence fgpu =
          MeasureFootprintEvidence(**fitted, true, kAutoBoxSupersampling, bounced, 2, on_device);
      std::printf("%s: footprint cpu %.2f px (reduction %.5f), device %.2f px (%.5f)\n",
                  name.c_str(), fcpu.footprint, fcpu.reduction, fgpu.footprint, fgpu.reduction);
      EXPECT_EQ(fgpu.images, fcpu.images);
      EXPECT_EQ(fgpu.footprint, fcpu.footprint);
      for (size_t f = 0; f < fcpu.error.size() && !c.interreflection; ++f) {
        EXPECT_TRUE(agree(fgpu.error[f], fcpu.error[f]))
            << kPixelFootprintCandidates[f] << " px: " << fgpu.error[f] << " vs " << fcpu.error[f];
      }
    }

    // Through RenderCapture: a backend that renders the evidence says so, and decides the same.
    CaptureRenderBackend backend = VulkanCaptureRenderBackend(renderer());
    backend.renders_evidence = true;
    CaptureRenderOptions automatic;
    automatic.indirect_rays = 16;
    const fs::path out = cap_dir / "auto_on_device";
    ASSERT_TRUE(RenderCapture(*capture, gt, out, automatic, backend).ok());
    const auto report = nlohmann::json::parse(ReadTextFile(out / "render_report.json").value());
    EXPECT_EQ(report["pixel_model"]["evidence"]["renderer"], "vulkan");
    EXPECT_EQ(report["indirect"]["evidence"]["renderer"], "vulkan");
    EXPECT_EQ(report["supersampling"], cpu.box ? kAutoBoxSupersampling : 1);
    EXPECT_EQ(report["indirect"]["used"], icpu.shows);
  }
}

}  // namespace
}  // namespace reflcap::render
