// CPU reference renderer (see reference_renderer.h). Rows are shaded in parallel; each sample is
// one closest-hit ray and, when the point faces the light, one occlusion ray.
#include "render/reference/reference_renderer.h"

#include <cmath>
#include <limits>

#include "engine/brdf/lafortune.h"
#include "engine/core/parallel.h"

namespace reflcap::render {
namespace {

constexpr float kInfinity = std::numeric_limits<float>::infinity();

// Rays of one image in the object frame.
struct RayGenerator {
  const Camera& camera;
  Rigid3 object_from_cam;

  void Ray(double px, double py, Vec3f* origin, Vec3f* dir) const {
    Vec3d o, d;
    camera.PixelRay({px, py}, &o, &d);
    *origin = (object_from_cam * o).cast<float>();
    *dir = (object_from_cam.rotation * d).normalized().cast<float>();
  }
};

// Texel whose parameters shade a hit: the atlas pixel under the hit's UV. Conservative atlas
// coverage guarantees one for UVs inside a triangle; rounding at a chart border can land one
// pixel off, so the 3x3 neighbourhood is searched before giving up (-1).
int TexelOfHit(const TexelAtlas& atlas, const Vec2f& uv) {
  int x, y;
  atlas.PixelOfUv(uv.x(), uv.y(), &x, &y);
  int t = atlas.TexelAt(x, y);
  if (t >= 0) return t;
  for (int dy = -1; dy <= 1; ++dy) {
    for (int dx = -1; dx <= 1; ++dx) {
      const int nx = x + dx, ny = y + dy;
      if (nx < 0 || ny < 0 || nx >= atlas.width || ny >= atlas.height) continue;
      if ((t = atlas.TexelAt(nx, ny)) >= 0) return t;
    }
  }
  return -1;
}

}  // namespace

Status RenderOptions::Validate() const {
  if (supersampling < 1 || supersampling > kMaxSupersampling) {
    return InvalidArgumentError("supersampling must be in [1, ", kMaxSupersampling, "], got ",
                                supersampling);
  }
  return OkStatus();
}

StatusOr<RenderResult> RenderImage(const ShadedScene& shaded, const Camera& camera,
                                   const Light& light, const Rigid3& world_from_object,
                                   double exposure_s, const RenderOptions& options) {
  REFLCAP_RETURN_IF_ERROR(options.Validate());
  REFLCAP_CHECK(shaded.scene && shaded.atlas && shaded.maps);
  REFLCAP_CHECK(shaded.maps->texels.size() == shaded.atlas->TexelCount());
  if (camera.model == CameraModel::kOrthographic && !(camera.pixel_size_m > 0)) {
    return InvalidArgumentError("camera \"", camera.id,
                                "\": orthographic rendering needs pixel_size_m");
  }
  const RayScene& scene = *shaded.scene;
  const TriangleMesh& mesh = scene.mesh();
  const TexelAtlas& atlas = *shaded.atlas;
  const Rigid3 object_from_world = world_from_object.Inverse();
  const RayGenerator rays{camera, (camera.cam_from_world * world_from_object).Inverse()};
  const bool point_light = light.type == LightType::kPoint;
  const Vec3f light_in_object = (object_from_world * light.position).cast<float>();
  const Vec3f light_dir_in_object =
      (object_from_world.rotation * light.direction).normalized().cast<float>();
  const Vec3f intensity = light.intensity.cast<float>();
  const float offset = scene.SurfaceOffset();
  const int n = options.supersampling;
  const float sample_weight = float(exposure_s) / float(n * n);

  RenderResult result{Image(camera.width, camera.height, 3, 0.0f),
                      Image(camera.width, camera.height, 1, 0.0f)};
  ParallelFor(0, camera.height, 4, [&](int64_t y0, int64_t y1, int) {
    for (int64_t y = y0; y < y1; ++y) {
      for (int x = 0; x < camera.width; ++x) {
        Vec3f origin, dir;
        rays.Ray(x, double(y), &origin, &dir);
        if (scene.Intersect(origin, dir, 0, kInfinity).hit) result.mask.at(x, int(y)) = 1;
        Vec3f sum = Vec3f::Zero();
        for (int sy = 0; sy < n; ++sy) {
          for (int sx = 0; sx < n; ++sx) {
            // Stratum centres: offsets (i + 0.5)/n - 0.5 within the pixel; n = 1 is the centre.
            rays.Ray(x + (sx + 0.5) / n - 0.5, double(y) + (sy + 0.5) / n - 0.5, &origin, &dir);
            const RayHit hit = scene.Intersect(origin, dir, 0, kInfinity);
            if (!hit.hit) continue;
            const auto& tri = mesh.triangles[hit.triangle];
            const float b0 = 1 - hit.b1 - hit.b2;
            const Vec3f p = b0 * mesh.positions[tri[0]] + hit.b1 * mesh.positions[tri[1]] +
                            hit.b2 * mesh.positions[tri[2]];
            const Vec3f n_g = mesh.GeometricNormal(hit.triangle);
            const auto& cn = mesh.corner_normals[hit.triangle];
            const Vec3f n_s = (b0 * cn[0] + hit.b1 * cn[1] + hit.b2 * cn[2]).normalized();
            const Vec3f wo = -dir;
            if (n_g.dot(wo) <= 0) continue;  // back face of an open mesh: black
            Vec3f wi;
            float dist = kInfinity;
            Vec3f irradiance_per_cos = intensity;
            if (point_light) {
              const Vec3f to_light = light_in_object - p;
              dist = to_light.norm();
              wi = to_light / dist;
              irradiance_per_cos /= dist * dist;
            } else {
              wi = light_dir_in_object;
            }
            const float cos_i = n_s.dot(wi);
            if (cos_i <= 0 || n_g.dot(wi) <= 0) continue;
            if (options.cast_shadows &&
                scene.Occluded(p + offset * n_g, wi, 0, point_light ? dist - offset : kInfinity)) {
              continue;
            }
            const auto& cuv = mesh.corner_uvs[hit.triangle];
            const Vec2f uv = b0 * cuv[0] + hit.b1 * cuv[1] + hit.b2 * cuv[2];
            const int texel = TexelOfHit(atlas, uv);
            if (texel < 0) continue;
            // The texel's tangent frame, re-orthogonalised against the normal at the hit.
            Vec3f t = atlas.tangent[texel] - n_s * n_s.dot(atlas.tangent[texel]);
            if (t.squaredNorm() < 1e-12f) t = n_s.unitOrthogonal();  // tangent ∥ normal: any
            t.normalize();
            const Vec3f b = n_s.cross(t);
            const Vec3f wi_local(t.dot(wi), b.dot(wi), cos_i);
            const Vec3f wo_local(t.dot(wo), b.dot(wo), n_s.dot(wo));
            if (wo_local.z() <= 0) continue;  // shading normal turned away from the viewer
            const Vec3f f = brdf::EvalRgb(shaded.maps->texels[texel], wi_local, wo_local);
            sum += f.cwiseProduct(irradiance_per_cos) * cos_i;
          }
        }
        float* px = result.pixels.pixel(x, int(y));
        for (int c = 0; c < 3; ++c) px[c] = sum[c] * sample_weight;
      }
    }
  });
  return result;
}

StatusOr<Image> RenderMask(const RayScene& scene, const Camera& camera,
                           const Rigid3& world_from_object) {
  if (camera.model == CameraModel::kOrthographic && !(camera.pixel_size_m > 0)) {
    return InvalidArgumentError("camera \"", camera.id,
                                "\": orthographic rendering needs pixel_size_m");
  }
  const RayGenerator rays{camera, (camera.cam_from_world * world_from_object).Inverse()};
  Image mask(camera.width, camera.height, 1, 0.0f);
  ParallelFor(0, camera.height, 8, [&](int64_t y0, int64_t y1, int) {
    for (int64_t y = y0; y < y1; ++y) {
      for (int x = 0; x < camera.width; ++x) {
        Vec3f origin, dir;
        rays.Ray(x, double(y), &origin, &dir);
        if (scene.Intersect(origin, dir, 0, kInfinity).hit) mask.at(x, int(y)) = 1;
      }
    }
  });
  return mask;
}

}  // namespace reflcap::render
