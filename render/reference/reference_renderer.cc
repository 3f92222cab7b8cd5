// CPU reference renderer (see reference_renderer.h). Rows are shaded in parallel; each sample is
// one closest-hit ray and, when the point faces the light, one occlusion ray. Normal-map captures
// are shaded per texel, without rays.
#include "render/reference/reference_renderer.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "engine/brdf/lafortune.h"
#include "engine/core/parallel.h"

namespace reflcap::render {
namespace {

constexpr float kInfinity = std::numeric_limits<float>::infinity();
// Pixels between a crack ray and its retry (ImageShader::Shade): far beyond the float rounding
// that lets a ray slip between two triangles (~1e-7 of a distance), far below anything a pixel
// resolves.
constexpr double kCrackNudgePx = 1e-4;

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

}  // namespace

Status RenderOptions::Validate() const {
  if (supersampling < 1 || supersampling > kMaxSupersampling) {
    return InvalidArgumentError("supersampling must be in [1, ", kMaxSupersampling, "], got ",
                                supersampling);
  }
  if (!(pixel_footprint >= 1 && pixel_footprint <= kMaxPixelFootprint)) {
    return InvalidArgumentError("pixel footprint must be in [1, ", kMaxPixelFootprint,
                                "] px, got ", pixel_footprint);
  }
  return OkStatus();
}

namespace {

// One image's shading as RenderImage traces it: the shared body of RenderImage (every pixel) and
// RenderPixels (some). Inputs are checked by the callers.
class ImageShader {
 public:
  ImageShader(const ShadedScene& shaded, const Camera& camera, const Light& light,
              const Rigid3& world_from_object, double exposure_s, const RenderOptions& options,
              const std::vector<float>* curvature)
      : shaded_(shaded),
        scene_(*shaded.scene),
        mesh_(scene_.mesh()),
        atlas_(*shaded.atlas),
        options_(options),
        rays_{camera, (camera.cam_from_world * world_from_object).Inverse()},
        point_light_(light.type == LightType::kPoint),
        intensity_(light.intensity.cast<float>()),
        offset_(scene_.SurfaceOffset()),
        n_(options.supersampling),
        footprint_(options.pixel_footprint),
        sample_weight_(float(exposure_s) / float(n_ * n_)) {
    const Rigid3 object_from_world = world_from_object.Inverse();
    light_in_object_ = (object_from_world * light.position).cast<float>();
    light_dir_in_object_ = (object_from_world.rotation * light.direction).normalized().cast<float>();
    if (options.aux_buffers) {
      if (curvature == nullptr) {
        own_curvature_ = SurfaceCurvature(mesh_);
        curvature = &own_curvature_;
      }
      curvature_ = curvature;
    }
  }

  // Pixel (x, y) of `result` (sized by the caller; its aux and mask at the pixel zero on entry):
  // radiance (the N x N stratified average times exposure), mask and aux from the centre ray.
  void ShadePixel(int x, int y, RenderResult* result) const {
    float* aux = options_.aux_buffers ? result->aux.pixel(x, y) : nullptr;
    Vec3f sum = Vec3f::Zero(), radiance;
    if (n_ == 1) {
      // The one sample is the centre ray: it gives the mask and the aux buffers too.
      if (Shade(x, double(y), &radiance, aux)) result->mask.at(x, y) = 1;
      sum = radiance;
    } else {
      if (aux) {
        if (Shade(x, double(y), &radiance, aux)) result->mask.at(x, y) = 1;
      } else {
        Vec3f origin, dir;
        rays_.Ray(x, double(y), &origin, &dir);
        if (scene_.Intersect(origin, dir, 0, kInfinity).hit) result->mask.at(x, y) = 1;
      }
      for (int sy = 0; sy < n_; ++sy) {
        for (int sx = 0; sx < n_; ++sx) {
          Shade(x + SampleOffset(sx, n_, footprint_), double(y) + SampleOffset(sy, n_, footprint_),
                &radiance, nullptr);
          sum += radiance;
        }
      }
    }
    float* px = result->pixels.pixel(x, y);
    for (int c = 0; c < 3; ++c) px[c] = sum[c] * sample_weight_;
  }

