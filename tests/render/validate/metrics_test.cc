// Metrics of `reflcap validate` on inputs whose answer is known.
#include "render/validate/metrics.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "render/reference/reference_renderer.h"
#include "render/validate/figures.h"

namespace reflcap::validate {
namespace {

Image RandomImage(int w, int h, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> u(0.05f, 2.0f);
  Image image(w, h, 3);
  for (float& v : image.data) v = u(rng);
  return image;
}

Image Square(int size, int x0, int y0, int side) {
  Image mask(size, size, 1, 0.0f);
  for (int y = y0; y < y0 + side; ++y) {
    for (int x = x0; x < x0 + side; ++x) mask.at(x, y) = 1;
  }
  return mask;
}

size_t Count(const Image& mask) {
  size_t n = 0;
  for (float v : mask.data) n += v > 0.5f;
  return n;
}

TEST(Metrics, IdenticalImagesScorePerfectly) {
  const Image photo = RandomImage(48, 48, 1);
  const Image mask = Square(48, 4, 4, 30);
  const ImageScore s = ScoreImage(photo, photo, mask, nullptr, std::nullopt, {});
  EXPECT_EQ(s.raw.pixels, 900);
  ASSERT_TRUE(s.raw.PsnrDb().has_value());
  EXPECT_EQ(*s.raw.PsnrDb(), kMaxPsnrDb) << "an exact match reports the finite cap, never Inf";
  EXPECT_EQ(*s.raw.RelRmse(), 0.0);
  EXPECT_DOUBLE_EQ(*s.raw.Ssim(), 1.0);
  EXPECT_EQ(*s.scaled.PsnrDb(), kMaxPsnrDb);
  EXPECT_DOUBLE_EQ(*s.scaled.Ssim(), 1.0);
  for (double scale : s.scale) EXPECT_DOUBLE_EQ(scale, 1.0);
}

TEST(Metrics, LeastSquaresScaleRemovesAConstantPerChannelScaleError) {
  const Image photo = RandomImage(40, 40, 2);
  const double k[3] = {0.8, 1.1, 0.6};
  Image render = photo;
  for (size_t i = 0; i < render.PixelCount(); ++i) {
    for (int c = 0; c < 3; ++c) render.data[i * 3 + c] = float(k[c] * photo.data[i * 3 + c]);
  }
  const Image mask = Square(40, 0, 0, 40);
  const ImageScore s = ScoreImage(photo, render, mask, nullptr, std::nullopt, {});
  EXPECT_LT(*s.raw.PsnrDb(), 25);
  EXPECT_GT(*s.raw.RelRmse(), 0.1);
  EXPECT_LT(*s.raw.Ssim(), 0.999);
  // s_c = 1 / k_c; the scaled render equals the photograph up to float rounding (~1e-7).
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(s.scale[c], 1 / k[c], 1e-6);
  EXPECT_GT(*s.scaled.PsnrDb(), 120);
  EXPECT_LT(*s.scaled.RelRmse(), 1e-6);
  EXPECT_NEAR(*s.scaled.Ssim(), 1.0, 1e-6);
}

TEST(Metrics, KnownNoiseGivesTheAnalyticPsnrAndTheBound) {
  // Photograph = 0.5 + N(0, sigma²) per value; render = 0.5. Expected MSE = sigma², so
  // PSNR = 10 log10(P² / sigma²) with P the photograph's max; the sample MSE of N = 3 x 160² values
  // has relative std sqrt(2 / N) = 0.6 %, i.e. 0.03 dB: 0.1 dB is > 3 std.
  constexpr double kSigma = 0.01;
  constexpr double kToleranceDb = 0.1;
  const int size = 160;
  Image photo(size, size, 3), render(size, size, 3, 0.5f);
  std::mt19937_64 rng(3);
  std::normal_distribution<double> noise(0, kSigma);
  double peak = 0;
  for (float& v : photo.data) {
    v = float(0.5 + noise(rng));
    peak = std::max(peak, double(v));
  }
  const Image mask = Square(size, 0, 0, size);
  const NoiseModel model{0, kSigma};  // read noise only: variance sigma² everywhere
  const ImageScore s = ScoreImage(photo, render, mask, nullptr, model, {});
  const double analytic = 10 * std::log10(peak * peak / (kSigma * kSigma));
  EXPECT_DOUBLE_EQ(s.peak, peak);
  EXPECT_NEAR(*s.raw.PsnrDb(), analytic, kToleranceDb);
  EXPECT_NEAR(*s.raw.NoiseBoundDb(), analytic, 1e-9) << "the bound is analytic here";
  EXPECT_NEAR(*s.raw.RelRmse(), kSigma / 0.5, 0.01 * kSigma / 0.5 * 3);
  std::printf("known noise: PSNR %.3f dB, analytic %.3f dB, bound %.3f dB\n", *s.raw.PsnrDb(),
              analytic, *s.raw.NoiseBoundDb());
}

TEST(Masks, ErosionByTwoPixelsShrinksASquareByTwoOnEachSide) {
  const Image square = Square(40, 10, 12, 20);
  const Image eroded = ErodeMask(square, kErodePx);
  EXPECT_EQ(Count(eroded), 16u * 16u);
  for (int y = 0; y < 40; ++y) {
    for (int x = 0; x < 40; ++x) {
      const bool inside = x >= 12 && x < 28 && y >= 14 && y < 30;
      ASSERT_EQ(eroded.at(x, y) > 0.5f, inside) << x << "," << y;
    }
  }
  // Touching the image border counts as touching the background.
  EXPECT_EQ(Count(ErodeMask(Square(10, 0, 0, 10), 2)), 36u);
  EXPECT_EQ(Count(ErodeMask(square, 0)), 400u);
  // A disc of radius 2 has 13 pixels: dilating one pixel gives it.
  EXPECT_EQ(Count(DilateMask(Square(9, 4, 4, 1), 2)), 13u);
}

TEST(Masks, EvaluationMaskDropsSaturatedAndNonFinitePixels) {
  Image photo(10, 10, 3, 0.5f);
  photo.at(5, 5, 1) = 0.99f;                     // saturated at 0.95
  photo.at(6, 5, 2) = std::nanf("");              // not finite
  size_t excluded = 0;
  const Image mask = EvaluationMask(Square(10, 0, 0, 10), photo, 0.95, 2, &excluded);
  EXPECT_EQ(excluded, 2u);
  EXPECT_EQ(Count(mask), 36u - 2u);
}

TEST(Regions, LabelsAConstructedCase) {
  using namespace render;
  const int size = 40;
  Image aux(size, size, kAuxChannelCount, 0.0f);
  for (int y = 0; y < size; ++y) {
    for (int x = 0; x < size; ++x) {
      float* a = aux.pixel(x, y);
      a[kAuxMask] = 1;
      a[kAuxCosThetaO] = y >= 35 ? 0.1f : 0.9f;   // grazing view in the bottom rows
      a[kAuxCosThetaI] = x < 5 ? -0.5f : 0.9f;    // columns 0-4 face away from the light
      a[kAuxCastShadow] = x >= 5 && x < 20 ? 1 : 0;  // cast shadow on columns 5-19
      a[kAuxCurvature] = y < 5 ? 5.0f : 1.0f;      // high curvature in the top rows
    }
  }
  const Image eval = Square(size, 0, 0, size);
  const std::vector<uint8_t> bits = LabelRegions(aux, eval, {});
  auto has = [&](int x, int y, Region r) { return (bits[size_t(y) * size + x] >> r) & 1; };
  for (int y = 0; y < size; ++y) {
    for (int x = 0; x < size; ++x) {
      // The lit / cast-shadow boundary is between columns 19 and 20: both are boundary pixels, and
      // shadow_edge is everything within 3 px of them. The face-away / cast-shadow border (4|5) is
      // no cast-shadow edge (both sides are dark).
      EXPECT_EQ(has(x, y, kShadowEdge), x >= 16 && x <= 23) << x << "," << y;
      EXPECT_EQ(has(x, y, kHighCurvatureRegion), y < 5) << x << "," << y;
      EXPECT_EQ(has(x, y, kGrazing), y >= 35 || x < 5) << x << "," << y;
      const bool none = !(x >= 16 && x <= 23) && y >= 5 && y < 35 && x >= 5;
      EXPECT_EQ(has(x, y, kElsewhere), none) << x << "," << y;
    }
  }
  // Pixels outside the evaluation mask get no label.
  const std::vector<uint8_t> none = LabelRegions(aux, Image(size, size, 1, 0.0f), {});
  for (uint8_t b : none) ASSERT_EQ(b, 0);
}

TEST(Figures, NiceScalesAndPercentLabels) {
  EXPECT_DOUBLE_EQ(NiceCeil(0.037), 0.05);
  EXPECT_DOUBLE_EQ(NiceCeil(0.05), 0.05);
  EXPECT_DOUBLE_EQ(NiceCeil(0.11), 0.2);
  EXPECT_DOUBLE_EQ(NiceCeil(0.21), 0.25);
  EXPECT_DOUBLE_EQ(NiceCeil(0), 1);
  EXPECT_EQ(FormatPercent(0.025), "2.5%");
  EXPECT_EQ(FormatPercent(0.1), "10%");
  EXPECT_EQ(TextWidth("10%", 1), 17);
}

TEST(Figures, ComposeFigureDrawsThreePanelsAndAColourBar) {
  const int size = 32;
  Image photo(size, size, 3, 0.5f), render(size, size, 3, 0.25f), error(size, size, 1, 0.02f);
  error.at(0, 0) = -1;  // not evaluated
  const Image figure = ComposeFigure(photo, render, error, 0.05, "TEST 1.5 DB");
  EXPECT_GT(figure.width, 3 * size);
  EXPECT_GT(figure.height, size);
  // Viridis at both ends: dark purple at 0, yellow at 1.
  EXPECT_LT(Viridis(0)[1], 0.05f);
  EXPECT_GT(Viridis(1)[0], 0.9f);
  EXPECT_GT(Viridis(1)[1], 0.85f);
}

}  // namespace
}  // namespace reflcap::validate

