// Image metrics of `reflcap validate` (definitions in metrics.h).
#include "render/validate/metrics.h"

#include <algorithm>
#include <cmath>
#include <functional>

#include <nlohmann/json.hpp>

#include "engine/core/check.h"
#include "engine/image/srgb.h"
#include "render/reference/reference_renderer.h"

namespace reflcap::validate {
namespace {

bool In(const Image& mask, int x, int y) { return mask.at(x, y, 0) > 0.5f; }

// Offsets of the disc of radius r (Euclidean, centre included).
std::vector<std::pair<int, int>> Disc(double radius_px) {
  std::vector<std::pair<int, int>> offsets;
  const int r = int(std::floor(radius_px));
  for (int dy = -r; dy <= r; ++dy) {
    for (int dx = -r; dx <= r; ++dx) {
      if (dx * dx + dy * dy <= radius_px * radius_px) offsets.push_back({dx, dy});
    }
  }
  return offsets;
}

// -10 log10(x), capped at kMaxPsnrDb (x = 0 gives the cap).
double CappedDb(double mse_over_peak2) {
  if (!(mse_over_peak2 > 0)) return kMaxPsnrDb;
  return std::min(kMaxPsnrDb, -10 * std::log10(mse_over_peak2));
}

// Separable Gaussian blur (zero outside the image) of a width x height scalar field into `out`,
// with `tmp` (same size) as scratch. Each output value is the sum over the kernel taps that fall
// inside the image, added in tap order starting from 0 — the loops run over a row per tap so the
// compiler vectorises across pixels, which changes no value's operations.
void Blur(const double* in, int width, int height, const std::vector<double>& kernel,
          double* tmp, double* out) {
  const int r = int(kernel.size() / 2);
  for (int y = 0; y < height; ++y) {
    const double* row = in + size_t(y) * width;
    double* t = tmp + size_t(y) * width;
    std::fill(t, t + width, 0.0);
    for (int k = -r; k <= r; ++k) {
      const double weight = kernel[k + r];
      const int x0 = std::max(0, -k), x1 = std::min(width, width - k);
      for (int x = x0; x < x1; ++x) t[x] += weight * row[x + k];
    }
  }
  for (int y = 0; y < height; ++y) {
    double* o = out + size_t(y) * width;
    std::fill(o, o + width, 0.0);
    for (int k = -r; k <= r; ++k) {
      const int yy = y + k;
      if (yy < 0 || yy >= height) continue;
      const double weight = kernel[k + r];
      const double* t = tmp + size_t(yy) * width;
      for (int x = 0; x < width; ++x) o[x] += weight * t[x];
    }
  }
}

std::vector<double> GaussianKernel() {
  std::vector<double> k(2 * kSsimRadius + 1);
  double sum = 0;
  for (int i = -kSsimRadius; i <= kSsimRadius; ++i) {
    k[i + kSsimRadius] = std::exp(-0.5 * i * i / (kSsimSigma * kSsimSigma));
    sum += k[i + kSsimRadius];
  }
  for (double& v : k) v /= sum;
  return k;
}

}  // namespace

const char* RegionName(int region) {
  switch (region) {
    case kShadowEdge: return "shadow_edge";
    case kHighCurvatureRegion: return "high_curvature";
    case kGrazing: return "grazing";
    default: return "elsewhere";
  }
}

Image BinaryMask(const Image& image) {
  Image out(image.width, image.height, 1, 0.0f);
  for (size_t i = 0; i < image.PixelCount(); ++i) {
    out.data[i] = image.data[i * image.channels] > 0.5f ? 1.0f : 0.0f;
  }
  return out;
}

Image ErodeMask(const Image& mask, double radius_px) {
  const auto disc = Disc(radius_px);
  Image out(mask.width, mask.height, 1, 0.0f);
  for (int y = 0; y < mask.height; ++y) {
    for (int x = 0; x < mask.width; ++x) {
      bool keep = In(mask, x, y);
      for (size_t i = 0; keep && i < disc.size(); ++i) {
        const int xx = x + disc[i].first, yy = y + disc[i].second;
        keep = xx >= 0 && yy >= 0 && xx < mask.width && yy < mask.height && In(mask, xx, yy);
      }
      out.at(x, y) = keep ? 1.0f : 0.0f;
    }
  }
  return out;
}

Image DilateMask(const Image& mask, double radius_px) {
  const auto disc = Disc(radius_px);
  Image out(mask.width, mask.height, 1, 0.0f);
  for (int y = 0; y < mask.height; ++y) {
    for (int x = 0; x < mask.width; ++x) {
      if (!In(mask, x, y)) continue;
      for (const auto& [dx, dy] : disc) {
        const int xx = x + dx, yy = y + dy;
        if (xx >= 0 && yy >= 0 && xx < mask.width && yy < mask.height) out.at(xx, yy) = 1;
      }
    }
  }
  return out;
}

double NoiseModel::Variance(double v) const {
  return photon_sigma_at_1 * photon_sigma_at_1 * std::max(v, 0.0) + read_sigma * read_sigma;
}

std::optional<NoiseModel> NoiseModelFromGroundTruth(const std::string& ground_truth_json) {
  if (ground_truth_json.empty()) return std::nullopt;
  const nlohmann::json truth = nlohmann::json::parse(ground_truth_json, nullptr, false);
  if (truth.is_discarded() || !truth.is_object()) return std::nullopt;
  auto it = truth.find("noise");
  if (it == truth.end() || !it->is_object()) return std::nullopt;
  auto photon = it->find("photon_sigma_at_1");
  auto read = it->find("read_sigma");
  if (photon == it->end() || read == it->end() || !photon->is_number() || !read->is_number()) {
    return std::nullopt;
  }
  NoiseModel model{photon->get<double>(), read->get<double>()};
  if (!(model.photon_sigma_at_1 >= 0) || !(model.read_sigma >= 0)) return std::nullopt;
  return model;
}

void ErrorSums::Add(const ErrorSums& o) {
  pixels += o.pixels;
  values += o.values;
  sse += o.sse;
  sse_over_peak2 += o.sse_over_peak2;
  photo_sq += o.photo_sq;
  noise_var_over_peak2 += o.noise_var_over_peak2;
  ssim_sum += o.ssim_sum;
  ldr_values += o.ldr_values;
  sse_ldr += o.sse_ldr;
}

std::optional<double> ErrorSums::PsnrDb() const {
  if (!(values > 0)) return std::nullopt;
  return CappedDb(sse_over_peak2 / values);
}

std::optional<double> ErrorSums::RelRmse() const {
  if (!(values > 0)) return std::nullopt;
  if (sse == 0) return 0.0;
  if (!(photo_sq > 0)) return std::nullopt;
  return std::sqrt(sse / photo_sq);
}

std::optional<double> ErrorSums::Ssim() const {
  if (!(pixels > 0)) return std::nullopt;
  return ssim_sum / pixels;
}

std::optional<double> ErrorSums::NoiseBoundDb() const {
  if (!(values > 0)) return std::nullopt;
  return CappedDb(noise_var_over_peak2 / values);
}

std::optional<double> ErrorSums::PsnrLDb() const {
  if (!(ldr_values > 0)) return std::nullopt;
  return CappedDb(sse_ldr / ldr_values);
}

float SrgbEncode(float x) { return LinearToSrgb(x); }

std::array<std::optional<double>, kWorstShareCount> WorstErrorShares(std::vector<float>* errors) {
  std::array<std::optional<double>, kWorstShareCount> shares;
  const size_t n = errors->size();
  double total = 0;
  for (float e : *errors) total += e;
  if (n == 0 || !(total > 0) || !std::isfinite(total)) return shares;
  // Largest first: the largest fraction partitions everything, each smaller one only its prefix.
  size_t end = n;
  for (int k = kWorstShareCount - 1; k >= 0; --k) {
    const size_t count = (n * size_t(kWorstPerMille[k]) + 999) / 1000;  // ceil, >= 1
    std::nth_element(errors->begin(), errors->begin() + std::ptrdiff_t(count - 1),
                     errors->begin() + std::ptrdiff_t(end), std::greater<float>());
    double worst = 0;
    for (size_t i = 0; i < count; ++i) worst += (*errors)[i];
    shares[size_t(k)] = std::min(1.0, worst / total);
    end = count;
  }
  return shares;
}

Image EvaluationMask(const Image& geometric_mask, const Image& photo, double saturation,
                     double erode_px, size_t* excluded) {
  REFLCAP_CHECK(geometric_mask.width == photo.width && geometric_mask.height == photo.height);
  Image mask = ErodeMask(geometric_mask, erode_px);
  size_t dropped = 0;
  for (int y = 0; y < mask.height; ++y) {
    for (int x = 0; x < mask.width; ++x) {
      if (!In(mask, x, y)) continue;
      bool valid = true;
      for (int c = 0; c < photo.channels; ++c) {
        const float v = photo.at(x, y, c);
        if (!std::isfinite(v) || (saturation > 0 && v >= saturation)) valid = false;
      }
      if (!valid) {
        mask.at(x, y) = 0;
        ++dropped;
      }
    }
  }
  if (excluded) *excluded = dropped;
  return mask;
}

std::vector<uint8_t> LabelRegions(const Image& aux, const Image& eval_mask,
                                  const ScoreOptions& options) {
  using render::kAuxCastShadow;
  using render::kAuxCosThetaI;
  using render::kAuxCosThetaO;
  using render::kAuxCurvature;
  using render::kAuxMask;
  REFLCAP_CHECK(aux.channels == render::kAuxChannelCount);
  REFLCAP_CHECK(aux.width == eval_mask.width && aux.height == eval_mask.height);
  const int w = aux.width, h = aux.height;
  // -1 background, 0 facing away from the light, 1 lit, 2 cast-shadowed.
  auto state = [&](int x, int y) {
    const float* a = aux.pixel(x, y);
    if (!(a[kAuxMask] > 0.5f)) return -1;
    if (a[kAuxCastShadow] > 0.5f) return 2;
    return a[kAuxCosThetaI] > 0 ? 1 : 0;
  };
  Image boundary(w, h, 1, 0.0f);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const int s = state(x, y);
      if (s < 1) continue;
      const int nb[4][2] = {{x + 1, y}, {x - 1, y}, {x, y + 1}, {x, y - 1}};
      for (const auto& q : nb) {
        if (q[0] < 0 || q[1] < 0 || q[0] >= w || q[1] >= h) continue;
        const int t = state(q[0], q[1]);
        if ((s == 1 && t == 2) || (s == 2 && t == 1)) boundary.at(x, y) = 1;
      }
    }
  }
  const Image near_edge = DilateMask(boundary, options.shadow_edge_px);
  std::vector<uint8_t> bits(size_t(w) * h, 0);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      if (!In(eval_mask, x, y)) continue;
      const float* a = aux.pixel(x, y);
      uint8_t b = 0;
      if (near_edge.at(x, y) > 0.5f) b |= 1u << kShadowEdge;
      if (a[kAuxCurvature] > options.high_curvature) b |= 1u << kHighCurvatureRegion;
      if (a[kAuxCosThetaI] < options.grazing_cos || a[kAuxCosThetaO] < options.grazing_cos) {
        b |= 1u << kGrazing;
      }
      if (b == 0) b = 1u << kElsewhere;
      bits[size_t(y) * w + x] = b;
    }
  }
  return bits;
}

