#pragma once
// What each texel's samples cover: how many samples, from how many viewpoints, how much of the
// (isotropic) BRDF domain, and how close to the specular configuration. The seed paper found that
// more viewpoints give more accurate fits; these statistics make that visible before fitting:
// a texel whose samples span few domain cells, or never come near the half-vector = normal
// configuration, cannot identify a specular lobe, however many samples it has.
//
// Domain cells (DomainCell): θi and θo in 15° bins over [0°, 90°), taken as an unordered pair
// (reciprocity: f(wi, wo) = f(wo, wi), so (θi, θo) and (θo, θi) are the same measurement), times
// the relative azimuth φ = angle between the tangent-plane projections of wi and wo in 30° bins
// over [0°, 180°] (isotropy: only |φi - φo| matters, folded into [0°, 180°]). 21 x 6 = 126 cells.
// The half-vector angle θh = angle(normalize(wi + wo), n) is 0 at the mirror configuration; a
// Lafortune lobe of exponent n has its peak within about 1/sqrt(n) rad of it (θh of half that).
#include <array>
#include <cstdint>
#include <filesystem>
#include <vector>

#include "engine/core/status.h"

#include "acquire/resample/chunk_writer.h"
#include "acquire/resample/image_resampler.h"

namespace reflcap::resample {

constexpr int kThetaBins = 6;      // 15° each over [0°, 90°)
constexpr int kPhiBins = 6;        // 30° each over [0°, 180°]
constexpr int kThetaPairs = kThetaBins * (kThetaBins + 1) / 2;
constexpr int kDomainCells = kThetaPairs * kPhiBins;  // 126

// Domain cell of a sample (wi, wo unit, tangent frame), in [0, kDomainCells).
int DomainCell(const float wi[3], const float wo[3]);
// Half-vector angle in degrees, in [0, 90] for directions in the upper hemisphere.
float HalfAngleDeg(const float wi[3], const float wo[3]);

// Per-texel accumulators, filled image by image.
class TexelCoverage {
 public:
  explicit TexelCoverage(size_t texels);

  // Adds one photograph: its per-texel outcomes (Outcome values) and kept samples (ascending
  // texel, one per kKept outcome). `view` identifies the (camera, turntable angle) it was taken
  // from; a texel's views count goes up when a sample arrives from a view other than its last
  // one, so images must arrive grouped by view. Parallel over texels.
  void AddImage(const std::vector<uint8_t>& outcome, const std::vector<TexelSample>& kept,
                int view, int threads = 0);

  size_t texels() const { return samples_.size(); }
  uint32_t samples(size_t t) const { return samples_[t]; }
  uint32_t views(size_t t) const { return views_[t]; }
  bool seen(size_t t) const { return seen_[t] != 0; }  // Seen() in some photograph
  uint32_t observations(size_t t) const { return observations_[t]; }  // Observed() photographs
  int cells(size_t t) const;              // distinct domain cells hit
  float min_half_angle_deg(size_t t) const { return min_half_deg_[t]; }  // 90 when no sample

  // Adds the coverage of other photographs of the same texels, taken from other views than
  // this one's (shards of a capture split at view boundaries): counts add up, seen flags and
  // domain cells are united, the smaller half-vector angle is kept. The views counted by each
  // must be distinct for the views counts to add up. Checked: the same texel count.
  void Merge(const TexelCoverage& other);

  // The whole state (also each texel's last view) to a file, atomically, with a CRC-32 over the
  // payload; and back. Load: NotFound when missing, DataLoss naming the file when it is
  // truncated, corrupt or of another texel count.
  Status Save(const std::filesystem::path& path) const;
  static StatusOr<TexelCoverage> Load(const std::filesystem::path& path, size_t texels);

 private:
  // The arrays in file order as (bytes, size) pairs: Save and Load stream them.
  template <typename Self>
  static auto Pieces(Self& c);

  std::vector<uint32_t> samples_;
  std::vector<uint16_t> views_;
  std::vector<int32_t> last_view_;
  std::vector<uint8_t> seen_;
  std::vector<uint32_t> observations_;
  std::vector<std::array<uint64_t, 2>> cells_;  // bit set of kDomainCells
  std::vector<float> min_half_deg_;
};

}  // namespace reflcap::resample
