#pragma once
// The exact plane scene of the resampler's radiometry tests: a 0.2 m square at z = 0 (8 x 8 quads,
// 40 x 40 texels) seen straight down from about 0.5 m, lit by a directional "sun". Every quantity
// of a sample is known in closed form there, so the tests compare against exact expectations.
#include <memory>

#include "engine/capture/capture.h"
#include "engine/mesh/ray_scene.h"
#include "engine/mesh/texel_atlas.h"
#include "tests/support/shapes.h"

namespace reflcap::testing {

// A pinhole camera at `eye` looking straight down -z (world = object frame), size x size pixels:
// +x right and +y down in the image are world +x and world -y.
inline Camera DownCamera(const Vec3d& eye, int size, double focal_px) {
  Camera cam;
  cam.id = "down";
  cam.width = cam.height = size;
  cam.K << focal_px, 0, 0.5 * (size - 1), 0, focal_px, 0.5 * (size - 1), 0, 0, 1;
  Mat3d r;
  r << 1, 0, 0, 0, -1, 0, 0, 0, -1;
  cam.cam_from_world = {r, -(r * eye)};
  return cam;
}

struct PlaneScene {
  TriangleMesh mesh;
  std::unique_ptr<RayScene> scene;
  TexelAtlas atlas;
  Vec3d eye{0.01, -0.02, 0.5};  // the camera's centre
  Capture capture;  // one camera ("down", 64 px, f = 140 px, at `eye`), light 0 = sun, no images
};

// The plane, its ray scene and atlas, and a capture with the camera and the sun (no images yet).
inline PlaneScene MakePlaneScene() {
  PlaneScene s;
  s.mesh = MakeGridPlane(0.2f, 0.2f, 8, 8);
  s.scene = RayScene::Create(s.mesh).value();
  s.atlas = BuildTexelAtlas(s.mesh, 40, 40).value();
  s.capture.json_path = "plane/capture.json";
  s.capture.mesh = "plane.obj";
  s.capture.cameras.push_back(DownCamera(s.eye, 64, 140));
  Light sun;
  sun.id = "sun";
  sun.type = LightType::kDirectional;
  sun.direction = Vec3d(0.3, 0.1, 1).normalized();
  sun.intensity = Vec3d(1, 2, 0.5);
  s.capture.lights = {sun};
  return s;
}

}  // namespace reflcap::testing
