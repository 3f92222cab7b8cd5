#pragma once
// FitStore and SigmaSpill: the per-texel results of `reflcap fit` for a whole atlas, held
// compactly from the chunks' fits through lobe transfer to the maps.
//
// A TexelFit is ~340 bytes (two BrdfParams sized for kMaxLobes lobes). FitStore keeps per texel
// only what lobe transfer, the maps and the report read — the parameters of the `lobes` lobes the
// fit used, as floats, the status, cost, iteration, sample and residual counts, the Lambert-only
// flag and the lobe donor: 4 (3 + 12 lobes) + 22 bytes per texel (82 for one lobe), in flat arrays
// (structure of arrays: no padding, no per-texel allocation).
//
// The sigmas are read by nothing between the fit and sigma.exr, so they do not stay in memory:
// SigmaSpill writes them to a scratch file chunk by chunk and reads them back once, in texel
// order, to build the map.
//
// Parameter layout of one texel (params and sigmas alike, ParamsPerTexel floats): rho_d R, G, B,
// then for each lobe k and channel c the four floats Cx, Cy, Cz, n.
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <functional>
#include <memory>
#include <vector>

#include "engine/brdf/lafortune.h"
#include "engine/core/large_buffer.h"
#include "engine/core/status.h"
#include "engine/fit/fitter.h"

namespace reflcap::fit {

// One texel's parameters (or sigmas) in the layout above, its first `lobes` lobes: to and from
// `3 + 12 lobes` floats. Unpack leaves the lobes past `lobes` as they are.
void PackParams(const brdf::BrdfParams& params, int lobes, float* out);
void UnpackParams(const float* in, int lobes, brdf::BrdfParams* params);

// Texels may be written concurrently from several threads when each thread writes other texels.
class FitStore {
 public:
  static constexpr int64_t kNoDonor = -1;
  static constexpr int64_t kClusterLobe = -2;
  // Not borrowed: the texel's own diffuse fall-off lobe (diffuse_falloff.h), fitted after the LM.
  static constexpr int64_t kDiffuseFalloff = -3;
  // Donor indices are int32: at most this many texels (an atlas of 2^31 texels would need far
  // more memory than any machine this runs on; the status map holds donors exactly only below
  // 2^24 anyway).
  static constexpr size_t kMaxTexels = size_t(INT32_MAX);

  // `texels` texels (<= kMaxTexels) of `lobes` lobes (0..kMaxLobes), each as a texel no chunk
  // holds: BeginTexel's zero parameters, status kTooFewSamples, no donor. Initialised on
  // `threads` threads (0: all).
  FitStore(size_t texels, int lobes, int threads = 0);

  size_t size() const { return status_.size(); }
  int lobes() const { return lobes_; }
  // Floats per texel of parameters (and of sigmas in a SigmaSpill): 3 + 12 lobes.
  int ParamsPerTexel() const { return stride_; }

  // Stores `fit` as texel t; fit.params.num_lobes must be lobes() (the lobes past it are not
  // kept, nor is fit.sigma: see SigmaSpill). The donor is left as it is.
  void Set(size_t t, const TexelFit& fit);
  // Texel t as a TexelFit; the lobes past lobes() and the sigmas are as BeginTexel leaves them
  // (default LobeParams, sigmas -1 = unknown).
  TexelFit Get(size_t t) const;

  // Raw per-texel parameters in the layout above (ParamsPerTexel() floats).
  const float* params(size_t t) const { return &params_[t * stride_]; }
  FitStatus status(size_t t) const { return FitStatus(status_[t]); }
  bool lambert_only(size_t t) const { return lambert_only_[t] != 0; }
  int samples(size_t t) const { return samples_[t]; }
  int residuals(size_t t) const { return residuals_[t]; }
  int iterations(size_t t) const { return iterations_[t]; }
  float cost(size_t t) const { return cost_[t]; }
  // The texel whose lobes texel t borrowed by lobe transfer (lobe_transfer.h), kNoDonor (-1)
  // for none, kClusterLobe (-2) for a lobe of its material cluster (material_clusters.h),
  // kDiffuseFalloff (-3) for a fall-off lobe fitted after the LM (diffuse_falloff.h).
  int64_t donor(size_t t) const { return donor_[t]; }
  // True when texel t's lobes are not the LM's: borrowed (from a neighbour or its cluster) or its
  // diffuse fall-off lobe (fitted in closed form after the LM, its sigmas unknown).
  bool borrowed(size_t t) const { return donor_[t] != kNoDonor; }
  void set_donor(size_t t, int64_t donor);

  // Frees the parameters (params(), Get()) once their map is built; the scalars stay.
  void ReleaseParams();

 private:
  int lobes_ = 0;
  int stride_ = 0;
  // On huge pages (large_buffer.h): a million-texel store is ~82 MB, and faulting it in 4 KiB at
  // a time took most of the 0.24 s that building it cost on 2 cores, before the first chunk.
  LargeBufferVector<float> params_;  // size() * stride_
  LargeBufferVector<float> cost_;
  LargeBufferVector<int32_t> iterations_, samples_, residuals_, donor_;
  LargeBufferVector<uint8_t> status_, lambert_only_;
};

// The sigmas of every texel's parameters in a scratch file, FitStore's layout, texel-major.
class SigmaSpill {
 public:
  // Creates `path` (replaced if it exists) holding `texels` texels of `lobes` lobes, each with
  // every sigma -1 (unknown, as BeginTexel leaves them). Internal on an I/O failure.
  static StatusOr<std::unique_ptr<SigmaSpill>> Create(const std::filesystem::path& path,
                                                      size_t texels, int lobes);
  // Removes the file unless Remove() did.
  ~SigmaSpill();

  // Stores fits[i].sigma (its first lobes() lobes) as texel first + i. Internal on I/O failure.
  Status Write(size_t first, const std::vector<TexelFit>& fits);
  // Calls each(t, sigma) for every texel t in order; sigma: FitStore::ParamsPerTexel() floats.
  // Internal on I/O failure (a short read included).
  Status ReadAll(const std::function<void(size_t t, const float* sigma)>& each);
  // Closes and deletes the file. Internal when it cannot be deleted.
  Status Remove();

  int lobes() const { return lobes_; }

 private:
  SigmaSpill(std::filesystem::path path, size_t texels, int lobes);
  std::filesystem::path path_;
  size_t texels_ = 0;
  int lobes_ = 0;
  int stride_ = 0;
  std::fstream file_;
  bool removed_ = false;
};

}  // namespace reflcap::fit
