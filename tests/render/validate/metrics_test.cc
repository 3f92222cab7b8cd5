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

TEST(Figures, TheSameErrorGetsTheSameColourInEveryFigureOfOneScale) {
  // Two images whose errors differ 10x, drawn on one scale: a pixel's colour depends on its error
  // and the scale only (not on the image's own error range), and the colour bars are the same.
  const int size = 32;
  const double scale = 0.05;
  Image photo(size, size, 3, 0.5f), render(size, size, 3, 0.25f);
  Image small(size, size, 1, 0.004f), large(size, size, 1, 0.04f);
  small.at(3, 4) = large.at(3, 4) = 0.025f;  // the same error in both
  const Image a = ComposeFigure(photo, render, small, scale, "A");
  const Image b = ComposeFigure(photo, render, large, scale, "B");
  ASSERT_EQ(a.width, b.width);
  ASSERT_EQ(a.height, b.height);
  // Panel geometry of ComposeFigure at this size (font scale 1): pad 4, title 7 + 2 pad.
  const int pad = 4, title_h = kGlyphHeight + 2 * pad, ex = 3 * pad + 2 * size;
  for (int c = 0; c < 3; ++c) {
    EXPECT_EQ(a.at(ex + 3, title_h + 4, c), b.at(ex + 3, title_h + 4, c));
    EXPECT_FLOAT_EQ(a.at(ex + 3, title_h + 4, c), Viridis(0.025 / scale)[c]);
    EXPECT_FLOAT_EQ(a.at(ex, title_h, c), Viridis(0.004 / scale)[c]);
    EXPECT_FLOAT_EQ(b.at(ex, title_h, c), Viridis(0.04 / scale)[c]);
  }
  // Everything right of the error panel (colour bar and its labels) is the same in both.
  for (int y = 0; y < a.height - (kGlyphHeight + 2 * pad); ++y) {
    for (int x = ex + size; x < a.width; ++x) {
      for (int c = 0; c < 3; ++c) ASSERT_EQ(a.at(x, y, c), b.at(x, y, c)) << x << "," << y;
    }
  }
}

TEST(Figures, ColourBarLegendRunsFromZeroToTheScale) {
  const Image bar = ComposeColourBar(0.05, "TITLE");
  EXPECT_GE(bar.width, 512);
  // The bar's row: its leftmost coloured pixel is Viridis(0), its rightmost Viridis(1).
  int row = -1;
  for (int y = 0; y < bar.height && row < 0; ++y) {
    for (int x = 0; x < bar.width; ++x) {
      if (bar.at(x, y, 0) == Viridis(1)[0] && bar.at(x, y, 1) == Viridis(1)[1]) row = y;
    }
  }
  ASSERT_GE(row, 0);
  int first = -1, last = -1;
  for (int x = 0; x < bar.width; ++x) {
    if (bar.at(x, row, 0) == Viridis(0)[0] && bar.at(x, row, 2) == Viridis(0)[2] && first < 0) first = x;
    if (bar.at(x, row, 0) == Viridis(1)[0] && bar.at(x, row, 1) == Viridis(1)[1]) last = x;
  }
  ASSERT_GE(first, 0);
  EXPECT_EQ(last - first + 1, 512);
  // Round tick steps for NiceCeil's scales: 2.5 % in 0.5 % steps, 2 % in 0.5 % steps.
  EXPECT_EQ(ColourBarTicks(0.025), 6);
  EXPECT_EQ(ColourBarTicks(0.05), 6);
  EXPECT_EQ(ColourBarTicks(0.02), 5);
  EXPECT_EQ(ColourBarTicks(0.1), 5);
  EXPECT_EQ(ColourBarTicks(0.037), 5);
}

