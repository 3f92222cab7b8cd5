// The camera, turntable and pixel conventions agree with an independent peer: object masks
// rendered from suzanne's mesh, cameras and turntable angles against Blender's own silhouettes.
#include <gtest/gtest.h>

#include <cstdio>
#include <set>

#include "engine/capture/capture.h"
#include "engine/image/png_io.h"
#include "engine/mesh/mesh_io.h"
#include "render/reference/reference_renderer.h"
#include "tests/support/test_support.h"

namespace reflcap::render {
namespace {

// The bar. Blender's masks test one ray per pixel centre, as RenderMask does, so only
// pixels whose centre ray grazes a silhouette triangle edge can disagree.
constexpr double kMinMaskIoU = 0.99;

TEST(SuzanneMasks, RenderedMasksMatchBlenderSilhouettes) {
  const auto shared = testing::SharedDataDir();
  if (!shared) GTEST_SKIP() << "../shared/data is absent: skipping the Blender silhouette check";
  const auto folder = *shared / "turntable" / "suzanne";
  auto capture = ReadCapture(folder / "capture.json");
  ASSERT_TRUE(capture.ok()) << capture.status().ToString();
  auto mesh = LoadMesh(capture->Resolve(capture->mesh));
  ASSERT_TRUE(mesh.ok()) << mesh.status().ToString();
  auto scene = RayScene::Create(*mesh);
  ASSERT_TRUE(scene.ok());

  std::set<std::pair<int, double>> views;  // (camera, angle) pairs of the capture
  for (const auto& image : capture->images) views.insert({image.camera, image.turntable_deg});
  ASSERT_EQ(views.size(), 48u);
  double worst = 1;
  for (const auto& [cam_index, angle] : views) {
    const Camera& cam = capture->cameras[cam_index];
    char name[64];
    std::snprintf(name, sizeof name, "masks/%s_%03d.png", cam.id.c_str(), int(angle));
    auto blender = ReadPng(folder / name);
    ASSERT_TRUE(blender.ok()) << blender.status().ToString();
    auto ours = RenderMask(**scene, cam, capture->turntable->WorldFromObject(angle));
    ASSERT_TRUE(ours.ok());
    size_t inter = 0, uni = 0;
    for (int y = 0; y < cam.height; ++y) {
      for (int x = 0; x < cam.width; ++x) {
        const bool a = blender->at(x, y, 0) > 0.5f, b = ours->at(x, y) > 0.5f;
        inter += a && b;
        uni += a || b;
      }
    }
    ASSERT_GT(uni, 0u);
    const double iou = double(inter) / double(uni);
    worst = std::min(worst, iou);
    EXPECT_GE(iou, kMinMaskIoU) << name;
  }
  std::printf("suzanne: worst mask IoU over 48 views = %.5f\n", worst);
}

}  // namespace
}  // namespace reflcap::render
