#pragma once
// Image metrics of `reflcap validate`: a re-render r against a photograph p, on the object pixels
// only, raw and after a per-channel least-squares scale, overall and by region, and the PSNR that
// the capture's own noise allows. Definitions (README.md, "reflcap validate", states them too):
//
// Evaluated pixels. E = erode(render mask AND capture mask, kErodePx), where the capture mask is
// the photograph's silhouette mask when the capture has one (masks/{camera}_{angle:03d}.png of
// synthetic and Blender captures, normal_map.mask of normal-map captures) — so a silhouette pixel
// that the photograph's pixel filter or a misaligned mesh makes partly background is never
// scored — minus pixels where the photograph is not finite or has a channel at or above its
// images[].saturation. Erosion is by a disc: a pixel stays when every pixel within Euclidean
// distance kErodePx of it (outside the image counts as background) is in the mask.
//
// Peak P: the largest photograph value over E and the three channels (per image).
// HDR PSNR = 10 log10(P² / MSE), MSE over E and the three channels; capped at kMaxPsnrDb (a
// perfect match reports the cap, never Inf). Relative RMSE = sqrt(Σ(r - p)² / Σ p²).
// Tone map (SSIM and figures): t(x) = (y / (1 + y))^(1/2.2), y = max(x, 0) / m, m = the mean of the
// photograph over E and channels — the same t, with the photograph's m, for both images.
// SSIM (Wang, Bovik, Sheikh, Simoncelli 2004) on t(p) and t(r) per channel: 11x11 Gaussian window,
// σ = 1.5 px, C1 = (0.01 L)², C2 = (0.03 L)², L = 1, with window statistics restricted to E
// (Gaussian weights renormalised over the window's pixels in E, so background never enters),
// averaged over E and the three channels.
// Scaled variant (Stanford-ORB): r is first multiplied per channel by s_c = Σ_E p_c r_c / Σ_E r_c²
// (1 when Σ r_c² = 0), which removes any global exposure / albedo-scale error; same metrics.
// Regions (each within E), from the render's aux buffers (reference_renderer.h):
//   shadow_edge     within kShadowEdgePx (Euclidean) of a cast-shadow boundary: a pair of
//                   4-neighbouring object pixels of which one is cast-shadowed and the other lit
//                   (cos θi > 0, not shadowed)
//   high_curvature  aux curvature (scale-free, 1 on a sphere) > kHighCurvature
//   grazing         cos θi < kGrazingCos or cos θo < kGrazingCos (includes pixels facing away
//                   from the light)
//   elsewhere       none of the three above; a pixel may be in several of the first three.
// Noise bound: with the capture's noise model (synthetic ground_truth.noise) the variance of a
// photograph value whose noise-free value is v is σ_p² max(v, 0) + σ_r²; using the render as v,
// PSNR_bound = 10 log10(P² / mean variance over E and channels) — what a perfect re-render scores
// on average.
// Pooling over images: squared errors are divided by their own image's P² and pooled over all
// evaluated pixels of all images (PSNR = -10 log10(Σ e²/P² / N)), so each image weighs by its
// pixel count and one image gives its own PSNR; relative RMSE pools Σ(r - p)² and Σ p²; SSIM
// averages over all evaluated pixels; the bound pools variance / P².
//
// PSNR-L (the LDR PSNR of Stanford-ORB, Kuang et al. 2023): per image, q99 = the photograph's 99th
// percentile over E and the three channels (nearest rank: the ceil(0.99 M)-th smallest of the
// M = 3 |E| values); both images map through L(x) = sRGB(clip(x / q99, 0, 1)), sRGB the piecewise
// OETF of IEC 61966-2-1 (12.92 x for x <= 0.0031308, else 1.055 x^(1/2.4) - 0.055); PSNR-L =
// 10 log10(1 / MSE) over E and RGB, capped like the HDR PSNR. An image whose q99 is not a positive
// finite number (an all-black photograph) has no PSNR-L: its values are left out of every PSNR-L
// (null when nothing is left). Pooled over images (and regions) as the mean of the LDR squared
// errors over all pixel channels of the images that have one: LDR values are already in [0, 1], so
// no further normalisation. The scaled variant maps s_c r (the same q99).
// Worst-pixel share: with the pixel error e = Σ_c (r - p)² (raw render), the share of Σ e over E
// carried by the K = ceil(f |E|) pixels of largest e, f = 0.1 % and 1 %. Pooled over images, e is
// divided by its own image's P² first (as PSNR pools), so the overall share is that of the error
// behind the pooled PSNR; within one image P² cancels. null when Σ e is 0 or not finite.
#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "engine/image/image.h"
#include "engine/image/ldr.h"

