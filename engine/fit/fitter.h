#pragma once
// The fitting engine's interface: one Fitter per backend behind one factory (after Ceres'
// DenseCholesky::Create), the options every backend honours alike, and the per-texel outcome.
//
// Per-texel outcomes are data, not errors (Gpufit, TinySolver): every texel gets a TexelFit with
// finite parameters, a FitStatus, its final cost and iteration count, and parameter standard
// deviations. A Fit call fails (Status) only when the options are invalid or a backend fails.
//
// Backends:
//   kCpu    the batched CPU path (engine/fit/batched_fitter.cc): several problems in lock-step
//           across SIMD lanes, all cores, no heap allocation per texel. The default.
//   kCeres  the reference (engine/fit/ceres_fitter.cc): one small ceres::Problem per fitting
//           problem, automatic derivatives, same model, bounds, start and stages. For
//           cross-checks and as the benchmarks' baseline.
//   kVulkan the GPU path (engine/fit/vulkan_fitter.h): kCpu's algorithm with the LM on a Vulkan
//           device (shaders/fit/lm_fit.comp; constants in shaders/shared/fit_status.h),
//           preparation and post-processing on the CPU. Unavailable without Vulkan.
// CreateScalarFitter gives the readable one-problem-at-a-time path in float or double
// (engine/fit/lm.h), which the batched path must match.
#include <array>
#include <memory>
#include <string>
#include <vector>

#include "engine/brdf/lafortune.h"
#include "engine/core/status.h"
#include "engine/fit/model.h"
#include "engine/texel/samples.h"
#include "shaders/shared/fit_status.h"

namespace reflcap::fit {

enum class Backend { kCpu, kCeres, kVulkan };
const char* BackendName(Backend backend);  // "cpu", "ceres", "vulkan"
StatusOr<Backend> ParseBackend(const std::string& name);

// Each value's condition is documented in shaders/shared/fit_status.h.
enum class FitStatus : int {
  kConverged = gpu::shared::kFitStatusConverged,
  kMaxIterations = gpu::shared::kFitStatusMaxIterations,
  kSingular = gpu::shared::kFitStatusSingular,
  kTooFewSamples = gpu::shared::kFitStatusTooFewSamples,
  kUnidentifiableLobe = gpu::shared::kFitStatusUnidentifiableLobe,
  kNonFiniteInput = gpu::shared::kFitStatusNonFiniteInput,
};
constexpr int kFitStatusCount = gpu::shared::kFitStatusCount;
// "converged", "max_iterations", "singular", "too_few_samples", "unidentifiable_lobe",
// "non_finite_input" (the fit_report.json keys).
const char* FitStatusName(FitStatus status);
// The texel status of several problems (the three channels of aniso/iso): the most severe, in
// the order non_finite_input > too_few_samples > unidentifiable_lobe > singular >
// max_iterations > converged.
FitStatus CombineStatus(FitStatus a, FitStatus b);

// How the start values are chosen (seed.h documents both).
enum class InitScheme {
  kSeed,   // the seed's data-driven start (section 4.2) and two-stage LM (section 4.3)
  kFixed,  // a fixed start in normalised units, one LM stage over all parameters
};
const char* InitSchemeName(InitScheme init);
StatusOr<InitScheme> ParseInitScheme(const std::string& name);

// Robust loss on the weighted residual r = sqrt(w) (f - y), in the σ units of the weights
// (inverse variances, as samples.h defines them), with scale a = FitOptions::loss_scale:
//   kNone    rho(s) = s                               (s = r^2; least squares)
//   kHuber   rho(s) = s for s <= a^2, else 2 a sqrt(s) - a^2
//   kCauchy  rho(s) = a^2 log(1 + s / a^2)
// as Ceres' HuberLoss(a) and CauchyLoss(a); cost = 1/2 sum rho(r_i^2).
enum class LossKind { kNone = 0, kHuber = 1, kCauchy = 2 };
const char* LossKindName(LossKind loss);
StatusOr<LossKind> ParseLossKind(const std::string& name);

// Lobe transfer (engine/fit/lobe_transfer.h): after the fit, a texel that never saw its mirror
// configuration (kUnidentifiableLobe) borrows the lobes of a nearby texel of similar albedo when
// its own samples do not contradict them. Applied by RunFit (the FIT driver), not by Fitter::Fit.
struct LobeTransferOptions {
  bool enabled = true;
  // Window half-size in atlas texels. 6: a 13 x 13 window, a few millimetres on a 512^2 atlas of
  // a 20 cm object; small enough to stay inside one material region, large enough to reach past
  // a band of unidentifiable texels (the rig's gaps in half-vector elevation are a few degrees
  // of normal, i.e. a few texels on a curved surface).
  int radius = 6;
  // Relative RGB albedo distance a donor may have. 0.15: texture variation within one material
  // (the synth's +-10 % modulation, Suzanne's patches) passes; distinct materials rarely do.
  double albedo_tolerance = 0.15;
  // Cost increase (1/2 sum w r^2 in noise units) the recipient's samples may show with the
  // borrowed lobe over its Lambert-only fit. 2 = a chi-square increase of 4 summed over the
  // texel's residuals: a 2-sigma change for the one effective parameter the lobe adds; a lobe
  // that contradicts the samples costs far more.
  double max_cost_increase = 2.0;
  // Rounds of transfer (lobe_transfer.h): round r lends the lobes borrowed in round r - 1 on.
  int rounds = 4;

