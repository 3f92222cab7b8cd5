#pragma once
// Merging one exposure bracket into linear HDR with per-pixel variance.
//
// Each measured code z at exposure t (0 < z < 255) gives an estimate x(z) / t of the pixel's raw
// rate (normalised raw per second, camera RGB) with variance var(z) / t², var(z) the sensor noise
// plus the quantisation of z's rounding bin (InverseResponse::CodeVariance). The merge is the
// inverse-variance weighted mean — the minimum-variance unbiased combination — and its variance
// is 1 / Σ weights. Codes 0 and 255 are censored (below the noise floor / clipped) and carry no
// weight. A channel with no measured code is either dark (every code 0: value 0, variance of a
// value uniform on [0, black edge / t_max]) or clipped (some code 255: flagged; the capture writer
// marks it at the saturation level so the resampler drops it).
#include <cstdint>
#include <vector>

#include "acquire/radiometry/brackets.h"
#include "acquire/radiometry/response.h"
#include "engine/image/image.h"

namespace reflcap::radiometry {

enum class MergeFlag : uint8_t { kMeasured = 0, kDark = 1, kClipped = 2 };

struct MergedBracket {
  Image value;     // 3 channels: normalised raw per second (x / t), camera RGB
  Image variance;  // 3 channels: variance of value
  std::vector<uint8_t> flags;  // per pixel and channel (MergeFlag)
  // Optional (keep_weights): for each exposure, its share of the total weight of the pixel's
  // green channel (exposures channels, shares sum to 1 where measured).
  Image weight_share;
  size_t measured = 0, dark = 0, clipped = 0;  // pixel-channels
};

// exposure_s: the bracket's exposure times (strictly increasing), one per images.codes entry.
MergedBracket MergeBracket(const BracketImages& images, const std::vector<double>& exposure_s,
                           const InverseResponse& response, bool keep_weights = false);

}  // namespace reflcap::radiometry
