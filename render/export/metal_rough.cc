// glTF metallic-roughness approximation of Lambert + Lafortune texels (metal_rough.h).
#include "render/export/metal_rough.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace reflcap::render {
namespace {

// Directions more than 60° from the normal are left out of the pair set: there glTF's microfacet
// peak grows as 1 / (cos θi cos θo) (the Smith visibility term) while a Lafortune lobe's stays
// bounded, so no (m, r) follows both, and a least-squares fit pulled by grazing pairs would trade
// the highlight everywhere else for them (measured on the demo: pairs up to 70° give a median
// error of 0.59, pairs up to 60° 0.35).
constexpr float kMinPairCos = 0.5f;
// Denominators below this are treated as zero (a cell whose A vanishes on every pair cannot
// determine c; it keeps c = 0). Far below any Σ w A² of a real cell (~1e-2).
constexpr double kMinNormal = 1e-20;

constexpr float kDegToRad = float(kPi / 180.0);

Vec3f FromSpherical(float theta_deg, float phi_deg) {
  const float t = theta_deg * kDegToRad, p = phi_deg * kDegToRad;
  return Vec3f(std::sin(t) * std::cos(p), std::sin(t) * std::sin(p), std::cos(t));
}

}  // namespace

std::vector<DirectionPair> MetalRoughDirections() {
  std::vector<DirectionPair> pairs;
  const float incident_theta[] = {0, 20, 40, 60};
  const float incident_phi[] = {0, 90};
  const float mirror_offsets_deg[] = {0.5f, 1, 2, 4, 8, 15, 25, 40};
  const float grid_theta[] = {10, 25, 40, 55};
  const float grid_phi[] = {0, 60, 120, 180, 240, 300};
  for (float ti : incident_theta) {
    for (float pi : incident_phi) {
      if (ti == 0 && pi != 0) continue;  // normal incidence has no azimuth
      const Vec3f wi = FromSpherical(ti, pi);
      const Vec3f mirror(-wi.x(), -wi.y(), wi.z());
      Vec3f u1 = mirror.unitOrthogonal();
      const Vec3f u2 = mirror.cross(u1);
      auto add = [&](const Vec3f& wo) {
        if (wo.z() < kMinPairCos) return;
        pairs.push_back({wi, wo.normalized(), wi.z()});
      };
      add(mirror);
      for (float d : mirror_offsets_deg) {
        const float dr = d * kDegToRad;
        for (int k = 0; k < 4; ++k) {
          const float psi = float(k) * float(kPi / 2);
          add(std::cos(dr) * mirror +
              std::sin(dr) * (std::cos(psi) * u1 + std::sin(psi) * u2));
        }
      }
      for (float to : grid_theta) {
        for (float po : grid_phi) add(FromSpherical(to, po));
      }
    }
  }
  return pairs;
}

namespace {

// A and B of f_gltf = c A + B (metal_rough.h) for one pair.
void GltfTerms(float metallic, float roughness, const Vec3f& wi, const Vec3f& wo, float* a,
               float* b) {
  const float alpha = roughness * roughness;
  const float a2 = alpha * alpha;
  const float nl = wi.z(), nv = wo.z();
  // wi + wo has length ≥ 2 cos(90°) = 0 only for opposite directions, which two directions above
  // the surface (z ≥ kMinPairCos or rendered with cos θ > 0) never are.
  const Vec3f h = (wi + wo).normalized();
  const float nh = std::max(h.z(), 0.0f);
  const float vh = std::min(std::abs(wo.dot(h)), 1.0f);
  const float d_denom = nh * nh * (a2 - 1) + 1;
  const float d = a2 / (float(kPi) * d_denom * d_denom);
  const float v = 1.0f / ((nl + std::sqrt(a2 + (1 - a2) * nl * nl)) *
                          (nv + std::sqrt(a2 + (1 - a2) * nv * nv)));
  const float s_spec = d * v;
  const float s = std::pow(1 - vh, 5.0f);
  const float f_d = 0.04f + 0.96f * s;
  *a = (1 - metallic) * (1 - f_d) * float(kInvPi) + metallic * (1 - s) * s_spec;
  *b = (1 - metallic) * f_d * s_spec + metallic * s * s_spec;
}

}  // namespace

float GltfBrdf(float base_color, float metallic, float roughness, const Vec3f& wi,
               const Vec3f& wo) {
  float a, b;
  GltfTerms(metallic, roughness, wi, wo, &a, &b);
  return base_color * a + b;
}

