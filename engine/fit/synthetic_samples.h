#pragma once
// BRDF samples generated directly from ground truth, for the fitting tests and benchmarks (no
// capture, no resampling): each texel is observed as a turntable rig would see it — point lights
// at a few elevations and azimuths, cameras on an arc, the object turned in steps, so the texel's
// tilted frame sees the fixed lights and cameras from changing directions — plus a few samples
// near the mirror configuration, as a rig designed for glossy objects guarantees (a real texel
// without them is kUnidentifiableLobe, which the hard-case tests cover with near_mirror_samples
// = 0). Values get relative Gaussian noise and inverse-variance weights. Deterministic for a
// seed: texel t's samples depend only on (seed, first_texel + t).
#include <cstdint>
#include <vector>

#include "engine/brdf/lafortune.h"
#include "engine/texel/samples.h"

namespace reflcap::fit {

// The six ground-truth materials of acquire/synth (synth.cc, MaterialParams; keep in step):
// matte (no lobe), glossy n = 25, sharp n = 250, anisotropic n = 40 (a = 0.985), coloured
// texture n = 10, coloured lobe n = 80. Lobe peaks ks (n + 2) / (2π).
constexpr int kSynthMaterialCount = 6;
const char* SynthMaterialName(int material);
// `stripe` in [0, 1] mixes the coloured texture's two albedos (ignored by the others).
brdf::BrdfParams SynthMaterialParams(int material, double stripe = 0.5);

struct SyntheticSampleOptions {
  int samples_per_texel = 100;
  // Relative noise: value = truth (1 + noise N(0, 1)), weight = 1 / (noise truth)^2.
  // 0 = noise-free (weights 1).
  double noise = 0.01;
  // How many of the samples have wo within near_mirror_max_deg of the mirror of wi.
  int near_mirror_samples = 12;
  double near_mirror_max_deg = 6.0;
  // Both directions keep cos(theta) >= min_cos.
  double min_cos = 0.1;
  // Texel normals tilt up to this far from the turntable axis (degrees).
  double max_tilt_deg = 50.0;
  uint64_t seed = 1;
};

// One chunk holding one texel per entry of `truth`, numbered from first_texel.
TexelSampleChunk MakeSyntheticChunk(const std::vector<brdf::BrdfParams>& truth,
                                    const SyntheticSampleOptions& options,
                                    uint32_t first_texel = 0);

// `count` texels cycling through the six materials (texel i has material i % 6), textured ones
// with stripe phases from `seed`.
std::vector<brdf::BrdfParams> SynthMaterialTexels(int count, uint64_t seed);

}  // namespace reflcap::fit