float ToneMap(float x, double inv_mean) {
  const double y = std::max(0.0, double(x)) * inv_mean;
  if (!std::isfinite(y)) return std::isnan(y) ? 0.0f : 1.0f;
  return float(std::pow(y / (1 + y), 1 / kToneMapGamma));
}

namespace {

// SsimSum of `a` against each of `bs` (sums[j] for bs[j]; ssim_maps[j] optional, may be null):
// what a and the mask contribute (their moments and blurs) is computed once for all of them.
void SsimSums(const Image& a, const std::vector<const Image*>& bs, const Image& eval_mask,
              double* sums, const std::vector<Image*>& ssim_maps) {
  REFLCAP_CHECK(eval_mask.width == a.width && eval_mask.height == a.height);
  for (size_t j = 0; j < bs.size(); ++j) {
    const Image& b = *bs[j];
    REFLCAP_CHECK(a.width == b.width && a.height == b.height && a.channels == b.channels);
    if (ssim_maps[j]) *ssim_maps[j] = Image(a.width, a.height, 1, 0.0f);
    sums[j] = 0;
  }
  // Work on the bounding box of the evaluated pixels: windows only use evaluated pixels, so
  // nothing outside it matters (and objects often fill a tenth of the frame).
  int x0 = a.width, y0 = a.height, x1 = -1, y1 = -1;
  for (int y = 0; y < a.height; ++y) {
    for (int x = 0; x < a.width; ++x) {
      if (!(eval_mask.at(x, y, 0) > 0.5f)) continue;
      x0 = std::min(x0, x), x1 = std::max(x1, x), y0 = std::min(y0, y), y1 = std::max(y1, y);
    }
  }
  if (x1 < 0) return;
  const int w = x1 - x0 + 1, h = y1 - y0 + 1;
  const size_t n = size_t(w) * h;
  auto full = [&](size_t i) { return (size_t(y0) + i / size_t(w)) * a.width + x0 + i % size_t(w); };
  const std::vector<double> kernel = GaussianKernel();
  std::vector<double> weight(n), weight_sum(n), tmp(n);
  for (size_t i = 0; i < n; ++i) weight[i] = eval_mask.data[full(i) * eval_mask.channels] > 0.5f ? 1 : 0;
  Blur(weight.data(), w, h, kernel, tmp.data(), weight_sum.data());
  const double c1 = kSsimK1 * kSsimK1, c2 = kSsimK2 * kSsimK2;  // L = 1
  std::vector<std::vector<double>> per_pixel(bs.size(), std::vector<double>(n, 0.0));
  std::vector<double> wa(n), wb(n), waa(n), wbb(n), wab(n);
  std::vector<double> ma(n), mb(n), maa(n), mbb(n), mab(n);
  for (int c = 0; c < a.channels; ++c) {
    for (size_t i = 0; i < n; ++i) {
      const double x = a.data[full(i) * a.channels + c];
      wa[i] = weight[i] * x;
      waa[i] = weight[i] * (x * x);
    }
    Blur(wa.data(), w, h, kernel, tmp.data(), ma.data());
    Blur(waa.data(), w, h, kernel, tmp.data(), maa.data());
    for (size_t j = 0; j < bs.size(); ++j) {
      const Image& b = *bs[j];
      for (size_t i = 0; i < n; ++i) {
        const size_t f = full(i);
        const double x = a.data[f * a.channels + c], y = b.data[f * b.channels + c];
        wb[i] = weight[i] * y;
        wbb[i] = weight[i] * (y * y);
        wab[i] = weight[i] * (x * y);
      }
      Blur(wb.data(), w, h, kernel, tmp.data(), mb.data());
      Blur(wbb.data(), w, h, kernel, tmp.data(), mbb.data());
      Blur(wab.data(), w, h, kernel, tmp.data(), mab.data());
      std::vector<double>& pp = per_pixel[j];
      for (size_t i = 0; i < n; ++i) {
        if (weight[i] == 0) continue;
        const double norm = 1 / weight_sum[i];  // > 0: the pixel itself is in the window
        const double mu_a = ma[i] * norm, mu_b = mb[i] * norm;
        const double var_a = maa[i] * norm - mu_a * mu_a, var_b = mbb[i] * norm - mu_b * mu_b;
        const double cov = mab[i] * norm - mu_a * mu_b;
        pp[i] += ((2 * mu_a * mu_b + c1) * (2 * cov + c2)) /
                 ((mu_a * mu_a + mu_b * mu_b + c1) * (var_a + var_b + c2));
      }
    }
  }
  for (size_t j = 0; j < bs.size(); ++j) {
    double sum = 0;
    for (size_t i = 0; i < n; ++i) {
      if (weight[i] == 0) continue;
      const double v = per_pixel[j][i] / a.channels;
      sum += v;
      if (ssim_maps[j]) ssim_maps[j]->data[full(i)] = float(v);
    }
    sums[j] = sum;
  }
}

}  // namespace

