#pragma once
// The hard cases of the fitting issue as sample builders, shared by fit_hard_cases_test.cc
// (each case's documented status on the CPU paths) and fit_vulkan_test.cc (the same cases on
// every backend): grazing directions, exponents at their bounds, highlights narrower than the
// sample spacing, no sample near the highlight, dark, clipped, NaN/Inf, negative, ten decades
// of values, duplicated samples, too few samples, collinear directions.
#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "engine/fit/fitter.h"
#include "engine/fit/synthetic_samples.h"

namespace reflcap::fit::testing {

inline TexelSampleChunk OneTexel(const std::vector<BrdfSample>& samples) {
  TexelSampleChunk chunk;
  chunk.texel_count = 1;
  chunk.offsets = {0, samples.size()};
  chunk.samples.assign(samples.begin(), samples.end());
  return chunk;
}

inline std::vector<BrdfSample> SamplesOf(const TexelSampleChunk& chunk, uint32_t t = 0) {
  return std::vector<BrdfSample>(chunk.SamplesOf(t), chunk.SamplesOf(t) + chunk.SampleCount(t));
}

// One synthetic texel of ground truth `truth` (seeded by `seed`).
inline std::vector<BrdfSample> Texel(const brdf::BrdfParams& truth, uint64_t seed,
                                     SyntheticSampleOptions so = {}) {
  so.seed = seed;
  return SamplesOf(MakeSyntheticChunk({truth}, so));
}

inline brdf::BrdfParams Glossy() { return SynthMaterialParams(1); }

// Drops the samples whose wo lies within `deg` degrees of the mirror direction of wi.
inline std::vector<BrdfSample> AwayFromMirror(const std::vector<BrdfSample>& in, double deg) {
  std::vector<BrdfSample> out;
  for (const BrdfSample& s : in) {
    const double mirror_cos = -s.wi[0] * s.wo[0] - s.wi[1] * s.wo[1] + s.wi[2] * s.wo[2];
    if (mirror_cos < std::cos(DegToRad(deg))) out.push_back(s);
  }
  return out;
}

// Every sample has cos(theta_o) = 0.03 < min_cos_theta = 0.05: nothing valid remains.
inline std::vector<BrdfSample> GrazingSamples() {
  std::vector<BrdfSample> samples = Texel(Glossy(), 1);
  for (BrdfSample& s : samples) {
    const double h = std::sqrt(1 - 0.03 * 0.03) / std::hypot(s.wo[0], s.wo[1]);
    s.wo[0] = float(s.wo[0] * h);
    s.wo[1] = float(s.wo[1] * h);
    s.wo[2] = 0.03f;
  }
  return samples;
}

// Directions down to 86.6 degrees from the normal, all valid.
inline std::vector<BrdfSample> NearGrazingSamples() {
  SyntheticSampleOptions so;
  so.min_cos = 0.06;
  so.max_tilt_deg = 80;
  return Texel(Glossy(), 2, so);
}

// n = 1 lobes.
inline std::vector<BrdfSample> LowerBoundExponentSamples() {
  brdf::BrdfParams truth = Glossy();
  for (auto& l : truth.lobes[0]) l = brdf::MirrorLobe(0.3, 1.0);
  return Texel(truth, 3);
}

// n = 1e4 (a needle 0.6 degrees wide) with no sample within 2 degrees of it; with `on_needle`,
// plus one sample exactly on it.
inline brdf::BrdfParams NeedleTruth() {
  brdf::BrdfParams truth = Glossy();
  for (auto& l : truth.lobes[0]) l = brdf::MirrorLobe(50.0, brdf::kMaxExponent);
  return truth;
}
inline std::vector<BrdfSample> UpperBoundExponentSamples(bool on_needle) {
  const brdf::BrdfParams truth = NeedleTruth();
  std::vector<BrdfSample> seen = AwayFromMirror(Texel(truth, 4), 2.0);
  if (!on_needle) return seen;
  BrdfSample on = seen[0];
  const float wi[3] = {0.3f, 0.2f, std::sqrt(1 - 0.13f)}, wo[3] = {-0.3f, -0.2f, wi[2]};
  std::copy(wi, wi + 3, on.wi);
  std::copy(wo, wo + 3, on.wo);
  const Vec3f f = brdf::EvalRgb(truth, Vec3f(wi[0], wi[1], wi[2]), Vec3f(wo[0], wo[1], wo[2]));
  for (int c = 0; c < 3; ++c) on.value[c] = f[c];
  seen.push_back(on);
  return seen;
}

// n = 2000 (half-width ~1.3 degrees) seen by near-mirror samples 2..8 degrees away.
inline std::vector<BrdfSample> NarrowHighlightSamples() {
  brdf::BrdfParams truth = Glossy();
  for (auto& l : truth.lobes[0]) l = brdf::MirrorLobe(100.0, 2000.0);
  return Texel(truth, 5);
}

// No sample within 15 degrees of the mirror configuration.
inline std::vector<BrdfSample> NoHighlightSamples() {
  SyntheticSampleOptions so;
  so.near_mirror_samples = 0;
  std::vector<BrdfSample> samples;
  for (const BrdfSample& s : Texel(Glossy(), 6, so)) {
    const double mirror_cos = -s.wi[0] * s.wo[0] - s.wi[1] * s.wo[1] + s.wi[2] * s.wo[2];
    if (mirror_cos < std::cos(DegToRad(15))) samples.push_back(s);
  }
  return samples;
}

inline std::vector<BrdfSample> AllDarkSamples() {
  std::vector<BrdfSample> samples = Texel(Glossy(), 7);
  for (BrdfSample& s : samples) {
    for (float& v : s.value) v = 0;
  }
  return samples;
}

// The sharp material (peak 20) clipped at 2 by the sensor.
inline std::vector<BrdfSample> ClippedSamples() {
  std::vector<BrdfSample> samples = Texel(SynthMaterialParams(2), 8);
  for (BrdfSample& s : samples) {
    for (float& v : s.value) v = std::min(v, 2.0f);
  }
  return samples;
}

// A few NaN and Inf values, weights and directions; with `all`, every value NaN.
inline std::vector<BrdfSample> NonFiniteSamples(bool all) {
  constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
  constexpr float kInf = std::numeric_limits<float>::infinity();
  std::vector<BrdfSample> samples = Texel(Glossy(), 9);
  samples[3].value[0] = kNaN;
  samples[10].value[1] = kInf;
  samples[17].weight[2] = -kInf;
  samples[21].wi[0] = kNaN;
  if (all) {
    for (BrdfSample& s : samples) s.value[0] = s.value[1] = s.value[2] = kNaN;
  }
  return samples;
}

// Every value slightly negative (noise around a dark texel).
inline std::vector<BrdfSample> NegativeSamples() {
  std::vector<BrdfSample> samples = Texel(Glossy(), 10);
  for (BrdfSample& s : samples) {
    for (float& v : s.value) v = -0.01f - 0.001f * float((&s - samples.data()) % 7);
  }
  return samples;
}

// The glossy texel with values and weights scaled to an overall `gain` (1 = as generated).
inline std::vector<BrdfSample> ScaledSamples(double gain) {
  std::vector<BrdfSample> scaled = Texel(Glossy(), 11);
  if (gain == 1) return scaled;
  for (BrdfSample& s : scaled) {
    for (int c = 0; c < 3; ++c) {
      s.value[c] = float(s.value[c] * gain);
      s.weight[c] = float(s.weight[c] / (gain * gain));
    }
  }
  return scaled;
}

// Diffuse level 1e-6 under a lobe peaking at 1e4.
inline brdf::BrdfParams TenDecadesTruth() {
  brdf::BrdfParams extreme = Glossy();
  for (int c = 0; c < 3; ++c) {
    extreme.rho_d[c] = float(kPi * 1e-6);
    extreme.lobes[0][c] = brdf::MirrorLobe(1e4, 25);
  }
  return extreme;
}
inline std::vector<BrdfSample> TenDecadesSamples() { return Texel(TenDecadesTruth(), 12); }

// The glossy texel, each sample `copies` times.
inline std::vector<BrdfSample> DuplicatedSamples(int copies) {
  const std::vector<BrdfSample> base = Texel(Glossy(), 13);
  std::vector<BrdfSample> out;
  for (const BrdfSample& s : base) out.insert(out.end(), copies, s);
  return out;
}

inline std::vector<BrdfSample> FewSamples(size_t count) {
  std::vector<BrdfSample> samples = Texel(Glossy(), 14);
  samples.resize(count);
  return samples;
}

// Every wi and wo in the x-z plane: wiy woy = 0, so Cy has no influence on any sample.
inline std::vector<BrdfSample> CollinearSamples() {
  std::vector<BrdfSample> samples;
  std::mt19937 rng(15);
  std::uniform_real_distribution<double> angle(-1.3, 1.3);
  const brdf::BrdfParams truth = Glossy();
  for (int i = 0; i < 100; ++i) {
    const double a = i < 15 ? 0.2 + 0.8 * i / 15.0 : angle(rng);
    const double b = i < 15 ? -a + 0.05 * std::sin(double(i)) : angle(rng);
    BrdfSample s{};
    const float wi[3] = {float(std::sin(a)), 0, float(std::cos(a))};
    const float wo[3] = {float(std::sin(b)), 0, float(std::cos(b))};
    std::copy(wi, wi + 3, s.wi);
    std::copy(wo, wo + 3, s.wo);
    const Vec3f f = brdf::EvalRgb(truth, Vec3f(wi[0], wi[1], wi[2]), Vec3f(wo[0], wo[1], wo[2]));
    for (int c = 0; c < 3; ++c) {
      s.value[c] = f[c];
      s.weight[c] = 1;
    }
    samples.push_back(s);
  }
  return samples;
}

struct HardCase {
  std::string name;
  std::vector<BrdfSample> samples;
  FitOptions options;
};

// Every case above with the options its test uses (default options unless noted).
inline std::vector<HardCase> HardCaseSuite() {
  FitOptions iso;
  iso.lobe_model = LobeModel::kIso;
  return {
      {"grazing", GrazingSamples(), {}},
      {"near_grazing", NearGrazingSamples(), {}},
      {"exponent_lower_bound", LowerBoundExponentSamples(), {}},
      {"exponent_upper_bound_unseen", UpperBoundExponentSamples(false), {}},
      {"exponent_upper_bound_one_sample", UpperBoundExponentSamples(true), {}},
      {"narrow_highlight", NarrowHighlightSamples(), {}},
      {"no_highlight", NoHighlightSamples(), {}},
      {"all_dark", AllDarkSamples(), {}},
      {"clipped", ClippedSamples(), {}},
      {"nan_inf", NonFiniteSamples(false), {}},
      {"all_nan", NonFiniteSamples(true), {}},
      {"negative", NegativeSamples(), {}},
      {"scale_1e-6", ScaledSamples(1e-6), {}},
      {"scale_1", ScaledSamples(1), {}},
      {"scale_1e4", ScaledSamples(1e4), {}},
      {"ten_decades", TenDecadesSamples(), {}},
      {"duplicated_x1", DuplicatedSamples(1), {}},
      {"duplicated_x3", DuplicatedSamples(3), {}},
      {"four_samples", FewSamples(4), {}},
      {"no_samples", FewSamples(0), {}},
      {"collinear_aniso", CollinearSamples(), {}},
      {"collinear_iso", CollinearSamples(), iso},
  };
}

}  // namespace reflcap::fit::testing
