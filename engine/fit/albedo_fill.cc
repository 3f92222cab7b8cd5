#include "engine/fit/albedo_fill.h"

#include <algorithm>
#include <array>
#include <utility>

#include "engine/core/log.h"

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

AlbedoFillStats FillUnseenAlbedo(const TexelAtlas& atlas, const AlbedoFillOptions& options,
                                 FitStore* fits, std::vector<uint8_t>* filled) {
  REFLCAP_CHECK(fits->size() == atlas.TexelCount());
  AlbedoFillStats stats;
  filled->assign(fits->size(), 0);
  if (!options.enabled) return stats;
  std::vector<int32_t> texel_at(size_t(atlas.width) * atlas.height, -1);
  for (size_t t = 0; t < fits->size(); ++t) texel_at[atlas.pixel_of_texel[t]] = int32_t(t);
  // known: has samples, or was filled in an earlier round.
  std::vector<uint8_t> known(fits->size());
  std::vector<uint32_t> open;  // unseen texels not filled yet
  for (size_t t = 0; t < fits->size(); ++t) {
    known[t] = fits->residuals(t) > 0;
    if (!known[t]) open.push_back(uint32_t(t));
  }
  stats.unseen = open.size();
  const int r = options.radius;
  std::vector<std::pair<uint32_t, std::array<float, 3>>> updates;
  for (int round = 0; round < options.rounds && !open.empty(); ++round) {
    updates.clear();
    std::vector<uint32_t> still_open;
    for (uint32_t t : open) {
      const int x0 = int(atlas.pixel_of_texel[t] % uint32_t(atlas.width));
      const int y0 = int(atlas.pixel_of_texel[t] / uint32_t(atlas.width));
      std::array<double, 3> sum{};
      int n = 0;
      for (int y = std::max(0, y0 - r); y <= std::min(atlas.height - 1, y0 + r); ++y) {
        for (int x = std::max(0, x0 - r); x <= std::min(atlas.width - 1, x0 + r); ++x) {
          const int32_t d = texel_at[size_t(y) * atlas.width + x];
          if (d < 0 || !known[d]) continue;
          for (int c = 0; c < 3; ++c) sum[c] += fits->params(d)[c];  // rho_d R, G, B
          ++n;
        }
      }
      if (n == 0) {
        still_open.push_back(t);
        continue;
      }
      updates.push_back({t, {float(sum[0] / n), float(sum[1] / n), float(sum[2] / n)}});
    }
    if (updates.empty()) break;
    for (const auto& [t, rho] : updates) {
      TexelFit fit = fits->Get(t);
      for (int c = 0; c < 3; ++c) fit.params.rho_d[c] = rho[c];
      const int64_t donor = fits->donor(t);
      fits->Set(t, fit);  // leaves the donor as it is (FitStore::Set)
      REFLCAP_CHECK(fits->donor(t) == donor);
      known[t] = 1;
      (*filled)[t] = 1;
    }
    stats.filled += updates.size();
    ++stats.rounds;
    open.swap(still_open);
  }
  return stats;
}

}  // namespace reflcap::fit