  Status Validate() const;
};

// Per-texel model choice between a texel's lobe and its material's (MaterialClusterOptions).
enum class ModelChoice { kKFold, kBic };
const char* ModelChoiceName(ModelChoice choice);  // "kfold", "bic"
StatusOr<ModelChoice> ParseModelChoice(const std::string& name);
// Most folds the k-fold comparison takes (per-fold sums on the stack).
constexpr int kMaxModelFolds = 20;

// Material clusters (engine/fit/material_clusters.h): after lobe transfer, the texels still
// without a lobe take one their material's pooled samples support. Applied by RunFit.
struct MaterialClusterOptions {
  bool enabled = true;
  // Albedo-space units (material_clusters.h step 1). Chromaticity 0.02: the synth's and
  // Suzanne's texture modulation of one material stays within a unit or two, distinct pigments
  // differ by several. Level 0.1 in ln(sum rho): a 10 % brightness step.
  double chroma_scale = 0.02;
  double level_scale = 0.1;
  // At most this many clusters (64: far more materials than an object shows; each costs a pooled
  // test of kClusterLobeCandidates lobes on up to pool_texels texels).
  int max_clusters = 64;
  // A split must leave both halves at least this many texels: fewer cannot tell a material from
  // a few badly fitted texels.
  int min_cluster_texels = 16;
  // Evidenced texels per cluster whose samples test the candidate lobes (an even stride through
  // the cluster): 256 texels of ~20-100 samples decide a lobe's few parameters many times over.
  int pool_texels = 256;
  // Lobes a cluster offers each recipient (best pooled cost first): a material whose lobe
  // varies (texture in the specular layer) is covered by a few.
  int lobes_per_cluster = 3;
  // How a texel with a lobe (its own, or a neighbour's) is compared with its cluster's lobes
  // (material_clusters.h step 4): by k-fold prediction of its own held-out photographs, or by
  // the Bayesian information criterion on all its samples.
  ModelChoice model_choice = ModelChoice::kKFold;
  int folds = 5;  // k of the k-fold: 5 holds out a fifth of the photographs each time
  // The k-fold refits of a texel's own lobe stop once the cluster lobe has won (each further
  // fold only adds a cost >= 0 to the own score): the same choices with ~half the refits. Off
  // only in the test that checks that claim; not in the fit options' JSON.
  bool stop_decided_refits = true;

