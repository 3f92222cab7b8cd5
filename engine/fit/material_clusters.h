#pragma once
// Material clusters: the lobe a material showed anywhere, for its texels that did not see it or
// saw too little of it (after Lensch et al. 2003, "Image-based reconstruction of spatial
// appearance and geometric detail": cluster the texels, fit each cluster's BRDF to the pooled
// samples of its texels, then choose per texel).
//
// Why: lobe transfer (lobe_transfer.h) lends a texel one neighbour's lobe and holds it to the
// texel's own evidence — its supremum may be at most 10x the brightest sample *that texel*
// showed. A texel without highlight evidence has only dim samples, so a real highlight lobe fails
// that bound (`synth --preset small --seed 11`: 6,048 of 11,162 recipients rejected by it at a
// 60-texel radius), and dropping the bound for single neighbours lets wrong lobes through (a
// 3-camera x 24-step synth rig fell from 40.3 to 19.8 dB holdout PSNR). A cluster supplies the
// missing evidence: a lobe is lent only when it explains the pooled samples of its material.
//
//   1. Clusters (BuildMaterialClusters). Every texel with at least kMinTransferSamples samples is
//      placed in albedo space: chromaticity (rho_R, rho_G) / (rho_R + rho_G + rho_B) in units of
//      `chroma_scale` and ln(rho_R + rho_G + rho_B) in units of `level_scale`. Bisecting 2-means
//      (split along the principal axis, then Lloyd iterations) splits the cluster with the largest
//      spread while its mean squared spread exceeds 1 unit^2 and both halves keep
//      `min_cluster_texels`, up to `max_clusters`. Deterministic: no random start.
//   2. Pool (StashClusterSamples, one pass over the chunks). Up to `pool_texels` evidenced members
//      per cluster — texels that fitted a lobe of their own, or saw their mirror configuration and
//      showed none ("lobe absent") — in an even stride; their usable samples (at most
//      kMaxPooledSamplesPerTexel each, an even stride) are kept, and the brightest per channel.
//   3. Lobes (ChooseClusterLobes). Candidates: the lobes of up to kClusterLobeCandidates members
//      that fitted one of their own (most samples first), and — one lobe, anisotropic or
//      isotropic model — the best of them refined by Levenberg-Marquardt (Ceres) on the whole
//      pool, one lobe per channel shared by all pool texels, each texel with its own albedo. Each
//      candidate is scored on the pool with every texel's albedo re-fitted under it (as lobe
//      transfer does): pooled cost, and how many pool texels it contradicts (cost above their
//      Lambert-only cost by more than max_cost_increase). Kept, best pooled cost first, up to
//      `lobes_per_cluster`: lobes that lower the pooled cost below Lambert-only, that at most
//      kMaxContradictedShare of the pool contradicts (a cluster mixing a matte and a glossy
//      material of one albedo lends nothing), and whose supremum stays within 10x the pool's
//      brightest sample per channel (problem.h kMaxLobeSupremum, on the material's evidence).
//   4. Per texel (ApplyClusterLobes, one pass over the chunks). Every clustered texel with at
//      least kMinTransferSamples samples whose cluster kept lobes compares, on its own samples,
//      its fit with each kept lobe (albedo re-fitted):
//        - a Lambert-only texel (kUnidentifiableLobe, kTooFewSamples, or lobe absent) takes the
//          lowest-cost lobe that costs at most max(max_cost_increase, 5 % of its Lambert cost)
//          more than its Lambert fit: its samples do not contradict it (lobe transfer's test,
//          relative as well: a sharp lobe's tail at a texel's samples is uncertain);
//        - a texel with a lobe (its own, or a neighbour's) takes the cluster lobe when it
//          predicts the texel's held-out photographs better (ModelChoice::kKFold, the default):
//          the samples fall into `folds` folds by photograph (PhotographFold); a
//          candidate's score is the summed cost of each fold under the model fitted without it —
//          the texel's own lobe refitted by the CPU batched fitter on the other folds, a borrowed
//          or cluster lobe with the albedo re-fitted on them. The cluster's lobe wins when its
//          score is lower by more than kKFoldMargin. The refits go fold by fold and stop for a
//          texel once its own score so far exceeds the cluster lobe's by the margin (each fold
//          adds a cost >= 0: the same choice; on the million preset 55 % of the refits).
//          Every chunk is scored before the refits, which batch many chunks' texels
//          (KFoldScores): the same refits, more texels per parallel loop.
//          Texels with some fold empty, and every
//          texel under ModelChoice::kBic, use the Bayesian information criterion instead:
//          2 cost + k ln N, k = 3 for the cluster lobe (the albedo only) and the texel's own
//          parameter count for its fit (3 for a borrowed lobe), N its residuals. This is the
//          cluster lobe as a prior: where the texel saw too little of its highlight to pin the
//          lobe, the material's lobe predicts better.
//      A cluster none of whose members had evidence either way (no lobe of its own, none measured
//      absent: a fragment that the split cut from a material whose texels saw little, such as a
//      dark metal whose chromaticity is noisy) has nothing to pool: it takes the verdict of the
//      nearest cluster by centroid that has evidence — that cluster's kept lobes, offered under
//      the same tests, or nothing when it is matte. Absence of evidence is not evidence of a matte
//      material.
//      A texel without samples (albedo filled, step 1b) takes the cluster's best lobe untested:
//      nothing it saw can contradict it, and its material's highlight is the best prediction.
//      A Lambert-only texel whose own cluster's best lobe still misfits its samples (reduced
//      chi-square above 2: a texture patch of one material whose colour matches another's) is
//      offered every other cluster's kept lobes, under its own evidence bound, and takes the best
//      if it at least halves the cost (MaterialClusterStats::foreign_lent).
//      A texel that takes a cluster lobe gets donor FitStore::kClusterLobe, its sigmas unknown
//      (-1), and keeps its status (the lobe is the material's, not measured by the texel alone).
//
// Runs after the fit on every backend alike (it reads the FitStore and the sample store, nothing
// of the fitter), so CPU and Vulkan fits take the same lobes given the same fits.
#include <array>
#include <cstdint>
#include <memory>
#include <vector>