namespace reflcap::validate {
namespace {

// SSIM written as the plain loops the metric is defined by (a separable Gaussian, zero outside
// the image, taps added in order; window statistics renormalised over the mask): SsimSum's
// vectorised loops and ScoreImage's shared moments must give the same bits.
double ReferenceSsimSum(const Image& a, const Image& b, const Image& mask) {
  const int w = a.width, h = a.height;
  std::vector<double> kernel(2 * kSsimRadius + 1);
  double ksum = 0;
  for (int i = -kSsimRadius; i <= kSsimRadius; ++i) {
    kernel[i + kSsimRadius] = std::exp(-0.5 * i * i / (kSsimSigma * kSsimSigma));
    ksum += kernel[i + kSsimRadius];
  }
  for (double& v : kernel) v /= ksum;
  int x0 = w, y0 = h, x1 = -1, y1 = -1;
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      if (mask.at(x, y) > 0.5f) x0 = std::min(x0, x), x1 = std::max(x1, x), y0 = std::min(y0, y),
                                y1 = std::max(y1, y);
    }
  }
  const int bw = x1 - x0 + 1, bh = y1 - y0 + 1;
  auto blur = [&](const std::vector<double>& in) {
    std::vector<double> tmp(in.size()), out(in.size());
    for (int y = 0; y < bh; ++y) {
      for (int x = 0; x < bw; ++x) {
        double s = 0;
        for (int k = -kSsimRadius; k <= kSsimRadius; ++k) {
          if (x + k >= 0 && x + k < bw) s += kernel[k + kSsimRadius] * in[y * bw + x + k];
        }
        tmp[y * bw + x] = s;
      }
    }
    for (int y = 0; y < bh; ++y) {
      for (int x = 0; x < bw; ++x) {
        double s = 0;
        for (int k = -kSsimRadius; k <= kSsimRadius; ++k) {
          if (y + k >= 0 && y + k < bh) s += kernel[k + kSsimRadius] * tmp[(y + k) * bw + x];
        }
        out[y * bw + x] = s;
      }
    }
    return out;
  };
  const size_t n = size_t(bw) * bh;
  std::vector<double> weight(n);
  for (size_t i = 0; i < n; ++i) weight[i] = mask.at(x0 + int(i % bw), y0 + int(i / bw)) > 0.5f;
  const std::vector<double> wsum = blur(weight);
  const double c1 = kSsimK1 * kSsimK1, c2 = kSsimK2 * kSsimK2;
  std::vector<double> per_pixel(n, 0.0);
  for (int c = 0; c < 3; ++c) {
    std::vector<double> wa(n), wb(n), waa(n), wbb(n), wab(n);
    for (size_t i = 0; i < n; ++i) {
      const double x = a.at(x0 + int(i % bw), y0 + int(i / bw), c);
      const double y = b.at(x0 + int(i % bw), y0 + int(i / bw), c);
      wa[i] = weight[i] * x, wb[i] = weight[i] * y, waa[i] = weight[i] * (x * x);
      wbb[i] = weight[i] * (y * y), wab[i] = weight[i] * (x * y);
    }
    const auto ma = blur(wa), mb = blur(wb), maa = blur(waa), mbb = blur(wbb), mab = blur(wab);
    for (size_t i = 0; i < n; ++i) {
      if (weight[i] == 0) continue;
      const double norm = 1 / wsum[i];
      const double mu_a = ma[i] * norm, mu_b = mb[i] * norm;
      const double var_a = maa[i] * norm - mu_a * mu_a, var_b = mbb[i] * norm - mu_b * mu_b;
      const double cov = mab[i] * norm - mu_a * mu_b;
      per_pixel[i] += ((2 * mu_a * mu_b + c1) * (2 * cov + c2)) /
                      ((mu_a * mu_a + mu_b * mu_b + c1) * (var_a + var_b + c2));
    }
  }
  double sum = 0;
  for (size_t i = 0; i < n; ++i) {
    if (weight[i] != 0) sum += per_pixel[i] / 3;
  }
  return sum;
}

