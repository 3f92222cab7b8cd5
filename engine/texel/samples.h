#pragma once
// BRDF samples: what the resampler produces and the fitters consume. One BrdfSample is one
// photograph's observation of one texel, already divided by the irradiance, with both
// directions in the texel's tangent frame (brdf/lafortune.h). Samples are stored texel-major in
// chunks of consecutive texels (CSR layout) so a fitter reads each texel's data once, in one place.
#include <cstdint>
#include <vector>

#include "engine/core/large_buffer.h"

namespace reflcap {

struct BrdfSample {
  float wi[3];      // unit, tangent frame (z = shading normal), from the texel towards the light
  float wo[3];      // unit, tangent frame, from the texel towards the camera
  float value[3];   // BRDF value per channel, 1/sr: radiance / irradiance
  float weight[3];  // per-channel weight: inverse variance of value from the noise model
                    // or the photograph's images[].variance
                    // (relative weights are what matter); 0 means "ignore this channel"
  uint32_t image;   // index of the capture image the sample came from
};
static_assert(sizeof(BrdfSample) == 52, "BrdfSample is a packed on-disk record");

// The samples of texels [first_texel, first_texel + texel_count): texel first_texel + i owns
// samples[offsets[i] .. offsets[i + 1]).
struct TexelSampleChunk {
  uint32_t first_texel = 0;
  uint32_t texel_count = 0;
  std::vector<uint64_t> offsets;  // texel_count + 1 entries, offsets[0] = 0
  // Grown without zeroing, and on huge pages when large (core/large_buffer.h): every grower
  // writes what it adds (a chunk read from its file, the k-fold refits' copies), and a chunk
  // read is written once, by the kernel's copy from the file, then kept.
  LargeBufferVector<BrdfSample> samples;

  uint64_t SampleCount(uint32_t i) const { return offsets[i + 1] - offsets[i]; }
  const BrdfSample* SamplesOf(uint32_t i) const { return samples.data() + offsets[i]; }
};

}  // namespace reflcap
