#pragma once
// `reflcap fit` as a library call: stream a sample store's chunks through a Fitter (reading the
// next chunk on a thread while the current one is fitted — double buffering, so disk reads
// overlap the CPU or GPU work and at most two chunks are in memory) and write the FIT folder.
// The fits of all texels are held in a FitStore (fit_store.h, 82 bytes per texel for one lobe),
// their sigmas in a scratch file in the staging folder (SigmaSpill); the maps are built and
// written one at a time:
//   FIT/params.exr       BrdfMaps (engine/texel/brdf_maps.h channel names), atlas layout
//   FIT/sigma.exr        the same channels, each parameter's standard deviation (-1 = unknown)
//   FIT/status.exr       channels `status` (FitStatus code, -1 where the atlas has no texel),
//                        `iterations`, `cost` (final 1/2 sum rho(r^2)) and `lobe_donor` (the
//                        texel whose lobes it borrowed by lobe transfer or from its material
//                        cluster, -1 for none), `albedo_filled`, `material_cluster` and
//                        `model` (TexelModel below)
//   FIT/fit_report.json  backend, device, options, texels, counts per status, cost and reduced
//                        chi^2 percentiles, iterations, fits_per_second, timings
// The folder is staged and moved into place only when complete (StagingDir).
#include <filesystem>
#include <string>
#include <vector>

#include "engine/core/status.h"
#include "engine/fit/fit_checkpoint.h"
#include "engine/fit/fit_store.h"
#include "engine/fit/fitter.h"
#include "engine/fit/vulkan_fitter.h"
#include "engine/mesh/texel_atlas.h"

namespace reflcap::fit {

struct FitRunSummary {
  size_t texels = 0;
  size_t texels_with_samples = 0;
  std::array<size_t, kFitStatusCount> status_counts{};
  double fit_seconds = 0;
  double total_seconds = 0;
  double fits_per_second = 0;  // problems (channel fits for aniso/iso, texels for shared) per s
  std::string device;
  size_t lobes_transferred = 0;   // lobe transfer: texels that took a neighbour's lobe
  int material_clusters = 0;      // material clusters formed, and those that kept a lobe
  int material_clusters_with_lobe = 0;
  size_t cluster_lobes_lent = 0;      // Lambert-only texels that took their cluster's lobe
  size_t cluster_lobes_replaced = 0;  // texels whose own or borrowed lobe gave way to it
  size_t falloff_candidates = 0;      // diffuse fall-off: texels tested
  size_t falloff_taken = 0;           // of those, texels that took the fall-off lobe
  size_t falloff_replaced = 0;        // of those, texels whose borrowed lobe it replaced
};

// Which model a texel's final parameters are (status.exr `model`, fit_report.json
// `model_counts`): Lambert because it saw its mirror configuration and showed no lobe; Lambert
// for lack of evidence (no lobe was measured or lent); its own fitted lobe; a neighbour's (lobe
// transfer); its material cluster's; no samples at all (an albedo from albedo fill or none); a
// diffuse fall-off lobe of its own (diffuse_falloff.h).
enum class TexelModel {
  kLambertLobeAbsent = 0,
  kLambertNoEvidence = 1,
  kOwnLobe = 2,
  kNeighbourLobe = 3,
  kClusterLobe = 4,
  kNoSamples = 5,
  kFalloffLobe = 6,  // its own diffuse fall-off lobe (diffuse_falloff.h)
};
constexpr int kTexelModelCount = 7;
extern const char* const kTexelModelNames[kTexelModelCount];
TexelModel TexelModelOf(const FitStore& fits, size_t t);

// Reads SAMPLES, fits with `backend`, writes FIT (refused when it exists non-empty, unless
// overwrite). `vulkan` configures kVulkan: its device ("" = automatic, else an index or a name
// substring), kernel and cluster size; `backend_choice`, when given, is written to fit_report.json as the reason for
// the backend (`--backend auto`). The report's "device" is Fitter::device() (for kVulkan the
// device's name and driver). Errors: NotFound/DataLoss from the store, Unavailable for a
// backend this build or machine lacks, NotFound when `device` matches no device,
// InvalidArgument for bad options.
//
// Every chunk's results are written to the checkpoint folder OUT.checkpoint as soon as they are
// fitted (fit_checkpoint.h); it is deleted when FIT is in place. A run that finds that folder
// refuses to start (FailedPrecondition) unless `control.resume`, which reads the chunks found
// there instead of fitting them (when the folder is of the same store, options, backend and
// shard; else FailedPrecondition naming the field) and gives maps bit-identical to an
// uninterrupted run. With control.shard.count > 1, only the shard's chunks are fitted and OUT is
// a part (fit_checkpoint.h) for MergeFitParts; its summary counts the shard's texels only.
struct FitRunControl {
  Shard shard;
  bool resume = false;
};
StatusOr<FitRunSummary> RunFit(const std::filesystem::path& samples,
                               const std::filesystem::path& out, Backend backend,
                               const FitOptions& options, bool overwrite,
                               const VulkanFitterOptions& vulkan = {},
                               const std::string& backend_choice = "",
                               const FitRunControl& control = {});

// `reflcap merge` of fit parts: checks that `parts` are the shards 0..N-1 of one fit (one store
// fingerprint, the same options, backend and N, each shard once, their chunk ranges tiling the
// store), reads every chunk result file, then runs the post-fit phase (lobe transfer, albedo
// fill, material clusters, diffuse fall-off, maps) on the whole atlas exactly as RunFit does,
// into `out`: maps bit-identical to a single run's. The store is read from `samples` when given, else from the
// path the parts record. Errors (nothing written): FailedPrecondition for parts that do not
// belong together, naming the part and the field; NotFound/DataLoss for a missing or corrupt
// part file or chunk result file, naming it.
StatusOr<FitRunSummary> MergeFitParts(const std::vector<std::filesystem::path>& parts,
                                      const std::filesystem::path& out, bool overwrite, int threads,
                                      const std::filesystem::path& samples = {});

// Writes status.exr, params.exr and sigma.exr for the per-texel fits in `atlas` layout into
// `dir`, one map at a time, each built straight from the store and the spill (no per-texel
// BrdfParams copy). A texel with a lobe donor gets albedo sigmas -1 (re-fitted, not measured).
// Releases the store's parameters once their map is built (FitStore::ReleaseParams): afterwards
// only its scalars remain. `albedo_filled` (one byte per texel, or empty for none) marks the
// texels albedo_fill.h filled: status.exr's `albedo_filled` channel (1 = filled). `cluster_of`
// (one per texel, or empty for none) is the `material_cluster` channel (material_clusters.h; -1 =
// no cluster); the `model` channel is TexelModelOf (-1 = no texel). Each map is compressed on
// `threads` threads (WriteExrChannels).
Status WriteFitMaps(const std::filesystem::path& dir, const TexelAtlas& atlas, FitStore* fits,
                    SigmaSpill* sigma, const std::vector<uint8_t>& albedo_filled = {},
                    const std::vector<int32_t>& cluster_of = {}, int threads = 0);

}  // namespace reflcap::fit
