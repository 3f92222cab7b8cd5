// Interreflection for re-renders (see indirect_light.h).
#include "render/reference/indirect_light.h"

#include <cmath>
#include <limits>

#include "engine/brdf/lafortune.h"
#include "engine/core/parallel.h"
#include "render/reference/reference_renderer.h"

namespace reflcap::render {
namespace {

constexpr float kInfinity = std::numeric_limits<float>::infinity();
constexpr double kPi = 3.14159265358979323846;

// A 64-bit mix (the finaliser of SplitMix64): decorrelates the jitter of neighbouring texels and
// rays so the strata of adjacent texels do not line up.
uint64_t Mix(uint64_t z) {
  z += 0x9e3779b97f4a7c15ull;
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
  return z ^ (z >> 31);
}

// Uniform in [0, 1) from 24 bits of h (exact in float).
float Unit(uint64_t h) { return float(h >> 40) * (1.0f / 16777216.0f); }

// The texel under a hit, or -1 when the ray hit nothing, or the back of a face (inside a closed
// mesh, or behind an open one: nothing lit is seen from there).
int32_t TexelOfRayHit(const RayScene& scene, const TexelAtlas& atlas, const RayHit& hit,
                 const Vec3f& dir) {
  if (!hit.hit) return -1;
  const TriangleMesh& mesh = scene.mesh();
  if (mesh.GeometricNormal(hit.triangle).dot(dir) >= 0) return -1;
  const auto& cuv = mesh.corner_uvs[hit.triangle];
  const Vec2f uv = (1 - hit.b1 - hit.b2) * cuv[0] + hit.b1 * cuv[1] + hit.b2 * cuv[2];
  return atlas.TexelUnderUv(uv);
}

bool SendsLight(const brdf::BrdfParams& p) {
  for (float r : p.rho_d) {
    if (!std::isfinite(r)) return false;
  }
  return true;
}

}  // namespace

StatusOr<IndirectLight> IndirectLight::Build(const RayScene& scene, const TexelAtlas& atlas,
                                             int rays) {
  if (rays < 1 || rays > kMaxIndirectRays) {
    return InvalidArgumentError("indirect rays per texel must be in [1, ", kMaxIndirectRays,
                                "], got ", rays);
  }
  for (size_t t = 0; t < atlas.TexelCount(); ++t) {
    if (atlas.triangle[t] < 0) {
      return InvalidArgumentError("indirect light needs a mesh atlas; texel ", t,
                                  " has no triangle (a normal-map atlas?)");
    }
  }
  IndirectLight out;
  out.rays_ = rays;
  out.texels_ = atlas.TexelCount();
  out.hit_.assign(out.texels_ * size_t(rays), -1);
  // Strata: a g × g grid covering the unit square (g = ceil √rays); ray r takes cell r of it, so
  // a square count stratifies fully and any other count takes the first cells row by row.
  const int grid = int(std::ceil(std::sqrt(double(rays))));
  const float offset = scene.SurfaceOffset();
  ParallelFor(0, int64_t(out.texels_), 256, [&](int64_t begin, int64_t end, int) {
    for (int64_t ti = begin; ti < end; ++ti) {
      const size_t t = size_t(ti);
      const Vec3f& n = atlas.shading_normal[t];
      const Vec3f& ng = atlas.geometric_normal[t];
      const Vec3f& tx = atlas.tangent[t];
      const Vec3f& bx = atlas.bitangent[t];
      const Vec3f origin = atlas.position[t] + offset * ng;
      for (int r = 0; r < rays; ++r) {
        const uint64_t h = Mix(uint64_t(t) * uint64_t(kMaxIndirectRays) + uint64_t(r));
        const float u1 = (float(r % grid) + Unit(h)) / float(grid);
        const float u2 = (float(r / grid) + Unit(Mix(h))) / float(grid);
        // Malley: a uniform point on the unit disc lifted to the hemisphere is cosine-distributed.
        const float radius = std::sqrt(u1), phi = float(2 * kPi) * u2;
        const float x = radius * std::cos(phi), y = radius * std::sin(phi);
        const float z = std::sqrt(std::max(0.0f, 1 - u1));
        Vec3f dir = (x * tx + y * bx + z * n).normalized();
        // Shading and geometric normals differ on a smooth-shaded mesh: a direction near the
        // shading horizon can point into the geometric surface. Mirrored about that surface it
        // stays a ray of the hemisphere (dropping it would darken every such texel by 1/rays).
        const float below = dir.dot(ng);
        if (below <= 0) dir = (dir - 2 * below * ng).normalized();
        if (!(dir.dot(ng) > 0)) continue;  // grazing exactly: no ray
        const RayHit hit = scene.Intersect(origin, dir, 0, kInfinity);
        out.hit_[t * size_t(rays) + size_t(r)] = TexelOfRayHit(scene, atlas, hit, dir);
      }
    }
  });
  return out;
}

std::vector<Vec3f> IndirectLight::TexelRadiance(const RayScene& scene, const TexelAtlas& atlas,
                                                const BrdfMaps& maps, const Light& light,
                                                const Rigid3& object_from_world, int bounces,
                                                bool cast_shadows) const {
  REFLCAP_CHECK(atlas.TexelCount() == texels_ && maps.texels.size() == texels_);
  REFLCAP_CHECK(bounces >= 1 && bounces <= kMaxIndirectBounces);
  const bool point_light = light.type == LightType::kPoint;
  const Vec3f light_in_object = (object_from_world * light.position).cast<float>();
  const Vec3f light_dir =
      (object_from_world.rotation * light.direction).normalized().cast<float>();
  const Vec3f intensity = light.intensity.cast<float>();
  const float offset = scene.SurfaceOffset();
  // What each texel sends: ρ/π · E (direct), then the last bounce's radiance.
  std::vector<Vec3f> send(texels_, Vec3f::Zero());
  ParallelFor(0, int64_t(texels_), 1024, [&](int64_t begin, int64_t end, int) {
    for (int64_t ti = begin; ti < end; ++ti) {
      const size_t t = size_t(ti);
      const brdf::BrdfParams& p = maps.texels[t];
      if (!SendsLight(p)) continue;
      const Vec3f& n = atlas.shading_normal[t];
      const Vec3f& ng = atlas.geometric_normal[t];
      Vec3f wi = light_dir;
      float dist = kInfinity;
      Vec3f irradiance_per_cos = intensity;
      if (point_light) {
        const Vec3f to_light = light_in_object - atlas.position[t];
        dist = to_light.norm();
        if (!(dist > 0)) continue;  // the light exactly at the texel: no direction to it
        wi = to_light / dist;
        irradiance_per_cos /= dist * dist;
      }
      const float cos_i = n.dot(wi);
      if (cos_i <= 0 || ng.dot(wi) <= 0) continue;
      if (cast_shadows && scene.Occluded(atlas.position[t] + offset * ng, wi, 0,
                                         point_light ? dist - offset : kInfinity)) {
        continue;
      }
      const Vec3f rho(p.rho_d[0], p.rho_d[1], p.rho_d[2]);
      send[t] = rho.cwiseProduct(irradiance_per_cos) * (cos_i / float(kPi));
    }
  });
  std::vector<Vec3f> total(texels_, Vec3f::Zero()), next(texels_);
  for (int b = 0; b < bounces; ++b) {
    ParallelFor(0, int64_t(texels_), 1024, [&](int64_t begin, int64_t end, int) {
      for (int64_t ti = begin; ti < end; ++ti) {
        const size_t t = size_t(ti);
        const brdf::BrdfParams& p = maps.texels[t];
        next[t] = Vec3f::Zero();
        if (!SendsLight(p)) continue;
        Vec3f gathered = Vec3f::Zero();
        const int32_t* hits = &hit_[t * size_t(rays_)];
        for (int r = 0; r < rays_; ++r) {
          if (hits[r] >= 0) gathered += send[size_t(hits[r])];
        }
        const Vec3f rho(p.rho_d[0], p.rho_d[1], p.rho_d[2]);
        next[t] = rho.cwiseProduct(gathered) / float(rays_);
      }
    });
    for (size_t t = 0; t < texels_; ++t) total[t] += next[t];
    send.swap(next);
  }
  return total;
}

void AddTexelRadiance(const RayScene& scene, const TexelAtlas& atlas, const Camera& camera,
                      const Rigid3& world_from_object, double exposure_s, int supersampling,
                      double footprint,
                      const std::vector<Vec3f>& radiance, Image* pixels) {
  REFLCAP_CHECK(pixels->width == camera.width && pixels->height == camera.height &&
                pixels->channels == 3);
  REFLCAP_CHECK(radiance.size() == atlas.TexelCount());
  const Rigid3 object_from_cam = (camera.cam_from_world * world_from_object).Inverse();
  const int n = std::max(1, supersampling);
  const float weight = float(exposure_s) / float(n * n);
  auto trace = [&](double px, double py) -> Vec3f {
    Vec3d o, d;
    camera.PixelRay({px, py}, &o, &d);
    const Vec3f origin = (object_from_cam * o).cast<float>();
    const Vec3f dir = (object_from_cam.rotation * d).normalized().cast<float>();
    const int32_t t = TexelOfRayHit(scene, atlas, scene.Intersect(origin, dir, 0, kInfinity), dir);
    return t < 0 ? Vec3f::Zero() : radiance[size_t(t)];
  };
  ParallelFor(0, camera.height, 4, [&](int64_t y0, int64_t y1, int) {
    for (int64_t y = y0; y < y1; ++y) {
      for (int x = 0; x < camera.width; ++x) {
        Vec3f sum = Vec3f::Zero();
        if (n == 1) {
          sum = trace(x, double(y));
        } else {
          for (int sy = 0; sy < n; ++sy) {
            for (int sx = 0; sx < n; ++sx) {
              sum += trace(x + SampleOffset(sx, n, footprint),
                           double(y) + SampleOffset(sy, n, footprint));
            }
          }
        }
        float* px = pixels->pixel(x, int(y));
        for (int c = 0; c < 3; ++c) px[c] += sum[c] * weight;
      }
    }
  });
}

}  // namespace reflcap::render
