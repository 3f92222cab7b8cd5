// The photographs' point spread for normal-map captures (see point_spread.h).
#include "render/reference/point_spread.h"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdlib>

#include "engine/core/check.h"
#include "render/reference/evidence_photos.h"

namespace reflcap::render {
namespace {

// The Gaussian is cut at this many σ: the weight beyond is 1 % of the centre's and 0.3 % of
// the total, below the photographs' noise.
constexpr double kPsfTruncationSigmas = 3.0;

std::vector<double> GaussianTaps(double sigma_px) {
  const int radius = int(std::ceil(kPsfTruncationSigmas * sigma_px));  // >= 1 for sigma > 0
  std::vector<double> taps(size_t(2 * radius + 1));
  for (int d = -radius; d <= radius; ++d) {
    taps[size_t(d + radius)] = std::exp(-0.5 * double(d * d) / (sigma_px * sigma_px));
  }
  return taps;  // unnormalised: the normalised convolution divides by the weights it used
}

}  // namespace

StatusOr<double> ParsePsf(const std::string& text, const std::string& option) {
  if (text == "auto") return kAutoPsf;
  if (text == "none") return 0.0;
  char* end = nullptr;
  errno = 0;
  const double sigma = std::strtod(text.c_str(), &end);
  if (text.empty() || end == nullptr || *end != '\0' || errno != 0 || !std::isfinite(sigma) ||
      sigma < 0 || sigma > kMaxPsfSigmaPx) {
    return InvalidArgumentError(option, ": \"", text, "\" is not auto, none or a standard "
                                "deviation in pixels in [0, ", kMaxPsfSigmaPx, "]");
  }
  return sigma;
}

void BlurWithinMask(const Image& mask, double sigma_px, Image* pixels) {
  REFLCAP_CHECK(sigma_px > 0 && mask.channels == 1 && mask.width == pixels->width &&
                mask.height == pixels->height);
  const std::vector<double> taps = GaussianTaps(sigma_px);
  const int radius = int(taps.size() / 2);
  const int w = pixels->width, h = pixels->height, nc = pixels->channels;
  const int stride = nc + 1;  // the masked channels, then the mask's weight
  constexpr int kMaxStride = 16;  // the vertical pass sums on the stack
  REFLCAP_CHECK(stride <= kMaxStride) << nc << " channels";
  // Masked values and the mask itself, blurred along x then along y.
  std::vector<double> in(size_t(w) * size_t(h) * size_t(stride), 0.0);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      if (!(mask.at(x, y) > 0.5f)) continue;
      double* v = &in[(size_t(y) * size_t(w) + size_t(x)) * size_t(stride)];
      const float* p = pixels->pixel(x, y);
      for (int c = 0; c < nc; ++c) v[c] = p[c];
      v[nc] = 1.0;
    }
  }
  std::vector<double> across(in.size(), 0.0);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      double* out = &across[(size_t(y) * size_t(w) + size_t(x)) * size_t(stride)];
      for (int d = -radius; d <= radius; ++d) {
        const int xx = x + d;
        if (xx < 0 || xx >= w) continue;
        const double* v = &in[(size_t(y) * size_t(w) + size_t(xx)) * size_t(stride)];
        if (v[nc] == 0) continue;
        const double g = taps[size_t(d + radius)];
        for (int c = 0; c <= nc; ++c) out[c] += g * v[c];
      }
    }
  }
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      if (!(mask.at(x, y) > 0.5f)) continue;
      std::array<double, kMaxStride> sum{};
      for (int d = -radius; d <= radius; ++d) {
        const int yy = y + d;
        if (yy < 0 || yy >= h) continue;
        const double* v = &across[(size_t(yy) * size_t(w) + size_t(x)) * size_t(stride)];
        const double g = taps[size_t(d + radius)];
        for (int c = 0; c <= nc; ++c) sum[size_t(c)] += g * v[c];
      }
      // sum[nc] > 0: the pixel itself is in the mask and its own weight is 1.
      float* p = pixels->pixel(x, y);
      for (int c = 0; c < nc; ++c) p[c] = float(sum[size_t(c)] / sum[size_t(nc)]);
    }
  }
}

PsfEvidence MeasurePsfEvidence(const FittedCapture& fitted, bool cast_shadows,
                               const StrayLight* stray) {
  REFLCAP_CHECK(fitted.normal_map);
  const Capture& capture = *fitted.capture;
  PsfEvidence evidence;
  RenderOptions direct;
  direct.cast_shadows = cast_shadows;
  EvidencePhotographs photos(capture, EvidenceImages(capture, kPsfEvidenceImages));
  for (size_t k = 0; k < photos.size(); ++k) {
    const size_t index = photos.index(k);
    const CaptureImage& image = capture.images[index];
    const Camera& camera = capture.cameras[image.camera];
    StatusOr<RenderResult> rendered = RenderCaptureImage(fitted, index, direct);
    StatusOr<Image> read = photos.Take(k, rendered.status(), "point-spread evidence");
    if (!read.ok()) {
      ++evidence.skipped;
      continue;
    }
    Image& sharp = rendered->pixels;
    if (stray != nullptr) AddStrayLight(fitted, *stray, index, &sharp);
    const Image& photo = *read;
    // Σ (photo − render)² over the usable mask pixels; returns how many there were.
    auto add_error = [&](const Image& render, double* error) {
      size_t pixels = 0;
      for (int y = 0; y < camera.height; ++y) {
        for (int x = 0; x < camera.width; ++x) {
          if (!(rendered->mask.at(x, y) > 0.5f)) continue;
          const float* p = photo.pixel(x, y);
          if (!UsablePixel(p, image)) continue;
          ++pixels;
          const float* q = render.pixel(x, y);
          for (int c = 0; c < 3; ++c) *error += (double(p[c]) - q[c]) * (double(p[c]) - q[c]);
        }
      }
      return pixels;
    };
    evidence.pixels += add_error(sharp, &evidence.error_sharp);
    for (size_t k = 0; k < kPsfCandidatesPx.size(); ++k) {
      Image blurred = sharp;
      BlurWithinMask(rendered->mask, kPsfCandidatesPx[k], &blurred);
      add_error(blurred, &evidence.error[k]);
    }
    ++evidence.images;
  }
  size_t best = 0;
  for (size_t k = 1; k < kPsfCandidatesPx.size(); ++k) {
    if (evidence.error[k] < evidence.error[best]) best = k;
  }
  evidence.best_sigma_px = kPsfCandidatesPx[best];
  evidence.reduction =
      evidence.error_sharp > 0 ? 1 - evidence.error[best] / evidence.error_sharp : 0.0;
  if (evidence.images > 0 && evidence.reduction >= kMinPsfErrorReduction) {
    evidence.sigma_px = kPsfCandidatesPx[best];
  }
  return evidence;
}

}  // namespace reflcap::render