  Status Validate() const;
};

// Albedo fill (engine/fit/albedo_fill.h): after the fit, a texel with no valid sample (no train
// photograph lit and saw it) takes the mean albedo of the texels around it that have one, so a
// held-out view that lights it shows the surrounding material instead of black. Applied by
// RunFit, not by Fitter::Fit.
struct AlbedoFillOptions {
  bool enabled = true;
  // Window half-size in atlas texels per round. 2: a 5 x 5 window, inside one material region.
  int radius = 2;
  // Rounds: round r also draws on the texels filled in round r - 1, so a hole fills inwards up to
  // radius x rounds texels from its rim (32 by default: the dimples and crevices no light
  // reached, not the underside of an object that no camera saw either).
  int rounds = 16;

  Status Validate() const;
};

struct FitOptions {
  // Lafortune lobes per texel, 0..3 (0 = Lambert only; at most 2 for the shared lobe model).
  int lobes = 1;
  // aniso (Cx, Cy, Cz, n per channel), iso (Cx = Cy) or shared (one shape, per-channel scale);
  // see model.h.
  LobeModel lobe_model = LobeModel::kAniso;
  // Per-texel model selection (`--lobe-model auto`; RunFit only, with lobe_model kAniso and
  // lobes > 0): every texel is fitted both anisotropic and isotropic (Cx = Cy), and keeps the
  // fit with the lower Bayesian information criterion 2 cost + k ln(residuals), k its free
  // parameters — the isotropic lobe unless the samples pay for the anisotropic one's extra
  // parameters. An unneeded Cx != Cy is unconstrained where no sample looked (grazing mirror
  // configurations) and extrapolates there.
  bool select_lobe_model = false;
  InitScheme init = InitScheme::kSeed;
  LossKind loss = LossKind::kNone;
  // Robust loss scale a in σ units of the sample weights, > 0. 3: samples more than 3 σ off
  // (shadows, interreflections, misregistration) are down-weighted, Gaussian noise is not.
  double loss_scale = 3.0;
  // Evaluated LM steps per stage (the seed scheme runs two stages), in [1, 10000].
  int max_iterations = 100;
  // Cap of the seed scheme's first stage (C's only, n held at start_exponent), in [1, 10000].
  // Stage 1 is there to bring the start lobe onto the data, not to converge: run to the end at
  // a wrong exponent, it bends the C's to imitate the width that n should give (e.g. Cz < 0 for
  // a sharp highlight fitted at n = 20), and stage 2 then starts in a wrong basin.
  int first_stage_iterations = 3;
  // The lobe exponent every start uses (the seed fixes n to a start value), in
  // [kMinExponent, kMaxExponent]. 20: a mid-range gloss, lobe half-width ~15 degrees.
  double start_exponent = 20.0;
  // A problem needs at least max(min_samples, parameters + 1) valid samples for a lobe fit,
  // else it is Lambert-only with kTooFewSamples. >= 1.
  int min_samples = 8;
  // Samples with cos(theta_i) or cos(theta_o) below this are masked (grazing directions: the
  // shading normal's error dominates there). In [0, 1).
  double min_cos_theta = 0.05;
  // Lobe identifiability: some valid sample must see wo within this angle (degrees) of the
  // mirror direction of wi, else kUnidentifiableLobe (and lobe transfer may lend the texel a
  // neighbour's lobe). In (0, 90]. 5: a texel whose nearest sample is 5-10 degrees off its
  // mirror direction cannot tell a tall narrow lobe from a low broad one, and its fit
  // extrapolates the holdout highlights; a borrowed lobe measured near its peak predicts them
  // better (holdout, 10 -> 5 degrees: suzanne 36.48 -> 36.96 dB, synth captures +1.2 to +1.5 dB,
  // DiLiGenT rel. RMSE better on ball16, bear, buddha, equal on cat and pot1, goblet 0.262 ->
  // 0.266; 3 degrees is no better; README.md "Which highlight cone").
  double highlight_cone_deg = 5.0;
  // Lobe evidence: the brightest excess over the start's Lambert level among the samples within
  // 45 degrees of the mirror configuration (problem.h kEvidenceConeDeg) must exceed this many
  // robust noise σ (from the lower quartile, problem.h) plus 2 % of that level, else the texel
  // is fitted Lambert-only (lobe absent, status kConverged). >= 0.
  double evidence_sigmas = 5.0;
  // Stopping tests (lm.h): relative step in Jacobi-scaled coordinates, relative cost decrease,
  // max-norm of the Jacobi-scaled gradient (normalised units). Each in [0, 1). 1e-5: two
  // orders below the parameters' statistical error at 1 % noise and ~100 float ulps, so the
  // float path can meet them; tighter only adds iterations.
  double step_tolerance = 1e-5;
  double cost_tolerance = 1e-5;
  double gradient_tolerance = 1e-10;
  // Channel retry (problem.h kChannelRetryCostRatio): a channel whose fit ended far worse than
  // its texel's best channel is solved again from that channel's lobes and keeps the better
  // solution. Every backend runs it (`--no-channel-retry`: off).
  bool channel_retry = true;
  // Worker threads (0 = all hardware threads).
  int threads = 0;
  LobeTransferOptions lobe_transfer;
  MaterialClusterOptions clusters;
  AlbedoFillOptions albedo_fill;
  // Diffuse fall-off (engine/fit/diffuse_falloff.h): after the clusters, a texel still
  // Lambert-only takes Lafortune's generalized diffuse lobe (Cx = Cy = 0) when its held-out
  // photographs (clusters.folds folds) prefer it. Applied by RunFit, not by Fitter::Fit.
  bool diffuse_falloff = true;