TEST(Metrics, SsimMatchesThePlainLoopsBitForBit) {
  const Image photo = RandomImage(53, 41, 7);
  Image render = RandomImage(53, 41, 8);
  for (size_t i = 0; i < render.data.size(); ++i) {
    render.data[i] = 0.7f * photo.data[i] + 0.3f * render.data[i];
  }
  // An irregular mask: a disc with a hole, touching the image's left edge (border taps).
  Image mask(53, 41, 1, 0.0f);
  for (int y = 0; y < 41; ++y) {
    for (int x = 0; x < 53; ++x) {
      const double r2 = (x - 18.0) * (x - 18.0) + (y - 20.0) * (y - 20.0);
      mask.at(x, y) = r2 < 19.0 * 19.0 && r2 > 16.0 ? 1.0f : 0.0f;
    }
  }
  Image photo_tm(53, 41, 3), render_tm(53, 41, 3);
  for (size_t i = 0; i < photo.data.size(); ++i) {
    photo_tm.data[i] = ToneMap(photo.data[i], 1.3);
    render_tm.data[i] = ToneMap(render.data[i], 1.3);
  }
  const double reference = ReferenceSsimSum(photo_tm, render_tm, mask);
  EXPECT_EQ(SsimSum(photo_tm, render_tm, mask), reference);
  EXPECT_GT(reference, 0.0);
}

