#pragma once
// Inverse camera response from exposure brackets, per channel, with a sensor noise model.
//
// Camera model: raw = x + n with x = g · t · L (normalised so that the sensor clips at raw = 1),
// n sensor noise of variance read² + photon · x, code = round(255 · f(clip(raw, 0, 1))). We
// estimate x(code) = f⁻¹(code / 255), the inverse response, normalised so that x(255) = 1, and the
// noise (read, photon) in the same units. Codes 0 and 255 are censored (below the first rounding
// threshold / clipped) and never used as measurements.
//
// Non-parametric (Debevec & Malik, SIGGRAPH 1997): g(z) = ln x(z) minimises
//   Σ_i Σ_j w(z_ij) (g(z_ij) − ln E_i − ln t_j)² + λ Σ_z (d²g / d(ln z)²)²
// over every sampled pixel i and exposure j. The per-pixel unknowns ln E_i are eliminated in
// closed form (for fixed g the best ln E_i is a weighted mean), which leaves a quadratic in the
// 256 values of g alone: every sample adds its (≤ 16)² block to a 256 × 256 normal matrix, so
// hundreds of thousands of samples cost no more to solve than a few. The smoothness acts in
// log–log coordinates, where a gamma curve is straight. Weights follow the noise, not Debevec's
// hat: w(z) = 1 / var(ln x | z) = x² / (read² + photon · x + Δx(z)² / 12), with Δx(z) the width of
// code z's rounding bin (quantisation); the noise parameters are estimated from the differences
// between consecutive exposures of each pixel (their variance is linear in read² and photon),
// and the solve is repeated. Monotonicity is enforced by an active set of increment constraints.
// Censored and noise-floor codes stay out of the data: codes within three noise σ of the
// censoring thresholds, and codes whose signal-to-noise ratio is below 20 (there noise and the
// dark-heavy distribution of pixel values bias a code's mean radiance; such codes are
// extrapolated by the chosen model).
//
// The equal-ratio ambiguity. When every exposure ratio is a power of one ratio k (0.125 … 32 s in
// steps of 4), any ripple of ln x periodic in ln x with period ln k fits the brackets exactly as
// well as the true curve (Grossberg & Nayar, "Determining the camera response from images: what is
// knowable?", PAMI 2003): the free-form curve is then undetermined (the smoothness prior picks
// one: max |log error| 0.028 on the shared brackets). Anchors — pixels whose relative radiance is
// known, the ColorChecker's under its light (SampleSet::anchored) — break it (0.005 there), and a
// parametric family cannot follow the ripple.
//
// Parametric families ("chosen by fit"): gamma x = y^γ; offset gamma (sRGB-like); log-logistic
// x = k (y s / (1 − y s))^(1/a), s = 1 / (1 + k^a) (the inverse of a sigmoid S(x) = x^a / (x^a + k^a)
// normalised to S(1)); polynomials in log–log coordinates ln x = Σ c_k (ln y)^k; Mitsunaga–Nayar
// polynomials x = Σ_{n=1..N} c_n y^n with Σ c_n = 1 (CVPR 1999); y = code / 255. Each is fitted by
// Gauss–Newton on the same eliminated objective (the data term, same weights). Choice (`auto`):
// among the families within 1 % of the best family's χ², the one with the fewest parameters; it
// is used when its χ² is within 5 % of the free-form curve's (which also fits some aliasing between
// the rounding bins of exposures, so the true curve's χ² is a few % above it), else the free-form
// curve, when the brackets or the anchors identify it. Measured on the shared brackets: the
// log-logistic family (max |log error| 0.0009) over the anchored free-form curve (0.0053).
//
// Normalisation: x(255) = 1 is placed half a code step above where code 255 begins, which is
// measured (pixels whose shorter exposures predict their value near the clip, clipped or not:
// a probit fit) rather than extrapolated from the top codes, where data are sparse.
//
// Sampling: pixels are binned by value (the code of their longest unclipped exposure, and that
// exposure) and reservoir-sampled per bin, each photo contributing: a bin is capped at
// samples_per_bin per channel, so dark codes (most of any photograph) cannot drown the bright
// ones, and within a bin the samples are uniformly spread over every photo's pixels.
#include <array>
#include <atomic>
#include <cstdint>
#include <string>
#include <vector>