#include "engine/brdf/lafortune.h"
#include "engine/core/large_buffer.h"
#include "engine/fit/fit_store.h"
#include "engine/fit/fitter.h"
#include "engine/fit/lobe_transfer.h"
#include "engine/fit/model.h"
#include "engine/texel/samples.h"

namespace reflcap::fit {

// Own lobes tried per cluster: enough to find the material's lobe among its best-sampled texels;
// each costs one lobe evaluation per pooled sample. 16, not 8: the refinement starts from the
// best of them, and a sharp lobe's pooled cost has several basins (synth sharp-highlight
// material, holdout rel. RMSE 0.36 with 8, 0.24 with 16; 24 no better). Refining from the three
// best instead found lower pooled costs that predicted worse (0.45): it stays one start.
constexpr int kClusterLobeCandidates = 16;
// A kept lobe may raise the cost of at most this share of the pool's texels above their
// Lambert-only cost (by more than max_cost_increase): a few texels of another material or with a
// poor fit are tolerated, a matte half of the cluster is not.
constexpr double kMaxContradictedShare = 0.2;
// Samples kept per pool texel (an even stride through its usable ones): 256 texels x 128
// samples bound a cluster's pool at ~1.7 MB, and a lobe's few parameters are decided many times
// over.
constexpr int kMaxPooledSamplesPerTexel = 64;
// A sparse texel joins a cluster only within this distance of its centroid (albedo-space units:
// 3 = three times the spread at which a cluster is split, so well inside a material's range).
constexpr double kSparseAssignRadius = 3.0;

struct MaterialClusterStats {
  int clusters = 0;             // clusters formed
  int clusters_with_lobe = 0;   // clusters that kept at least one lobe
  int refined = 0;              // clusters whose kept lobes include the pooled LM fit
  int borrowing = 0;            // clusters without evidence offered the nearest one's lobes
  size_t clustered_texels = 0;  // texels with a cluster
  size_t recipients = 0;        // Lambert-only texels that could take a lobe
  size_t no_lobe = 0;           // recipients without a cluster, or whose cluster kept no lobe
  size_t rejected = 0;          // recipients whose samples contradict every kept lobe
  size_t transferred = 0;       // recipients that took a cluster lobe
  size_t replaced = 0;          // texels with a lobe that took the cluster's instead (criterion)
  size_t sparse_assigned = 0;   // texels with 1-2 samples or a filled albedo given a cluster
  size_t sparse_lent = 0;       // of those, texels that took its lobe
  size_t foreign_lent = 0;      // recipients that took another cluster's lobe (misfit own)
  size_t kfold_refit = 0;       // texels with an own lobe refitted without some fold
  size_t kfold_refits = 0;      // the refits (a texel and a fold each; at most folds per texel)
  size_t kfold_batches = 0;     // batches the refits ran in (KFoldScores)
  double refit_seconds = 0;     // ApplyClusterLobes' k-fold refits of texels with own lobes
};

struct MaterialClusters {
  int count = 0;
  std::vector<int32_t> cluster_of;  // per texel: its cluster, -1 for none

