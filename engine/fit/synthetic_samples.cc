#include "engine/fit/synthetic_samples.h"

#include <algorithm>
#include <cmath>
#include <random>

#include "engine/math/types.h"

namespace reflcap::fit {
namespace {

// The rig (after acquire/synth): light elevations and azimuths, camera elevations, turntable steps.
constexpr double kLightElevationsDeg[] = {20, 50, 75};
constexpr int kLightAzimuths = 12;   // -165 .. 165 degrees in 30 degree steps
constexpr double kCameraElevationsDeg[] = {10, 25, 40, 55, 70};
constexpr int kTurntableSteps = 24;  // 15 degrees apart

double Peak(double ks, double n) { return ks * (n + 2) / (2 * kPi); }

Vec3d Spherical(double elevation, double azimuth) {
  return Vec3d(std::cos(elevation) * std::cos(azimuth), std::cos(elevation) * std::sin(azimuth),
               std::sin(elevation));
}

}  // namespace

const char* SynthMaterialName(int material) {
  static const char* kNames[kSynthMaterialCount] = {"matte", "glossy", "sharp_highlight",
                                                    "anisotropic", "coloured_texture",
                                                    "coloured_lobe"};
  return material >= 0 && material < kSynthMaterialCount ? kNames[material] : "?";
}

brdf::BrdfParams SynthMaterialParams(int material, double stripe) {
  brdf::BrdfParams p;
  p.num_lobes = 1;
  auto set = [&](Vec3d rho, Vec3d ks, double n, double anisotropy = 1) {
    for (int c = 0; c < 3; ++c) {
      p.rho_d[c] = float(rho[c]);
      p.lobes[0][c] = ks[c] > 0 ? brdf::MirrorLobe(Peak(ks[c], n), n, anisotropy)
                                : brdf::LobeParams{0, 0, 0, 1};
    }
  };
  switch (material) {
    case 0: set({0.60, 0.55, 0.50}, {0, 0, 0}, 1); break;
    case 1: set({0.25, 0.35, 0.60}, {0.35, 0.35, 0.35}, 25); break;
    case 2: set({0.50, 0.15, 0.10}, {0.5, 0.5, 0.5}, 250); break;
    case 3: set({0.30, 0.50, 0.30}, {0.3, 0.3, 0.3}, 40, 0.985); break;
    case 4: {
      const Vec3d a(0.70, 0.45, 0.15), b(0.15, 0.30, 0.55);
      set(a + stripe * (b - a), {0.1, 0.1, 0.1}, 10);
      break;
    }
    default: set({0.05, 0.04, 0.02}, {0.9, 0.7, 0.35}, 80); break;
  }
  return p;
}

std::vector<brdf::BrdfParams> SynthMaterialTexels(int count, uint64_t seed) {
  std::mt19937_64 rng(seed * 7919 + 11);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::vector<brdf::BrdfParams> texels;
  for (int i = 0; i < count; ++i) texels.push_back(SynthMaterialParams(i % kSynthMaterialCount, unit(rng)));
  return texels;
}

TexelSampleChunk MakeSyntheticChunk(const std::vector<brdf::BrdfParams>& truth,
                                    const SyntheticSampleOptions& options, uint32_t first_texel) {
  TexelSampleChunk chunk;
  chunk.first_texel = first_texel;
  chunk.texel_count = uint32_t(truth.size());
  chunk.offsets.push_back(0);
  const int near = std::clamp(options.near_mirror_samples, 0, options.samples_per_texel);
  for (size_t t = 0; t < truth.size(); ++t) {
    std::mt19937_64 rng(options.seed * 1000003ull + first_texel + t);
    std::uniform_real_distribution<double> unit(0.0, 1.0);
    std::normal_distribution<double> gauss(0.0, 1.0);
    // The texel's frame on the object: normal tilted from the turntable axis, random tangent.
    const double tilt = DegToRad(options.max_tilt_deg) * unit(rng);
    const double tilt_azimuth = 2 * kPi * unit(rng);
    const Vec3d normal = Spherical(kPi / 2 - tilt, tilt_azimuth);
    Vec3d helper = std::abs(normal.z()) < 0.9 ? Vec3d::UnitZ() : Vec3d::UnitX();
    Vec3d tangent = normal.cross(helper).normalized();
    const double twist = 2 * kPi * unit(rng);
    tangent = Eigen::AngleAxisd(twist, normal) * tangent;
    const Vec3d bitangent = normal.cross(tangent);

    auto add = [&](const Vec3d& wi, const Vec3d& wo) {
      BrdfSample s{};
      for (int j = 0; j < 3; ++j) {
        s.wi[j] = float(wi[j]);
        s.wo[j] = float(wo[j]);
      }
      const double wid[3] = {s.wi[0], s.wi[1], s.wi[2]}, wod[3] = {s.wo[0], s.wo[1], s.wo[2]};
      for (int c = 0; c < 3; ++c) {
        const auto params = truth[t].Channel(c);
        double p[brdf::kMaxParamsPerChannel];
        for (int j = 0; j < brdf::kMaxParamsPerChannel; ++j) p[j] = params[j];
        const double value = brdf::EvalChannel(wid, wod, p, truth[t].num_lobes);
        if (options.noise > 0) {
          s.value[c] = float(value * (1 + options.noise * gauss(rng)));
          const double sigma = options.noise * std::max(value, 1e-6);
          s.weight[c] = float(1.0 / (sigma * sigma));
        } else {
          s.value[c] = float(value);
          s.weight[c] = 1.0f;
        }
      }
      s.image = uint32_t(chunk.samples.size() - chunk.offsets.back());
      chunk.samples.push_back(s);
    };

    int made = 0;
    for (int attempt = 0; made < options.samples_per_texel - near && attempt < 100000; ++attempt) {
      const double light_el = DegToRad(kLightElevationsDeg[rng() % 3]);
      const double light_az = DegToRad(-165.0 + 30.0 * double(rng() % kLightAzimuths));
      const double cam_el = DegToRad(kCameraElevationsDeg[rng() % 5]);
      const double step = 2 * kPi * double(rng() % kTurntableSteps) / kTurntableSteps;
      // Turning the object by `step` about z turns the texel's frame with it.
      const Eigen::AngleAxisd turn(step, Vec3d::UnitZ());
      const Vec3d n = turn * normal, u = turn * tangent, v = turn * bitangent;
      const Vec3d light = Spherical(light_el, light_az), camera = Spherical(cam_el, 0);
      const Vec3d wi(light.dot(u), light.dot(v), light.dot(n));
      const Vec3d wo(camera.dot(u), camera.dot(v), camera.dot(n));
      if (wi.z() < options.min_cos || wo.z() < options.min_cos) continue;
      add(wi, wo);
      ++made;
    }
    for (int attempt = 0; made < options.samples_per_texel && attempt < 100000; ++attempt) {
      const double el = DegToRad(20 + 55 * unit(rng));
      const Vec3d wi = Spherical(el, 2 * kPi * unit(rng));
      const Vec3d mirror(-wi.x(), -wi.y(), wi.z());
      // Uniform in solid angle within the cone around the mirror direction.
      const double cos_max = std::cos(DegToRad(options.near_mirror_max_deg));
      const double cos_a = 1 - unit(rng) * (1 - cos_max);
      const Vec3d axis = mirror.cross(Spherical(0, 2 * kPi * unit(rng)) + Vec3d(0, 0, 0.3)).normalized();
      const Vec3d wo = Eigen::AngleAxisd(std::acos(cos_a), axis) * mirror;
      if (wi.z() < options.min_cos || wo.z() < options.min_cos) continue;
      add(wi, wo);
      ++made;
    }
    chunk.offsets.push_back(chunk.samples.size());
  }
  return chunk;
}

}  // namespace reflcap::fit