TEST(Metrics, MapErrorHistogramQuantileBracketsTheExactOne) {
  // The pooled quantile read off the histogram is the upper edge of the bin that holds the exact
  // nearest-rank quantile: not below it, and above it by less than one bin's factor.
  const double bin_factor = std::pow(10.0, 1.0 / kMapErrorBinsPerDecade);
  std::mt19937 rng(7);
  std::lognormal_distribution<double> dist(std::log(0.01), 1.0);
  MapErrorHistogram a, b;
  std::vector<float> all;
  for (int k = 0; k < 20000; ++k) {
    const double v = dist(rng);
    (k % 3 ? a : b).Add(v);
    all.push_back(float(v));
  }
  MapErrorHistogram pooled;
  pooled.Merge(a);
  pooled.Merge(b);
  EXPECT_EQ(pooled.Total(), 20000u);
  const std::optional<double> q = pooled.Quantile(kMapErrorScaleQuantile);
  const std::optional<float> exact = NearestRankPercentile(&all, kMapErrorScaleQuantile);
  ASSERT_TRUE(q && exact);
  // The exact quantile is of the values rounded to float (relative error 6e-8): margin 1e-6.
  constexpr double kFloatRoundingRel = 1e-6;
  EXPECT_GE(*q, *exact * (1 - kFloatRoundingRel));
  EXPECT_LT(*q, *exact * bin_factor * (1 + kFloatRoundingRel));
  // Zero errors land in the first bin; an empty histogram has no quantile.
  MapErrorHistogram zeros;
  zeros.Add(0);
  EXPECT_DOUBLE_EQ(*zeros.Quantile(0.99), kMapErrorMin * bin_factor);
  EXPECT_FALSE(MapErrorHistogram().Quantile(0.99).has_value());
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

namespace reflcap::validate {
namespace {

// Tolerance for closed-form PSNR-L values: SrgbEncode runs in float (relative error ~1e-7 in
// 1 - sRGB(0.5), i.e. ~1e-6 dB); the squared errors are summed in double.
constexpr double kClosedFormDb = 1e-5;

TEST(PsnrL, SrgbEncodingAtItsEndsAndAtTheLinearBoundary) {
  EXPECT_EQ(SrgbEncode(0), 0.0f);
  EXPECT_NEAR(SrgbEncode(1), 1.0, 1e-7);          // 1.055 - 0.055 in float
  EXPECT_NEAR(SrgbEncode(0.5f), 0.7353569830524495, 1e-7);
  // x = 0.0031308 takes the linear branch (IEC 61966-2-1: x <= 0.0031308) ...
  EXPECT_EQ(SrgbEncode(0.0031308f), 12.92f * 0.0031308f);
  EXPECT_EQ(SrgbEncode(0.001f), 12.92f * 0.001f);
  // ... and the next float the power branch; the standard's rounded constants leave a step of
  // 2.9e-8 between the branches there (0.040449936 vs 0.0404499075), and float rounding of the
  // result is 3.7e-9 (half an ulp at 0.04): 5e-8 bounds both.
  const float above = std::nextafter(0.0031308f, 1.0f);
  EXPECT_EQ(SrgbEncode(above), 1.055f * std::pow(above, 1 / 2.4f) - 0.055f);
  EXPECT_NEAR(SrgbEncode(above), SrgbEncode(0.0031308f), 5e-8);
  EXPECT_NEAR(SrgbEncode(above), 1.055 * std::pow(double(above), 1 / 2.4) - 0.055, 1e-8);
  // L clips before encoding; NaN reads as black.
  EXPECT_EQ(LdrValue(-3, 1), 0.0f);
  EXPECT_EQ(LdrValue(7, 0.5), 1.0f);
  EXPECT_EQ(LdrValue(std::nan(""), 1), 0.0f);
  EXPECT_EQ(LdrValue(INFINITY, 1), 1.0f);
}

TEST(PsnrL, NearestRankPercentile) {
  // 1..100: the 99th percentile is the 99th smallest, 99 (not 100: 0.99 · 100 is exactly 99).
  std::vector<float> values;
  for (int i = 100; i >= 1; --i) values.push_back(float(i));
  EXPECT_EQ(*NearestRankPercentile(&values, 0.99), 99.0f);
  // 1..101: rank ceil(99.99) = 100.
  values.push_back(101);
  EXPECT_EQ(*NearestRankPercentile(&values, 0.99), 100.0f);
  std::vector<float> one = {4};
  EXPECT_EQ(*NearestRankPercentile(&one, 0.99), 4.0f);
  std::vector<float> none;
  EXPECT_FALSE(NearestRankPercentile(&none, 0.99).has_value());
}

TEST(PsnrL, ConstantImagesGiveTheClosedForm) {
  // Photograph 2 everywhere: q99 = 2, L(p) = sRGB(1) = 1. Render 1: L(r) = sRGB(0.5) = 0.73536.
  // PSNR-L = -10 log10((1 - sRGB(0.5))²) = 11.5468 dB, the same in every region and pooled.
  const int size = 30;
  const Image photo(size, size, 3, 2.0f), render(size, size, 3, 1.0f);
  const Image mask = Square(size, 0, 0, size);
  const ImageScore s = ScoreImage(photo, render, mask, nullptr, std::nullopt, {});
  ASSERT_TRUE(s.q99.has_value());
  EXPECT_EQ(*s.q99, 2.0);
  const double expected = -20 * std::log10(1 - (1.055 * std::pow(0.5, 1 / 2.4) - 0.055));
  EXPECT_NEAR(expected, 11.546791222281529, 1e-12);  // python3, double
  ASSERT_TRUE(s.raw.PsnrLDb().has_value());
  EXPECT_NEAR(*s.raw.PsnrLDb(), expected, kClosedFormDb);
  // The LS scale is 2 per channel: the scaled render equals the photograph.
  EXPECT_EQ(*s.scaled.PsnrLDb(), kMaxPsnrDb);
  // The HDR PSNR differs: 10 log10(2² / 1²) = 6.02 dB.
  EXPECT_NEAR(*s.raw.PsnrDb(), 20 * std::log10(2.0), kClosedFormDb);
  // Pooled with a copy of itself (ErrorSums::Add): the same PSNR-L.
  ErrorSums pooled = s.raw;
  pooled.Add(s.raw);
  EXPECT_NEAR(*pooled.PsnrLDb(), expected, kClosedFormDb);
}

TEST(PsnrL, ValuesAboveTheWhitePointClipInBothImages) {
  // 40 x 40 photograph at 1 with 5 bright pixels (15 of 4800 values, 0.3 % < 1 %) at 5: q99 = 1.
  // The render gets 3 at the bright pixels: a large HDR error, but both clip to white, so PSNR-L
  // sees no error at all (the cap), while the HDR PSNR does.
  const int size = 40;
  Image photo(size, size, 3, 1.0f);
  Image render = photo;
  for (int k = 0; k < 5; ++k) {
    for (int c = 0; c < 3; ++c) {
      photo.at(5 + 6 * k, 20, c) = 5;
      render.at(5 + 6 * k, 20, c) = 3;
    }
  }
  const Image mask = Square(size, 0, 0, size);
  const ImageScore s = ScoreImage(photo, render, mask, nullptr, std::nullopt, {});
  EXPECT_EQ(*s.q99, 1.0);
  EXPECT_EQ(*s.raw.PsnrLDb(), kMaxPsnrDb);
  EXPECT_LT(*s.raw.PsnrDb(), 40);
  // One bright render pixel below white (0.5 under a photograph of 5) is seen: it can fail.
  render.at(5, 20, 0) = 0.5f;
  const ImageScore t = ScoreImage(photo, render, mask, nullptr, std::nullopt, {});
  EXPECT_LT(*t.raw.PsnrLDb(), 50);
}

TEST(PsnrL, ScaleInvariantPsnrLRecoversAHalvedRender) {
  const Image photo = RandomImage(36, 36, 21);
  Image render = photo;
  for (float& v : render.data) v *= 0.5f;
  const Image mask = Square(36, 2, 2, 30);
  const ImageScore s = ScoreImage(photo, render, mask, nullptr, std::nullopt, {});
  ASSERT_TRUE(s.raw.PsnrLDb() && s.scaled.PsnrLDb());
  EXPECT_LT(*s.raw.PsnrLDb(), 20) << "a render at half the brightness is far off in LDR too";
  // The scale is exactly 2 up to float rounding of the products: the scaled render matches to
  // ~1e-7, i.e. well above 100 dB.
  EXPECT_GT(*s.scaled.PsnrLDb(), 100);
  EXPECT_GE(*s.scaled.PsnrLDb(), *s.raw.PsnrLDb());
}

TEST(PsnrL, AnAllBlackPhotographHasNoPsnrLAndNoNaN) {
  const Image photo(20, 20, 3, 0.0f), render(20, 20, 3, 0.1f);
  const Image mask = Square(20, 0, 0, 20);
  const ImageScore s = ScoreImage(photo, render, mask, nullptr, std::nullopt, {});
  EXPECT_FALSE(s.q99.has_value());
  EXPECT_FALSE(s.raw.PsnrLDb().has_value());
  EXPECT_FALSE(s.scaled.PsnrLDb().has_value());
  EXPECT_EQ(s.raw.ldr_values, 0.0);
  ASSERT_TRUE(s.raw.PsnrDb().has_value());  // the HDR PSNR falls back to errors relative to 1
  EXPECT_TRUE(std::isfinite(*s.raw.PsnrDb()));
  // Pooled with an image that has one, the black image's values stay out of PSNR-L.
  const Image lit(20, 20, 3, 2.0f), half(20, 20, 3, 1.0f);
  const ImageScore l = ScoreImage(lit, half, mask, nullptr, std::nullopt, {});
  ErrorSums pooled = s.raw;
  pooled.Add(l.raw);
  EXPECT_NEAR(*pooled.PsnrLDb(), *l.raw.PsnrLDb(), kClosedFormDb);
  // Black against black: no error anywhere, so no worst-pixel share (0 / 0), never NaN.
  const ImageScore b = ScoreImage(photo, photo, mask, nullptr, std::nullopt, {});
  EXPECT_FALSE(b.worst_share[0].has_value());
  EXPECT_TRUE(b.worst_pixels.empty());
}

TEST(WorstPixels, SharesOfOnePixelAndOfUniformError) {
  // One pixel carries all the error: both shares are 1.
  std::vector<float> one(5000, 0.0f);
  one[1234] = 0.7f;
  auto shares = WorstErrorShares(&one);
  EXPECT_EQ(*shares[0], 1.0);
  EXPECT_EQ(*shares[1], 1.0);
  // Uniform error over 1000 pixels: the worst 1 (0.1 %) and 10 (1 %) carry 1/1000 and 10/1000;
  // 1e-12 bounds the rounding of the double sums of equal floats.
  std::vector<float> uniform(1000, 0.25f);
  shares = WorstErrorShares(&uniform);
  EXPECT_NEAR(*shares[0], 0.001, 1e-12);
  EXPECT_NEAR(*shares[1], 0.01, 1e-12);
  // 1500 pixels: ceil(1.5) = 2 and ceil(15) = 15 pixels.
  std::vector<float> uneven(1500, 0.25f);
  shares = WorstErrorShares(&uneven);
  EXPECT_NEAR(*shares[0], 2.0 / 1500, 1e-12);
  EXPECT_NEAR(*shares[1], 15.0 / 1500, 1e-12);
  // Two levels: 1000 errors of 1 and 9000 of 0.1 (total 1900); the worst 10 carry 10, the worst
  // 100 carry 100.
  std::vector<float> levels(10000, 0.1f);
  for (int i = 0; i < 1000; ++i) levels[size_t(i) * 10 + 3] = 1;
  shares = WorstErrorShares(&levels);
  EXPECT_NEAR(*shares[0], 10.0 / (1000 + 9000 * double(0.1f)), 1e-9);
  EXPECT_NEAR(*shares[1], 100.0 / (1000 + 9000 * double(0.1f)), 1e-9);
  std::vector<float> empty, zero(10, 0.0f), bad = {1.0f, NAN};
  EXPECT_FALSE(WorstErrorShares(&empty)[0].has_value());
  EXPECT_FALSE(WorstErrorShares(&zero)[1].has_value());
  EXPECT_FALSE(WorstErrorShares(&bad)[0].has_value());
}

TEST(WorstPixels, ScoreImageRanksTheWorstPixelsAndReportsTheirShare) {
  // 40 x 40 evaluated pixels at 0.5; the render is off by 0.01 everywhere, by 0.3 at (7, 9) and by
  // 0.2 at (30, 2) (one channel each). Pixel errors: 3e-4 uniformly, 0.09 + 2e-4, 0.04 + 2e-4.
  const int size = 40;
  const Image photo(size, size, 3, 0.5f);
  Image render(size, size, 3, 0.51f);
  render.at(7, 9, 1) = 0.8f;
  render.at(30, 2, 2) = 0.7f;
  const Image mask = Square(size, 0, 0, size);
  const ImageScore s = ScoreImage(photo, render, mask, nullptr, std::nullopt, {});
  ASSERT_EQ(s.worst_pixels.size(), size_t(kWorstPixelsListed));
  EXPECT_EQ(s.worst_pixels[0].x, 7);
  EXPECT_EQ(s.worst_pixels[0].y, 9);
  EXPECT_EQ(s.worst_pixels[0].render[1], 0.8f);
  EXPECT_EQ(s.worst_pixels[0].photo[1], 0.5f);
  EXPECT_EQ(s.worst_pixels[1].x, 30);
  EXPECT_EQ(s.worst_pixels[1].y, 2);
  // Then equal errors in row-major order: (0, 0), (1, 0), ...
  EXPECT_EQ(s.worst_pixels[2].x, 0);
  EXPECT_EQ(s.worst_pixels[2].y, 0);
  EXPECT_EQ(s.worst_pixels[3].x, 1);
  // 0.1 % of 1600 pixels is 2: the two outliers. Float inputs make the errors inexact; 1e-5
  // relative covers float rounding of 0.51 - 0.5 (~2e-6 relative in its square).
  auto sq = [](double v) { return v * v; };
  const double e_uniform = 3 * sq(double(0.51f) - 0.5);
  const double e1 = sq(double(0.8f) - 0.5) + 2 * sq(double(0.51f) - 0.5);
  const double e2 = sq(double(0.7f) - 0.5) + 2 * sq(double(0.51f) - 0.5);
  const double total = e1 + e2 + 1598 * e_uniform;
  EXPECT_NEAR(*s.worst_share[0], (e1 + e2) / total, 1e-5 * (e1 + e2) / total);
  // 1 % is 16 pixels: the outliers and 14 uniform ones.
  EXPECT_NEAR(*s.worst_share[1], (e1 + e2 + 14 * e_uniform) / total, 1e-5);
  EXPECT_EQ(s.pixel_errors.size(), 1600u);
}

}  // namespace
}  // namespace reflcap::validate
