// Diffuse fall-off (engine/fit/diffuse_falloff.h): which Lambert-only texels take the generalized
// diffuse lobe, and what it then predicts. Samples are rendered from known BRDFs with seeded
// Gaussian noise, as a fixed camera sees a texel under many lamps (a DiLiGenT-like capture).
#include "engine/fit/diffuse_falloff.h"

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include "engine/brdf/lafortune.h"
#include "engine/fit/fit_driver.h"
#include "engine/fit/fit_store.h"
#include "engine/math/types.h"
#include "tests/engine/fit/fit_test_util.h"
#include "tests/engine/fit/transfer_fixtures.h"

namespace reflcap::fit {
namespace {

using testing::Chunk;
using testing::Direction;
using testing::RecipientFit;
using testing::StoreOf;

constexpr int kPhotographs = 60;
// Noise of every sample: 0.002 / sr, 1-3 % of the values below (DiLiGenT's photographs carry
// about 1 %); weights are its inverse variance, as the resampler writes them.
constexpr double kSigma = 0.002;

// A surface darker than Lambert at grazing light: rho / pi + (Cz cos_i cos_o)^0.5, the lobe
// 0.12 / sr at normal light and view (B = Cz^n). Its light-to-Lambert ratio falls from 1 at
// cos theta_i = 1 to 0.55 at 0.15, about pot1's.
brdf::BrdfParams Falloff() {
  brdf::BrdfParams p;
  p.num_lobes = 1;
  p.rho_d = {0.20f, 0.16f, 0.12f};
  for (int c = 0; c < brdf::kChannels; ++c) p.lobes[0][c] = {0, 0, float(std::pow(0.12, 2.0)), 0.5f};
  return p;
}

brdf::BrdfParams Lambert() {
  brdf::BrdfParams p;
  p.num_lobes = 1;
  p.rho_d = {0.5f, 0.4f, 0.3f};
  for (int c = 0; c < brdf::kChannels; ++c) p.lobes[0][c] = {0, 0, 0, 20};
  return p;
}

// The lamp of photograph i: elevation 10-81 degrees from the normal (cos theta_i 0.16-0.98, as
// a resampled store keeps them: above 0.15), azimuths spread by the golden angle.
Vec3f Lamp(int i) {
  const double theta = 10 + 71.0 * ((i * 37) % kPhotographs) / (kPhotographs - 1);
  return Direction(theta, 137.5 * i);
}

// One texel's samples, photograph i = image i, the camera 15 degrees off the normal. With
// `off_mirror`, every lamp lies within 60 degrees of azimuth of the camera, so at least 95 degrees
// from the mirror direction (azimuth 20): no sample of a glossy lobe's highlight.
std::vector<BrdfSample> Photographs(const brdf::BrdfParams& truth, std::mt19937* rng,
                                    bool off_mirror = false) {
  std::normal_distribution<double> noise(0.0, kSigma);
  std::vector<BrdfSample> out;
  const Vec3f wo = Direction(15, 200);
  for (int i = 0; i < kPhotographs; ++i) {
    Vec3f lamp = Lamp(i);
    if (off_mirror) {
      const double theta = 10 + 71.0 * ((i * 37) % kPhotographs) / (kPhotographs - 1);
      lamp = Direction(theta, 140 + 120.0 * ((i * 23) % kPhotographs) / (kPhotographs - 1));
    }
    BrdfSample s = testing::ExactSample(truth, lamp, wo);
    for (int c = 0; c < 3; ++c) {
      s.value[c] = float(s.value[c] + noise(*rng));
      s.weight[c] = float(1.0 / (kSigma * kSigma));
    }
    s.image = uint32_t(i);
    out.push_back(s);
  }
  return out;
}

// Worst relative error of `fit` against `truth` over lamps at cos theta_i 0.16-1 (the camera as
// above), channel by channel.
double WorstRelativeError(const brdf::BrdfParams& fit, const brdf::BrdfParams& truth) {
  double worst = 0;
  const Vec3f wo = Direction(15, 200);
  for (double theta = 0; theta <= 80; theta += 5) {
    for (double phi = 0; phi < 360; phi += 45) {
      const Vec3f a = brdf::EvalRgb(fit, Direction(theta, phi), wo);
      const Vec3f b = brdf::EvalRgb(truth, Direction(theta, phi), wo);
      for (int c = 0; c < 3; ++c) worst = std::max(worst, double(std::abs(a[c] - b[c]) / b[c]));
    }
  }
  return worst;
}

FitOptions Options() {
  FitOptions options;
  options.threads = 1;
  return options;
}

TEST(DiffuseFalloff, ATexelDarkerAtGrazingLightTakesTheLobeAndPredictsIt) {
  std::mt19937 rng(7);
  const brdf::BrdfParams truth = Falloff();
  std::vector<std::vector<BrdfSample>> samples;
  std::vector<TexelFit> fits;
  for (int t = 0; t < 20; ++t) {
    samples.push_back(Photographs(truth, &rng));
    fits.push_back(RecipientFit({0.3f, 0.25f, 0.2f}));
  }
  FitStore store = StoreOf(fits);
  DiffuseFalloffStats stats;
  ApplyDiffuseFalloff(Chunk(samples), Options(), 5, &store, &stats);
  EXPECT_EQ(stats.candidates, 20u);
  EXPECT_EQ(stats.taken, 20u);
  // The best Lambert fit of this surface (the weighted mean of a texel's samples: equal weights)
  // is 50 % off at grazing light; the lobe's fit is within 3 % everywhere (measured 1.0-1.5 %;
  // noise 1-3 % per sample, 60 samples).
  brdf::BrdfParams lambert = Lambert();
  for (int c = 0; c < 3; ++c) {
    double sum = 0;
    for (const BrdfSample& s : samples[0]) sum += s.value[c];
    lambert.rho_d[size_t(c)] = float(kPi * sum / kPhotographs);
  }
  ASSERT_GT(WorstRelativeError(lambert, truth), 0.15) << "the test surface is not darker";
  for (size_t t = 0; t < 20; ++t) {
    EXPECT_EQ(store.donor(t), FitStore::kDiffuseFalloff) << t;
    EXPECT_EQ(TexelModelOf(store, t), TexelModel::kFalloffLobe) << t;
    EXPECT_FALSE(store.lambert_only(t)) << t;
    const TexelFit fit = store.Get(t);
    EXPECT_LT(WorstRelativeError(fit.params, truth), 0.03) << t << " " << fit.params.ToString();
    // A generalized diffuse lobe: no x or y term, an exponent of the grid.
    for (int c = 0; c < 3; ++c) {
      EXPECT_EQ(fit.params.lobes[0][c].cx, 0.0f);
      EXPECT_EQ(fit.params.lobes[0][c].cy, 0.0f);
      EXPECT_GE(fit.params.lobes[0][c].n, float(brdf::kMinLobeExponent));
    }
  }
  // Every texel finds the true exponent, 0.5, among the grid's.
  for (int k = 0; k < kFalloffExponentCount; ++k) {
    EXPECT_EQ(stats.by_exponent[size_t(k)], kFalloffExponents[size_t(k)] == 0.5 ? 20u : 0u)
        << "n = " << kFalloffExponents[size_t(k)];
  }
}

TEST(DiffuseFalloff, LambertTexelsKeepPredictingLambert) {
  // 200 Lambert texels with the same noise. Seven exponents compete against the margin, so a few
  // texels take a lobe by chance; those lobes must stay within the noise of Lambert's prediction.
  std::mt19937 rng(11);
  const brdf::BrdfParams truth = Lambert();
  std::vector<std::vector<BrdfSample>> samples;
  std::vector<TexelFit> fits;
  for (int t = 0; t < 200; ++t) {
    samples.push_back(Photographs(truth, &rng));
    fits.push_back(RecipientFit(truth.rho_d));
  }
  FitStore store = StoreOf(fits);
  DiffuseFalloffStats stats;
  ApplyDiffuseFalloff(Chunk(samples), Options(), 5, &store, &stats);
  EXPECT_EQ(stats.candidates, 200u);
  // Measured 25 of 200 (seed 11; the demo's in-model capture: 239 of 1,680); a quarter would
  // mean the margin lets noise decide.
  EXPECT_LT(stats.taken, 50u);
  double worst = 0;
  for (size_t t = 0; t < 200; ++t) worst = std::max(worst, WorstRelativeError(store.Get(t).params, truth));
  // Samples of 0.1-0.16 / sr with 0.002 noise: 60 of them pin the level to ~0.3 %; a chance lobe
  // may bend the curve by a few times that (measured: 1.6 % at worst), not by the 50 % of the
  // fall-off above.
  EXPECT_LT(worst, 0.03);
}

TEST(DiffuseFalloff, ABorrowedLobeGivesWayOnlyToAClearWin) {
  std::mt19937 rng(13);
  // 0: a fall-off surface that borrowed a glossy lobe from its cluster; 1: the glossy material
  // whose lobe it is, its diffuse layer slightly darker at grazing light (a fall-off of 0.028 / sr
  // at normal incidence). Neither texel's photographs show a highlight (every lamp is far from
  // the mirror direction). On texel 1 a fall-off lobe predicts them better by more than the
  // absolute margin and less than kBorrowedFalloffMargin: with the relative margin at 0 it takes
  // the fall-off and drops the highlight (checked; 0.026 / sr is below the absolute margin, 0.03
  // above the relative one), as noise made seed-11 texels do.
  const brdf::BrdfParams falloff = Falloff(), glossy = testing::Glossy();
  brdf::BrdfParams glossy_darker = glossy;
  glossy_darker.num_lobes = 2;
  for (int c = 0; c < 3; ++c) glossy_darker.lobes[1][c] = {0, 0, float(std::pow(0.028, 2.0)), 0.5f};
  std::vector<std::vector<BrdfSample>> samples = {Photographs(falloff, &rng, true),
                                                  Photographs(glossy_darker, &rng, true)};
  TexelFit lent = testing::DonorFit(glossy);
  lent.status = FitStatus::kUnidentifiableLobe;
  FitStore store = StoreOf({lent, lent});
  store.set_donor(0, FitStore::kClusterLobe);
  store.set_donor(1, 0);  // texel 0 lent it (lobe transfer)
  DiffuseFalloffStats stats;
  ApplyDiffuseFalloff(Chunk(samples), Options(), 5, &store, &stats);
  EXPECT_EQ(stats.candidates, 2u);
  EXPECT_EQ(stats.taken, 1u);
  EXPECT_EQ(stats.replaced, 1u);
  EXPECT_EQ(store.donor(0), FitStore::kDiffuseFalloff);
  EXPECT_LT(WorstRelativeError(store.Get(0).params, falloff), 0.03);
  // The glossy texel keeps the lobe its photographs cannot judge, with its albedo as it was.
  EXPECT_EQ(store.donor(1), 0);
  EXPECT_EQ(store.Get(1).params.ToString(), lent.params.ToString());
}

TEST(DiffuseFalloff, OwnLobesAndTexelsWithTooFewPhotographsAreLeftAlone) {
  std::mt19937 rng(3);
  const brdf::BrdfParams truth = Falloff();
  std::vector<std::vector<BrdfSample>> samples;
  std::vector<TexelFit> fits;
  // 0: a lobe of its own; 1: every sample from one photograph (one fold).
  for (int t = 0; t < 2; ++t) samples.push_back(Photographs(truth, &rng));
  for (BrdfSample& s : samples[1]) s.image = 4;
  fits.push_back(testing::DonorFit(testing::Glossy()));
  fits.push_back(RecipientFit({0.3f, 0.25f, 0.2f}));
  FitStore store = StoreOf(fits);
  const std::vector<TexelFit> before = {store.Get(0), store.Get(1)};
  DiffuseFalloffStats stats;
  ApplyDiffuseFalloff(Chunk(samples), Options(), 5, &store, &stats);
  EXPECT_EQ(stats.candidates, 0u);
  EXPECT_EQ(stats.taken, 0u);
  for (size_t t = 0; t < 2; ++t) {
    EXPECT_EQ(store.Get(t).params.ToString(), before[t].params.ToString()) << t;
    EXPECT_EQ(store.donor(t), FitStore::kNoDonor) << t;
  }
}

TEST(DiffuseFalloff, NonFiniteAndZeroWeightSamplesAreIgnored) {
  std::mt19937 rng(5);
  const brdf::BrdfParams truth = Falloff();
  std::vector<BrdfSample> samples = Photographs(truth, &rng);
  samples[3].value[0] = std::numeric_limits<float>::quiet_NaN();
  samples[4].weight[1] = std::numeric_limits<float>::infinity();
  samples[5].value[2] = 1e6f;  // an outlier the resampler would never write, with weight 0
  samples[5].weight[2] = 0;
  FitStore store = StoreOf({RecipientFit({0.3f, 0.25f, 0.2f})});
  DiffuseFalloffStats stats;
  ApplyDiffuseFalloff(Chunk({samples}), Options(), 5, &store, &stats);
  ASSERT_EQ(stats.taken, 1u);
  const TexelFit fit = store.Get(0);
  EXPECT_TRUE(brdf::IsFinite(fit.params));
  EXPECT_TRUE(std::isfinite(fit.cost));
  EXPECT_LT(WorstRelativeError(fit.params, truth), 0.03) << fit.params.ToString();
}

}  // namespace
}  // namespace reflcap::fit