namespace reflcap::validate {

// Erosion of the evaluation mask, px: the silhouette band where a photograph mixes object and
// background (pixel filter up to ~1.5 px, calibration error) stays out.
constexpr double kErodePx = 2;
// Distance to a cast-shadow boundary, px, within which a pixel counts as shadow_edge: a soft
// (area-light) penumbra or a shadow shifted by a pixel of calibration error lies in it.
constexpr double kShadowEdgePx = 3;
// cos θ below which a direction is grazing (75.5 degrees).
constexpr double kGrazingCos = 0.25;
// Scale-free curvature above which a pixel is high_curvature: a radius of curvature below a
// quarter of the object's size (a sphere reads 1).
constexpr double kHighCurvature = 4;
// PSNR reported for an exact match (and the largest ever reported): float32 rounding of values
// near the peak limits any meaningful HDR PSNR to about 20 log10(2^24) = 144 dB.
constexpr double kMaxPsnrDb = 150;
// Tone-map gamma.
constexpr double kToneMapGamma = 2.2;
// SSIM constants (Wang et al. 2004), for images in [0, L], L = 1.
constexpr int kSsimRadius = 5;          // 11x11 window
constexpr double kSsimSigma = 1.5;      // px
constexpr double kSsimK1 = 0.01, kSsimK2 = 0.03;

// The percentile of the photograph that PSNR-L maps to white.
constexpr double kLdrWhitePercentile = 0.99;
// Worst-pixel shares: the worst kWorstPerMille[k] / 1000 of the evaluated pixels (0.1 %, 1 %).
constexpr int kWorstShareCount = 2;
constexpr int kWorstPerMille[kWorstShareCount] = {1, 10};
// Worst pixels kept per image and listed in the report (overall): enough to see whether the worst
// error sits in one spot, one image or one region, few enough for a table.
constexpr int kWorstPixelsListed = 20;

enum Region : int { kShadowEdge = 0, kHighCurvatureRegion, kGrazing, kElsewhere, kRegionCount };
// "shadow_edge", "high_curvature", "grazing", "elsewhere".
const char* RegionName(int region);

// Mask helpers: 1-channel images, a pixel is "in" when > 0.5; results hold 0 or 1.
Image ErodeMask(const Image& mask, double radius_px);
Image DilateMask(const Image& mask, double radius_px);
// Channel 0 of `image` thresholded at 0.5 (any channel count).
Image BinaryMask(const Image& image);

// Photon + read noise of a photograph: var(v) = photon_sigma_at_1² max(v, 0) + read_sigma².
struct NoiseModel {
  double photon_sigma_at_1 = 0;
  double read_sigma = 0;
  double Variance(double v) const;
};
// ground_truth.noise of a capture's ground_truth block (compact JSON text, "" when absent);
// nullopt when absent or malformed.
std::optional<NoiseModel> NoiseModelFromGroundTruth(const std::string& ground_truth_json);

// Sums from which every metric derives; additive over pixels and images.
struct ErrorSums {
  double pixels = 0;               // evaluated pixels
  double values = 0;               // pixel channels (3 per pixel)
  double sse = 0;                  // Σ (r - p)²
  double sse_over_peak2 = 0;       // Σ (r - p)² / P²  (P of each value's own image)
  double photo_sq = 0;             // Σ p²
  double noise_var_over_peak2 = 0; // Σ var(r) / P²   (0 when no noise model)
  double ssim_sum = 0;             // Σ over pixels of the SSIM averaged over channels
  double ldr_values = 0;           // pixel channels of images that have a PSNR-L
  double sse_ldr = 0;              // Σ (L(r) - L(p))² over those (PSNR-L)