MetalRoughFitter::MetalRoughFitter() : pairs_(MetalRoughDirections()) {
  for (int i = 0; i < kMetallicSteps; ++i) metallic_[i] = float(i) / float(kMetallicSteps - 1);
  for (int i = 0; i < kRoughnessSteps; ++i) {
    roughness_[i] = kMinRoughness * std::pow(1.0f / kMinRoughness, float(i) / float(kRoughnessSteps - 1));
  }
  const size_t cells = size_t(kMetallicSteps) * kRoughnessSteps, n = pairs_.size();
  a_.resize(cells * n);
  b_.resize(cells * n);
  saa_.assign(cells, 0);
  sab_.assign(cells, 0);
  sbb_.assign(cells, 0);
  for (int mi = 0; mi < kMetallicSteps; ++mi) {
    for (int ri = 0; ri < kRoughnessSteps; ++ri) {
      const size_t cell = size_t(mi) * kRoughnessSteps + ri;
      for (size_t j = 0; j < n; ++j) {
        float a, b;
        GltfTerms(metallic_[mi], roughness_[ri], pairs_[j].wi, pairs_[j].wo, &a, &b);
        a_[cell * n + j] = a;
        b_[cell * n + j] = b;
        const double w = pairs_[j].weight;
        saa_[cell] += w * a * a;
        sab_[cell] += w * a * b;
        sbb_[cell] += w * b * b;
      }
    }
  }
}

MetalRough MetalRoughFitter::Fit(const brdf::BrdfParams& params) const {
  const size_t n = pairs_.size();
  // Target values per pair and channel, and the luminance (channel mean) the grid search uses.
  std::vector<float> f(3 * n), lum(n);
  double sff_lum = 0;
  for (size_t j = 0; j < n; ++j) {
    Vec3f v = brdf::EvalRgb(params, pairs_[j].wi, pairs_[j].wo);
    // A non-finite parameter (never written by the fitter, but a FIT is a file) shades black.
    if (!v.allFinite()) v.setZero();
    for (int c = 0; c < 3; ++c) f[3 * j + c] = v[c];
    lum[j] = v.mean();
    sff_lum += pairs_[j].weight * double(lum[j]) * lum[j];
  }
  Vec3f rho = Vec3f::Zero();
  for (int c = 0; c < 3; ++c) {
    rho[c] = std::isfinite(params.rho_d[c]) ? std::clamp(params.rho_d[c], 0.0f, 1.0f) : 0.0f;
  }
  // Closed-form c of one cell for a target column, clamped to [0, 1].
  auto solve_c = [&](size_t cell, double saf) {
    if (saa_[cell] < kMinNormal) return 0.0;
    return std::clamp((saf - sab_[cell]) / saa_[cell], 0.0, 1.0);
  };
  size_t best_cell = 0;
  double best_error = std::numeric_limits<double>::infinity();
  for (int mi = 0; mi < kMetallicSteps; ++mi) {
    for (int ri = 0; ri < kRoughnessSteps; ++ri) {
      const size_t cell = size_t(mi) * kRoughnessSteps + ri;
      const float* a = &a_[cell * n];
      const float* b = &b_[cell * n];
      double saf = 0, sbf = 0;
      for (size_t j = 0; j < n; ++j) {
        const double wf = pairs_[j].weight * lum[j];
        saf += wf * a[j];
        sbf += wf * b[j];
      }
      const double c = mi == 0 ? double(rho.mean()) : solve_c(cell, saf);
      const double error = sff_lum - 2 * c * saf - 2 * sbf + c * c * saa_[cell] +
                           2 * c * sab_[cell] + sbb_[cell];
      if (error < best_error) {
        best_error = error;
        best_cell = cell;
      }
    }
  }
  const int mi = int(best_cell / kRoughnessSteps), ri = int(best_cell % kRoughnessSteps);
  MetalRough out;
  out.metallic = metallic_[mi];
  out.roughness = roughness_[ri];
  const float* a = &a_[best_cell * n];
  const float* b = &b_[best_cell * n];
  for (int c = 0; c < 3; ++c) {
    if (mi == 0) {
      out.base_color[c] = rho[c];
      continue;
    }
    double saf = 0, sbf = 0;
    for (size_t j = 0; j < n; ++j) {
      const double wf = pairs_[j].weight * f[3 * j + c];
      saf += wf * a[j];
      sbf += wf * b[j];
    }
    out.base_color[c] = float(solve_c(best_cell, saf));
  }
  double num = 0, den = 0;
  for (size_t j = 0; j < n; ++j) {
    for (int c = 0; c < 3; ++c) {
      const double diff = double(out.base_color[c]) * a[j] + b[j] - f[3 * j + c];
      num += pairs_[j].weight * diff * diff;
      den += pairs_[j].weight * double(f[3 * j + c]) * f[3 * j + c];
    }
  }
  // A black texel (den = 0) is matched exactly by nothing but is also invisible: error 0.
  out.error = den > 0 && std::isfinite(num) ? float(std::sqrt(num / den)) : 0.0f;
  return out;
}

}  // namespace reflcap::render