double SsimSum(const Image& a, const Image& b, const Image& eval_mask, Image* ssim_map) {
  double sum = 0;
  SsimSums(a, {&b}, eval_mask, &sum, {ssim_map});
  return sum;
}

void MapErrorHistogram::Add(double map_error) {
  constexpr int kBins = kMapErrorBinsPerDecade * kMapErrorDecades;
  if (counts.empty()) counts.assign(kBins, 0);
  int bin = 0;
  if (map_error > kMapErrorMin) {
    const double b = std::floor(std::log10(map_error / kMapErrorMin) * kMapErrorBinsPerDecade);
    bin = b >= kBins - 1 || !std::isfinite(b) ? kBins - 1 : int(b);  // NaN: the last bin
  }
  ++counts[size_t(bin)];
}

void MapErrorHistogram::Merge(const MapErrorHistogram& other) {
  if (other.counts.empty()) return;
  if (counts.empty()) counts.assign(other.counts.size(), 0);
  for (size_t k = 0; k < counts.size(); ++k) counts[k] += other.counts[k];
}

uint64_t MapErrorHistogram::Total() const {
  uint64_t total = 0;
  for (uint64_t c : counts) total += c;
  return total;
}

std::optional<double> MapErrorHistogram::Quantile(double q) const {
  const uint64_t total = Total();
  if (total == 0) return std::nullopt;
  // Nearest rank: the ceil(q n)-th smallest value (1-based), in [1, n]; (1 - 1e-12) as in
  // NearestRankPercentile (0.99 x 100 must not round up to the next rank).
  const uint64_t rank = std::clamp<uint64_t>(
      uint64_t(std::ceil(q * double(total) * (1 - 1e-12))), 1, total);
  uint64_t seen = 0;
  for (size_t k = 0; k < counts.size(); ++k) {
    seen += counts[k];
    if (seen >= rank) return kMapErrorMin * std::pow(10.0, double(k + 1) / kMapErrorBinsPerDecade);
  }
  return kMapErrorMin * std::pow(10.0, double(kMapErrorDecades));
}