  Status Validate() const;
  std::string ToString() const;
};

// One texel's result. params and sigma are natural units in brdf::BrdfParams layout (aniso
// form for every lobe model, so a texture set reads the same whatever was fitted).
struct TexelFit {
  brdf::BrdfParams params;
  // Standard deviation of every parameter slot of `params`, from (J^T J)^-1 scaled by the
  // residual variance 2 cost / (residuals - free parameters), propagated through the map to
  // natural units. -1 where unknown: parameters not fitted (the lobes of a Lambert-only fit),
  // no redundancy (residuals <= free parameters), or a singular J^T J.
  brdf::BrdfParams sigma;
  FitStatus status = FitStatus::kTooFewSamples;
  float cost = 0;        // 1/2 sum rho(r^2), r = sqrt(w) (f - y) in natural units; summed
                         // over the texel's problems
  int iterations = 0;    // evaluated LM steps over all stages; the max over the texel's problems
  int samples = 0;       // valid samples used (the max over problems)
  int residuals = 0;     // valid (sample, channel) residuals, summed over problems
  bool lambert_only = false;  // some problem of the texel was fitted without lobes
};

// One Fit call at a time per Fitter (it reuses its per-worker workspaces); use one Fitter per
// thread that fits.
class Fitter {
 public:
  virtual ~Fitter() = default;
  virtual Backend backend() const = 0;
  // What runs the fits, e.g. "cpu: 2 threads, 16-lane batches (x86-64-v4 kernel)".
  virtual std::string device() const = 0;
  // Fits every texel of `chunk`; results->at(i) is texel chunk.first_texel + i (resized to
  // chunk.texel_count). InvalidArgument for invalid options or an inconsistent chunk.
  virtual Status Fit(const TexelSampleChunk& chunk, const FitOptions& options,
                     std::vector<TexelFit>* results) = 0;
};

// threads: CPU worker threads, 0 = all. device (kVulkan only): "" = automatic choice, an index
// or a name substring (VulkanFitterOptions::device). kVulkan is Unavailable when this build or
// machine has no Vulkan device (vulkan_fitter.h says how `--backend auto` decides).
StatusOr<std::unique_ptr<Fitter>> CreateFitter(Backend backend, int threads = 0,
                                               const std::string& device = "");
// The scalar reference path (lm.h) in double or float, one problem at a time per thread.
std::unique_ptr<Fitter> CreateScalarFitter(bool use_double, int threads = 0);

// Lobe value at normal incidence, max(0, Cz)^n: the "peak" the accuracy tests compare (for a
// mirror lobe it is the value at the mirror direction for every incidence).
double LobePeak(const brdf::LobeParams& lobe);

}  // namespace reflcap::fit
