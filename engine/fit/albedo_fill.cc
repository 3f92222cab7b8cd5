#include "engine/fit/albedo_fill.h"

#include <algorithm>
#include <array>
#include <utility>

#include "engine/core/large_buffer.h"
#include "engine/core/log.h"
#include "engine/core/parallel.h"

namespace reflcap::fit {

Status AlbedoFillOptions::Validate() const {
  if (radius < 1 || radius > 64) {
    return InvalidArgumentError("albedo fill radius ", radius, " outside [1, 64] texels");
  }
  if (rounds < 1 || rounds > 1024) {
    return InvalidArgumentError("albedo fill rounds ", rounds, " outside [1, 1024]");
  }
  return OkStatus();
}

namespace {

// Open texels per task of a round's parallel loops: an open texel reads a window of up to
// (2 radius + 1)^2 pixels, so a task of 1,024 is several microseconds of work.
constexpr int64_t kOpenTexelsPerTask = 1024;
// Texels per task of the grid's construction (one store each).
constexpr int64_t kTexelsPerTask = 1 << 16;

}  // namespace

AlbedoFillStats FillUnseenAlbedo(const TexelAtlas& atlas, const AlbedoFillOptions& options,
                                 FitStore* fits, std::vector<uint8_t>* filled, int threads) {
  REFLCAP_CHECK(fits->size() == atlas.TexelCount());
  AlbedoFillStats stats;
  filled->assign(fits->size(), 0);
  if (!options.enabled) return stats;
  // One texel per pixel: the writes do not race.
  LargeBufferVector<int32_t> texel_at(size_t(atlas.width) * atlas.height);
  ParallelFill(&texel_at, -1, threads);
  ParallelFor(0, int64_t(fits->size()), kTexelsPerTask, [&](int64_t begin, int64_t end, int) {
    for (int64_t t = begin; t < end; ++t) texel_at[atlas.pixel_of_texel[size_t(t)]] = int32_t(t);
  }, threads);
  // known: has samples, or was filled in an earlier round.
  std::vector<uint8_t> known(fits->size());
  std::vector<uint32_t> open;  // unseen texels not filled yet, ascending
  for (size_t t = 0; t < fits->size(); ++t) {
    known[t] = fits->residuals(t) > 0;
    if (!known[t]) open.push_back(uint32_t(t));
  }
  stats.unseen = open.size();
  const int r = options.radius;
  // Per open texel of a round: its new albedo, and whether it has one. Every open texel is
  // read on the round's start state (`known` changes only between rounds), so the texels are
  // independent, and the round's result does not depend on the threads.
  std::vector<std::array<float, 3>> rho;
  std::vector<uint8_t> found;
  for (int round = 0; round < options.rounds && !open.empty(); ++round) {
    rho.resize(open.size());
    found.assign(open.size(), 0);
    ParallelFor(0, int64_t(open.size()), kOpenTexelsPerTask, [&](int64_t begin, int64_t end, int) {
      for (int64_t i = begin; i < end; ++i) {
        const uint32_t t = open[size_t(i)];
        const int x0 = int(atlas.pixel_of_texel[t] % uint32_t(atlas.width));
        const int y0 = int(atlas.pixel_of_texel[t] / uint32_t(atlas.width));
        std::array<double, 3> sum{};
        int n = 0;
        for (int y = std::max(0, y0 - r); y <= std::min(atlas.height - 1, y0 + r); ++y) {
          for (int x = std::max(0, x0 - r); x <= std::min(atlas.width - 1, x0 + r); ++x) {
            const int32_t d = texel_at[size_t(y) * atlas.width + x];
            if (d < 0 || !known[size_t(d)]) continue;
            for (int c = 0; c < 3; ++c) sum[c] += fits->params(size_t(d))[c];  // rho_d R, G, B
            ++n;
          }
        }
        if (n == 0) continue;
        found[size_t(i)] = 1;
        rho[size_t(i)] = {float(sum[0] / n), float(sum[1] / n), float(sum[2] / n)};
      }
    }, threads);
    // The round's albedos stored (each texel its own: in parallel), then the texels still open.
    ParallelFor(0, int64_t(open.size()), kOpenTexelsPerTask, [&](int64_t begin, int64_t end, int) {
      for (int64_t i = begin; i < end; ++i) {
        if (!found[size_t(i)]) continue;
        const uint32_t t = open[size_t(i)];
        TexelFit fit = fits->Get(t);
        for (int c = 0; c < 3; ++c) fit.params.rho_d[c] = rho[size_t(i)][size_t(c)];
        fits->Set(t, fit);  // leaves the donor as it is (FitStore::Set)
        known[t] = 1;
        (*filled)[t] = 1;
      }
    }, threads);
    size_t kept = 0, round_filled = 0;
    for (size_t i = 0; i < open.size(); ++i) {
      if (found[i]) {
        ++round_filled;
      } else {
        open[kept++] = open[i];
      }
    }
    if (round_filled == 0) break;
    open.resize(kept);
    stats.filled += round_filled;
    ++stats.rounds;
  }
  return stats;
}

}  // namespace reflcap::fit