ImageScore ScoreImage(const Image& photo, const Image& render, const Image& eval_mask,
                      const Image* aux, const std::optional<NoiseModel>& noise,
                      const ScoreOptions& options) {
  REFLCAP_CHECK(photo.channels == 3 && render.channels == 3);
  REFLCAP_CHECK(photo.width == render.width && photo.height == render.height);
  REFLCAP_CHECK(eval_mask.width == photo.width && eval_mask.height == photo.height);
  const int w = photo.width, h = photo.height;
  const size_t n = photo.PixelCount();
  std::vector<size_t> pixels;
  for (size_t i = 0; i < n; ++i) {
    if (eval_mask.data[i * eval_mask.channels] > 0.5f) pixels.push_back(i);
  }
  ImageScore score;
  score.has_noise = noise.has_value();
  double peak = 0, mean = 0;
  std::array<double, 3> pr{}, rr{};
  for (size_t i : pixels) {
    for (int c = 0; c < 3; ++c) {
      const double p = photo.data[i * 3 + c], r = render.data[i * 3 + c];
      peak = std::max(peak, p);
      mean += p;
      pr[c] += p * r;
      rr[c] += r * r;
    }
  }
  if (!pixels.empty()) mean /= double(pixels.size() * 3);
  score.peak = peak;
  score.tone_mean = mean;
  // A photograph that is nowhere positive has no peak: errors are then relative to 1.
  const double p2 = peak > 0 ? peak * peak : 1.0;
  const double inv_mean = mean > 0 ? 1 / mean : 1.0;
  for (int c = 0; c < 3; ++c) score.scale[c] = rr[c] > 0 ? pr[c] / rr[c] : 1.0;
  {
    std::vector<float> values;
    values.reserve(pixels.size() * 3);
    for (size_t i : pixels) values.insert(values.end(), &photo.data[i * 3], &photo.data[i * 3 + 3]);
    const std::optional<float> q = NearestRankPercentile(&values, kLdrWhitePercentile);
    if (q && *q > 0 && std::isfinite(*q)) score.q99 = *q;
  }
  const double inv_white = score.q99 ? 1 / *score.q99 : 0.0;
  const double ldr_values = score.q99 ? 3 : 0;

  std::vector<uint8_t> bits;
  if (aux) {
    bits = LabelRegions(*aux, eval_mask, options);
    score.has_regions = true;
  }
  score.pixel_errors.reserve(pixels.size());
  // Worst pixels: a heap of at most kWorstPixelsListed whose top is the least bad kept.
  auto worse = [](const WorstPixel& a, const WorstPixel& b) {
    if (a.error_over_peak2 != b.error_over_peak2) return a.error_over_peak2 > b.error_over_peak2;
    return a.y != b.y ? a.y < b.y : a.x < b.x;
  };
  std::vector<WorstPixel>& worst = score.worst_pixels;
  for (size_t i : pixels) {
    ErrorSums raw_px, scaled_px;
    raw_px.pixels = scaled_px.pixels = 1;
    raw_px.values = scaled_px.values = 3;
    raw_px.ldr_values = scaled_px.ldr_values = ldr_values;
    double abs_error = 0;
    for (int c = 0; c < 3; ++c) {
      const double p = photo.data[i * 3 + c], r = render.data[i * 3 + c];
      const double e = r - p, es = score.scale[c] * r - p;
      abs_error += std::abs(e);
      raw_px.sse += e * e;
      raw_px.sse_over_peak2 += e * e / p2;
      raw_px.photo_sq += p * p;
      scaled_px.sse += es * es;
      scaled_px.sse_over_peak2 += es * es / p2;
      scaled_px.photo_sq += p * p;
      if (noise) raw_px.noise_var_over_peak2 += noise->Variance(r) / p2;
      if (score.q99) {
        const double lp = LdrValue(p, inv_white);
        const double el = LdrValue(r, inv_white) - lp;
        const double els = LdrValue(score.scale[c] * r, inv_white) - lp;
        raw_px.sse_ldr += el * el;
        scaled_px.sse_ldr += els * els;
      }
    }
    score.map_error.Add(abs_error / 3 / std::sqrt(p2));
    score.raw.Add(raw_px);
    score.scaled.Add(scaled_px);
    if (aux) {
      for (int k = 0; k < kRegionCount; ++k) {
        if (bits[i] & (1u << k)) score.regions[k].Add(raw_px);
      }
    }
    score.pixel_errors.push_back(float(raw_px.sse_over_peak2));
    if (raw_px.sse > 0) {
      WorstPixel px;
      px.x = int(i % size_t(w));
      px.y = int(i / size_t(w));
      px.error = raw_px.sse;
      px.error_over_peak2 = raw_px.sse_over_peak2;
      if (worst.size() < size_t(kWorstPixelsListed) || worse(px, worst.front())) {
        for (int c = 0; c < 3; ++c) {
          px.photo[c] = photo.data[i * 3 + c];
          px.render[c] = render.data[i * 3 + c];
        }
        if (aux) px.region_bits = bits[i];
        if (worst.size() == size_t(kWorstPixelsListed)) {
          std::pop_heap(worst.begin(), worst.end(), worse);
          worst.back() = px;
        } else {
          worst.push_back(px);
        }
        std::push_heap(worst.begin(), worst.end(), worse);
      }
    }
  }
  std::sort_heap(worst.begin(), worst.end(), worse);
  // Reorders pixel_errors, which the pooled shares read in any order.
  score.worst_share = WorstErrorShares(&score.pixel_errors);

  // Tone maps: SSIM reads them only inside the bounding box of the evaluated pixels (SsimSum);
  // figures need the photograph and the render everywhere.
  int bx0 = w, by0 = h, bx1 = -1, by1 = -1;
  for (size_t i : pixels) {
    const int x = int(i % size_t(w)), y = int(i / size_t(w));
    bx0 = std::min(bx0, x), bx1 = std::max(bx1, x), by0 = std::min(by0, y), by1 = std::max(by1, y);
  }
  Image photo_tm(w, h, 3), render_tm(w, h, 3), scaled_tm(w, h, 3);
  for (int y = 0; y < h; ++y) {
    const bool in_rows = y >= by0 && y <= by1;
    if (!in_rows && !options.keep_figure_data) continue;
    for (int x = 0; x < w; ++x) {
      const bool in_box = in_rows && x >= bx0 && x <= bx1;
      if (!in_box && !options.keep_figure_data) continue;
      const size_t i = size_t(y) * w + x;
      for (int c = 0; c < 3; ++c) {
        photo_tm.data[i * 3 + c] = ToneMap(photo.data[i * 3 + c], inv_mean);
        render_tm.data[i * 3 + c] = ToneMap(render.data[i * 3 + c], inv_mean);
        if (in_box) {
          scaled_tm.data[i * 3 + c] =
              ToneMap(float(score.scale[c] * render.data[i * 3 + c]), inv_mean);
        }
      }
    }
  }
  double ssim_sums[2];
  SsimSums(photo_tm, {&render_tm, &scaled_tm}, eval_mask, ssim_sums, {nullptr, nullptr});
  score.raw.ssim_sum = ssim_sums[0];
  score.scaled.ssim_sum = ssim_sums[1];

  if (options.keep_figure_data) {
    score.error = Image(w, h, 1, -1.0f);
    for (size_t i : pixels) {
      double e = 0;
      for (int c = 0; c < 3; ++c) e += std::abs(double(render.data[i * 3 + c]) - photo.data[i * 3 + c]);
      score.error.data[i] = float(e / 3 / std::sqrt(p2));
    }
    score.photo_tm = std::move(photo_tm);
    score.render_tm = std::move(render_tm);
    score.region_bits = std::move(bits);
  }
  return score;
}

}  // namespace reflcap::validate
