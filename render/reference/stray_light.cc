// Stray light of normal-map captures (see stray_light.h).
#include "render/reference/stray_light.h"

#include <algorithm>
#include <chrono>
#include <cmath>

#include <Eigen/Dense>

#include "engine/core/log.h"
#include "render/reference/evidence_photos.h"

namespace reflcap::render {
namespace {

// A texel's albedo below this says nothing of the irradiance it receives (s / ρ is its noise):
// it is left out of the environment fit (it still receives s = ρ · model, near 0).
constexpr double kMinModelAlbedo = 0.01;
// Ridge on the environment model's normal terms, relative to the texel count: keeps the fit
// solvable when the observed normals span fewer than three directions (one flat face), and is
// negligible against any spread of normals (with none, the normal terms stay 0: the constant).
constexpr double kEnvironmentRidge = 1e-6;

// Per-texel sums of one fold of photographs.
struct Sums {
  uint32_t n = 0;                 // observations
  std::array<double, 3> pw{};     // Σ p w per channel
  std::array<double, 3> ww{};     // Σ w² per channel
};

struct Solution {
  std::vector<Vec3f> s;
  size_t observed = 0, modelled = 0;
  std::array<std::array<double, 4>, 3> environment{};
};

// Steps 2–3 of stray_light.h over the folds in `folds` (bit f = fold f).
Solution Solve(const FittedCapture& fitted, const std::vector<std::array<Sums, 2>>& sums,
               unsigned folds) {
  const TexelAtlas& atlas = fitted.atlas;
  const size_t texels = atlas.TexelCount();
  Solution out;
  out.s.assign(texels, Vec3f::Zero());
  std::vector<uint8_t> own(texels, 0);
  std::array<Eigen::Matrix4d, 3> ata;
  std::array<Eigen::Vector4d, 3> atb;
  std::array<size_t, 3> rows{};
  for (int c = 0; c < 3; ++c) {
    ata[c].setZero();
    atb[c].setZero();
  }
  for (size_t t = 0; t < texels; ++t) {
    uint32_t n = 0;
    std::array<double, 3> pw{}, ww{};
    for (int f = 0; f < 2; ++f) {
      if (!(folds & (1u << f))) continue;
      n += sums[t][f].n;
      for (int c = 0; c < 3; ++c) {
        pw[c] += sums[t][f].pw[c];
        ww[c] += sums[t][f].ww[c];
      }
    }
    if (n < uint32_t(kMinStrayObservations)) continue;
    own[t] = 1;
    ++out.observed;
    const Vec3f& normal = atlas.shading_normal[t];
    const Eigen::Vector4d x(1.0, normal.x(), normal.y(), normal.z());
    for (int c = 0; c < 3; ++c) {
      // ww > 0: every observation has w = exposure · I_c > 0 (capture validation).
      const double s = ww[c] > 0 ? std::max(0.0, pw[c] / ww[c]) : 0.0;
      out.s[t][c] = float(s);
      const double rho = fitted.maps.texels[t].rho_d[size_t(c)];
      if (!(rho >= kMinModelAlbedo)) continue;
      ata[c] += x * x.transpose();
      atb[c] += x * (s / rho);
      ++rows[c];
    }
  }
  for (int c = 0; c < 3; ++c) {
    if (rows[c] < kMinStrayModelTexels) continue;
    Eigen::Matrix4d a = ata[c];
    for (int k = 1; k < 4; ++k) a(k, k) += kEnvironmentRidge * double(rows[c]);
    const Eigen::Vector4d e = a.ldlt().solve(atb[c]);
    if (!e.allFinite()) continue;
    for (int k = 0; k < 4; ++k) out.environment[size_t(c)][size_t(k)] = e[k];
  }
  for (size_t t = 0; t < texels; ++t) {
    if (own[t]) continue;
    ++out.modelled;
    const Vec3f& normal = atlas.shading_normal[t];
    for (int c = 0; c < 3; ++c) {
      const auto& e = out.environment[size_t(c)];
      // Clamped at 0: a first-order fit can dip below 0 for normals it saw none of; light can't.
      const double irradiance =
          std::max(0.0, e[0] + e[1] * normal.x() + e[2] * normal.y() + e[3] * normal.z());
      const double rho = fitted.maps.texels[t].rho_d[size_t(c)];
      const double s = irradiance * rho;
      out.s[t][c] = std::isfinite(s) && s > 0 ? float(s) : 0.0f;
    }
  }
  return out;
}

Vec3d LampWeight(const Capture& capture, const CaptureImage& image) {
  return image.exposure_s * capture.lights[image.light].intensity;
}

}  // namespace

StrayLight EstimateStrayLight(const FittedCapture& fitted, bool cast_shadows) {
  const auto start = std::chrono::steady_clock::now();
  REFLCAP_CHECK(fitted.normal_map);
  const Capture& capture = *fitted.capture;
  const TexelAtlas& atlas = fitted.atlas;
  const size_t texels = atlas.TexelCount();
  std::vector<std::array<Sums, 2>> sums(texels);
  std::array<double, 2> pp{};  // Σ p² per fold, over all observations
  StrayLight out;
  RenderOptions direct;
  direct.cast_shadows = cast_shadows;
  direct.aux_buffers = true;
  int read = 0;
  EvidencePhotographs photos(capture, EvidenceImages(capture, int(capture.images.size())));
  for (size_t k = 0; k < photos.size(); ++k) {
    const size_t index = photos.index(k);
    const CaptureImage& image = capture.images[index];
    const Camera& camera = capture.cameras[image.camera];
    StatusOr<RenderResult> rendered = RenderCaptureImage(fitted, index, direct);
    StatusOr<Image> photo = photos.Take(k, rendered.status(), "stray-light estimate");
    if (!photo.ok()) {
      ++out.skipped;
      continue;
    }
    const Image& aux = rendered->aux;
    const int fold = read++ % 2;
    const Vec3d w = LampWeight(capture, image);
    auto unlit = [&](int x, int y) {
      if (x < 0 || y < 0 || x >= camera.width || y >= camera.height) return false;
      const float* a = aux.pixel(x, y);
      return a[kAuxMask] > 0.5f && (a[kAuxCosThetaI] <= 0 || a[kAuxCastShadow] > 0.5f);
    };
    for (size_t t = 0; t < texels; ++t) {
      int x, y;
      atlas.PixelOf(t, &x, &y);
      bool ok = true;
      for (int dy = -1; dy <= 1 && ok; ++dy) {
        for (int dx = -1; dx <= 1 && ok; ++dx) ok = unlit(x + dx, y + dy);
      }
      if (!ok) continue;
      const float* p = photo->pixel(x, y);
      if (!UsablePixel(p, image)) continue;
      Sums& s = sums[t][size_t(fold)];
      ++s.n;
      ++out.observations;
      for (int c = 0; c < 3; ++c) {
        s.pw[size_t(c)] += double(p[c]) * w[c];
        s.ww[size_t(c)] += w[c] * w[c];
        pp[size_t(fold)] += double(p[c]) * p[c];
      }
    }
  }
  out.images = read;
  // Evidence: each fold's estimate against the other fold's observations.
  double error = 0;
  for (int f = 0; f < 2; ++f) {
    const int g = 1 - f;
    const Solution held = Solve(fitted, sums, 1u << f);
    error += pp[size_t(g)];
    for (size_t t = 0; t < texels; ++t) {
      const Sums& s = sums[t][size_t(g)];
      if (s.n == 0) continue;
      for (int c = 0; c < 3; ++c) {
        const double q = held.s[t][c];
        // Σ (p − w q)² = Σ p² − 2 q Σ p w + q² Σ w².
        error += q * (q * s.ww[size_t(c)] - 2 * s.pw[size_t(c)]);
      }
    }
  }
  const double total = pp[0] + pp[1];
  out.error_reduction = total > 0 ? 1 - error / total : 0.0;
  out.shows = out.observations >= kMinStrayEvidenceObservations &&
              out.error_reduction >= kMinStrayErrorReduction;
  Solution all = Solve(fitted, sums, 3u);
  out.per_intensity = std::move(all.s);
  out.observed_texels = all.observed;
  out.modelled_texels = all.modelled;
  out.environment = all.environment;
  out.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return out;
}

void AddStrayLight(const FittedCapture& fitted, const StrayLight& stray, size_t index,
                   Image* pixels) {
  const Capture& capture = *fitted.capture;
  const CaptureImage& image = capture.images[index];
  const Vec3d w = LampWeight(capture, image);
  const TexelAtlas& atlas = fitted.atlas;
  REFLCAP_CHECK(stray.per_intensity.size() == atlas.TexelCount());
  for (size_t t = 0; t < atlas.TexelCount(); ++t) {
    int x, y;
    atlas.PixelOf(t, &x, &y);
    if (x < 0 || y < 0 || x >= pixels->width || y >= pixels->height) continue;
    float* p = pixels->pixel(x, y);
    for (int c = 0; c < 3; ++c) p[c] += float(w[c] * stray.per_intensity[t][c]);
  }
}

}  // namespace reflcap::render