#include "acquire/radiometry/brackets.h"
#include "engine/core/status.h"

namespace reflcap::radiometry {

constexpr int kCodeCount = 256;
constexpr int kClipCode = 255;  // a clipped pixel (raw at or above the last rounding threshold)

// Sensor noise of one channel in normalised raw units (clip = 1).
struct SensorNoise {
  double read_sigma = 0;   // signal-independent standard deviation
  double photon_gain = 0;  // shot noise: variance per unit raw value
  // Variance of the raw value behind a code of inverse response x and rounding-bin width bin.
  double Variance(double x, double bin) const {
    return read_sigma * read_sigma + photon_gain * (x > 0 ? x : 0) + bin * bin / 12.0;
  }
};

// The inverse response of three channels, and their noise.
struct InverseResponse {
  std::string model;                              // "debevec", "gamma", "loglogistic", "polynomial4"...
  std::array<std::array<double, kCodeCount>, 3> log_x{};  // ln x(code); log_x[c][255] = 0
  std::array<SensorNoise, 3> noise{};
  // The codes each channel's data covered (outside: extrapolated).
  std::array<int, 3> first_code{{1, 1, 1}}, last_code{{254, 254, 254}};

  double X(int c, int code) const;
  // Width of code's rounding bin in raw units: x(code + ½) − x(code − ½), from the neighbours.
  double BinWidth(int c, int code) const;
  // Variance of the raw value behind `code` (noise + quantisation).
  double CodeVariance(int c, int code) const { return noise[c].Variance(X(c, code), BinWidth(c, code)); }
  // The raw value at the rounding threshold between codes 0 and 1 (below it: code 0).
  double BlackEdge(int c) const;
};

struct ResponseOptions {
  // "auto" (lowest BIC), "debevec", "gamma", "loglogistic", "polynomial" (best degree 2..6).
  std::string model = "auto";
  // Smoothness λ of the Debevec solve, relative to the mean data weight per code; > 0. Measured
  // max |log error| of the anchored free-form curve on the shared brackets: 0.009 at 1e-3, 0.004
  // at 0.1, 0.0055 at 1, 0.011 at 10 (the log-logistic's curvature is penalised); at 1 the
  // free-form χ² no longer follows the rounding-bin aliasing that made a true gamma curve look
  // 6.7 % worse than it (2.7 % at 1).
  double smoothness = 1;
  // Debevec prior on d²g/d(ln code)² (true) or d²g/dcode² (false, Debevec's original).
  bool log_smoothness = true;
  // Samples kept per value bin and channel, >= 16.
  int samples_per_bin = 2000;
  // Weight / noise re-estimation rounds, 1..20 (the first uses Debevec's hat weights).
  int iterations = 4;
  uint64_t seed = 1;
  Status Validate() const;
};

// Sampled pixels: each is one channel's codes through one photo's exposures.
struct ResponseSample {
  uint16_t list = 0;   // index into SampleSet::log_exposures
  uint8_t count = 0;   // exposures
  uint8_t codes[kMaxExposuresPerPhoto] = {};
  // Pixels of the photo's population this sample stands for (1 / its inclusion probability):
  // bins are capped, so statistics over the population must weight samples by it.
  float population_weight = 1;
};
// A pixel whose radiance is known up to one constant shared by every anchored sample of its
// channel (a reference chart's pixels: ρ/π · E from the chart's pose and albedos).
struct AnchoredSample {
  ResponseSample codes;
  double log_radiance = 0;  // ln of the known relative radiance
};
struct SampleSet {
  std::vector<std::vector<double>> log_exposures;  // ln exposure_s, per distinct exposure list
  std::array<std::vector<ResponseSample>, 3> samples;
  // Anchored samples tie codes of different pixels together at known, non-commensurate ratios.
  // Brackets whose exposures are all powers of one ratio k leave the response ambiguous by any
  // function periodic in ln x with period ln k (Grossberg & Nayar, PAMI 2003); a few anchored
  // radiances break that ambiguity. Empty when there is no chart.
  std::array<std::vector<AnchoredSample>, 3> anchored;
  std::vector<uint16_t> list_of_photo;  // exposure list index of every photo given to the sampler
  size_t photos = 0;  // photos sampled
  std::array<size_t, 3> candidates{};  // pixels with >= 2 unclipped, non-black codes, before capping
};

// Collects samples photo by photo. AddPhoto may run concurrently for different photos.
class ResponseSampler {
 public:
  // exposure_lists[p]: photo p's exposure times (strictly increasing).
  ResponseSampler(const ResponseOptions& options, const std::vector<std::vector<double>>& exposure_lists);
  void AddPhoto(size_t photo, const BracketImages& images);
  // Combines the photos' reservoirs (deterministically, in photo order).
  SampleSet Finish();

