// Inverse response estimation on brackets simulated in memory (the brackets/1 camera model):
// recovery of a family's curve and parameters, of a curve no family fits, of the noise, of the
// clip normalisation; the equal-ratio ambiguity and the anchors that remove it.
#include "acquire/radiometry/response.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <functional>

#include "tests/acquire/radiometry/synthetic_brackets.h"

namespace reflcap::radiometry {
namespace {

// The accuracy goal for the inverse response (max |log error| over codes 20–235).
constexpr double kResponseGoal = 0.01;
// What a correct family reaches on 6 photos of 96² px: the curve is pinned by ~10⁵ observations,
// each to ~1 % (quantisation): measured 2e-4 to 1e-3; 3e-3 leaves room for other seeds.
constexpr double kFamilyTolerance = 3e-3;
// The clip normalisation (x(255) = 1 from the measured start of code 255): measured < 1e-3.
constexpr double kScaleTolerance = 3e-3;

// The fitted exponent: its log error is the curve's (≤ 1e-3 over ln y ∈ [−2.5, 0]) / |ln y| ~ 0.1 %.
constexpr double kGammaTolerance = 0.005;

const std::vector<double> kPowersOfFour = {0.125, 0.5, 2.0, 8.0, 32.0};

struct SimCamera {
  std::function<double(double)> f;
  std::vector<double> exposures = kPowersOfFour;
  double read_sigma = 0.001;
};

std::vector<double> TrueInverse(const std::function<double(double)>& f) {
  std::vector<double> x(256);
  for (int k = 0; k < 256; ++k) {
    double lo = 0, hi = 1;
    for (int i = 0; i < 100; ++i) {
      const double mid = 0.5 * (lo + hi);
      (f(mid) < k / 255.0 ? lo : hi) = mid;
    }
    x[size_t(k)] = 0.5 * (lo + hi);
  }
  return x;
}

// A photo of independent pixels with log-uniform radiance in [1e-4, 12] through the camera (gains 1).
BracketImages Photo(const SimCamera& cam, int size, uint64_t seed) {
  BracketImages images;
  images.width = images.height = size;
  uint64_t s = seed * 0x9E3779B97F4A7C15ull + 1;
  auto uniform = [&s]() {
    s = s * 6364136223846793005ull + 1442695040888963407ull;
    return double(s >> 11) * (1.0 / 9007199254740992.0);
  };
  const size_t n = size_t(size) * size_t(size) * 3;
  std::vector<double> L(n), noise(n * cam.exposures.size());
  for (double& l : L) l = std::exp(std::log(1e-4) + uniform() * (std::log(12.0) - std::log(1e-4)));
  for (double& v : noise) {
    const double u1 = std::max(uniform(), 1e-300), u2 = uniform();
    v = cam.read_sigma * std::sqrt(-2 * std::log(u1)) * std::cos(2 * kPi * u2);
  }
  for (size_t e = 0; e < cam.exposures.size(); ++e) {
    std::vector<uint8_t> codes(n);
    for (size_t i = 0; i < n; ++i) {
      const double raw = std::clamp(cam.exposures[e] * L[i] + noise[e * n + i], 0.0, 1.0);
      codes[i] = uint8_t(std::lround(255 * cam.f(raw)));
    }
    images.codes.push_back(std::move(codes));
  }
  return images;
}

SampleSet Sample(const SimCamera& cam, int photos, int size, const ResponseOptions& options) {
  std::vector<std::vector<double>> lists(size_t(photos), cam.exposures);
  ResponseSampler sampler(options, lists);
  for (int p = 0; p < photos; ++p) sampler.AddPhoto(size_t(p), Photo(cam, size, uint64_t(p) + 1));
  return sampler.Finish();
}

// Anchors: pixels of known relative radiance (a reference target), as the chart provides.
void AddAnchors(const SimCamera& cam, int count, SampleSet* set) {
  uint64_t s = 12345;
  auto uniform = [&s]() {
    s = s * 6364136223846793005ull + 1442695040888963407ull;
    return double(s >> 11) * (1.0 / 9007199254740992.0);
  };
  for (int i = 0; i < count; ++i) {
    const double L = std::exp(std::log(3e-3) + uniform() * (std::log(2.0) - std::log(3e-3)));
    for (int c = 0; c < 3; ++c) {
      AnchoredSample a;
      a.codes.count = uint8_t(cam.exposures.size());
      for (size_t e = 0; e < cam.exposures.size(); ++e) {
        const double raw = std::clamp(cam.exposures[e] * L, 0.0, 1.0);
        a.codes.codes[e] = uint8_t(std::lround(255 * cam.f(raw)));
      }
      a.log_radiance = std::log(L);
      set->anchored[size_t(c)].push_back(a);
    }
  }
}

double Gamma22(double x) { return std::pow(x, 1 / 2.2); }

TEST(ResponseEstimation, ChoosesAndRecoversTheTrueFamily) {
  const SimCamera cam{Gamma22};
  ResponseOptions options;
  const SampleSet set = Sample(cam, 6, 96, options);
  auto fit = EstimateResponse(set, options);
  ASSERT_TRUE(fit.ok()) << fit.status().ToString();
  EXPECT_EQ(fit->response.model, "gamma");

  const ResponseError e = CompareResponse(fit->response, TrueInverse(cam.f));
  EXPECT_LT(e.max_over_channels, kFamilyTolerance);
  for (int c = 0; c < 3; ++c) EXPECT_LT(e.max_abs_log_absolute[size_t(c)], kScaleTolerance);
  const auto gamma = std::find_if(fit->candidates.begin(), fit->candidates.end(),
                                  [](const ModelFit& m) { return m.model == "gamma"; });
  ASSERT_NE(gamma, fit->candidates.end());
  EXPECT_NEAR(gamma->params[1][0], 2.2, 2.2 * kGammaTolerance);
  // Read noise: 0.001 of the clip level, estimated from the exposures' residuals.
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(fit->response.noise[size_t(c)].read_sigma, 0.001, 0.0002);
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(fit->reduced_chi2[size_t(c)], 1.0, 0.2);
}

TEST(ResponseEstimation, AnSrgbCameraIsAnOffsetGamma) {
  // The sRGB encoding: linear below 0.0031308 (codes < 11, under the noise floor), a power law
  // with an offset above.
  const SimCamera cam{[](double x) { return x <= 0.0031308 ? 12.92 * x : 1.055 * std::pow(x, 1 / 2.4) - 0.055; }};
  ResponseOptions options;
  auto fit = EstimateResponse(Sample(cam, 6, 96, options), options);
  ASSERT_TRUE(fit.ok()) << fit.status().ToString();
  EXPECT_EQ(fit->response.model, "offsetgamma");
  // Measured 0.005: codes 20–37 lie below the noise floor (SNR 20) and are the family's
  // extrapolation, where its two parameters' correlation shows.
  EXPECT_LT(CompareResponse(fit->response, TrueInverse(cam.f)).max_over_channels, kResponseGoal);
}

TEST(ResponseEstimation, LogLogisticIsRecoveredAndNormalisedAtTheClip) {
  const SimCamera cam{testing::LogLogisticResponse};
  ResponseOptions options;
  auto fit = EstimateResponse(Sample(cam, 6, 96, options), options);
  ASSERT_TRUE(fit.ok()) << fit.status().ToString();
  EXPECT_EQ(fit->response.model, "loglogistic");
  const ResponseError e = CompareResponse(fit->response, TrueInverse(cam.f));
  EXPECT_LT(e.max_over_channels, kFamilyTolerance);
  for (int c = 0; c < 3; ++c) EXPECT_LT(e.max_abs_log_absolute[size_t(c)], kScaleTolerance);
}

TEST(ResponseEstimation, FreeFormCurveWhereNoFamilyFits) {
  // Exposure ratios that are not powers of one number (2, 5, 3, 7): the data alone determine the
  // curve.
  SimCamera cam{testing::RippledResponse, {0.1, 0.2, 1.0, 3.0, 21.0}};
  ResponseOptions options;
  auto fit = EstimateResponse(Sample(cam, 6, 96, options), options);
  ASSERT_TRUE(fit.ok()) << fit.status().ToString();
  EXPECT_EQ(fit->response.model, "debevec");
  // Over the codes the data measure (below, noise-floor codes are extrapolated: see response.h);
  // measured 0.005.
  const int first = std::max(20, fit->response.first_code[1]);
  EXPECT_LT(CompareResponse(fit->response, TrueInverse(cam.f), first).max_over_channels, kResponseGoal);
}

TEST(ResponseEstimation, AnchorsRemoveTheEqualRatioAmbiguity) {
  // Powers of 4 only: any ripple periodic in ln x with period ln 4 fits the brackets equally well,
  // so the free-form curve is wrong without anchors (Grossberg & Nayar); anchored pixels of known
  // relative radiance (the chart's) pin it.
  const SimCamera cam{testing::RippledResponse};
  ResponseOptions options;
  options.model = "debevec";
  SampleSet set = Sample(cam, 6, 96, options);
  auto plain = EstimateResponse(set, options);
  ASSERT_TRUE(plain.ok());
  EXPECT_FALSE(plain->debevec_identified);
  const int first = std::max(20, plain->response.first_code[1]);
  const double plain_error = CompareResponse(plain->response, TrueInverse(cam.f), first).max_over_channels;
  AddAnchors(cam, 2000, &set);
  auto anchored = EstimateResponse(set, options);
  ASSERT_TRUE(anchored.ok());
  EXPECT_TRUE(anchored->debevec_identified);
  const double anchored_error =
      CompareResponse(anchored->response, TrueInverse(cam.f), first).max_over_channels;
  EXPECT_GT(plain_error, kResponseGoal) << "the ambiguity should show without anchors";
  EXPECT_LT(anchored_error, kResponseGoal);
  EXPECT_GT(anchored->anchored_observations[1], 0u);
}

TEST(ResponseEstimation, NothingMeasuredIsAnError) {
  SampleSet set;
  set.log_exposures = {{0.0, 1.0}};
  ResponseOptions options;
  auto fit = EstimateResponse(set, options);
  ASSERT_FALSE(fit.ok());
  EXPECT_EQ(fit.status().code(), StatusCode::kFailedPrecondition);
  EXPECT_NE(fit.status().message().find("every bracket is clipped or dark"), std::string::npos);
}

TEST(ResponseEstimation, OptionsAreValidated) {
  ResponseOptions o;
  EXPECT_TRUE(o.Validate().ok());
  o.model = "spline";
  EXPECT_FALSE(o.Validate().ok());
  o = ResponseOptions();
  o.smoothness = 0;
  EXPECT_FALSE(o.Validate().ok());
  o = ResponseOptions();
  o.samples_per_bin = 3;
  EXPECT_FALSE(o.Validate().ok());
}

TEST(ResponseSampler, CapsBinsAndWeightsThePopulation) {
  const SimCamera cam{Gamma22};
  ResponseOptions options;
  options.samples_per_bin = 50;
  const SampleSet set = Sample(cam, 3, 64, options);
  // 64 bins per exposure x 5 exposures at most, 50 each.
  EXPECT_LE(set.samples[0].size(), size_t(5 * 64 * 50));
  EXPECT_GT(set.samples[0].size(), 0u);
  double population = 0;
  for (const ResponseSample& s : set.samples[0]) population += s.population_weight;
  // The weights add up to the candidates they stand for.
  EXPECT_NEAR(population, double(set.candidates[0]), 1e-3 * double(set.candidates[0]));
}

}  // namespace
}  // namespace reflcap::radiometry
