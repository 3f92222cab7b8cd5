#pragma once
// Fixtures of the lobe transfer and material cluster tests: a glossy material, fits as the fitter
// leaves donors and recipients, samples rendered from a known BRDF, and a chunk holding them.
#include <array>
#include <cmath>
#include <vector>

#include "engine/brdf/lafortune.h"
#include "engine/fit/fitter.h"
#include "engine/math/types.h"
#include "engine/texel/samples.h"

namespace reflcap::fit::testing {

// The glossy material the tests use: albedo (0.4, 0.3, 0.2) and a mirror lobe of peak `peak` / sr,
// n = 40 (half-width ~11 degrees). Peak 0.5 stays within the transfer's evidence bound (10x the
// recipient's brightest sample per channel: blue, the darkest, shows 0.2 / pi = 0.064 / sr off the
// highlight); peak 5 exceeds it.
inline brdf::BrdfParams Glossy(double peak = 0.5) {
  brdf::BrdfParams p;
  p.num_lobes = 1;
  p.rho_d = {0.4f, 0.3f, 0.2f};
  for (int c = 0; c < brdf::kChannels; ++c) p.lobes[0][c] = brdf::MirrorLobe(peak, 40.0);
  return p;
}

inline TexelFit DonorFit(const brdf::BrdfParams& p) {
  TexelFit f;
  f.params = p;
  f.status = FitStatus::kConverged;
  f.samples = 50;
  return f;
}

// A recipient as the fitter leaves it: Lambert-only (zero lobe), kUnidentifiableLobe.
inline TexelFit RecipientFit(const std::array<float, 3>& rho) {
  TexelFit f;
  f.params.num_lobes = 1;
  f.params.rho_d = rho;
  for (int c = 0; c < brdf::kChannels; ++c) f.params.lobes[0][c] = {0, 0, 0, 20};
  f.status = FitStatus::kUnidentifiableLobe;
  f.lambert_only = true;
  f.samples = 24;
  return f;
}

inline Vec3f Direction(double theta_deg, double phi_deg) {
  const double t = DegToRad(theta_deg), p = DegToRad(phi_deg);
  return Vec3f(float(std::sin(t) * std::cos(p)), float(std::sin(t) * std::sin(p)), float(std::cos(t)));
}

// The exact value of `truth` for (wi, wo), weight 1e4 (sigma 0.01 / sr) in every channel.
inline BrdfSample ExactSample(const brdf::BrdfParams& truth, const Vec3f& wi, const Vec3f& wo) {
  BrdfSample s{};
  const Vec3f f = brdf::EvalRgb(truth, wi, wo);
  for (int j = 0; j < 3; ++j) {
    s.wi[j] = wi[j];
    s.wo[j] = wo[j];
    s.value[j] = f[j];
    s.weight[j] = 1e4f;
  }
  return s;
}

// Samples of `truth` for one texel: 24 configurations, wi at 20..70 degrees from the normal and
// azimuth 0, wo at the same elevation and azimuth 60..90 or 260..290 — at least 90 degrees of
// azimuth from the mirror direction (azimuth 180), where an n = 40 lobe is negligible — except,
// with `near_mirror`, every sixth sample, which lies exactly on the mirror direction.
inline std::vector<BrdfSample> Samples(const brdf::BrdfParams& truth, bool near_mirror) {
  std::vector<BrdfSample> out;
  for (int i = 0; i < 24; ++i) {
    const Vec3f wi = Direction(20 + 10 * (i % 6), 0);
    const double phi = near_mirror && i % 6 == 0 ? 180 : 60 + 10 * (i / 6) + (i % 2 ? 200 : 0);
    out.push_back(ExactSample(truth, wi, Direction(20 + 10 * (i % 6), phi)));
  }
  return out;
}

inline TexelSampleChunk Chunk(const std::vector<std::vector<BrdfSample>>& per_texel) {
  TexelSampleChunk chunk;
  chunk.first_texel = 0;
  chunk.texel_count = uint32_t(per_texel.size());
  chunk.offsets.push_back(0);
  for (const auto& v : per_texel) {
    chunk.samples.insert(chunk.samples.end(), v.begin(), v.end());
    chunk.offsets.push_back(chunk.samples.size());
  }
  return chunk;
}

}  // namespace reflcap::fit::testing