  // Per cluster.
  std::vector<std::vector<brdf::BrdfParams>> candidate_params;  // lobes of its best-sampled texels
  std::vector<std::vector<uint32_t>> pool;        // pool texels, ascending
  std::vector<std::vector<BrdfSample>> stash;     // their kept samples, pool order
  std::vector<std::vector<UsableSample>> usable;  // the same, prepared
  std::vector<std::vector<uint32_t>> stash_offsets;  // pool.size() + 1
  std::vector<std::array<double, brdf::kChannels>> brightest;  // over the pool's samples
  std::vector<std::vector<brdf::BrdfParams>> kept;  // step 3's lobes, best first
  std::vector<std::array<double, 3>> centroid;       // albedo-space mean of its texels (step 1)
  std::vector<uint32_t> absent;                       // members whose lobe was measured absent
  // Whose kept lobes its texels are offered (step 3): itself when it kept any; when none of its
  // members had any evidence (no lobe of their own, none measured absent), the nearest cluster
  // by centroid that has evidence, if that one kept lobes; else -1.
  std::vector<int32_t> lend_from;

  std::vector<uint32_t> all_pool;  // every cluster's pool texels, ascending

  // True when some pool texel of some cluster lies in texels [first, end).
  bool PoolIn(uint64_t first, uint64_t end) const;
  // The cluster whose kept lobes texel t is offered: lend_from of its cluster, -1 for none.
  int32_t LenderOf(size_t t) const {
    return cluster_of[t] < 0 ? -1 : lend_from[size_t(cluster_of[t])];
  }
  // True when some texel in [first, end) is offered a cluster's kept lobes.
  bool KeptIn(uint64_t first, uint64_t end) const;
};

// Step 4's k-fold: the fold (0 .. folds - 1) of a photograph, by its index in the capture,
// scattered (Fibonacci hashing) so that photographs held out or ordered with some period still
// fill every fold.
int PhotographFold(uint32_t image, int folds);

// Step 1 (and the candidates of step 3). Empty (count 0) when options.enabled is false or the
// fit has no lobes.
// Per-texel passes on `threads` threads (0: all); the result does not depend on it.
MaterialClusters BuildMaterialClusters(const FitStore& fits, const MaterialClusterOptions& options,
                                       MaterialClusterStats* stats, int threads = 0);

// Step 1b: texels too sparse to form clusters — 1 or 2 samples, or none but an albedo from albedo
// fill (`albedo_filled`, one byte per texel, or empty) — join the cluster whose centroid is
// nearest to their albedo when it lies within kSparseAssignRadius units; step 4 then gives them
// its lobe (tested on their samples when they have any).
void AssignSparseTexels(const FitStore& fits, const std::vector<uint8_t>& albedo_filled,
                        const MaterialClusterOptions& options, MaterialClusters* clusters,
                        MaterialClusterStats* stats, int threads = 0);

// Step 2 for the pool texels of one chunk. Chunks must come in ascending order (each pool's
// samples are appended in texel order).
void StashClusterSamples(const TexelSampleChunk& chunk, double min_cos_theta,
                         MaterialClusters* clusters);

// Step 3, once every chunk is stashed; frees the stash.
void ChooseClusterLobes(const FitOptions& options, MaterialClusters* clusters,
                        MaterialClusterStats* stats);

// Step 4's k-fold scores (ModelChoice::kKFold) over the whole store, so that the refits of the
// own lobes batch texels of many chunks: a chunk holds ~1,000 of them on the million preset,
// too few for 16 threads through five folds of parallel loops (0.35 s of the fit did not shrink
// with threads on an H200 host). Fill it chunk by chunk (ScoreClusterLobes, chunks in ascending
// order), flush the last refits (RefitOwnLobes), then apply chunk by chunk.
class KFoldScores {
 public:
  // Refits run once the waiting texels hold this many samples (52 bytes each: 27 MB, and as much
  // again for a fold's training copy): ~8,000 texels of 64 samples, 24,000 problems for the
  // batched fitter, enough for every thread of a 16-core host. A batch 4x larger was 0.2 s
  // slower on 2 cores (memory traffic: every fold streams the batch 3 times).
  static constexpr uint64_t kRefitBatchSamples = uint64_t{1} << 19;

