#pragma once
// A glTF 2.0 metallic-roughness approximation of a texel's Lambert + Lafortune BRDF, fitted per
// texel by least squares over a fixed set of direction pairs.
//
// The target is the glTF model of the specification's Appendix B (the one the Khronos sample
// viewer implements), per colour channel with base colour c, metallic m and roughness r:
//   S      = D(h) V(l, v)                           GGX with α = r², height-correlated Smith V
//   s      = (1 - |v·h|)^5                          Schlick's weight
//   F_d    = 0.04 + 0.96 s                          dielectric Fresnel (ior 1.5)
//   f_gltf = (1-m) [(1 - F_d) c/π + F_d S] + m [(c + (1-c) s) S]
// which is linear in c for fixed (m, r): f_gltf = c A(m, r) + B(m, r). The fit picks (m, r) on a
// grid (kMetallicSteps x kRoughnessSteps, roughness spaced geometrically) by the error of the
// texel's luminance (the mean of R, G, B), with c in closed form per grid cell; then c per channel
// in closed form at the chosen cell, clamped to [0, 1]. Dielectric cells (m = 0) take c = ρ_d
// (clamped to [0, 1]), so a texel the fit calls dielectric has the base colour of its ρ_d exactly.
//
// Direction pairs (MetalRoughDirections): incident directions at θi ∈ {0, 20, 40, 60}° and
// azimuths {0, 90}° (both tangent axes, for anisotropic lobes); per incident direction, outgoing
// directions at the mirror direction and 0.5–40° from it in four directions (dense where a lobe
// is), plus a coarse grid at θo ∈ {10, 25, 40, 55}° (where the diffuse term is); only pairs with
// both directions within 60° of the normal (see kMinPairCos in metal_rough.cc: beyond it glTF's
// microfacet peak grows as 1/cos while a Lafortune lobe's does not). Each pair weighs cos θi (the
// reflected radiance f cos θi per unit irradiance at normal incidence).
//
// Error (relative RMS, per texel, over the pairs and the three channels):
//   e = sqrt(Σ w (f_gltf - f)² / Σ w f²)     (0 for a black texel)
// with f the texel's Lafortune BRDF (brdf::EvalRgb, the C++ twin the renderers use).
#include <array>
#include <vector>

#include "engine/brdf/lafortune.h"
#include "engine/math/types.h"

namespace reflcap::render {

// Metallic grid {0, 1/(steps-1), ..., 1}; roughness grid geometric in [kMinRoughness, 1].
constexpr int kMetallicSteps = 5;
constexpr int kRoughnessSteps = 32;
// Roughness 0.02 (α = 4e-4) is sharper than any lobe a capture resolves (n = 1e4, reflcap's
// kMaxExponent, is ~0.6° wide, α ≈ 0.01); below it GGX's peak overflows nothing but means nothing.
constexpr float kMinRoughness = 0.02f;

struct MetalRough {
  Vec3f base_color = Vec3f::Zero();  // linear, [0, 1]
  float metallic = 0;                // [0, 1]
  float roughness = 1;               // [kMinRoughness, 1]
  float error = 0;                   // relative RMS error e (above), finite, >= 0
};

// One direction pair in the tangent frame (z = normal), both unit and above the surface.
struct DirectionPair {
  Vec3f wi, wo;
  float weight = 0;
};
// The fixed pair set described above.
std::vector<DirectionPair> MetalRoughDirections();

// glTF's f (the formula above) for one channel; wi, wo unit in the tangent frame, above it.
float GltfBrdf(float base_color, float metallic, float roughness, const Vec3f& wi,
               const Vec3f& wo);

// Fits texels. Build once (tabulates A and B on every grid cell and pair), then call Fit from
// any number of threads.
class MetalRoughFitter {
 public:
  MetalRoughFitter();
  MetalRough Fit(const brdf::BrdfParams& params) const;
  size_t PairCount() const { return pairs_.size(); }

 private:
  std::vector<DirectionPair> pairs_;
  std::array<float, kMetallicSteps> metallic_{};
  std::array<float, kRoughnessSteps> roughness_{};
  // Per cell (m major, r minor), per pair: A and B of f_gltf = c A + B, and Σ w A², Σ w A B, Σ w B².
  std::vector<float> a_, b_;
  std::vector<double> saa_, sab_, sbb_;
};

}  // namespace reflcap::render
