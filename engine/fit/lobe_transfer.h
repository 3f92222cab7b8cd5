#pragma once
// Lobe transfer: a texel whose samples never came near its mirror configuration
// (kUnidentifiableLobe) is fitted Lambert-only, so a held-out view that shows its highlight shows
// none in the re-render. Surfaces are made of materials that span many texels; the neighbours
// of such a texel often did see their highlight. So, after every texel is fitted:
//
//   1. Candidates (atlas space). For each recipient — a texel with status kUnidentifiableLobe and
//      at least kMinTransferSamples valid samples — the donors are the texels within `radius`
//      atlas texels (a square window) that fitted a lobe of their own (status kConverged, not
//      Lambert-only) and whose diffuse albedo is within `albedo_tolerance` of the recipient's
//      (|rho_a - rho_b| / max(|rho_a|, |rho_b|), RGB Euclidean). Up to kMaxTransferCandidates,
//      closest albedo first.
//   2. Test (the recipient's own samples, a second pass over the store). For each candidate the
//      recipient keeps the donor's lobes and re-fits its albedo by weighted least squares with
//      them fixed (rho_c = pi sum w (y - lobe) / sum w, clamped at 0). The candidate is accepted
//      when (a) in every channel the lobes' supremum over the hemisphere is at most
//      kMaxLobeSupremum (10) times the recipient's brightest sample — the evidence bound its own
//      fit is held to (problem.h): a lobe far above anything the texel showed is extrapolation,
//      and a wrong one makes a held-out image many times too bright (measured: a 3-camera,
//      24-step synth rig fell from 33.8 to 19.8 dB holdout PSNR without this test, and rose to
//      39.4 dB with it) — and (b) its cost exceeds the recipient's Lambert-only cost by at most
//      `max_cost_increase` (1/2 sum w r^2, noise units): the samples do not contradict the lobe.
//      Among accepted candidates the lowest cost wins.
//
// Rounds: a texel that borrowed a lobe lends it on in the next round, so a lobe spreads through
// a region of one material as far as the albedo and sample tests let it (region growing), up to
// `rounds` rounds, each a pass over the chunks that hold recipients with candidates. A round's
// counts add to the stats in the FIT report; `recipients`, `no_donor` and `rejected` are the first
// round's, `transferred` the sum over rounds.
//
// A matte texel next to a glossy one is protected twice: the albedo test (different materials
// differ in albedo more often than not), and kUnidentifiableLobe itself — a texel that had a
// sample near its mirror direction and showed no lobe there is "lobe absent" (kConverged,
// Lambert-only), never a recipient. The transferred texel keeps its status (the lobe is
// borrowed, not measured), its lobe sigmas stay -1 (unknown), and the FIT maps record the donor.
#include <array>
#include <cstdint>
#include <vector>

#include "engine/brdf/lafortune.h"
#include "engine/core/status.h"
#include "engine/fit/fit_store.h"
#include "engine/fit/fitter.h"
#include "engine/mesh/texel_atlas.h"
#include "engine/texel/samples.h"

namespace reflcap::fit {

// LobeTransferOptions (the settings) live in fitter.h, as FitOptions::lobe_transfer.

// A recipient needs this many valid samples for its albedo re-fit and the cost test to mean
// anything (3: one per channel would fit rho exactly and every lobe would pass).
constexpr int kMinTransferSamples = 3;
// Candidates tested per recipient: the few closest in albedo; more only costs time (a texel's
// material is usually found among its nearest donors).
constexpr int kMaxTransferCandidates = 4;

struct LobeTransferStats {
  size_t recipients = 0;   // unidentifiable texels with enough samples
  size_t no_donor = 0;     // no donor in the window within the albedo tolerance
  size_t rejected = 0;     // every candidate beyond the evidence bound or contradicted by the
                           // recipient's samples
  size_t transferred = 0;  // took a donor's lobes
  int rounds = 0;          // rounds run
};

// Candidate donors of the recipients in compressed rows: recipient `recipients[i]` (ascending
// texel indices; only recipients with at least one candidate appear) tests the donors
// `donors[offsets[i] .. offsets[i + 1])`, closest albedo first. A few bytes per recipient
// instead of a vector per texel.
struct LobeCandidates {
  std::vector<uint32_t> recipients;
  std::vector<uint64_t> offsets{0};  // recipients.size() + 1
  std::vector<uint32_t> donors;