  // For `texels` texels (the store's); folds from options (0 under ModelChoice::kBic: nothing
  // is scored and ApplyClusterLobes uses the BIC for every texel). The refits run whenever
  // `batch_samples` samples wait (tests pass small batches).
  KFoldScores(size_t texels, const FitOptions& options,
              uint64_t batch_samples = kRefitBatchSamples);

  int folds() const { return folds_; }

 private:
  friend void ScoreClusterLobes(const TexelSampleChunk&, const MaterialClusters&,
                                const FitOptions&, const FitStore&, KFoldScores*,
                                MaterialClusterStats*);
  friend void RefitOwnLobes(const FitOptions&, KFoldScores*, MaterialClusterStats*);
  friend void ApplyClusterLobes(const TexelSampleChunk&, const MaterialClusters&,
                                const FitOptions&, const KFoldScores&, FitStore*,
                                MaterialClusterStats*);

  int folds_ = 0;
  uint64_t batch_samples_ = kRefitBatchSamples;
  // Per texel of the store (empty without folds).
  LargeBufferVector<double> best_cv_;     // the best kept lobe's held-out cost
  LargeBufferVector<int16_t> best_lobe_;  // its index in kept[LenderOf(t)]; -1: none scored
  LargeBufferVector<double> own_cv_;      // an own lobe's held-out cost, refitted without each fold
  // Texels whose own lobes wait for their refits (store indices, ascending), with their samples
  // (waiting texel j owns waiting_samples_ texel j's).
  std::vector<uint32_t> waiting_;
  TexelSampleChunk waiting_samples_;
  TexelSampleChunk train_;  // one fold's training samples; buffers kept from batch to batch
  std::vector<TexelFit> fold_fit_;  // one fold's refits; kept from batch to batch
  std::unique_ptr<Fitter> fitter_;  // the CPU batched fitter of the refits, made once
};

// Step 4, k-fold part, for the texels of one chunk: each kept lobe's held-out score, and the own
// lobes that need refits (run here once a batch is full). Does nothing without folds.
void ScoreClusterLobes(const TexelSampleChunk& chunk, const MaterialClusters& clusters,
                       const FitOptions& options, const FitStore& fits, KFoldScores* scores,
                       MaterialClusterStats* stats);
// The refits still waiting (call once every chunk is scored).
void RefitOwnLobes(const FitOptions& options, KFoldScores* scores, MaterialClusterStats* stats);
// Step 4 for the texels of one chunk, every chunk scored and refitted first.
void ApplyClusterLobes(const TexelSampleChunk& chunk, const MaterialClusters& clusters,
                       const FitOptions& options, const KFoldScores& scores, FitStore* fits,
                       MaterialClusterStats* stats);
// Step 4 for a store of this one chunk: score, refit, apply.
void ApplyClusterLobes(const TexelSampleChunk& chunk, const MaterialClusters& clusters,
                       const FitOptions& options, FitStore* fits, MaterialClusterStats* stats);

}  // namespace reflcap::fit
