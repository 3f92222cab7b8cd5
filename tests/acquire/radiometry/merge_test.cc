// HDR merge: unbiased values, a variance that matches the scatter, censored codes flagged.
#include "acquire/radiometry/merge.h"

#include <gtest/gtest.h>

#include <cmath>

namespace reflcap::radiometry {
namespace {

// The brackets/1 camera with a gamma-2.2 response: raw = t L + n, code = round(255 f(clip(raw))).
constexpr double kGamma = 2.2;
constexpr double kReadSigma = 0.002;
const std::vector<double> kExposures = {0.125, 0.5, 2.0, 8.0, 32.0};

InverseResponse GammaResponse() {
  InverseResponse r;
  r.model = "gamma";
  for (int c = 0; c < 3; ++c) {
    for (int z = 1; z < kCodeCount; ++z) r.log_x[size_t(c)][size_t(z)] = kGamma * std::log(z / 255.0);
    r.log_x[size_t(c)][0] = std::log(std::pow(0.5 / 255.0, kGamma) / 2);
    r.noise[size_t(c)].read_sigma = kReadSigma;
  }
  return r;
}

// A constant radiance per channel over size² pixels, noisy exposures.
BracketImages Constant(const Vec3d& radiance, int size, uint64_t seed, double sigma = kReadSigma) {
  BracketImages images;
  images.width = images.height = size;
  uint64_t s = seed;
  auto uniform = [&s]() {
    s = s * 6364136223846793005ull + 1442695040888963407ull;
    return double(s >> 11) * (1.0 / 9007199254740992.0);
  };
  for (double t : kExposures) {
    std::vector<uint8_t> codes(size_t(size) * size_t(size) * 3);
    for (size_t i = 0; i < codes.size(); ++i) {
      const double u1 = std::max(uniform(), 1e-300), u2 = uniform();
      const double n = sigma * std::sqrt(-2 * std::log(u1)) * std::cos(2 * kPi * u2);
      const double raw = std::clamp(t * radiance[int(i % 3)] + n, 0.0, 1.0);
      codes[i] = uint8_t(std::lround(255 * std::pow(raw, 1 / kGamma)));
    }
    images.codes.push_back(std::move(codes));
  }
  return images;
}

TEST(MergeBracket, MeanIsUnbiasedAndVarianceMatchesTheScatter) {
  // Radiances chosen so that each channel's best exposures differ.
  const Vec3d radiance(0.0123, 0.17, 2.9);
  const int size = 128;
  const MergedBracket m = MergeBracket(Constant(radiance, size, 7), kExposures, GammaResponse(), true);
  for (int c = 0; c < 3; ++c) {
    double mean = 0, predicted = 0;
    const size_t n = size_t(size) * size_t(size);
    for (size_t p = 0; p < n; ++p) {
      ASSERT_EQ(m.flags[p * 3 + size_t(c)], uint8_t(MergeFlag::kMeasured));
      mean += m.value.data[p * 3 + size_t(c)];
      predicted += m.variance.data[p * 3 + size_t(c)];
    }
    mean /= double(n);
    predicted /= double(n);
    double scatter = 0;
    for (size_t p = 0; p < n; ++p) {
      const double d = m.value.data[p * 3 + size_t(c)] - mean;
      scatter += d * d;
    }
    scatter /= double(n - 1);
    // Bias: dithered quantisation averages out to well below the per-pixel noise (a few 1e-4).
    EXPECT_NEAR(mean / radiance[c], 1.0, 2e-3) << "channel " << c;
    // The variance model (read noise + quantisation, through the weights) against the scatter of
    // 16384 pixels (the sampling error of a variance is sqrt(2/n) = 1 %); the quantisation term
    // assumes a uniform position in the bin, which dither by the noise only approximates.
    EXPECT_NEAR(predicted / scatter, 1.0, 0.25) << "channel " << c;
  }
  // Weight shares per exposure sum to 1 where measured.
  const int E = m.weight_share.channels;
  ASSERT_EQ(E, 5);
  double sum = 0;
  for (int e = 0; e < E; ++e) sum += m.weight_share.data[size_t(e)];
  EXPECT_NEAR(sum, 1.0, 1e-5);
}

TEST(MergeBracket, ClippedAndDarkChannelsAreFlagged) {
  // Red clips even at the shortest exposure (0.125 · 20 > 1); blue is black even at the longest
  // (noise-free: with noise, a gamma curve's steep toe turns noise into codes > 0).
  const MergedBracket m =
      MergeBracket(Constant(Vec3d(20, 0.1, 0), 4, 3, /*sigma=*/0), kExposures, GammaResponse());
  EXPECT_EQ(m.flags[0], uint8_t(MergeFlag::kClipped));
  EXPECT_EQ(m.flags[1], uint8_t(MergeFlag::kMeasured));
  EXPECT_EQ(m.flags[2], uint8_t(MergeFlag::kDark));
  EXPECT_EQ(m.value.data[2], 0.0f);
  EXPECT_GT(m.variance.data[2], 0.0f);
  EXPECT_EQ(m.clipped, 16u);
  EXPECT_EQ(m.dark, 16u);
  EXPECT_EQ(m.measured, 16u);
}

}  // namespace
}  // namespace reflcap::radiometry