  void Add(const ErrorSums& other);
  // nullopt when there are no values; capped at kMaxPsnrDb.
  std::optional<double> PsnrDb() const;
  // nullopt when Σ p² = 0 and the error is not 0.
  std::optional<double> RelRmse() const;
  std::optional<double> Ssim() const;
  std::optional<double> NoiseBoundDb() const;  // needs noise_var_over_peak2 > 0 or caps
  // 10 log10(1 / mean (L(r) - L(p))²); nullopt when no value has a PSNR-L; capped at kMaxPsnrDb.
  std::optional<double> PsnrLDb() const;
};

// The sRGB OETF (IEC 61966-2-1) of a linear value x in [0, 1]; linear branch for x <= 0.0031308.
// In float: display values need no more (errors ~1e-7 put a floor near 140 dB under PSNR-L, above
// any real score), and powf costs half of pow (PSNR-L encodes 9 values per pixel).
float SrgbEncode(float x);
// L(x) of PSNR-L: SrgbEncode(clip(x inv_white, 0, 1)); NaN maps to 0 (as ToneMap does).
// engine/image/ldr.h, shared with the render's pixel-footprint evidence.
using ::reflcap::LdrValue;
// The nearest-rank percentile of *values (engine/image/ldr.h).
using ::reflcap::NearestRankPercentile;
// Shares of Σ errors carried by the ceil(kWorstPerMille[k] / 1000 · n) largest of the n errors
// (nth_element; reorders *errors). nullopt when n = 0 or Σ errors is 0 or not finite.
std::array<std::optional<double>, kWorstShareCount> WorstErrorShares(std::vector<float>* errors);

// The error maps of the figures show |r - p| / P averaged over RGB ("map error"). All of a
// report's maps share one colour scale, chosen from this error over every evaluated pixel of every
// selected image: each image counts its pixels into a log-spaced histogram (integer counts, so the
// pooled histogram, and the scale, do not depend on the thread count), and the pooled quantile is
// read off it as the upper edge of the bin that holds it (never below the exact quantile; above it
// by at most one bin, a factor 10^(1/kMapErrorBinsPerDecade)).
// Bins: kMapErrorBinsPerDecade per decade over [kMapErrorMin, kMapErrorMin 10^kMapErrorDecades);
// the first bin also holds smaller values (0 included), the last larger ones.
constexpr int kMapErrorBinsPerDecade = 50;  // 4.7 % wide: finer than the 1-2-2.5-5 rounding after
constexpr double kMapErrorMin = 1e-6;       // 1 ppm of the peak: below any photograph's noise
constexpr int kMapErrorDecades = 8;         // up to 100x the peak: any render that is not garbage
// The quantile of the map error that the shared scale covers (before rounding up, NiceCeil).
constexpr double kMapErrorScaleQuantile = 0.99;

struct MapErrorHistogram {
  std::vector<uint64_t> counts;  // empty until the first Add
  void Add(double map_error);
  void Merge(const MapErrorHistogram& other);
  uint64_t Total() const;
  // Upper edge of the bin holding the nearest-rank q-quantile; nullopt when empty.
  std::optional<double> Quantile(double q) const;
};

// One evaluated pixel of an image and its error, for the worst-pixels table.
struct WorstPixel {
  int x = 0, y = 0;
  std::array<float, 3> photo{}, render{};
  uint8_t region_bits = 0;      // 1 << Region; 0 when the render has no aux buffers
  double error = 0;             // Σ_c (r - p)²
  double error_over_peak2 = 0;  // error / P² (the ranking key, pooled over images)
};

// What one photograph scores.
struct ImageScore {
  double peak = 0;                  // P
  double tone_mean = 0;             // m of the tone map
  std::array<double, 3> scale{};    // least-squares s_c
  std::optional<double> q99;        // PSNR-L white (photograph's 99th percentile); none: no PSNR-L
  size_t excluded_invalid = 0;      // geometric-mask pixels dropped as saturated / non-finite
  ErrorSums raw, scaled;
  std::array<ErrorSums, kRegionCount> regions;  // raw
  bool has_regions = false;
  bool has_noise = false;
  // Worst-pixel shares of this image (kWorstPerMille order).
  std::array<std::optional<double>, kWorstShareCount> worst_share;
  // e / P² of every evaluated pixel (order unspecified), for the shares pooled over images.
  std::vector<float> pixel_errors;
  // The (up to) kWorstPixelsListed pixels of largest error > 0, worst first (ties: row-major).
  std::vector<WorstPixel> worst_pixels;
  // The map error of every evaluated pixel (always filled), for the shared error-map scale.
  MapErrorHistogram map_error;
  // Figure data when requested (else empty): tone-mapped photograph and render (3 channels, the
  // whole image), and the error |r - p| / P averaged over channels (1 channel; -1 outside E).
  Image photo_tm, render_tm, error;
  // Region bits per pixel (1 << Region), 0 outside E; when requested and aux is given.
  std::vector<uint8_t> region_bits;
};

struct ScoreOptions {
  double erode_px = kErodePx;
  double shadow_edge_px = kShadowEdgePx;
  double grazing_cos = kGrazingCos;
  double high_curvature = kHighCurvature;
  bool keep_figure_data = false;
};

// The evaluation mask E: erode(geometric_mask, erode_px) minus pixels of `photo` that are not
// finite or have a channel >= saturation (when saturation > 0). `excluded` (optional) receives how
// many eroded-mask pixels were dropped that way.
Image EvaluationMask(const Image& geometric_mask, const Image& photo, double saturation,
                     double erode_px, size_t* excluded);

// Region bits (1 << Region) of the pixels in `eval_mask`, from aux buffers with the channels of
// render::AuxChannel.
std::vector<uint8_t> LabelRegions(const Image& aux, const Image& eval_mask,
                                  const ScoreOptions& options);

// Mean SSIM over `eval_mask` of two tone-mapped 3-channel images (definition above); returns the
// per-pixel sum (mean over channels), to be divided by the pixel count. `ssim_map` (optional,
// 1 channel) receives the per-pixel value.
double SsimSum(const Image& a, const Image& b, const Image& eval_mask, Image* ssim_map = nullptr);

// The tone map t(x) with 1/m = inv_mean.
float ToneMap(float x, double inv_mean);

// Scores `render` against `photo` on `eval_mask` (from EvaluationMask). aux (optional) gives the
// regions; noise (optional) the bound. Images must have the same size (checked).
ImageScore ScoreImage(const Image& photo, const Image& render, const Image& eval_mask,
                      const Image* aux, const std::optional<NoiseModel>& noise,
                      const ScoreOptions& options);

}  // namespace reflcap::validate
