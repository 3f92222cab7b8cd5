#include "engine/fit/lobe_transfer.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <utility>

#include "engine/brdf/lafortune.h"
#include "engine/core/check.h"
#include "engine/core/large_buffer.h"
#include "engine/core/parallel.h"
#include "engine/fit/batched_kernel.h"
#include "engine/fit/material_clusters.h"
#include "engine/fit/problem.h"

namespace reflcap::fit {

Status LobeTransferOptions::Validate() const {
  if (radius < 1 || radius > 64) {
    return InvalidArgumentError("lobe transfer radius ", radius, " outside [1, 64] texels");
  }
  if (!(albedo_tolerance > 0 && albedo_tolerance <= 1)) {
    return InvalidArgumentError("lobe transfer albedo tolerance ", albedo_tolerance,
                                " outside (0, 1]");
  }
  if (rounds < 1 || rounds > 64) {
    return InvalidArgumentError("lobe transfer rounds ", rounds, " outside [1, 64]");
  }
  if (!(max_cost_increase >= 0 && std::isfinite(max_cost_increase))) {
    return InvalidArgumentError("lobe transfer cost increase ", max_cost_increase,
                                " must be finite and >= 0");
  }
  return OkStatus();
}

namespace {

// Below this norm an albedo is black: the relative distance of two near-black albedos measures
// noise, so the denominator never falls under it (1e-3 = 0.1 % reflectance).
constexpr double kBlackAlbedo = 1e-3;

// rho_a, rho_b: the three diffuse albedos (FitStore layout: the first floats of a texel).
double AlbedoDistance(const float* a, const float* b) {
  double diff = 0, na = 0, nb = 0;
  for (int c = 0; c < brdf::kChannels; ++c) {
    diff += (double(a[c]) - b[c]) * (double(a[c]) - b[c]);
    na += double(a[c]) * a[c];
    nb += double(b[c]) * b[c];
  }
  return std::sqrt(diff) / std::max({std::sqrt(na), std::sqrt(nb), kBlackAlbedo});
}

// A texel that fitted its own lobe, or borrowed one in an earlier round.
bool IsDonor(const FitStore& fits, size_t t) {
  return !fits.lambert_only(t) && fits.lobes() > 0 &&
         (fits.status(t) == FitStatus::kConverged || fits.donor(t) >= 0);
}

bool IsRecipient(const FitStore& fits, size_t t) {
  return fits.status(t) == FitStatus::kUnidentifiableLobe &&
         fits.samples(t) >= kMinTransferSamples && fits.lobes() > 0 && fits.lambert_only(t) &&
         fits.donor(t) < 0;
}

}  // namespace

UsableSample PrepareUsableSample(const BrdfSample& s, double min_cos_theta) {
  UsableSample u;
  double ni = 0, no = 0;
  for (int j = 0; j < 3; ++j) {
    if (!std::isfinite(s.wi[j]) || !std::isfinite(s.wo[j])) return u;
    ni += double(s.wi[j]) * s.wi[j];
    no += double(s.wo[j]) * s.wo[j];
  }
  // As PrepareTexel: shorter than kMinDirectionNorm is a zeroed record, longer is re-normalised.
  const double min_norm2 = kMinDirectionNorm * kMinDirectionNorm;
  if (ni < min_norm2 || no < min_norm2) return u;
  // One division per direction, not three (this runs for every sample of every post-fit test);
  // the products round to the same floats as the quotients but where a double lies within an
  // ulp of a float's rounding boundary (~1 in 10^9 components).
  const double inv_i = 1.0 / std::sqrt(ni), inv_o = 1.0 / std::sqrt(no);
  for (int j = 0; j < 3; ++j) {
    u.wi[j] = float(s.wi[j] * inv_i);
    u.wo[j] = float(s.wo[j] * inv_o);
  }
  u.usable = u.wi[2] >= min_cos_theta && u.wo[2] >= min_cos_theta;
  return u;
}

namespace {

// Channel c of `params` in the EvalChannel layout with the albedo slot zeroed: its lobes only
// (no term at all when `params` is null).
std::array<float, brdf::kMaxParamsPerChannel> LobeChannel(const brdf::BrdfParams* params, int c) {
  std::array<float, brdf::kMaxParamsPerChannel> channel{};
  if (params) channel = params->Channel(c);
  channel[0] = 0;  // the lobe part only
  return channel;
}

// Sample s's channel c as a weighted residual against the model `channel` (EvalChannel layout,
// `lobes` lobes): false when it is none (the sample not usable, its weight not > 0 or either
// value non-finite); else *w its weight and *e = y - f(wi, wo).
bool ChannelResidual(const BrdfSample& s, const UsableSample& u, int c, const float* channel,
                     int lobes, double* w, double* e) {
  const float weight = s.weight[c], y = s.value[c];
  if (!u.usable || !(weight > 0) || !std::isfinite(weight) || !std::isfinite(y)) return false;
  *w = weight;
  *e = double(y) - double(brdf::EvalChannel(u.wi, u.wo, channel, lobes));
  return true;
}

}  // namespace

// Per channel: the albedo re-fit with `params`' lobes fixed (no lobes when `params` is null) and
// its cost, in one pass: with e = y - lobe, S0 = sum w, S1 = sum w e, S2 = sum w e^2, the
// least-squares diffuse level is d = max(0, S1 / S0) and the cost 1/2 (S2 - 2 d S1 + d^2 S0).
double RefitAlbedoCost(const BrdfSample* samples, size_t count, const UsableSample* usable,
                       const brdf::BrdfParams* params, std::array<float, brdf::kChannels>* rho) {
  double cost = 0;
  for (int c = 0; c < brdf::kChannels; ++c) {
    const auto channel = LobeChannel(params, c);
    const int lobes = params ? params->num_lobes : 0;
    double s0 = 0, s1 = 0, s2 = 0;
    for (size_t i = 0; i < count; ++i) {
      double w, e;
      if (!ChannelResidual(samples[i], usable[i], c, channel.data(), lobes, &w, &e)) continue;
      s0 += w;
      s1 += w * e;
      s2 += w * e * e;
    }
    // No usable residual in this channel: albedo 0, no cost.
    const double diffuse = s0 > 0 ? std::max(0.0, s1 / s0) : 0.0;
    (*rho)[c] = float(diffuse * kPi);
    // Rounding can leave a tiny negative where the fit is exact; a cost is never below 0.
    cost += std::max(0.0, 0.5 * (s2 - 2 * diffuse * s1 + diffuse * diffuse * s0));
  }
  return cost;
}

void TexelResiduals::Prepare(const BrdfSample* samples, size_t count, double min_cos_theta,
                             int folds) {
  // Sized for every sample (padded) up front and filled by index; cut to the usable ones below.
  Resize((count + kLanes - 1) / kLanes * kLanes);
  size_t n = 0;
  for (size_t i = 0; i < count; ++i) {
    const BrdfSample& s = samples[i];
    const UsableSample u = PrepareUsableSample(s, min_cos_theta);
    if (!u.usable) continue;
    xx_[n] = u.wi[0] * u.wo[0];
    yy_[n] = u.wi[1] * u.wo[1];
    zz_[n] = u.wi[2] * u.wo[2];
    fold_[n] = folds > 0 ? uint8_t(PhotographFold(s.image, folds)) : 0;
    for (int c = 0; c < brdf::kChannels; ++c) {
      const float weight = s.weight[c], y = s.value[c];
      const bool valid = weight > 0 && std::isfinite(weight) && std::isfinite(y);
      y_[size_t(c)][n] = valid ? y : 0.0f;
      w_[size_t(c)][n] = valid ? weight : 0.0f;
    }
    ++n;
  }
  usable_ = n;
  // Padding: base 0 gives lobe value 0, and weight 0 adds nothing to any sum.
  const size_t padded = (n + kLanes - 1) / kLanes * kLanes;
  for (size_t i = n; i < padded; ++i) {
    xx_[i] = yy_[i] = zz_[i] = 0.0f;
    fold_[i] = 0;
    for (int c = 0; c < brdf::kChannels; ++c) y_[size_t(c)][i] = w_[size_t(c)][i] = 0.0f;
  }
  Resize(padded);
}

void TexelResiduals::Resize(size_t size) {
  xx_.resize(size);
  yy_.resize(size);
  zz_.resize(size);
  fold_.resize(size);
  for (int c = 0; c < brdf::kChannels; ++c) {
    y_[size_t(c)].resize(size);
    w_[size_t(c)].resize(size);
  }
  values_.resize(size);
}

const float* TexelResiduals::Lobes(const brdf::BrdfParams* params, int c) {
  if (params == nullptr || params->num_lobes == 0) {
    std::fill(values_.begin(), values_.end(), 0.0f);
  } else {
    const auto channel = params->Channel(c);
    EvaluateLobeSum(xx_.data(), yy_.data(), zz_.data(), padded(), channel.data(),
                    params->num_lobes, values_.data());
  }
  return values_.data();
}

const float* TexelResiduals::Model(const brdf::BrdfParams& params, int c) {
  Lobes(&params, c);
  // The diffuse term rho / pi in float plus the summed lobes (for one lobe EvalChannel's order).
  const float diffuse = params.rho_d[size_t(c)] * float(kInvPi);
  for (float& v : values_) v = diffuse + v;
  return values_.data();
}

std::array<double, brdf::kChannels> TexelResiduals::Brightest() const {
  std::array<double, brdf::kChannels> brightest{};
  for (int c = 0; c < brdf::kChannels; ++c) {
    for (size_t i = 0; i < usable_; ++i) {
      if (w_[size_t(c)][i] > 0) {
        brightest[size_t(c)] = std::max(brightest[size_t(c)], double(y_[size_t(c)][i]));
      }
    }
  }
  return brightest;
}

double RefitAlbedoCost(TexelResiduals* r, const brdf::BrdfParams* params,
                       std::array<float, brdf::kChannels>* rho) {
  double cost = 0;
  for (int c = 0; c < brdf::kChannels; ++c) {
    const float* lobe = r->Lobes(params, c);
    const float* y = r->y(c);
    const float* w = r->w(c);
    double s0 = 0, s1 = 0, s2 = 0;
    for (size_t i = 0; i < r->padded(); ++i) {
      const double e = double(y[i]) - double(lobe[i]);
      s0 += w[i];
      s1 += w[i] * e;
      s2 += w[i] * e * e;
    }
    // As the per-sample RefitAlbedoCost above.
    const double diffuse = s0 > 0 ? std::max(0.0, s1 / s0) : 0.0;
    (*rho)[c] = float(diffuse * kPi);
    cost += std::max(0.0, 0.5 * (s2 - 2 * diffuse * s1 + diffuse * diffuse * s0));
  }
  return cost;
}

// The largest value the lobes of `p` reach in channel c over the hemisphere: per lobe
// max(|Cx|, |Cy|, Cz)^n (the base's supremum over unit wi, wo with z >= 0), summed.
double LobeSupremum(const brdf::BrdfParams& p, int c) {
  double sum = 0;
  for (int k = 0; k < p.num_lobes; ++k) {
    const brdf::LobeParams& l = p.lobes[k][c];
    const double c_max = std::max({std::abs(double(l.cx)), std::abs(double(l.cy)), double(l.cz)});
    if (c_max <= 0) continue;
    // Capped as LafortuneLobe caps a value: exp of a huge argument must not overflow.
    sum += std::exp(std::min(double(l.n) * std::log(c_max), std::log(brdf::kMaxLobeValue)));
  }
  return sum;
}

bool WithinEvidence(const brdf::BrdfParams& p,
                    const std::array<double, brdf::kChannels>& brightest) {
  for (int c = 0; c < brdf::kChannels; ++c) {
    if (!(LobeSupremum(p, c) <= kMaxLobeSupremum * brightest[size_t(c)])) return false;
  }
  return true;
}

std::vector<uint32_t> LobeCandidates::Of(uint32_t t) const {
  const auto it = std::lower_bound(recipients.begin(), recipients.end(), t);
  if (it == recipients.end() || *it != t) return {};
  const size_t i = size_t(it - recipients.begin());
  return std::vector<uint32_t>(donors.begin() + offsets[i], donors.begin() + offsets[i + 1]);
}

bool LobeCandidates::AnyIn(uint64_t first, uint64_t end) const {
  const auto it = std::lower_bound(recipients.begin(), recipients.end(), first,
                                   [](uint32_t r, uint64_t v) { return uint64_t(r) < v; });
  return it != recipients.end() && uint64_t(*it) < end;
}

LobeCandidates FindLobeDonors(const TexelAtlas& atlas, const FitStore& fits,
                              const LobeTransferOptions& options, LobeTransferStats* stats,
                              const std::vector<uint8_t>* lenders) {
  REFLCAP_CHECK(fits.size() == atlas.TexelCount());
  REFLCAP_CHECK(!lenders || lenders->size() == fits.size());
  LobeCandidates candidates;
  if (!options.enabled) return candidates;
  // The donors in atlas space: the texel at each pixel that may lend (-1: none), and a
  // summed-area table of their count, so that a recipient with no donor in its window (most of
  // them from the second round on, where only the last round's borrowers lend) is passed over in
  // O(1), and one with donors reads a compact grid instead of the fit store per pixel. The
  // candidates are those of a plain scan of every window (the window relation is symmetric).
  const size_t width = size_t(atlas.width), height = size_t(atlas.height);
  // Both grids on huge pages, written before they are read (a million-texel atlas: 13 MB a
  // round; in 4 KiB pages the million fit's rounds took ~14,000 page faults here).
  // FitStore::kMaxTexels keeps texel indices within int32.
  LargeBufferVector<int32_t> donor_at(width * height);
  ParallelFill(&donor_at, -1);
  ParallelFor(0, int64_t(fits.size()), 1 << 16, [&](int64_t begin, int64_t end, int) {
    for (int64_t d = begin; d < end; ++d) {
      if ((lenders && !(*lenders)[size_t(d)]) || !IsDonor(fits, size_t(d))) continue;
      donor_at[atlas.pixel_of_texel[size_t(d)]] = int32_t(d);  // one texel per pixel: no race
    }
  });
  // count[(y + 1) * (width + 1) + x + 1] = donors in pixels [0, x] x [0, y]; row 0 and column 0
  // are 0.
  LargeBufferVector<uint32_t> count((width + 1) * (height + 1));
  std::fill(count.begin(), count.begin() + (width + 1), 0u);
  for (size_t y = 0; y < height; ++y) {
    uint32_t row = 0;
    const int32_t* src = donor_at.data() + y * width;
    const uint32_t* above = count.data() + y * (width + 1);
    uint32_t* out = count.data() + (y + 1) * (width + 1);
    out[0] = 0;
    for (size_t x = 0; x < width; ++x) {
      row += src[x] >= 0;
      out[x + 1] = above[x + 1] + row;
    }
  }
  const auto donors_in = [&](size_t x0, size_t y0, size_t x1, size_t y1) {  // inclusive bounds
    const size_t w1 = width + 1;
    return count[(y1 + 1) * w1 + x1 + 1] - count[y0 * w1 + x1 + 1] - count[(y1 + 1) * w1 + x0] +
           count[y0 * w1 + x0];
  };
  // Each block of texels collects its rows on its own; the blocks are joined in texel order, so
  // the result does not depend on which thread ran which block.
  constexpr int64_t kBlock = 4096;  // texels per block: enough work per block to amortise a task
  struct Rows {
    std::vector<uint32_t> recipients;
    std::vector<uint8_t> counts;  // candidates per recipient, <= kMaxTransferCandidates
    std::vector<uint32_t> donors;
  };
  std::vector<Rows> blocks(size_t((int64_t(fits.size()) + kBlock - 1) / kBlock));
  std::atomic<size_t> recipients{0}, no_donor{0};
  const int r = options.radius;
  ParallelFor(0, int64_t(fits.size()), kBlock, [&](int64_t begin, int64_t end, int) {
    Rows& rows = blocks[size_t(begin / kBlock)];
    std::vector<std::pair<double, uint32_t>> found;
    size_t block_recipients = 0, block_no_donor = 0;
    for (int64_t t = begin; t < end; ++t) {
      if (!IsRecipient(fits, size_t(t))) continue;
      ++block_recipients;
      const int x0 = int(atlas.pixel_of_texel[t] % uint32_t(atlas.width));
      const int y0 = int(atlas.pixel_of_texel[t] / uint32_t(atlas.width));
      const size_t xa = size_t(std::max(0, x0 - r)), xb = size_t(std::min(atlas.width - 1, x0 + r));
      const size_t ya = size_t(std::max(0, y0 - r)), yb = size_t(std::min(atlas.height - 1, y0 + r));
      found.clear();
      if (donors_in(xa, ya, xb, yb) > 0) {
        const float* albedo = fits.params(size_t(t));
        for (size_t y = ya; y <= yb; ++y) {
          const int32_t* row = donor_at.data() + y * width;
          for (size_t x = xa; x <= xb; ++x) {
            const int32_t d = row[x];
            if (d < 0) continue;
            const double distance = AlbedoDistance(albedo, fits.params(size_t(d)));
            if (distance <= options.albedo_tolerance) found.emplace_back(distance, uint32_t(d));
          }
        }
      }
      if (found.empty()) {
        ++block_no_donor;
        continue;
      }
      const size_t keep = std::min(found.size(), size_t(kMaxTransferCandidates));
      std::partial_sort(found.begin(), found.begin() + keep, found.end());
      rows.recipients.push_back(uint32_t(t));
      rows.counts.push_back(uint8_t(keep));
      for (size_t i = 0; i < keep; ++i) rows.donors.push_back(found[i].second);
    }
    recipients += block_recipients;
    no_donor += block_no_donor;
  });
  size_t total_recipients = 0, total_donors = 0;
  for (const Rows& rows : blocks) {
    total_recipients += rows.recipients.size();
    total_donors += rows.donors.size();
  }
  candidates.recipients.reserve(total_recipients);
  candidates.offsets.reserve(total_recipients + 1);
  candidates.donors.reserve(total_donors);
  for (Rows& rows : blocks) {
    candidates.recipients.insert(candidates.recipients.end(), rows.recipients.begin(),
                                 rows.recipients.end());
    for (uint8_t count : rows.counts) candidates.offsets.push_back(candidates.offsets.back() + count);
    candidates.donors.insert(candidates.donors.end(), rows.donors.begin(), rows.donors.end());
    rows = Rows{};
  }
  stats->recipients += recipients;
  stats->no_donor += no_donor;
  return candidates;
}

void ApplyLobeTransfer(const TexelSampleChunk& chunk, const LobeCandidates& candidates,
                       const LobeTransferOptions& options, double min_cos_theta, int threads,
                       FitStore* fits, LobeTransferStats* stats, std::vector<uint8_t>* borrowed) {
  if (!options.enabled) return;
  REFLCAP_CHECK(!borrowed || borrowed->size() == fits->size());
  // The rows of this chunk's recipients: [row_begin, row_end).
  const auto& rec = candidates.recipients;
  const uint64_t first = chunk.first_texel, end = first + chunk.texel_count;
  const auto less = [](uint32_t r, uint64_t v) { return uint64_t(r) < v; };
  const int64_t row_begin = std::lower_bound(rec.begin(), rec.end(), first, less) - rec.begin();
  const int64_t row_end = std::lower_bound(rec.begin(), rec.end(), end, less) - rec.begin();
  std::atomic<size_t> rejected{0}, transferred{0};
  // 16 recipients per task: each tests up to kMaxTransferCandidates lobes on all its samples.
  ParallelFor(row_begin, row_end, 16, [&](int64_t begin, int64_t stop, int) {
    TexelResiduals residuals;
    // Counted per task, added once: a shared atomic per recipient contends on many threads.
    size_t task_rejected = 0, task_transferred = 0;
    for (int64_t row = begin; row < stop; ++row) {
      const size_t t = rec[size_t(row)];
      const uint32_t i = uint32_t(t - first);
      residuals.Prepare(chunk.SamplesOf(i), chunk.SampleCount(i), min_cos_theta);
      std::array<float, brdf::kChannels> rho{};
      const double lambert_cost = RefitAlbedoCost(&residuals, nullptr, &rho);
      // The evidence bound of the texel's own fit (problem.h kMaxLobeSupremum): a lobe may rise
      // at most 10x above the brightest value the texel showed, per channel.
      const std::array<double, brdf::kChannels> brightest = residuals.Brightest();
      double best_cost = lambert_cost + options.max_cost_increase;
      int64_t best = -1;
      std::array<float, brdf::kChannels> best_rho{};
      brdf::BrdfParams best_params;
      for (uint64_t j = candidates.offsets[size_t(row)]; j < candidates.offsets[size_t(row) + 1];
           ++j) {
        const uint32_t donor = candidates.donors[size_t(j)];
        const brdf::BrdfParams lobes = fits->Get(donor).params;
        if (!WithinEvidence(lobes, brightest)) continue;
        const double cost = RefitAlbedoCost(&residuals, &lobes, &rho);
        if (std::isfinite(cost) && cost <= best_cost) {
          best_cost = cost;
          best = donor;
          best_rho = rho;
          best_params = lobes;
        }
      }
      if (best < 0) {
        ++task_rejected;
        continue;
      }
      TexelFit f = fits->Get(t);
      f.params.lobes = best_params.lobes;
      f.params.rho_d = best_rho;
      f.cost = float(best_cost);
      f.lambert_only = false;
      fits->Set(t, f);
      fits->set_donor(t, best);
      if (borrowed) (*borrowed)[t] = 1;
      ++task_transferred;
    }
    rejected += task_rejected;
    transferred += task_transferred;
  }, threads);
  stats->rejected += rejected;
  stats->transferred += transferred;
}

}  // namespace reflcap::fit