TEST(Metrics, ScoreImageSsimIsSsimSumOfTheToneMappedImages) {
  // ScoreImage tone-maps only where SSIM looks (unless figure data is kept) and shares the
  // photograph's moments between the raw and the scaled SSIM: same bits as the separate calls.
  const Image photo = RandomImage(45, 38, 11);
  Image render = RandomImage(45, 38, 12);
  for (size_t i = 0; i < render.data.size(); ++i) {
    render.data[i] = 0.5f * (photo.data[i] + render.data[i]);
  }
  Image mask(45, 38, 1, 0.0f);
  for (int y = 6; y < 31; ++y) {
    for (int x = 9; x < 34; ++x) mask.at(x, y) = 1;
  }
  for (bool keep : {false, true}) {
    ScoreOptions options;
    options.keep_figure_data = keep;
    const ImageScore s = ScoreImage(photo, render, mask, nullptr, std::nullopt, options);
    const double inv_mean = 1 / s.tone_mean;
    Image photo_tm(45, 38, 3), render_tm(45, 38, 3), scaled_tm(45, 38, 3);
    for (size_t i = 0; i < photo.PixelCount(); ++i) {
      for (int c = 0; c < 3; ++c) {
        photo_tm.data[i * 3 + c] = ToneMap(photo.data[i * 3 + c], inv_mean);
        render_tm.data[i * 3 + c] = ToneMap(render.data[i * 3 + c], inv_mean);
        scaled_tm.data[i * 3 + c] = ToneMap(float(s.scale[c] * render.data[i * 3 + c]), inv_mean);
      }
    }
    EXPECT_EQ(s.raw.ssim_sum, SsimSum(photo_tm, render_tm, mask)) << keep;
    EXPECT_EQ(s.scaled.ssim_sum, SsimSum(photo_tm, scaled_tm, mask)) << keep;
    if (keep) {
      EXPECT_EQ(s.photo_tm.data, photo_tm.data);
    }
  }
}

}  // namespace
}  // namespace reflcap::validate