 private:
  struct Reservoir {
    std::vector<ResponseSample> kept;
    uint64_t seen = 0;
  };
  ResponseOptions options_;
  std::vector<uint16_t> list_of_photo_;
  std::vector<std::vector<double>> lists_;
  int per_photo_cap_ = 0;
  // [photo][channel][bin]
  std::vector<std::array<std::vector<Reservoir>, 3>> photo_bins_;
  std::array<std::vector<size_t>, 3> candidates_;
  std::atomic<size_t> photos_added_{0};
};

// One candidate model's fit.
struct ModelFit {
  std::string model;
  int parameters = 0;         // free parameters per channel
  std::array<std::vector<double>, 3> params;  // family parameters (empty for debevec)
  double chi2 = 0;            // data term, all channels (noise units)
  double bic = 0;
  bool monotone = true;
  // ln x at the measured start of code 255 (after normalisation; NaN: too few near-clip pixels,
  // the model's own extrapolation set the scale).
  std::array<double, 3> clip_log_threshold{};
  InverseResponse response;
};

struct ResponseFit {
  InverseResponse response;          // the chosen model
  std::vector<ModelFit> candidates;  // every model tried, chosen one included
  std::array<size_t, 3> samples{};
  std::array<size_t, 3> observations{};  // code measurements used (after censoring)
  std::array<size_t, 3> anchored_observations{};  // of which from anchored samples
  std::array<double, 3> reduced_chi2{};  // chosen model: χ² / degrees of freedom (≈ 1 when the
                                         // noise model describes the data)
  int iterations = 0;
  // False when every exposure ratio is a power of one ratio and no anchor was given: the free-form
  // curve is then undetermined (see SampleSet::anchored) and only competes when asked for.
  bool debevec_identified = true;
  double seconds = 0;
};

// Estimates the inverse response from samples. FailedPrecondition when a channel has no pixel
// measured in two exposures (every bracket clipped or black).
StatusOr<ResponseFit> EstimateResponse(const SampleSet& samples, const ResponseOptions& options);

// Accuracy of a response against a known inverse response (x_of_code, 256 entries, x(255) = 1),
// over codes [first, last]: per channel, "shape" errors after removing the median log ratio (the
// per-channel scale no response estimate can know without a reference) and "absolute" ones.
struct ResponseError {
  std::array<double, 3> max_abs_log{}, median_abs_log{};          // shape
  std::array<double, 3> max_abs_log_absolute{}, median_abs_log_absolute{};
  std::array<double, 3> scale{};                                  // exp(median log ratio)
  double max_over_channels = 0, median_over_channels = 0;
};
ResponseError CompareResponse(const InverseResponse& response, const std::vector<double>& x_of_code,
                              int first = 20, int last = 235);

}  // namespace reflcap::radiometry
