// The hard cases of the issue: each must give finite parameters and standard deviations, the
// documented status, and the same status in the float and double scalar paths and the batched
// lanes (and Ceres, which shares the classification).
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>

#include "engine/fit/fitter.h"
#include "engine/fit/synthetic_samples.h"
#include "tests/engine/fit/fit_test_util.h"

namespace reflcap::fit {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
constexpr float kInf = std::numeric_limits<float>::infinity();

TexelSampleChunk OneTexel(const std::vector<BrdfSample>& samples) {
  TexelSampleChunk chunk;
  chunk.texel_count = 1;
  chunk.offsets = {0, samples.size()};
  chunk.samples = samples;
  return chunk;
}

std::vector<BrdfSample> SamplesOf(const TexelSampleChunk& chunk, uint32_t t = 0) {
  return std::vector<BrdfSample>(chunk.SamplesOf(t), chunk.SamplesOf(t) + chunk.SampleCount(t));
}

// One synthetic texel of material `material` (seeded by `seed`).
std::vector<BrdfSample> Texel(const brdf::BrdfParams& truth, uint64_t seed,
                              SyntheticSampleOptions so = {}) {
  so.seed = seed;
  return SamplesOf(MakeSyntheticChunk({truth}, so));
}

bool AllFinite(const TexelFit& f) {
  if (!brdf::IsFinite(f.params) || !brdf::IsFinite(f.sigma) || !std::isfinite(f.cost)) return false;
  return true;
}

struct Outcome {
  FitStatus status;
  TexelFit fit;  // double path's
};

// Fits with the scalar double and float paths, the batched lanes and Ceres; checks finiteness
// everywhere and that our three LM paths agree on the status (Ceres runs another LM, which may
// stop elsewhere in a degenerate case); returns the double path's fit.
Outcome FitEverywhere(const std::vector<BrdfSample>& samples, const FitOptions& options = {}) {
  const TexelSampleChunk chunk = OneTexel(samples);
  std::vector<TexelFit> fits[4];
  std::unique_ptr<Fitter> fitters[4] = {CreateScalarFitter(true), CreateScalarFitter(false),
                                        CreateFitter(Backend::kCpu).value(),
                                        CreateFitter(Backend::kCeres).value()};
  const char* names[4] = {"double", "float", "batched", "ceres"};
  for (int i = 0; i < 4; ++i) {
    EXPECT_TRUE(fitters[i]->Fit(chunk, options, &fits[i]).ok());
    EXPECT_TRUE(AllFinite(fits[i][0])) << names[i] << " " << fits[i][0].params.ToString();
    if (i == 3) continue;
    EXPECT_EQ(fits[i][0].status, fits[0][0].status)
        << names[i] << " says " << FitStatusName(fits[i][0].status) << ", double says "
        << FitStatusName(fits[0][0].status);
  }
  return {fits[0][0].status, fits[0][0]};
}

const brdf::BrdfParams kGlossy = SynthMaterialParams(1);

TEST(FitHardCases, GrazingDirectionsAreMaskedAndTooFewRemain) {
  // Every sample has cos(theta_o) = 0.03 < min_cos_theta = 0.05.
  std::vector<BrdfSample> samples = Texel(kGlossy, 1);
  for (BrdfSample& s : samples) {
    const double h = std::sqrt(1 - 0.03 * 0.03) / std::hypot(s.wo[0], s.wo[1]);
    s.wo[0] = float(s.wo[0] * h);
    s.wo[1] = float(s.wo[1] * h);
    s.wo[2] = 0.03f;
  }
  const Outcome o = FitEverywhere(samples);
  EXPECT_EQ(o.status, FitStatus::kTooFewSamples);
  EXPECT_EQ(o.fit.samples, 0);
}

TEST(FitHardCases, NearGrazingButValidDirectionsFit) {
  SyntheticSampleOptions so;
  so.min_cos = 0.06;  // down to 86.6 degrees
  so.max_tilt_deg = 80;
  const Outcome o = FitEverywhere(Texel(kGlossy, 2, so));
  EXPECT_EQ(o.status, FitStatus::kConverged);
}

TEST(FitHardCases, ExponentAtTheLowerBound) {
  brdf::BrdfParams truth = kGlossy;
  for (auto& l : truth.lobes[0]) l = brdf::MirrorLobe(0.3, 1.0);
  const Outcome o = FitEverywhere(Texel(truth, 3));
  // n = 1 lobes are broad: fitted, n lands on (or at) its lower bound.
  EXPECT_EQ(o.status, FitStatus::kConverged);
  EXPECT_NEAR(o.fit.params.lobes[0][0].n, 1.0, 0.2);
}

// Drops the samples whose wo lies within `deg` degrees of the mirror direction of wi.
std::vector<BrdfSample> AwayFromMirror(const std::vector<BrdfSample>& in, double deg) {
  std::vector<BrdfSample> out;
  for (const BrdfSample& s : in) {
    const double mirror_cos = -s.wi[0] * s.wo[0] - s.wi[1] * s.wo[1] + s.wi[2] * s.wo[2];
    if (mirror_cos < std::cos(DegToRad(deg))) out.push_back(s);
  }
  return out;
}

TEST(FitHardCases, ExponentAtTheUpperBound) {
  // n = 1e4: a needle 0.6 degrees wide.
  brdf::BrdfParams truth = kGlossy;
  for (auto& l : truth.lobes[0]) l = brdf::MirrorLobe(50.0, brdf::kMaxExponent);
  // No sample within 2 degrees: the needle is invisible (cos^1e4(2 deg) = 2e-3 of its peak
  // is below the noise) — no lobe evidence, a Lambert-only fit.
  const Outcome unseen = FitEverywhere(AwayFromMirror(Texel(truth, 4), 2.0));
  EXPECT_EQ(unseen.status, FitStatus::kConverged);
  EXPECT_TRUE(unseen.fit.lambert_only);
  EXPECT_NEAR(unseen.fit.params.rho_d[0], truth.rho_d[0], 0.01 * truth.rho_d[0]);
  // One sample exactly on the needle: evidence, but one sample cannot fix C and n.
  std::vector<BrdfSample> seen = AwayFromMirror(Texel(truth, 4), 2.0);
  BrdfSample on = seen[0];
  const float wi[3] = {0.3f, 0.2f, std::sqrt(1 - 0.13f)}, wo[3] = {-0.3f, -0.2f, wi[2]};
  std::copy(wi, wi + 3, on.wi);
  std::copy(wo, wo + 3, on.wo);
  const Vec3f f = brdf::EvalRgb(truth, Vec3f(wi[0], wi[1], wi[2]), Vec3f(wo[0], wo[1], wo[2]));
  for (int c = 0; c < 3; ++c) on.value[c] = f[c];
  seen.push_back(on);
  const Outcome one = FitEverywhere(seen);
  EXPECT_EQ(one.status, FitStatus::kSingular);
}

TEST(FitHardCases, HighlightNarrowerThanTheSampleSpacing) {
  // n = 2000 (lobe half-width ~1.3 degrees) seen by near-mirror samples 2..8 degrees away.
  brdf::BrdfParams truth = kGlossy;
  for (auto& l : truth.lobes[0]) l = brdf::MirrorLobe(100.0, 2000.0);
  std::vector<BrdfSample> samples = Texel(truth, 5);
  const Outcome o = FitEverywhere(samples);
  EXPECT_TRUE(o.status == FitStatus::kConverged || o.status == FitStatus::kSingular)
      << FitStatusName(o.status);
}

TEST(FitHardCases, NoSampleNearTheHighlightIsUnidentifiable) {
  SyntheticSampleOptions so;
  so.near_mirror_samples = 0;
  std::vector<BrdfSample> samples;
  for (const BrdfSample& s : Texel(kGlossy, 6, so)) {
    const double mirror_cos = -s.wi[0] * s.wo[0] - s.wi[1] * s.wo[1] + s.wi[2] * s.wo[2];
    if (mirror_cos < std::cos(DegToRad(15))) samples.push_back(s);
  }
  ASSERT_GE(samples.size(), 20u);
  const Outcome o = FitEverywhere(samples);
  EXPECT_EQ(o.status, FitStatus::kUnidentifiableLobe);
  EXPECT_TRUE(o.fit.lambert_only);
  EXPECT_EQ(o.fit.params.lobes[0][0].cz, 0.0f);
  EXPECT_EQ(o.fit.sigma.lobes[0][0].n, -1.0f);  // not fitted
  EXPECT_GT(o.fit.sigma.rho_d[0], 0.0f);
}

TEST(FitHardCases, AllDarkTexel) {
  std::vector<BrdfSample> samples = Texel(kGlossy, 7);
  for (BrdfSample& s : samples) {
    for (float& v : s.value) v = 0;
  }
  const Outcome o = FitEverywhere(samples);
  EXPECT_EQ(o.status, FitStatus::kConverged);
  EXPECT_EQ(o.fit.params.rho_d[0], 0.0f);
  EXPECT_TRUE(o.fit.lambert_only);
}

TEST(FitHardCases, ClippedSamples) {
  std::vector<BrdfSample> samples = Texel(SynthMaterialParams(2), 8);  // sharp, peak 20
  for (BrdfSample& s : samples) {
    for (float& v : s.value) v = std::min(v, 2.0f);  // the sensor clipped the highlight
  }
  const Outcome o = FitEverywhere(samples);
  EXPECT_TRUE(o.status == FitStatus::kConverged || o.status == FitStatus::kSingular)
      << FitStatusName(o.status);
}

TEST(FitHardCases, NanAndInfSamplesAreDroppedAndFlagged) {
  std::vector<BrdfSample> samples = Texel(kGlossy, 9);
  samples[3].value[0] = kNaN;
  samples[10].value[1] = kInf;
  samples[17].weight[2] = -kInf;
  samples[21].wi[0] = kNaN;
  const Outcome o = FitEverywhere(samples);
  EXPECT_EQ(o.status, FitStatus::kNonFiniteInput);
  // The rest still fits the truth.
  EXPECT_NEAR(o.fit.params.rho_d[0], kGlossy.rho_d[0], 0.02 * kGlossy.rho_d[0]);
  // A texel of nothing but NaN.
  for (BrdfSample& s : samples) s.value[0] = s.value[1] = s.value[2] = kNaN;
  EXPECT_EQ(FitEverywhere(samples).status, FitStatus::kNonFiniteInput);
}

TEST(FitHardCases, NegativeValuesAreKeptAndRhoStaysNonNegative) {
  std::vector<BrdfSample> samples = Texel(kGlossy, 10);
  for (BrdfSample& s : samples) {
    for (float& v : s.value) v = -0.01f - 0.001f * float((&s - samples.data()) % 7);
  }
  const Outcome o = FitEverywhere(samples);
  EXPECT_EQ(o.status, FitStatus::kConverged);
  EXPECT_EQ(o.fit.params.rho_d[0], 0.0f);  // projected onto its bound
}

TEST(FitHardCases, ValuesSpanningTenDecades) {
  // The same texel at overall scales 1e-6 and 1e4 gives the same relative parameters; and one
  // texel whose diffuse level is 1e-6 under a lobe peaking at 1e4.
  const std::vector<BrdfSample> base = Texel(kGlossy, 11);
  const Outcome reference = FitEverywhere(base);
  for (double gain : {1e-6, 1e4}) {
    std::vector<BrdfSample> scaled = base;
    for (BrdfSample& s : scaled) {
      for (int c = 0; c < 3; ++c) {
        s.value[c] = float(s.value[c] * gain);
        s.weight[c] = float(s.weight[c] / (gain * gain));
      }
    }
    const Outcome o = FitEverywhere(scaled);
    EXPECT_EQ(o.status, reference.status);
    // Normalisation makes the problems identical up to float rounding of the inputs.
    EXPECT_NEAR(o.fit.params.rho_d[0] / gain, reference.fit.params.rho_d[0], 1e-4 * reference.fit.params.rho_d[0]);
    EXPECT_NEAR(o.fit.params.lobes[0][0].n, reference.fit.params.lobes[0][0].n, 1e-3 * reference.fit.params.lobes[0][0].n);
  }
  brdf::BrdfParams extreme = kGlossy;
  for (int c = 0; c < 3; ++c) {
    extreme.rho_d[c] = float(kPi * 1e-6);
    extreme.lobes[0][c] = brdf::MirrorLobe(1e4, 25);
  }
  const Outcome o = FitEverywhere(Texel(extreme, 12));
  EXPECT_EQ(o.status, FitStatus::kConverged);
  // With inverse-variance weights of 1 % relative noise the 1e-6 samples weigh 1e20 x the
  // highlight's, so rho_d is what the data pin down (the peak is an extrapolation).
  EXPECT_NEAR(o.fit.params.rho_d[0], extreme.rho_d[0], 0.01 * extreme.rho_d[0]);
}

TEST(FitHardCases, DuplicatedSamplesChangeNothing) {
  const std::vector<BrdfSample> base = Texel(kGlossy, 13);
  std::vector<BrdfSample> tripled;
  for (const BrdfSample& s : base) tripled.insert(tripled.end(), 3, s);
  const Outcome a = FitEverywhere(base), b = FitEverywhere(tripled);
  EXPECT_EQ(b.status, FitStatus::kConverged);
  // Same least-squares problem (weights x 3): same optimum in double to the LM tolerance.
  EXPECT_NEAR(b.fit.params.lobes[0][0].n, a.fit.params.lobes[0][0].n, 1e-4 * a.fit.params.lobes[0][0].n);
  EXPECT_NEAR(b.fit.params.rho_d[1], a.fit.params.rho_d[1], 1e-4 * a.fit.params.rho_d[1]);
  // Its standard deviations shrink by sqrt(3) (3x the samples at the same residuals) -- roughly,
  // as the residual variance divides by m - p.
  EXPECT_LT(b.fit.sigma.rho_d[1], 0.7 * a.fit.sigma.rho_d[1]);
}

TEST(FitHardCases, FewerThanFiveSamples) {
  std::vector<BrdfSample> samples = Texel(kGlossy, 14);
  samples.resize(4);
  const Outcome o = FitEverywhere(samples);
  EXPECT_EQ(o.status, FitStatus::kTooFewSamples);
  EXPECT_TRUE(o.fit.lambert_only);
  EXPECT_GT(o.fit.params.rho_d[0], 0.0f);
  samples.clear();
  EXPECT_EQ(FitEverywhere(samples).status, FitStatus::kTooFewSamples);
}

TEST(FitHardCases, CollinearDirectionsLeaveCyUndetermined) {
  // Every wi and wo in the x-z plane: wiy woy = 0, so Cy has no influence on any sample.
  std::vector<BrdfSample> samples;
  std::mt19937 rng(15);
  std::uniform_real_distribution<double> angle(-1.3, 1.3);
  const brdf::BrdfParams truth = kGlossy;
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
  EXPECT_EQ(FitEverywhere(samples).status, FitStatus::kSingular);
  // The isotropic model ties Cy to Cx: determined.
  FitOptions iso;
  iso.lobe_model = LobeModel::kIso;
  EXPECT_EQ(FitEverywhere(samples, iso).status, FitStatus::kConverged);
}

}  // namespace
}  // namespace reflcap::fit