  // The candidates of texel t, closest albedo first (empty when it has none).
  std::vector<uint32_t> Of(uint32_t t) const;
  // True when some texel in [first, end) has candidates.
  bool AnyIn(uint64_t first, uint64_t end) const;
};

// Shared with material clusters (material_clusters.h) ------------------------------------------

// One sample as the fit used it: unit directions; usable when both are above min_cos_theta (and
// finite, and not a zeroed record: problem.h kMinDirectionNorm).
struct UsableSample {
  float wi[3], wo[3];
  bool usable = false;
};
UsableSample PrepareUsableSample(const BrdfSample& s, double min_cos_theta);

// Per channel: the albedo re-fit with `params`' lobes fixed (no lobes when `params` is null),
// written to `rho`, and the summed cost 1/2 sum w r^2 over the usable samples.
double RefitAlbedoCost(const BrdfSample* samples, size_t count, const UsableSample* usable,
                       const brdf::BrdfParams* params, std::array<float, brdf::kChannels>* rho);

// A texel's residuals laid out once for testing many lobes on them (lobe transfer, clusters):
// per usable sample (PrepareUsableSample) the direction products wi_j wo_j as EvalChannel forms
// them, its photograph's fold, and per channel the value and weight — weight 0 and value 0 where
// ChannelResidual has no residual — padded with zero-weight entries to a multiple of kLanes.
// The lobes go through EvaluateLobeSum (batched_kernel.h), kLanes samples per vector step.
class TexelResiduals {
 public:
  // `folds` > 0 records each sample's PhotographFold(image, folds).
  void Prepare(const BrdfSample* samples, size_t count, double min_cos_theta, int folds = 0);

  size_t usable() const { return usable_; }  // usable samples
  // Channel c's summed lobes of `params` at every entry (0 where params is null: Lambert);
  // valid until the next call.
  const float* Lobes(const brdf::BrdfParams* params, int c);
  // The whole model of `params` (albedo and lobes) in channel c, like Lobes.
  const float* Model(const brdf::BrdfParams& params, int c);

  size_t padded() const { return xx_.size(); }
  const float* y(int c) const { return y_[size_t(c)].data(); }
  const float* w(int c) const { return w_[size_t(c)].data(); }
  const uint8_t* fold() const { return fold_.data(); }
  const float* zz() const { return zz_.data(); }  // cos theta_i cos theta_o
  // Per channel the brightest value with a residual (0 when none): the evidence bound's scale.
  std::array<double, brdf::kChannels> Brightest() const;

 private:
  void Resize(size_t size);  // every per-entry array

  size_t usable_ = 0;
  std::vector<float> xx_, yy_, zz_;
  std::array<std::vector<float>, brdf::kChannels> y_, w_;
  std::vector<uint8_t> fold_;
  std::vector<float> values_;
};

// RefitAlbedoCost on prepared residuals (the same sums; the lobes by EvaluateLobeSum).
double RefitAlbedoCost(TexelResiduals* r, const brdf::BrdfParams* params,
                       std::array<float, brdf::kChannels>* rho);

// The largest value the lobes of `p` reach in channel c over the hemisphere.
double LobeSupremum(const brdf::BrdfParams& p, int c);

// The evidence bound of a texel's own fit (problem.h kMaxLobeSupremum) for a lobe it did not fit:
// in every channel the lobes of `p` rise at most kMaxLobeSupremum times the texel's brightest
// value (TexelResiduals::Brightest).
bool WithinEvidence(const brdf::BrdfParams& p,
                    const std::array<double, brdf::kChannels>& brightest);

// Phase 1: for every recipient in `fits`, its candidate donors. fits.donor(t) >= 0 marks a texel
// that borrowed its lobes in an earlier round: it lends them on and is no longer a recipient.
// `lenders`, when given (one byte per texel), restricts the donors to the texels it marks — the
// driver passes the texels that borrowed in the previous round, since every other donor was
// already tested against every recipient in its reach (a recipient they did not convince would
// refuse again).
LobeCandidates FindLobeDonors(const TexelAtlas& atlas, const FitStore& fits,
                              const LobeTransferOptions& options, LobeTransferStats* stats,
                              const std::vector<uint8_t>* lenders = nullptr);

// Phase 2 for the texels of one chunk: tests each recipient's candidates on its samples and, for
// the accepted one, overwrites its fit (albedo re-fitted, the donor's lobes, lambert_only false)
// and sets its donor (the maps then write its albedo sigmas as unknown: WriteFitMaps).
// `min_cos_theta` masks grazing samples as the fit did. `borrowed`, when given (one byte per
// texel), gets 1 for every texel that took a lobe.
void ApplyLobeTransfer(const TexelSampleChunk& chunk, const LobeCandidates& candidates,
                       const LobeTransferOptions& options, double min_cos_theta, int threads,
                       FitStore* fits, LobeTransferStats* stats,
                       std::vector<uint8_t>* borrowed = nullptr);

}  // namespace reflcap::fit
