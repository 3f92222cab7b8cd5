#pragma once
// What a resample writes besides the chunks, computed from the per-texel coverage and the
// counters its photographs left: used by a run (resample.cc) and by the merge of a run's shards
// (resample_merge.cc), so both write the same maps and report fields. Internal to the module.
#include <array>
#include <cstdint>
#include <filesystem>
#include <string>

#include <nlohmann/json.hpp>

#include "acquire/resample/coverage.h"
#include "acquire/resample/image_resampler.h"
#include "engine/core/status.h"
#include "engine/mesh/texel_atlas.h"

namespace reflcap::resample {

// A shard's part (resample --shard I/N): resample_part.json beside a store of the shard's
// photographs' samples and coverage.bin (TexelCoverage::Save).
constexpr const char* kResamplePartFormat = "reflcap-resample-part/1";
constexpr const char* kResamplePartFile = "resample_part.json";
constexpr const char* kPartCoverageFile = "coverage.bin";

// The counters a run sums over its photographs: saved with a checkpoint and in a part, added
// up by the merge.
struct Tally {
  std::array<uint64_t, kOutcomeCount> outcome_counts{};
  uint64_t primary_rays = 0, tap_shadow_rays = 0, visibility_rays = 0, shadow_rays = 0;
  uint64_t variance_images = 0;          // photographs weighted by their images[].variance
  uint64_t ignored_variance_images = 0;  // photographs whose variance image was not used
  double read_wait_s = 0, resample_s = 0, stream_s = 0, gpu_s = 0;

  nlohmann::json ToJson() const;
  bool FromJson(const nlohmann::json& j);  // false when a field is missing or mistyped
  void Add(const Tally& other);
};

// What the photographs left, summed: a run's, or its shards' together.
struct Counted {
  uint64_t texels_seen = 0, texels_with_samples = 0, kept = 0, rejected_total = 0, pairs = 0;
  std::array<uint64_t, kReasonCount> reasons{};
};

// Writes coverage.exr, domain.exr and coverage.png from `coverage` (unless !write_maps: a
// shard's part, whose maps the merge writes), and sets every field of `report` that depends on
// the photographs' outcomes (counts, distributions, the domain, rays, the noise model's
// variance-image counts); the caller sets the rest. Internal when the kept count disagrees with
// the samples written.
StatusOr<Counted> WriteCountedOutputs(const std::filesystem::path& out_dir, const TexelAtlas& atlas,
                                      const TexelCoverage& coverage, const Tally& tally,
                                      uint64_t images, uint64_t samples_written,
                                      nlohmann::json* report, bool write_maps = true);

// The few lines `reflcap resample` prints, from the report.
std::string SummaryText(const nlohmann::json& report, double seconds);

// The first key of `a` whose value differs in `b` ("" when none).
std::string FirstDifference(const nlohmann::json& a, const nlohmann::json& b);

}  // namespace reflcap::resample
