// Gray code + phase-shift decoding (see decode.h).
#include "acquire/scan/decode.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <mutex>

#include "engine/core/parallel.h"
#include "engine/image/png_io.h"
#include "engine/math/types.h"

namespace reflcap::scan {

namespace {

// Floor of the per-pixel intensity noise: the quantisation of 8-bit photographs, 1/255/sqrt(12).
// Without it a noise-free (synthetic) sinusoid would claim zero phase noise and infinite weight.
constexpr double kMinIntensityNoise = 1.0 / 255.0 / 3.4641016151377544;

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

StatusOr<Image> ReadGrey(const std::string& file, int width, int height) {
  REFLCAP_ASSIGN_OR_RETURN(Image im, ReadPng(file));
  if (im.width != width || im.height != height) {
    return InvalidArgumentError(file, ": size ", im.width, "x", im.height, " differs from the camera's ",
                                width, "x", height);
  }
  if (im.channels == 1) return im;
  // Grey + alpha: the grey channel; RGB(A): the mean of the colour channels.
  const int colours = im.channels >= 3 ? 3 : 1;
  Image grey(width, height, 1);
  for (size_t i = 0; i < grey.PixelCount(); ++i) {
    float s = 0;
    for (int c = 0; c < colours; ++c) s += im.data[i * im.channels + c];
    grey.data[i] = s / colours;
  }
  return grey;
}

struct PhaseResult {
  double frac = 0;       // coordinate within the period, [0, P)
  double amplitude = 0;  // B of A + B cos(...)
  double sigma_px = 0;   // standard deviation of the coordinate, projector px
};

PhaseResult FitPhase(const std::vector<Image>& seq, size_t pixel, int period) {
  const int k_count = int(seq.size());
  double s = 0, c = 0, mean = 0;
  for (int k = 0; k < k_count; ++k) {
    const double value = seq[k].data[pixel];
    const double angle = 2 * kPi * k / k_count;
    s += value * std::sin(angle);
    c += value * std::cos(angle);
    mean += value;
  }
  mean /= k_count;
  PhaseResult r;
  double phi = std::atan2(s, c);
  if (phi < 0) phi += 2 * kPi;
  r.amplitude = 2.0 / k_count * std::sqrt(s * s + c * c);
  r.frac = phi / (2 * kPi) * period;
  if (r.frac >= period) r.frac -= period;  // phi = 2π exactly after rounding
  double residual2 = 0;
  for (int k = 0; k < k_count; ++k) {
    const double model = mean + r.amplitude * std::cos(phi - 2 * kPi * k / k_count);
    const double d = seq[k].data[pixel] - model;
    residual2 += d * d;
  }
  // Three parameters (mean, amplitude, phase) are fitted: K - 3 degrees of freedom remain.
  const double noise = k_count > 3 ? std::sqrt(residual2 / (k_count - 3)) : 0.0;
  const double sigma_i = std::max(noise, kMinIntensityNoise);
  // var(φ) = 2σ²/(K B²) for K equally spaced shifts.
  const double sigma_phi = r.amplitude > 0 ? sigma_i * std::sqrt(2.0 / k_count) / r.amplitude
                                           : std::numeric_limits<double>::infinity();
  r.sigma_px = sigma_phi * period / (2 * kPi);
  return r;
}

double Unwrap(double frac, double reference, int period) {
  return frac + period * std::round((reference - frac) / period);
}

struct AxisResult {
  PixelOutcome outcome = PixelOutcome::kDecoded;
  double x = 0, sigma = 0;
};

AxisResult DecodeAxis(const AxisPhotos& axis, size_t pixel, double contrast, int extent,
                      const DecodeOptions& options) {
  AxisResult out;
  const int bits = int(axis.gray.size());
  const int fine_period = axis.phase.begin()->first;
  // Bits whose misreading moves the code by >= P/2 (Gray bit b flips the binary value by up to
  // 2^(bits-b) - 1) must be read: their mean contrast is the low-contrast test.
  double bit_contrast = 0;
  int coarse_bits = 0;
  uint32_t gray = 0;
  for (int b = 0; b < bits; ++b) {
    const double d = double(axis.gray[b].data[pixel]) - axis.gray_inverse[b].data[pixel];
    gray = (gray << 1) | (d > 0 ? 1u : 0u);
    if ((1 << (bits - b)) > fine_period / 2) {
      bit_contrast += std::abs(d);
      ++coarse_bits;
    }
  }
  if (coarse_bits > 0 && bit_contrast / coarse_bits < options.min_bit_contrast * contrast) {
    out.outcome = PixelOutcome::kLowContrast;
    return out;
  }
  uint32_t binary = 0;
  for (int b = bits - 1; b >= 0; --b) {
    binary = (binary << 1) | (((gray >> b) & 1u) ^ (binary & 1u));
  }
  if (int64_t(binary) >= extent) {
    out.outcome = PixelOutcome::kOutOfRange;
    return out;
  }
  const double gray_x = double(binary);
  auto it = axis.phase.begin();
  const PhaseResult fine = FitPhase(it->second, pixel, fine_period);
  if (fine.amplitude < options.min_modulation * 0.5 * contrast) {
    out.outcome = PixelOutcome::kLowModulation;
    return out;
  }
  const double x = Unwrap(fine.frac, gray_x, fine_period);
  if (std::abs(x - gray_x) > options.max_gray_phase_px) {
    out.outcome = PixelOutcome::kInconsistent;
    return out;
  }
  if (axis.phase.size() > 1) {
    // Temporal unwrapping, coarse to fine: the coarsest period is absolute when it spans the
    // projector (else the Gray code unwraps it), each finer one is unwrapped by the previous. It
    // must pick the same fine fringe as the Gray code, or one of the two is wrong.
    auto coarse = axis.phase.rbegin();
    const PhaseResult c = FitPhase(coarse->second, pixel, coarse->first);
    double ref;
    if (coarse->first >= extent) {
      // One period covers the projector: the coordinate is the phase itself, wrapped half-way
      // into the unused part of the period so that x just below -0.5 is not read as ~P.
      ref = c.frac > extent - 0.5 + 0.5 * (coarse->first - extent) ? c.frac - coarse->first : c.frac;
    } else {
      ref = Unwrap(c.frac, gray_x, coarse->first);
    }
    for (++coarse; coarse != axis.phase.rend(); ++coarse) {
      const PhaseResult p = coarse->first == fine_period ? fine : FitPhase(coarse->second, pixel, coarse->first);
      ref = Unwrap(p.frac, ref, coarse->first);
    }
    if (std::abs(ref - x) > 0.5 * fine_period) {
      out.outcome = PixelOutcome::kInconsistent;
      return out;
    }
  }
  // Projector pixel centres are integers: the coded area is [-0.5, extent - 0.5].
  if (x < -0.5 || x > extent - 0.5) {
    out.outcome = PixelOutcome::kOutOfRange;
    return out;
  }
  if (!(fine.sigma_px <= options.max_sigma_px)) {
    out.outcome = PixelOutcome::kNoisy;
    return out;
  }
  out.x = x;
  out.sigma = fine.sigma_px;
  return out;
}

Status CheckSize(const Image& im, int w, int h, const char* what) {
  if (im.width != w || im.height != h || im.channels != 1) {
    return InvalidArgumentError("photograph ", what, ": ", im.width, "x", im.height, "x",
                                im.channels, " (expected ", w, "x", h, "x1 like white)");
  }
  return OkStatus();
}

}  // namespace

Status DecodeOptions::Validate() const {
  if (!(min_contrast > 0 && min_contrast < 1)) {
    return InvalidArgumentError("min_contrast must be in (0, 1), got ", min_contrast);
  }
  if (!(min_bit_contrast >= 0 && min_bit_contrast < 1)) {
    return InvalidArgumentError("min_bit_contrast must be in [0, 1), got ", min_bit_contrast);
  }
  if (!(min_modulation >= 0 && min_modulation < 1)) {
    return InvalidArgumentError("min_modulation must be in [0, 1), got ", min_modulation);
  }
  if (!(max_gray_phase_px > 0 && max_gray_phase_px < 1e6)) {
    return InvalidArgumentError("max_gray_phase_px must be positive, got ", max_gray_phase_px);
  }
  if (!(max_sigma_px > 0 && max_sigma_px < 1e6)) {
    return InvalidArgumentError("max_sigma_px must be positive, got ", max_sigma_px);
  }
  return OkStatus();
}

const char* PixelOutcomeName(PixelOutcome outcome) {
  switch (outcome) {
    case PixelOutcome::kDecoded: return "decoded";
    case PixelOutcome::kShadow: return "shadow";
    case PixelOutcome::kLowContrast: return "low_contrast";
    case PixelOutcome::kLowModulation: return "low_modulation";
    case PixelOutcome::kOutOfRange: return "out_of_range";
    case PixelOutcome::kInconsistent: return "inconsistent";
    case PixelOutcome::kNoisy: return "noisy";
  }
  return "unknown";
}

double DecodedView::Coverage() const {
  const int64_t lit = int64_t(outcome.size()) - counts[int(PixelOutcome::kShadow)];
  return lit > 0 ? double(Decoded()) / double(lit) : 0.0;
}

StatusOr<AnglePhotos> LoadAnglePhotos(const AngleImages& angle, int width, int height) {
  AnglePhotos photos;
  std::vector<std::pair<const std::string*, Image*>> jobs = {{&angle.white, &photos.white},
                                                             {&angle.black, &photos.black}};
  for (int axis = 0; axis < 2; ++axis) {
    const AxisPatterns& files = axis == 0 ? angle.col : angle.row;
    AxisPhotos& dst = axis == 0 ? photos.col : photos.row;
    dst.gray.resize(files.gray.size());
    dst.gray_inverse.resize(files.gray_inverse.size());
    for (size_t b = 0; b < files.gray.size(); ++b) {
      jobs.push_back({&files.gray[b], &dst.gray[b]});
      jobs.push_back({&files.gray_inverse[b], &dst.gray_inverse[b]});
    }
    for (const auto& [period, seq] : files.phase) {
      auto& out = dst.phase[period];
      out.resize(seq.size());
      for (size_t k = 0; k < seq.size(); ++k) jobs.push_back({&seq[k], &out[k]});
    }
  }
  std::mutex mutex;
  Status first_error;
  ParallelFor(0, int64_t(jobs.size()), 1, [&](int64_t b, int64_t e, int) {
    for (int64_t i = b; i < e; ++i) {
      auto image = ReadGrey(*jobs[i].first, width, height);
      std::lock_guard<std::mutex> lock(mutex);
      if (!image.ok()) {
        if (first_error.ok()) first_error = image.status();
        continue;
      }
      *jobs[i].second = std::move(*image);
    }
  });
  REFLCAP_RETURN_IF_ERROR(first_error);
  return photos;
}

StatusOr<DecodedView> DecodeAngle(const AnglePhotos& photos, int projector_width,
                                  int projector_height, const DecodeOptions& options) {
  REFLCAP_RETURN_IF_ERROR(options.Validate());
  const int w = photos.white.width, h = photos.white.height;
  REFLCAP_RETURN_IF_ERROR(CheckSize(photos.white, w, h, "white"));
  REFLCAP_RETURN_IF_ERROR(CheckSize(photos.black, w, h, "black"));
  for (const AxisPhotos* axis : {&photos.col, &photos.row}) {
    if (axis->gray.empty() || axis->gray.size() != axis->gray_inverse.size() || axis->phase.empty()) {
      return InvalidArgumentError("an axis needs Gray bits with inverses and a phase sequence");
    }
    for (size_t b = 0; b < axis->gray.size(); ++b) {
      REFLCAP_RETURN_IF_ERROR(CheckSize(axis->gray[b], w, h, "gray"));
      REFLCAP_RETURN_IF_ERROR(CheckSize(axis->gray_inverse[b], w, h, "gray inverse"));
    }
    for (const auto& [period, seq] : axis->phase) {
      if (seq.size() < 3) return InvalidArgumentError("a phase sequence needs >= 3 shifts");
      for (const Image& im : seq) REFLCAP_RETURN_IF_ERROR(CheckSize(im, w, h, "phase"));
    }
  }
  DecodedView view;
  view.width = w;
  view.height = h;
  const size_t n = size_t(w) * h;
  view.u.assign(n, kNaN);
  view.v.assign(n, kNaN);
  view.sigma_u.assign(n, kNaN);
  view.sigma_v.assign(n, kNaN);
  view.contrast.assign(n, 0.0f);
  view.outcome.assign(n, uint8_t(PixelOutcome::kShadow));
  ParallelFor(0, int64_t(n), 4096, [&](int64_t begin, int64_t end, int) {
    for (int64_t p = begin; p < end; ++p) {
      const double contrast = double(photos.white.data[p]) - photos.black.data[p];
      view.contrast[p] = std::isfinite(contrast) ? float(contrast) : 0.0f;
      if (!(contrast >= options.min_contrast)) continue;
      const AxisResult cu = DecodeAxis(photos.col, size_t(p), contrast, projector_width, options);
      if (cu.outcome != PixelOutcome::kDecoded) {
        view.outcome[p] = uint8_t(cu.outcome);
        continue;
      }
      const AxisResult cv = DecodeAxis(photos.row, size_t(p), contrast, projector_height, options);
      if (cv.outcome != PixelOutcome::kDecoded) {
        view.outcome[p] = uint8_t(cv.outcome);
        continue;
      }
      view.outcome[p] = uint8_t(PixelOutcome::kDecoded);
      view.u[p] = float(cu.x);
      view.v[p] = float(cv.x);
      view.sigma_u[p] = float(cu.sigma);
      view.sigma_v[p] = float(cv.sigma);
    }
  });
  for (uint8_t o : view.outcome) ++view.counts[o];
  return view;
}

}  // namespace reflcap::scan