 private:
  // Traces the ray through (px, py) and returns its radiance contribution f E cos θi (before
  // exposure); fills `aux` (kAuxChannelCount floats, zero on entry) when given. Returns false on
  // a miss.
  bool Shade(double px, double py, Vec3f* radiance, float* aux) const {
    *radiance = Vec3f::Zero();
    Vec3f origin, dir;
    rays_.Ray(px, py, &origin, &dir);
    RayHit hit = scene_.Intersect(origin, dir, 0, kInfinity);
    if (!hit.hit) return false;
    if (!(mesh_.GeometricNormal(hit.triangle).dot(dir) < 0)) {
      // A back face first. On a closed surface that is a ray that slipped between two triangles
      // (Embree is not exactly watertight: ~15 pixels of a million-preset image went black, as
      // isolated pixels amid lit ones); the ray kCrackNudgePx beside it meets the surface the
      // pixel sees. A true back face (an open mesh seen from behind) stays: the nudged ray meets
      // it too.
      Vec3f nudged_origin, nudged_dir;
      rays_.Ray(px + kCrackNudgePx, py + kCrackNudgePx, &nudged_origin, &nudged_dir);
      const RayHit nudged = scene_.Intersect(nudged_origin, nudged_dir, 0, kInfinity);
      if (nudged.hit && mesh_.GeometricNormal(nudged.triangle).dot(nudged_dir) < 0) {
        hit = nudged;
        dir = nudged_dir;
      }
    }
    const auto& tri = mesh_.triangles[hit.triangle];
    const float b0 = 1 - hit.b1 - hit.b2;
    const Vec3f p = b0 * mesh_.positions[tri[0]] + hit.b1 * mesh_.positions[tri[1]] +
                    hit.b2 * mesh_.positions[tri[2]];
    const Vec3f n_g = mesh_.GeometricNormal(hit.triangle);
    const auto& cn = mesh_.corner_normals[hit.triangle];
    const Vec3f n_s = (b0 * cn[0] + hit.b1 * cn[1] + hit.b2 * cn[2]).normalized();
    const Vec3f wo = -dir;
    Vec3f wi;
    float dist = kInfinity;
    Vec3f irradiance_per_cos = intensity_;
    if (point_light_) {
      const Vec3f to_light = light_in_object_ - p;
      dist = to_light.norm();
      wi = to_light / dist;
      irradiance_per_cos /= dist * dist;
    } else {
      wi = light_dir_in_object_;
    }
    const float cos_i = n_s.dot(wi);
    if (aux) {
      aux[kAuxMask] = 1;
      aux[kAuxCosThetaI] = cos_i;
      aux[kAuxCosThetaO] = n_s.dot(wo);
      aux[kAuxCurvature] = (*curvature_)[hit.triangle];
    }
    if (n_g.dot(wo) <= 0) return true;  // back face of an open mesh: black
    if (cos_i <= 0 || n_g.dot(wi) <= 0) return true;
    if (options_.cast_shadows &&
        scene_.Occluded(p + offset_ * n_g, wi, 0, point_light_ ? dist - offset_ : kInfinity)) {
      if (aux) aux[kAuxCastShadow] = 1;
      return true;
    }
    const auto& cuv = mesh_.corner_uvs[hit.triangle];
    const Vec2f uv = b0 * cuv[0] + hit.b1 * cuv[1] + hit.b2 * cuv[2];
    const int texel = atlas_.TexelUnderUv(uv);
    if (texel < 0) return true;
    // The texel's tangent frame, re-orthogonalised against the normal at the hit.
    Vec3f t = atlas_.tangent[texel] - n_s * n_s.dot(atlas_.tangent[texel]);
    if (t.squaredNorm() < 1e-12f) t = n_s.unitOrthogonal();  // tangent ∥ normal: any
    t.normalize();
    const Vec3f b = n_s.cross(t);
    const Vec3f wi_local(t.dot(wi), b.dot(wi), cos_i);
    const Vec3f wo_local(t.dot(wo), b.dot(wo), n_s.dot(wo));
    if (wo_local.z() <= 0) return true;  // shading normal turned away from the viewer
    const Vec3f f = brdf::EvalRgb(shaded_.maps->texels[texel], wi_local, wo_local);
    *radiance = f.cwiseProduct(irradiance_per_cos) * cos_i;
    return true;
  }

  const ShadedScene& shaded_;
  const RayScene& scene_;
  const TriangleMesh& mesh_;
  const TexelAtlas& atlas_;
  const RenderOptions options_;
  const RayGenerator rays_;
  const bool point_light_;
  Vec3f light_in_object_, light_dir_in_object_;
  const Vec3f intensity_;
  const float offset_;
  const int n_;
  const double footprint_;
  const float sample_weight_;
  std::vector<float> own_curvature_;
  const std::vector<float>* curvature_ = nullptr;
};

Status CheckRenderInputs(const ShadedScene& shaded, const Camera& camera,
                         const RenderOptions& options) {
  REFLCAP_RETURN_IF_ERROR(options.Validate());
  REFLCAP_CHECK(shaded.scene && shaded.atlas && shaded.maps);
  REFLCAP_CHECK(shaded.maps->texels.size() == shaded.atlas->TexelCount());
  if (camera.model == CameraModel::kOrthographic && !(camera.pixel_size_m > 0)) {
    return InvalidArgumentError("camera \"", camera.id,
                                "\": orthographic rendering needs pixel_size_m");
  }
  return OkStatus();
}

}  // namespace

StatusOr<RenderResult> RenderImage(const ShadedScene& shaded, const Camera& camera,
                                   const Light& light, const Rigid3& world_from_object,
                                   double exposure_s, const RenderOptions& options) {
  REFLCAP_RETURN_IF_ERROR(CheckRenderInputs(shaded, camera, options));
  const ImageShader shader(shaded, camera, light, world_from_object, exposure_s, options, nullptr);
  RenderResult result{Image(camera.width, camera.height, 3, 0.0f),
                      Image(camera.width, camera.height, 1, 0.0f), Image()};
  if (options.aux_buffers) result.aux = Image(camera.width, camera.height, kAuxChannelCount, 0.0f);
  ParallelFor(0, camera.height, 4, [&](int64_t y0, int64_t y1, int) {
    for (int64_t y = y0; y < y1; ++y) {
      for (int x = 0; x < camera.width; ++x) shader.ShadePixel(x, int(y), &result);
    }
  });
  return result;
}

Status RenderPixels(const ShadedScene& shaded, const Camera& camera, const Light& light,
                    const Rigid3& world_from_object, double exposure_s,
                    const RenderOptions& options, const std::vector<float>* curvature,
                    const std::vector<uint32_t>& pixels, RenderResult* result) {
  REFLCAP_RETURN_IF_ERROR(CheckRenderInputs(shaded, camera, options));
  const size_t count = size_t(camera.width) * camera.height;
  if (result->pixels.width != camera.width || result->pixels.height != camera.height ||
      result->pixels.channels != 3 || result->mask.data.size() != count ||
      (options.aux_buffers && result->aux.data.size() != count * kAuxChannelCount)) {
    return InvalidArgumentError("RenderPixels: the result is not a ", camera.width, "x",
                                camera.height, " render of camera \"", camera.id, "\"");
  }
  for (uint32_t i : pixels) {
    if (i >= count) {
      return InvalidArgumentError("RenderPixels: pixel ", i, " outside the ", camera.width, "x",
                                  camera.height, " image");
    }
  }
  const ImageShader shader(shaded, camera, light, world_from_object, exposure_s, options,
                           curvature);
  ParallelFor(0, int64_t(pixels.size()), 64, [&](int64_t begin, int64_t end, int) {
    for (int64_t k = begin; k < end; ++k) {
      const uint32_t i = pixels[size_t(k)];
      const int x = int(i % uint32_t(camera.width)), y = int(i / uint32_t(camera.width));
      // Written afresh, as RenderImage writes a pixel of a zeroed result.
      result->mask.at(x, y) = 0;
      if (options.aux_buffers) {
        std::fill_n(result->aux.pixel(x, y), kAuxChannelCount, 0.0f);
      }
      shader.ShadePixel(x, y, result);
    }
  });
  return OkStatus();
}

const std::vector<std::string>& AuxChannelNames() {
  static const std::vector<std::string> names = {"cast_shadow", "cos_theta_i", "cos_theta_o",
                                                 "curvature", "mask"};
  return names;
}

std::vector<float> SurfaceCurvature(const TriangleMesh& mesh) {
  // Object size S: area-weighted RMS distance of triangle centroids from the surface centroid.
  double area_sum = 0;
  Vec3d centroid = Vec3d::Zero();
  std::vector<double> areas(mesh.TriangleCount());
  std::vector<Vec3d> centres(mesh.TriangleCount());
  for (size_t t = 0; t < mesh.TriangleCount(); ++t) {
    const auto& tri = mesh.triangles[t];
    const Vec3d a = mesh.positions[tri[0]].cast<double>(), b = mesh.positions[tri[1]].cast<double>(),
                c = mesh.positions[tri[2]].cast<double>();
    areas[t] = 0.5 * (b - a).cross(c - a).norm();
    centres[t] = (a + b + c) / 3;
    area_sum += areas[t];
    centroid += areas[t] * centres[t];
  }
  std::vector<float> curvature(mesh.TriangleCount(), 0.0f);
  if (!(area_sum > 0)) return curvature;
  centroid /= area_sum;
  double spread = 0;
  for (size_t t = 0; t < mesh.TriangleCount(); ++t) {
    spread += areas[t] * (centres[t] - centroid).squaredNorm();
  }
  const double size = std::sqrt(spread / area_sum);
  for (size_t t = 0; t < mesh.TriangleCount(); ++t) {
    const auto& tri = mesh.triangles[t];
    const auto& cn = mesh.corner_normals[t];
    double worst = 0;
    for (int i = 0; i < 3; ++i) {
      const int j = (i + 1) % 3;
      const double length = (mesh.positions[tri[i]] - mesh.positions[tri[j]]).cast<double>().norm();
      if (!(length > 0)) continue;
      const Vec3d a = cn[i].cast<double>(), b = cn[j].cast<double>();
      // atan2 of |a x b| and a . b: accurate for small angles, where acos(a . b) is not.
      const double angle = std::atan2(a.cross(b).norm(), a.dot(b));
      worst = std::max(worst, angle / length);
    }
    curvature[t] = float(worst * size);
  }
  return curvature;
}

std::vector<float> NormalMapCurvature(const TexelAtlas& atlas, const Camera& camera) {
  std::vector<float> curvature(atlas.TexelCount(), 0.0f);
  if (atlas.TexelCount() == 0) return curvature;
  // Image axes x (right), y (down) and the viewing axis z in the world frame (OpenCV rows).
  const Mat3d& r = camera.cam_from_world.rotation;
  const Vec3f axes[3] = {r.row(0).transpose().cast<float>(), r.row(1).transpose().cast<float>(),
                         r.row(2).transpose().cast<float>()};
  const double size = std::sqrt(double(atlas.TexelCount()) / kPi);
  auto texel_at = [&](int px, int py) {
    if (px < 0 || py < 0 || px >= atlas.width || py >= atlas.height) return -1;
    return atlas.TexelAt(px, py);
  };
  ParallelFor(0, int64_t(atlas.TexelCount()), 4096, [&](int64_t t0, int64_t t1, int) {
    for (int64_t t = t0; t < t1; ++t) {
      int x, y;
      atlas.PixelOf(size_t(t), &x, &y);
      const Vec3f& n = atlas.shading_normal[size_t(t)];
      const double nz = std::max(double(std::abs(n.dot(axes[2]))), kMinNormalMapCos);
      double worst = 0;
      for (int dim = 0; dim < 2; ++dim) {
        const int dx = dim == 0 ? 1 : 0, dy = 1 - dx;
        int a = texel_at(x - dx, y - dy), b = texel_at(x + dx, y + dy);
        double steps = 2;  // central difference over 2 px, one-sided (1 px) at the border
        if (a < 0 && b < 0) continue;
        if (a < 0 || b < 0) {
          steps = 1;
          if (a < 0) a = int(t);
          if (b < 0) b = int(t);
        }
        // Arc length per pixel step of the height field z(x, y): sqrt(1 + (dz/dx)²), with
        // dz/dx = -n_x / n_z along this image axis.
        const double slope = double(n.dot(axes[dim])) / nz;
        const double stretch = std::sqrt(1 + slope * slope);
        const Vec3d na = atlas.shading_normal[size_t(a)].cast<double>();
        const Vec3d nb = atlas.shading_normal[size_t(b)].cast<double>();
        const double angle = std::atan2(na.cross(nb).norm(), na.dot(nb));
        worst = std::max(worst, angle / (steps * stretch));
      }
      curvature[size_t(t)] = float(worst * size);
    }
  });
  return curvature;
}

StatusOr<RenderResult> RenderNormalMapImage(const TexelAtlas& atlas, const BrdfMaps& maps,
                                            const Camera& camera, const Light& light,
                                            double exposure_s, const RenderOptions& options,
                                            const HeightField* heights) {
  REFLCAP_RETURN_IF_ERROR(options.Validate());
  REFLCAP_CHECK(maps.texels.size() == atlas.TexelCount());
  if (atlas.width != camera.width || atlas.height != camera.height) {
    return InvalidArgumentError("camera \"", camera.id, "\" is ", camera.width, "x", camera.height,
                                " but the normal map is ", atlas.width, "x", atlas.height);
  }
  if (light.type != LightType::kDirectional) {
    return InvalidArgumentError("light \"", light.id,
                                "\": normal-map captures are rendered with directional lights "
                                "only (the surface positions are unknown)");
  }
  if (heights != nullptr && (heights->width != atlas.width || heights->height != atlas.height)) {
    return InvalidArgumentError("the height field is ", heights->width, "x", heights->height,
                                " but the normal map is ", atlas.width, "x", atlas.height);
  }
  const bool shadows = options.cast_shadows && heights != nullptr;
  const HeightFieldMarch march =
      shadows ? MakeHeightFieldMarch(*heights, light.direction) : HeightFieldMarch{};
  const Rigid3 world_from_cam = camera.cam_from_world.Inverse();
  const Vec3f wi = light.direction.normalized().cast<float>();
  const Vec3f intensity = light.intensity.cast<float>();
  const Vec3d axis = camera.AxisInWorld();
  std::vector<float> curvature;
  if (options.aux_buffers) curvature = NormalMapCurvature(atlas, camera);
  RenderResult result{Image(camera.width, camera.height, 3, 0.0f),
                      Image(camera.width, camera.height, 1, 0.0f), Image()};
  if (options.aux_buffers) result.aux = Image(camera.width, camera.height, kAuxChannelCount, 0.0f);
  ParallelFor(0, int64_t(atlas.TexelCount()), 4096, [&](int64_t t0, int64_t t1, int) {
    for (int64_t t = t0; t < t1; ++t) {
      int x, y;
      atlas.PixelOf(size_t(t), &x, &y);
      Vec3f wo = -axis.cast<float>();
      if (camera.model == CameraModel::kPinhole) {
        Vec3d o, d;
        camera.PixelRay({double(x), double(y)}, &o, &d);
        wo = -(world_from_cam.rotation * d).normalized().cast<float>();
      }
      const Vec3f& n = atlas.shading_normal[size_t(t)];
      const Vec3f& tangent = atlas.tangent[size_t(t)];
      const Vec3f& bitangent = atlas.bitangent[size_t(t)];
      const float cos_i = n.dot(wi), cos_o = n.dot(wo);
      result.mask.at(x, y) = 1;
      if (options.aux_buffers) {
        float* aux = result.aux.pixel(x, y);
        aux[kAuxMask] = 1;
        aux[kAuxCosThetaI] = cos_i;
        aux[kAuxCosThetaO] = cos_o;
        aux[kAuxCurvature] = curvature[size_t(t)];
      }
      if (cos_i <= 0) continue;
      if (shadows && HeightFieldShadowed(heights->heights_px.data(), march, x, y)) {
        if (options.aux_buffers) result.aux.pixel(x, y)[kAuxCastShadow] = 1;
        continue;
      }
      if (cos_o <= 0) continue;
      const Vec3f wi_local(tangent.dot(wi), bitangent.dot(wi), cos_i);
      const Vec3f wo_local(tangent.dot(wo), bitangent.dot(wo), cos_o);
      const Vec3f f = brdf::EvalRgb(maps.texels[size_t(t)], wi_local, wo_local);
      const Vec3f value = f.cwiseProduct(intensity) * (cos_i * float(exposure_s));
      float* px = result.pixels.pixel(x, y);
      for (int c = 0; c < 3; ++c) px[c] = value[c];
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
