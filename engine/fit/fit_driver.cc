#include "engine/fit/fit_driver.h"

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <deque>
#include <cmath>
#include <functional>
#include <future>
#include <memory>
#include <optional>
#include <sstream>
#include <utility>

#ifdef __GLIBC__
#include <malloc.h>
#endif

#include <nlohmann/json.hpp>

#include "engine/core/atomic_file.h"
#include "engine/core/log.h"
#include "engine/core/parallel.h"
#include "engine/core/progress.h"
#include "engine/fit/albedo_fill.h"
#include "engine/fit/diffuse_falloff.h"
#include "engine/fit/lobe_transfer.h"
#include "engine/fit/material_clusters.h"
#include "engine/fit/problem.h"
#include "engine/image/exr_io.h"
#include "engine/texel/brdf_maps.h"
#include "engine/texel/sample_store.h"

namespace reflcap::fit {
namespace fs = std::filesystem;
using Json = nlohmann::json;

namespace {

// SigmaSpill's scratch file in the staging folder (deleted before the folder is committed).
constexpr const char* kSigmaScratchFile = "sigma.scratch";

double Seconds(std::chrono::steady_clock::time_point since) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - since).count();
}

// The values at the positions the sorted v would have them, found by selection in increasing
// order (each on the part above the last): linear time, where sorting a million texels' costs
// took ~0.1 s of the fit's serial tail.
Json Percentiles(std::vector<double> v) {
  if (v.empty()) return Json::object();
  Json out = Json::object();
  auto first = v.begin();
  for (const auto& [name, q] : {std::pair<const char*, double>{"p10", 0.10}, {"p50", 0.50},
                                {"p90", 0.90}, {"p99", 0.99}, {"max", 1.0}}) {
    const size_t k = std::min(v.size() - 1, size_t(q * double(v.size() - 1) + 0.5));
    const auto at = v.begin() + std::ptrdiff_t(k);
    std::nth_element(first, at, v.end());
    out[name] = *at;
    first = at;
  }
  return out;
}

// Bayesian information criterion of a texel's fit: 2 cost (= chi-square in noise units) plus
// k ln(residuals), k = the free parameters of `model` (3, the albedos, for a Lambert-only fit).
double Bic(const TexelFit& f, LobeModel model, int lobes) {
  const int k = f.lambert_only ? 3 : NumParams(model, lobes) * ProblemsPerTexel(model);
  return 2.0 * double(f.cost) + k * std::log(double(std::max(f.residuals, 1)));
}

// Image channel of each FitStore parameter slot (fit_store.h layout: rho_d, then per lobe and
// channel Cx, Cy, Cz, n) in the BrdfChannelNames order (rho_d, then per lobe and field R, G, B).
std::vector<int> MapChannelOfSlot(int lobes) {
  std::vector<int> channel(size_t(brdf::kChannels * brdf::ParamsPerChannel(lobes)));
  for (int c = 0; c < brdf::kChannels; ++c) channel[c] = c;
  for (int k = 0; k < lobes; ++k) {
    for (int c = 0; c < brdf::kChannels; ++c) {
      for (int f = 0; f < 4; ++f) {
        channel[brdf::kChannels + 4 * (brdf::kChannels * k + c) + f] =
            brdf::kChannels + 4 * brdf::kChannels * k + brdf::kChannels * f + c;
      }
    }
  }
  return channel;
}

// Fills pixel `px` of a parameter map from one texel's floats in the FitStore layout.
void PutTexel(const std::vector<int>& channel, const float* in, float* px) {
  for (size_t i = 0; i < channel.size(); ++i) px[channel[i]] = in[i];
}

// Gives the heap's free pages back to the system (glibc keeps them in its arenas, the chunk
// reader thread's among them), so that little of one phase's memory (the chunks) stays resident
// under the next (the maps). Not all of it: at 1 M texels ~65 MB of freed chunk-sized blocks
// stay resident.
void ReleaseFreeHeap() {
#ifdef __GLIBC__
  malloc_trim(0);
#endif
}

}  // namespace

const char* const kTexelModelNames[kTexelModelCount] = {
    "lambert_lobe_absent", "lambert_no_evidence", "own_lobe", "neighbour_lobe", "cluster_lobe",
    "no_samples", "falloff_lobe"};

TexelModel TexelModelOf(const FitStore& fits, size_t t) {
  if (fits.donor(t) == FitStore::kDiffuseFalloff) return TexelModel::kFalloffLobe;
  if (fits.samples(t) == 0 && fits.donor(t) != FitStore::kClusterLobe) return TexelModel::kNoSamples;
  if (fits.donor(t) == FitStore::kClusterLobe) return TexelModel::kClusterLobe;
  if (fits.donor(t) >= 0) return TexelModel::kNeighbourLobe;
  if (!fits.lambert_only(t)) return TexelModel::kOwnLobe;
  return fits.status(t) == FitStatus::kConverged ? TexelModel::kLambertLobeAbsent
                                                 : TexelModel::kLambertNoEvidence;
}

// Sample-store chunks a fit pass reads ahead of the one it fits. One was too few on a 16-core
// host (NVIDIA H200 machine, million preset, `reflcap fit --threads 4/8/16`): reading a chunk
// (~30 MB, one thread) outlasted fitting it on 16 threads, and the pass waited 0.09 / 0.29 /
// 0.57-0.62 s for chunks. Three bound the extra memory to two decoded chunks.
constexpr size_t kFitChunksReadAhead = 3;
// Work per ParallelFor task while the maps are filled: large enough that a task's hand-over is
// negligible, small enough to balance (a million-texel atlas is ~1,300 rows).
constexpr int64_t kMapRowsPerTask = 16;
constexpr int64_t kMapTexelsPerTask = 1 << 14;

// An atlas-sized map with every value `fill`, its pages first touched on all threads: a
// zero-filled Image of the million atlas (72 MB) took 0.06-0.09 s on one thread, most of it
// page faults, three of them 0.15 s of the maps' 0.75 s on 2 cores.
Image FilledMap(const TexelAtlas& atlas, int channels, float fill, int threads) {
  Image map = Image::Uninitialized(atlas.width, atlas.height, channels);
  const int64_t per_task = kMapRowsPerTask * int64_t(atlas.width) * channels;
  ParallelFor(0, int64_t(map.data.size()), per_task, [&](int64_t begin, int64_t end, int) {
    std::fill(map.data.begin() + begin, map.data.begin() + end, fill);
  }, threads);
  return map;
}

Status WriteFitMaps(const fs::path& dir, const TexelAtlas& atlas, FitStore* fits,
                    SigmaSpill* sigma, const std::vector<uint8_t>& albedo_filled,
                    const std::vector<int32_t>& cluster_of, int threads) {
  REFLCAP_CHECK(fits->size() == atlas.TexelCount());
  REFLCAP_CHECK(sigma->lobes() == fits->lobes());
  REFLCAP_CHECK(albedo_filled.empty() || albedo_filled.size() == fits->size());
  REFLCAP_CHECK(cluster_of.empty() || cluster_of.size() == fits->size());
  // The three files are filled on all threads (each texel owns its pixel) and written at once,
  // each compressed on OpenEXR's pool. One after another, each write's part outside the pool
  // (the file, the sigma spill's read) left the pool waiting: maps 0.59 s of the million fit on
  // an H200 host at 16 threads and 0.71 at 8; on 2 cores 0.93 s then, 0.73-0.75 s at once, the
  // files byte-identical.
  const std::vector<std::string> names = BrdfChannelNames(fits->lobes());
  const std::vector<int> channel = MapChannelOfSlot(fits->lobes());
  REFLCAP_CHECK(names.size() == channel.size());
  const int n = int(channel.size());
  // The sigma spill is read from disk on a thread of its own while the other two images are
  // filled (its callback reads only the donors, which stay).
  Image sigmas = FilledMap(atlas, n, 0.0f, threads);
  std::future<Status> sigmas_read_pending = std::async(std::launch::async, [&] {
    return sigma->ReadAll([&](size_t t, const float* in) {
      float* px = &sigmas.data[size_t(atlas.pixel_of_texel[t]) * n];
      PutTexel(channel, in, px);
      // Lobe transfer re-fitted the albedo of a texel with a donor: re-fitted, not measured. A
      // cluster lobe replaced whatever lobe the texel fitted, and a fall-off lobe was fitted in
      // closed form after the LM: none of its own sigmas apply.
      if (fits->borrowed(t)) {
        const int unknown = fits->donor(t) < 0 ? n : brdf::kChannels;
        for (int c = 0; c < unknown; ++c) px[c] = -1;
      }
    });
  });
  std::future<Status> status_written, params_written;
  {
    constexpr int kStatusChannels = 7;
    auto status_image = std::make_shared<Image>(
        Image::Uninitialized(atlas.width, atlas.height, kStatusChannels));
    Image& status = *status_image;
    // Pixels without a texel: no texel, 0 iterations and cost, no donor, not filled, no
    // cluster, no model.
    ParallelFor(0, int64_t(status.PixelCount()), kMapRowsPerTask * atlas.width,
                [&](int64_t begin, int64_t end, int) {
      for (int64_t p = begin; p < end; ++p) {
        float* px = &status.data[kStatusChannels * size_t(p)];
        px[0] = float(gpu::shared::kFitStatusNoTexel);
        px[1] = 0;
        px[2] = 0;
        px[3] = -1;
        px[4] = 0;
        px[5] = -1;
        px[6] = -1;
      }
    }, threads);
    ParallelFor(0, int64_t(fits->size()), kMapTexelsPerTask, [&](int64_t begin, int64_t end, int) {
      for (int64_t t = begin; t < end; ++t) {
        float* px = &status.data[kStatusChannels * size_t(atlas.pixel_of_texel[t])];
        px[0] = float(int(fits->status(t)));
        px[1] = float(fits->iterations(t));
        px[2] = fits->cost(t);
        // Texel indices below 2^24 are exact in float; atlases stay far below (16.7 M texels).
        px[3] = float(fits->donor(t));
        px[4] = albedo_filled.empty() ? 0.0f : float(albedo_filled[t]);
        px[5] = cluster_of.empty() ? -1.0f : float(cluster_of[t]);
        px[6] = float(int(TexelModelOf(*fits, t)));
      }
    }, threads);
    status_written = std::async(std::launch::async, [status_image, dir, threads] {
      return WriteExrChannels(dir / "status.exr", *status_image,
                              {"status", "iterations", "cost", "lobe_donor", "albedo_filled",
                               "material_cluster", "model"},
                              ExrPixelType::kFloat, threads);
    });
  }
  {
    auto params_image = std::make_shared<Image>(FilledMap(atlas, n, 0.0f, threads));
    Image& params = *params_image;
    ParallelFor(0, int64_t(fits->size()), kMapTexelsPerTask, [&](int64_t begin, int64_t end, int) {
      for (int64_t t = begin; t < end; ++t) {
        PutTexel(channel, fits->params(t), &params.data[size_t(atlas.pixel_of_texel[t]) * n]);
      }
    }, threads);
    // The parameters are in the image now: freed before it is written.
    fits->ReleaseParams();
    params_written = std::async(std::launch::async, [params_image, dir, names, threads] {
      return WriteExrChannels(dir / "params.exr", *params_image, names, ExrPixelType::kFloat,
                              threads);
    });
  }
  const Status sigmas_read = sigmas_read_pending.get();
  const Status sigmas_written =
      sigmas_read.ok()
          ? WriteExrChannels(dir / "sigma.exr", sigmas, names, ExrPixelType::kFloat, threads)
          : sigmas_read;
  // Every write finished (and its file renamed into place or not) before any error returns.
  const Status status_status = status_written.get();
  const Status params_status = params_written.get();
  for (const Status& s : {status_status, params_status, sigmas_written}) {
    if (!s.ok()) return s;
  }
  return OkStatus();
}

namespace {

// fit_report.json `diffuse_falloff`: candidates, taken, and taken per exponent ("0.25", "1", ...).
Json FalloffJson(const DiffuseFalloffStats& s) {
  Json by = Json::object();
  for (int k = 0; k < kFalloffExponentCount; ++k) {
    std::ostringstream name;
    name << kFalloffExponents[size_t(k)];
    by[name.str()] = s.by_exponent[size_t(k)];
  }
  return {{"candidates", s.candidates}, {"taken", s.taken}, {"replaced", s.replaced},
          {"by_exponent", by}};
}

// Decoded sample chunks RunFit keeps in memory for lobe transfer: a quarter of the machine's
// physical memory, at most 8 GiB (the million preset's store decodes to ~1.9 GiB), so the fit
// stage's peak memory stays well inside what the machine has.
uint64_t SampleCacheBudget() {
  constexpr uint64_t kMaxBytes = uint64_t{8} << 30;
  const long pages = sysconf(_SC_PHYS_PAGES), page = sysconf(_SC_PAGE_SIZE);
  if (pages <= 0 || page <= 0) return 0;
  return std::min(kMaxBytes, uint64_t(pages) * uint64_t(page) / 4);
}

}  // namespace

namespace {

// What the per-chunk phase leaves for the post-fit phase (FinishFit).
struct FitPass {
  std::unique_ptr<FitStore> fits;
  std::unique_ptr<SigmaSpill> sigma;
  // Chunks kept after the fit pass for lobe transfer and the clusters, which test recipients on
  // their own samples: re-reading and checking the store for each took 8.3 of the transfer's
  // 11.9 s on the million preset (2 cores). Kept while their decoded size stays within
  // SampleCacheBudget(); the others are read again.
  std::vector<std::optional<TexelSampleChunk>> cached;
  uint64_t cached_bytes = 0;
  double read_seconds = 0, fit_seconds = 0, checkpoint_seconds = 0;
  // Before the first chunk (the fitter's creation: a Vulkan device; the store opened; the
  // result store allocated), and the wait for the fitters' release (0 for a merge).
  double setup_seconds = 0, release_seconds = 0;
  std::future<void> released;  // the fitters' release, running past the fit (RunFit)
  size_t iso_chosen = 0;  // --lobe-model auto: texels that kept the isotropic fit
  VulkanFitStats vulkan_stats;  // summed over the chunks (kVulkan)
  bool used_vulkan = false;
  uint32_t chunks_in_flight = 1;  // chunks fitted at once (VulkanFitterOptions::chunks_in_flight)
  uint32_t fitted_chunks = 0, resumed_chunks = 0;
};

// The store's atlas, checked against store.json.
StatusOr<TexelAtlas> StoreAtlas(const fs::path& samples, const SampleStoreInfo& info) {
  TexelAtlas atlas;
  atlas.width = info.atlas_width;
  atlas.height = info.atlas_height;
  atlas.pixel_of_texel = info.pixel_of_texel;
  if (atlas.pixel_of_texel.size() != info.texels) {
    return DataLossError(samples.string(), ": atlas.bin holds ", atlas.pixel_of_texel.size(),
                         " texels but store.json says ", info.texels);
  }
  for (uint32_t p : atlas.pixel_of_texel) {
    if (uint64_t(p) >= uint64_t(atlas.width) * uint64_t(atlas.height)) {
      return DataLossError(samples.string(), ": atlas.bin: pixel ", p, " outside the ",
                           atlas.width, "x", atlas.height, " atlas");
    }
  }
  if (info.texels > FitStore::kMaxTexels) {
    return InvalidArgumentError(samples.string(), ": ", info.texels, " texels; fit takes at most ",
                                FitStore::kMaxTexels);
  }
  return atlas;
}

uint32_t ChunkFirstTexel(const SampleStoreInfo& info, uint32_t c) { return c * info.chunk_texels; }
// Memory a decoded chunk holds (what the sample cache counts against its budget).
uint64_t DecodedBytes(const TexelSampleChunk& chunk) {
  return chunk.samples.size() * sizeof(BrdfSample) + chunk.offsets.size() * sizeof(uint64_t);
}

uint32_t ChunkTexelCount(const SampleStoreInfo& info, uint32_t c) {
  return uint32_t(std::min<uint64_t>(info.chunk_texels, uint64_t(info.texels) - ChunkFirstTexel(info, c)));
}

// Stores one chunk's results in the pass.
Status Keep(uint32_t first_texel, const std::vector<TexelFit>& results, FitPass* pass) {
  // A shard's pass keeps nothing: its results are the chunk result files it writes.
  if (pass->fits == nullptr) return OkStatus();
  for (size_t i = 0; i < results.size(); ++i) pass->fits->Set(first_texel + i, results[i]);
  return pass->sigma->Write(first_texel, results);
}

// The per-chunk phase over chunks [range.begin, range.end): each chunk fitted (the next read on
// a thread meanwhile) and its results kept in the pass and, when `checkpoint` is not empty,
// written there as a chunk result file. With `resume`, chunks whose result file is already there
// are read instead of fitted. With `second` (which returns a second fitter, or null when there is
// none after all; called once, when the second chunk is due), two chunks are fitted at once,
// each on its own fitter (VulkanFitterOptions::chunks_in_flight); results are kept in chunk
// order all the same, so they do not depend on it.
Status FitChunks(const SampleStoreReader& store, ChunkRange range, Fitter* fitter,
                 const std::function<Fitter*()>& second, const FitOptions& options,
                 const fs::path& checkpoint, bool resume, FitPass* pass) {
  const SampleStoreInfo& info = store.info();
  uint64_t range_texels = 0;
  for (uint32_t c = range.begin; c < range.end; ++c) range_texels += ChunkTexelCount(info, c);
  Progress progress("fit", range_texels);
  std::vector<uint32_t> todo;
  for (uint32_t c = range.begin; c < range.end; ++c) {
    const fs::path file = checkpoint.empty() ? fs::path() : checkpoint / FitChunkFileName(c);
    std::error_code ec;
    if (resume && !file.empty() && fs::exists(file, ec)) {
      REFLCAP_ASSIGN_OR_RETURN(std::vector<TexelFit> results,
                               ReadFitChunk(file, ChunkFirstTexel(info, c), ChunkTexelCount(info, c),
                                            options.lobes));
      REFLCAP_RETURN_IF_ERROR(Keep(ChunkFirstTexel(info, c), results, pass));
      ++pass->resumed_chunks;
      progress.Advance(ChunkTexelCount(info, c));
    } else {
      todo.push_back(c);
    }
  }
  if (pass->resumed_chunks > 0) {
    REFLCAP_LOG(kInfo) << "fit: resumed " << pass->resumed_chunks << " of " << range.end - range.begin
                       << " chunks from " << checkpoint.string() << "; fitting " << todo.size();
  }
  // --lobe-model auto (FitOptions::select_lobe_model): a second, isotropic fit of every chunk.
  const bool select_model =
      options.select_lobe_model && options.lobe_model == LobeModel::kAniso && options.lobes > 0;
  FitOptions iso_options = options;
  iso_options.lobe_model = LobeModel::kIso;
  // Kept only for a post-fit phase in this process (not by a shard: its merge reads the store).
  const bool keep_chunks = (options.lobe_transfer.enabled || options.clusters.enabled) &&
                           options.lobes > 0 && pass->cached.size() == info.chunks;
  const uint64_t cache_budget = keep_chunks ? SampleCacheBudget() : 0;
  // Chunks read ahead, each on a thread of its own, in order.
  auto read = [&store](uint32_t index) { return store.ReadChunk(index); };
  std::deque<std::future<StatusOr<TexelSampleChunk>>> ahead;
  size_t issued = 0;
  auto read_ahead = [&] {
    while (ahead.size() < kFitChunksReadAhead && issued < todo.size()) {
      ahead.push_back(std::async(std::launch::async, read, todo[issued++]));
    }
  };
  // A chunk being fitted: its samples, its results and what the fitter said of it.
  struct Job {
    uint32_t c = 0;
    TexelSampleChunk chunk;
    std::vector<TexelFit> results, iso_results;
    size_t iso_chosen = 0;
    bool used_vulkan = false;
    VulkanFitStats vulkan_stats;
    std::future<Status> done;
  };
  const auto fit_job = [&](Fitter* f, Job* job) -> Status {
    REFLCAP_RETURN_IF_ERROR(f->Fit(job->chunk, options, &job->results));
    if (const auto* vk = dynamic_cast<const VulkanFitter*>(f)) {
      job->vulkan_stats = vk->last_stats();
      job->used_vulkan = true;
    }
    if (select_model) {
      REFLCAP_RETURN_IF_ERROR(f->Fit(job->chunk, iso_options, &job->iso_results));
      for (size_t i = 0; i < job->results.size(); ++i) {
        if (Bic(job->iso_results[i], LobeModel::kIso, options.lobes) <
            Bic(job->results[i], LobeModel::kAniso, options.lobes)) {
          job->results[i] = job->iso_results[i];
          ++job->iso_chosen;
        }
      }
    }
    return OkStatus();
  };
  // Results vectors of stored jobs, emptied, for the next jobs: a chunk's results (~5.5 MB at
  // 16,384 texels) in fresh memory were faulted in anew every chunk, on the fitting thread.
  std::vector<std::vector<TexelFit>> spare_results;
  const auto take_spare = [&](std::vector<TexelFit>* out) {
    if (spare_results.empty()) return;
    *out = std::move(spare_results.back());
    spare_results.pop_back();
  };
  // The oldest job, waited for. Its results are stored (store_job below) once the next job is
  // on its fitter.
  std::deque<std::unique_ptr<Job>> running;
  const auto wait_oldest = [&]() -> StatusOr<std::unique_ptr<Job>> {
    std::unique_ptr<Job> job = std::move(running.front());
    running.pop_front();
    REFLCAP_RETURN_IF_ERROR(job->done.get());
    if (job->used_vulkan) {
      const VulkanFitStats& st = job->vulkan_stats;
      VulkanFitStats& sum = pass->vulkan_stats;
      sum.kernel = st.kernel;
      sum.cluster_size = st.cluster_size;
      sum.native_math = st.native_math;
      sum.records_mapped = st.records_mapped;
      sum.batches += st.batches;
      sum.dispatches += st.dispatches;
      sum.gpu_problems += st.gpu_problems;
      sum.cpu_problems += st.cpu_problems;
      sum.device_seconds += st.device_seconds;
      sum.prepare_seconds += st.prepare_seconds;
      sum.prepare_texel_thread_seconds += st.prepare_texel_thread_seconds;
      sum.prepare_layout_thread_seconds += st.prepare_layout_thread_seconds;
      sum.finish_seconds += st.finish_seconds;
      sum.reprepared_texels += st.reprepared_texels;
      pass->used_vulkan = true;
    }
    return job;
  };
  // A fitted job's results kept and checkpointed, and its chunk cached (in chunk order).
  const auto store_job = [&](std::unique_ptr<Job> job) -> Status {
    pass->iso_chosen += job->iso_chosen;
    const TexelSampleChunk& chunk = job->chunk;
    REFLCAP_RETURN_IF_ERROR(Keep(chunk.first_texel, job->results, pass));
    if (!checkpoint.empty()) {
      const auto write_start = std::chrono::steady_clock::now();
      REFLCAP_RETURN_IF_ERROR(WriteFitChunk(checkpoint / FitChunkFileName(job->c),
                                            chunk.first_texel, options.lobes, job->results));
      pass->checkpoint_seconds += Seconds(write_start);
    }
    ++pass->fitted_chunks;
    progress.Advance(chunk.texel_count);
    const uint64_t bytes = DecodedBytes(chunk);
    if (pass->cached_bytes + bytes <= cache_budget) {
      pass->cached_bytes += bytes;
      pass->cached[job->c] = std::move(job->chunk);
    }
    for (std::vector<TexelFit>* results : {&job->results, &job->iso_results}) {
      if (results->capacity() == 0) continue;
      results->clear();
      spare_results.push_back(std::move(*results));
    }
    return OkStatus();
  };
  Fitter* fitters[2] = {fitter, nullptr};
  size_t depth = second ? 2 : 1;
  // The pass's fit time: its wall time less its waits for chunks being read. (The waits for
  // each fit alone would leave out the storing of results that overlaps the next fit.)
  const auto pass_start = std::chrono::steady_clock::now();
  const double read_before = pass->read_seconds;
  read_ahead();
  for (size_t k = 0; k < todo.size(); ++k) {
    const uint32_t c = todo[k];
    const auto read_start = std::chrono::steady_clock::now();
    StatusOr<TexelSampleChunk> chunk = ahead.front().get();
    ahead.pop_front();
    pass->read_seconds += Seconds(read_start);
    if (!chunk.ok()) return chunk.status();
    read_ahead();
    if (uint64_t(chunk->first_texel) + chunk->texel_count > info.texels) {
      return DataLossError(store.ChunkPath(c).string(), ": texels ", chunk->first_texel, "..",
                           chunk->first_texel + chunk->texel_count, " beyond the store's ",
                           info.texels);
    }
    if (k == 1 && depth == 2) {
      fitters[1] = second();
      if (fitters[1] == nullptr) depth = 1;
    }
    // Job k runs on fitter k mod depth: that fitter's previous job (k - depth) is complete.
    std::vector<std::unique_ptr<Job>> fitted;
    while (running.size() >= depth) {
      REFLCAP_ASSIGN_OR_RETURN(std::unique_ptr<Job> done, wait_oldest());
      fitted.push_back(std::move(done));
    }
    auto job = std::make_unique<Job>();
    take_spare(&job->results);
    if (select_model) take_spare(&job->iso_results);
    job->c = c;
    job->chunk = std::move(chunk).value();
    Fitter* f = fitters[k % depth];
    Job* j = job.get();
    // On a thread of its own, while this one stores the job before it (and, with two in
    // flight, reads the next chunk): stored between fits, a chunk's results (kept,
    // checkpointed: 1.5 ms a chunk on the H200 host) left the fitter idle meanwhile.
    job->done = std::async(std::launch::async, [&fit_job, f, j] { return fit_job(f, j); });
    running.push_back(std::move(job));
    for (std::unique_ptr<Job>& done : fitted) REFLCAP_RETURN_IF_ERROR(store_job(std::move(done)));
  }
  while (!running.empty()) {
    REFLCAP_ASSIGN_OR_RETURN(std::unique_ptr<Job> done, wait_oldest());
    REFLCAP_RETURN_IF_ERROR(store_job(std::move(done)));
  }
  pass->fit_seconds += Seconds(pass_start) - (pass->read_seconds - read_before);
  pass->chunks_in_flight = uint32_t(std::min(depth, std::max<size_t>(todo.size(), 1)));
  progress.Finish();
  return OkStatus();
}

// Starts or continues the checkpoint folder `dir` of a run described by `manifest`: a folder
// left by an interrupted run is continued only with `resume` and only when it is of the same
// store, options, backend and shard.
Status OpenCheckpoint(const fs::path& dir, const FitPartManifest& manifest, bool resume) {
  std::error_code ec;
  const fs::path file = dir / kFitCheckpointFile;
  if (fs::exists(dir, ec)) {
    if (!resume) {
      return FailedPreconditionError(
          dir.string(), ": holds the chunk results of an interrupted fit to this output (pass "
                        "--resume to continue it, or delete the folder to start over)");
    }
    REFLCAP_ASSIGN_OR_RETURN(std::string text, ReadTextFile(file));
    const Json json = Json::parse(text, nullptr, false);
    if (json.is_discarded()) return DataLossError(file.string(), ": not valid JSON");
    REFLCAP_ASSIGN_OR_RETURN(FitPartManifest before, FitPartManifest::FromJson(json, file.string()));
    std::string mismatch = manifest.Mismatch(before);
    if (mismatch.empty() && (before.shard.index != manifest.shard.index ||
                             before.range.begin != manifest.range.begin ||
                             before.range.end != manifest.range.end)) {
      mismatch = "shard";
    }
    if (!mismatch.empty()) {
      return FailedPreconditionError(file.string(), ": ", mismatch,
                                     " differs from this run: the checkpoint belongs to another "
                                     "fit (delete ", dir.string(), " to start over)");
    }
    return OkStatus();
  }
  if (resume) {
    REFLCAP_LOG(kWarning) << "fit: --resume: no checkpoint at " << dir.string()
                          << "; fitting from the start";
  }
  fs::create_directories(dir, ec);
  if (ec) return InternalError(dir.string(), ": cannot create folder: ", ec.message());
  return WriteTextFileAtomic(file, manifest.ToJson().dump(2) + "\n");
}

// The post-fit phase: lobe transfer, albedo fill, material clusters, the maps and
// fit_report.json, written into `dir`. `extra` is merged into the report.
StatusOr<FitRunSummary> FinishFit(const fs::path& samples, const SampleStoreReader& store,
                                  const TexelAtlas& atlas, const FitOptions& options,
                                  const std::string& backend_name, const std::string& device,
                                  const std::string& backend_choice, FitPass* pass,
                                  const fs::path& dir, const Json& extra,
                                  std::chrono::steady_clock::time_point start) {
  const SampleStoreInfo& info = store.info();
  FitStore& fits = *pass->fits;
  auto& cached = pass->cached;
  const double read_seconds = pass->read_seconds, fit_seconds = pass->fit_seconds;
  const size_t iso_chosen = pass->iso_chosen;
  const VulkanFitStats& vulkan_stats = pass->vulkan_stats;
  const bool used_vulkan = pass->used_vulkan;
  const bool select_model =
      options.select_lobe_model && options.lobe_model == LobeModel::kAniso && options.lobes > 0;
  auto read = [&store](uint32_t index) { return store.ReadChunk(index); };
  const uint64_t cache_budget =
      (options.lobe_transfer.enabled || options.clusters.enabled || options.diffuse_falloff) &&
              options.lobes > 0
          ? SampleCacheBudget()
          : 0;
  FitRunSummary summary;
  summary.device = device;
  // Lobe transfer (lobe_transfer.h): candidates from the maps, then a second pass over the
  // chunks that hold recipients to test them on their own samples.
  const auto transfer_start = std::chrono::steady_clock::now();
  LobeTransferStats transfer;
  double transfer_read_seconds = 0, transfer_test_seconds = 0;  // waiting for chunks; testing
  // Calls visit(chunk) for every chunk c with wanted(first texel, end) true, in ascending order:
  // kept chunks from memory, the others read, the next while one is visited (as the fit pass
  // prefetches).
  const auto visit_chunks = [&](const std::function<bool(uint64_t, uint64_t)>& wanted_range,
                                const std::function<void(const TexelSampleChunk&)>& visit) -> Status {
    std::vector<uint32_t> wanted;
    for (uint32_t c = 0; c < info.chunks; ++c) {
      const uint64_t first = uint64_t(c) * info.chunk_texels;
      const uint64_t end = std::min<uint64_t>(first + info.chunk_texels, info.texels);
      if (wanted_range(first, end)) wanted.push_back(c);
    }
    std::vector<uint32_t> to_read;
    for (uint32_t c : wanted) {
      if (!cached[c].has_value()) to_read.push_back(c);
    }
    std::future<StatusOr<TexelSampleChunk>> pending;
    size_t next_read = 0;
    if (next_read < to_read.size()) pending = std::async(std::launch::async, read, to_read[next_read]);
    for (uint32_t c : wanted) {
      StatusOr<TexelSampleChunk> loaded = UnavailableError("not read");
      const TexelSampleChunk* chunk = nullptr;
      if (cached[c].has_value()) {
        chunk = &*cached[c];
      } else {
        const auto wait_start = std::chrono::steady_clock::now();
        loaded = pending.get();
        transfer_read_seconds += Seconds(wait_start);
        if (!loaded.ok()) return loaded.status();
        if (++next_read < to_read.size()) {
          pending = std::async(std::launch::async, read, to_read[next_read]);
        }
        chunk = &*loaded;
      }
      const auto test_start = std::chrono::steady_clock::now();
      visit(*chunk);
      transfer_test_seconds += Seconds(test_start);
      // A chunk read here (the fit pass did not keep it: a merge, or a resumed chunk) is kept for
      // the later rounds and the clusters while the budget allows, as the fit pass keeps its own.
      if (loaded.ok()) {
        const uint64_t bytes = DecodedBytes(*loaded);
        if (pass->cached_bytes + bytes <= cache_budget) {
          pass->cached_bytes += bytes;
          cached[c] = std::move(loaded).value();
        }
      }
    }
    return OkStatus();
  };
  if (options.lobe_transfer.enabled && options.lobes > 0) {
    // round >= 1: the texels that borrowed in the last round (one byte per texel).
    std::vector<uint8_t> lenders;
    for (int round = 0; round < options.lobe_transfer.rounds; ++round) {
      LobeTransferStats round_stats;
      const LobeCandidates candidates = FindLobeDonors(
          atlas, fits, options.lobe_transfer, &round_stats, round == 0 ? nullptr : &lenders);
      if (round == 0) {
        transfer.recipients = round_stats.recipients;
        transfer.no_donor = round_stats.no_donor;
      }
      if (round_stats.no_donor == round_stats.recipients) break;  // no candidate anywhere
      lenders.assign(info.texels, 0);
      // Chunks hold consecutive texels: only those with a recipient that has candidates.
      REFLCAP_RETURN_IF_ERROR(visit_chunks(
          [&](uint64_t first, uint64_t end) { return candidates.AnyIn(first, end); },
          [&](const TexelSampleChunk& chunk) {
            ApplyLobeTransfer(chunk, candidates, options.lobe_transfer, options.min_cos_theta,
                              options.threads, &fits, &round_stats, &lenders);
          }));
      if (round == 0) transfer.rejected = round_stats.rejected;
      transfer.transferred += round_stats.transferred;
      ++transfer.rounds;
      if (round_stats.transferred == 0) break;
    }
  }
  const double transfer_seconds = Seconds(transfer_start);
  const double transfer_chunk_read_seconds = transfer_read_seconds;
  const double transfer_chunk_test_seconds = transfer_test_seconds;
  // Albedo fill (albedo_fill.h): texels no train photograph lit and saw. Before the clusters,
  // which give a filled texel its material's lobe.
  const auto fill_start = std::chrono::steady_clock::now();
  std::vector<uint8_t> albedo_filled;
  const AlbedoFillStats fill =
      FillUnseenAlbedo(atlas, options.albedo_fill, &fits, &albedo_filled, options.threads);
  const double fill_seconds = Seconds(fill_start);
  // Material clusters (material_clusters.h): the texels still without a lobe take one that the
  // pooled samples of their material support.
  const auto cluster_start = std::chrono::steady_clock::now();
  MaterialClusterStats cluster_stats;
  MaterialClusters clusters =
      BuildMaterialClusters(fits, options.clusters, &cluster_stats, options.threads);
  AssignSparseTexels(fits, albedo_filled, options.clusters, &clusters, &cluster_stats,
                     options.threads);
  double cluster_build_seconds = Seconds(cluster_start), cluster_pool_seconds = 0,
         cluster_choose_seconds = 0;
  if (clusters.count > 0) {
    auto part_start = std::chrono::steady_clock::now();
    REFLCAP_RETURN_IF_ERROR(visit_chunks(
        [&](uint64_t first, uint64_t end) { return clusters.PoolIn(first, end); },
        [&](const TexelSampleChunk& chunk) {
          StashClusterSamples(chunk, options.min_cos_theta, &clusters);
        }));
    cluster_pool_seconds = Seconds(part_start);
    part_start = std::chrono::steady_clock::now();
    ChooseClusterLobes(options, &clusters, &cluster_stats);
    cluster_choose_seconds = Seconds(part_start);
    // k-fold: every chunk scored first, so that the own lobes' refits batch many chunks' texels
    // (material_clusters.h KFoldScores); then applied chunk by chunk (the chunks are kept).
    KFoldScores scores(fits.size(), options);
    if (scores.folds() > 0) {
      REFLCAP_RETURN_IF_ERROR(visit_chunks(
          [&](uint64_t first, uint64_t end) { return clusters.KeptIn(first, end); },
          [&](const TexelSampleChunk& chunk) {
            ScoreClusterLobes(chunk, clusters, options, fits, &scores, &cluster_stats);
          }));
      RefitOwnLobes(options, &scores, &cluster_stats);
    }
    REFLCAP_RETURN_IF_ERROR(visit_chunks(
        [&](uint64_t first, uint64_t end) { return clusters.KeptIn(first, end); },
        [&](const TexelSampleChunk& chunk) {
          ApplyClusterLobes(chunk, clusters, options, scores, &fits, &cluster_stats);
        }));
  }
  const double cluster_seconds = Seconds(cluster_start);
  // Diffuse fall-off (diffuse_falloff.h): the texels still Lambert-only, or holding a borrowed
  // lobe, may take a generalized diffuse lobe, when their own held-out photographs prefer it.
  const auto falloff_start = std::chrono::steady_clock::now();
  DiffuseFalloffStats falloff;
  if (options.diffuse_falloff && options.lobes > 0) {
    REFLCAP_RETURN_IF_ERROR(visit_chunks(
        [&](uint64_t first, uint64_t end) { return DiffuseFalloffCandidatesIn(fits, first, end); },
        [&](const TexelSampleChunk& chunk) {
          ApplyDiffuseFalloff(chunk, options, options.clusters.folds, &fits, &falloff);
        }));
  }
  const double falloff_seconds = Seconds(falloff_start);
  // The kept chunks are not needed past the post-fit passes: freed on a thread of their own
  // while the maps are written (1.3 GB of the million preset: 0.1 s on 2 cores).
  std::future<void> cache_freed =
      std::async(std::launch::async, [kept = std::move(cached)]() mutable {
        kept = {};
        ReleaseFreeHeap();
      });
  cached = {};

  const auto write_start = std::chrono::steady_clock::now();
  if (pass->released.valid()) {
    const auto release_wait = std::chrono::steady_clock::now();
    pass->released.get();
    pass->release_seconds = Seconds(release_wait);
  }
  // The report's totals, on a thread of their own while the maps are written (a serial pass
  // over every texel and the percentiles' selections: 0.06-0.08 s on 2 cores). They read only
  // the per-texel scalars, which the maps leave as they are.
  struct Totals {
    std::array<size_t, kFitStatusCount> status_counts{};
    std::array<size_t, kTexelModelCount> model_counts{};
    size_t texels_with_samples = 0, lambert_only = 0;
    double iterations = 0;
    int max_iterations = 0;
    Json cost_percentiles, chi2_percentiles;
  };
  std::future<Totals> totals_pending = std::async(std::launch::async, [&fits, &options] {
    Totals totals;
    std::vector<double> costs, chi2;
    costs.reserve(fits.size());
    chi2.reserve(fits.size());
    const int params_per_problem = NumParams(options.lobe_model, options.lobes);
    for (size_t t = 0; t < fits.size(); ++t) {
      ++totals.status_counts[size_t(fits.status(t))];
      ++totals.model_counts[size_t(TexelModelOf(fits, t))];
      if (fits.residuals(t) == 0) continue;
      ++totals.texels_with_samples;
      costs.push_back(fits.cost(t));
      const int dof = fits.residuals(t) - params_per_problem * ProblemsPerTexel(options.lobe_model);
      if (dof > 0) chi2.push_back(2.0 * fits.cost(t) / dof);
      totals.iterations += fits.iterations(t);
      totals.max_iterations = std::max(totals.max_iterations, fits.iterations(t));
      totals.lambert_only += fits.lambert_only(t);
    }
    totals.cost_percentiles = Percentiles(std::move(costs));
    totals.chi2_percentiles = Percentiles(std::move(chi2));
    return totals;
  });
  REFLCAP_RETURN_IF_ERROR(
      WriteFitMaps(dir, atlas, &fits, pass->sigma.get(), albedo_filled, clusters.cluster_of,
                   options.threads > 0 ? options.threads : HardwareThreads()));
  clusters = MaterialClusters();
  albedo_filled = std::vector<uint8_t>();
  REFLCAP_RETURN_IF_ERROR(pass->sigma->Remove());
  cache_freed.get();  // within the run's time
  Totals totals = totals_pending.get();
  for (int st = 0; st < kFitStatusCount; ++st) summary.status_counts[st] = totals.status_counts[size_t(st)];
  summary.texels_with_samples = totals.texels_with_samples;
  const std::array<size_t, kTexelModelCount>& model_counts = totals.model_counts;
  const size_t lambert_only = totals.lambert_only;
  const double iterations = totals.iterations;
  const int max_iterations = totals.max_iterations;

  summary.texels = info.texels;
  summary.fit_seconds = fit_seconds;
  summary.lobes_transferred = transfer.transferred;
  summary.material_clusters = cluster_stats.clusters;
  summary.material_clusters_with_lobe = cluster_stats.clusters_with_lobe;
  summary.cluster_lobes_lent = cluster_stats.transferred;
  summary.cluster_lobes_replaced = cluster_stats.replaced;
  summary.falloff_candidates = falloff.candidates;
  summary.falloff_taken = falloff.taken;
  summary.falloff_replaced = falloff.replaced;
  const double fits_count = double(info.texels) * ProblemsPerTexel(options.lobe_model);
  summary.fits_per_second = fit_seconds > 0 ? fits_count / fit_seconds : 0;

  Json status_names = Json::array(), model_names = Json::array(), models = Json::object();
  for (int s = 0; s < kFitStatusCount; ++s) status_names.push_back(FitStatusName(FitStatus(s)));
  for (int m = 0; m < kTexelModelCount; ++m) {
    model_names.push_back(kTexelModelNames[m]);
    models[kTexelModelNames[m]] = model_counts[size_t(m)];
  }
  Json counts = Json::object();
  for (int s = 0; s < kFitStatusCount; ++s) counts[FitStatusName(FitStatus(s))] = summary.status_counts[s];
  Json report = {
      {"format", "reflcap-fit/1"},
      {"samples", fs::absolute(samples).string()},
      {"backend", backend_name},
      {"device", summary.device},
      {"texels", info.texels},
      {"texels_with_samples", summary.texels_with_samples},
      {"fits", size_t(fits_count)},
      {"status_counts", counts},
      {"status_names", status_names},
      {"model_counts", models},
      {"model_names", model_names},
      {"lambert_only", lambert_only},
      {"lobe_transfer",
       {{"recipients", transfer.recipients},
        {"no_donor", transfer.no_donor},
        {"rejected", transfer.rejected},
        {"transferred", transfer.transferred},
        {"rounds", transfer.rounds}}},
      {"clusters",
       {{"clusters", cluster_stats.clusters},
        {"clusters_with_lobe", cluster_stats.clusters_with_lobe},
        {"refined", cluster_stats.refined},
        {"borrowing", cluster_stats.borrowing},
        {"clustered_texels", cluster_stats.clustered_texels},
        {"recipients", cluster_stats.recipients},
        {"no_lobe", cluster_stats.no_lobe},
        {"rejected", cluster_stats.rejected},
        {"transferred", cluster_stats.transferred},
        {"replaced", cluster_stats.replaced},
        {"kfold_refit", cluster_stats.kfold_refit},
        {"kfold_refits", cluster_stats.kfold_refits},
        {"kfold_batches", cluster_stats.kfold_batches},
        {"sparse_assigned", cluster_stats.sparse_assigned},
        {"sparse_lent", cluster_stats.sparse_lent},
        {"foreign_lent", cluster_stats.foreign_lent}}},
      {"diffuse_falloff", FalloffJson(falloff)},
      {"albedo_fill", {{"unseen", fill.unseen}, {"filled", fill.filled}, {"rounds", fill.rounds}}},
      {"cost_percentiles", std::move(totals.cost_percentiles)},
      {"reduced_chi2_percentiles", std::move(totals.chi2_percentiles)},
      {"iterations", {{"mean", summary.texels_with_samples ? iterations / summary.texels_with_samples : 0.0},
                      {"max", max_iterations}}},
      {"fits_per_second", summary.fits_per_second},
      {"texels_per_second", fit_seconds > 0 ? info.texels / fit_seconds : 0.0},
  };
  report["options"] = FitOptionsToJson(options);
  if (select_model) report["options"]["lobe_model"] = "auto";
  if (!backend_choice.empty()) report["backend_choice"] = backend_choice;
  for (auto it = extra.begin(); it != extra.end(); ++it) report[it.key()] = it.value();
  if (used_vulkan) {
    // Where the Vulkan fitter's time went (wall-clock seconds summed over chunks; the device's
    // batches overlap the host's preparation and post-processing, and with two chunks in
    // flight the two chunks' times overlap too).
    report["vulkan"] = {{"kernel", VulkanFitKernelName(vulkan_stats.kernel)},
                        {"cluster_size", vulkan_stats.cluster_size},
                        {"native_math", vulkan_stats.native_math},
                        {"records_mapped", vulkan_stats.records_mapped},
                        {"chunks_in_flight", pass->chunks_in_flight},
                        {"batches", vulkan_stats.batches},
                        {"dispatches", vulkan_stats.dispatches},
                        {"device_problems", vulkan_stats.gpu_problems},
                        {"cpu_route_problems", vulkan_stats.cpu_problems},
                        {"device_s", vulkan_stats.device_seconds},
                        {"prepare_s", vulkan_stats.prepare_seconds},
                        {"prepare_texel_thread_s", vulkan_stats.prepare_texel_thread_seconds},
                        {"prepare_layout_thread_s", vulkan_stats.prepare_layout_thread_seconds},
                        {"finish_s", vulkan_stats.finish_seconds},
                        {"reprepared_texels", vulkan_stats.reprepared_texels}};
  }
  if (select_model) {
    report["lobe_model_choice"] = {{"aniso", info.texels - iso_chosen}, {"iso", iso_chosen}};
    // Chunk result files do not record which model won: chunks read back by --resume count as
    // aniso here (their parameters are the chosen ones all the same).
    if (pass->resumed_chunks > 0) report["lobe_model_choice"]["resumed_chunks_not_counted"] = pass->resumed_chunks;
  }
  const double write_seconds_so_far = Seconds(write_start);
  summary.total_seconds = Seconds(start);
  report["timings_s"] = {{"setup", pass->setup_seconds},
                         {"release_fitter", pass->release_seconds},
                         {"read_wait", read_seconds},
                         {"checkpoint_write", pass->checkpoint_seconds},
                         {"fit", fit_seconds},
                         {"lobe_transfer", transfer_seconds},
                         {"lobe_transfer_read_wait", transfer_chunk_read_seconds},
                         {"lobe_transfer_test", transfer_chunk_test_seconds},
                         {"clusters", cluster_seconds},
                         {"clusters_build", cluster_build_seconds},
                         {"clusters_pool", cluster_pool_seconds},
                         {"clusters_choose", cluster_choose_seconds},
                         {"clusters_kfold_refit", cluster_stats.refit_seconds},
                         {"diffuse_falloff", falloff_seconds},
                         {"lobe_transfer_kept_mib", double(pass->cached_bytes) / (1 << 20)},
                         {"albedo_fill", fill_seconds},
                         {"write_maps", write_seconds_so_far},
                         {"total", summary.total_seconds}};
  REFLCAP_RETURN_IF_ERROR(WriteTextFileAtomic(dir / "fit_report.json", report.dump(2) + "\n"));
  return summary;
}

}  // namespace

StatusOr<FitRunSummary> RunFit(const fs::path& samples, const fs::path& out, Backend backend,
                               const FitOptions& options, bool overwrite,
                               const VulkanFitterOptions& vulkan, const std::string& backend_choice,
                               const FitRunControl& control) {
  const auto start = std::chrono::steady_clock::now();
  REFLCAP_RETURN_IF_ERROR(options.Validate());
  // The fitter is made while the store is opened and the result store allocated: a Vulkan
  // fitter's device and pipelines took 0.13 s of the million fit's 0.23 s setup on an H200 host.
  std::future<StatusOr<std::unique_ptr<Fitter>>> fitter_pending =
      std::async(std::launch::async, [backend, &options, &vulkan] {
        return CreateFitter(backend, options.threads, vulkan);
      });
  REFLCAP_ASSIGN_OR_RETURN(std::unique_ptr<SampleStoreReader> store, SampleStoreReader::Open(samples));
  std::error_code ec;
  if (fs::exists(samples / "resample_part.json", ec)) {
    // A resample shard's store holds only its views' samples: fitting it alone would be wrong.
    return FailedPreconditionError(samples.string(), ": is one part of a sharded resample "
                                   "(resample_part.json): join the parts with reflcap merge first");
  }
  const SampleStoreInfo& info = store->info();
  REFLCAP_ASSIGN_OR_RETURN(TexelAtlas atlas, StoreAtlas(samples, info));
  const bool sharded = control.shard.count > 1;
  ChunkRange range{0, info.chunks};
  if (sharded) {
    REFLCAP_ASSIGN_OR_RETURN(range, ShardChunks(control.shard, info.chunks));
  }
  FitPartManifest manifest;
  manifest.samples = fs::absolute(samples).lexically_normal().string();
  manifest.fingerprint = store->fingerprint();
  manifest.texels = info.texels;
  manifest.chunks = info.chunks;
  manifest.chunk_texels = info.chunk_texels;
  manifest.shard = control.shard;
  manifest.range = range;
  manifest.backend = BackendName(backend);
  manifest.options = FitOptionsToJson(options);

  REFLCAP_ASSIGN_OR_RETURN(StagingDir staging, StagingDir::Create(out, overwrite));
  const fs::path checkpoint = CheckpointDir(staging.destination());
  REFLCAP_RETURN_IF_ERROR(OpenCheckpoint(checkpoint, manifest, control.resume));
  // A run that fails before its first chunk is saved leaves no checkpoint behind; one that
  // saved chunks keeps them for --resume (and a finished run removes the folder below).
  CheckpointCleanup cleanup(checkpoint, ".rcf");

  // Texels no chunk holds keep the store's initial state: zero parameters, too few samples,
  // unknown sigmas. A shard keeps no per-texel state (82 bytes a texel for the whole atlas, and
  // the sigma spill): its part is the chunk result files.
  FitPass pass;
  if (!sharded) {
    pass.fits = std::make_unique<FitStore>(info.texels, options.lobes, options.threads);
    REFLCAP_ASSIGN_OR_RETURN(pass.sigma, SigmaSpill::Create(staging.path() / kSigmaScratchFile,
                                                            info.texels, options.lobes));
    pass.cached.resize(info.chunks);
  }
  REFLCAP_ASSIGN_OR_RETURN(std::unique_ptr<Fitter> fitter, fitter_pending.get());
  const std::string device = fitter->device();
  // VulkanFitterOptions::chunks_in_flight: a second fitter on the same device (its creation, a
  // Vulkan device and pipelines, overlaps the first chunk's fit). Should it fail, the chunks
  // are fitted one after another on the first.
  std::future<StatusOr<std::unique_ptr<Fitter>>> second_pending;
  if (const auto* vk = dynamic_cast<const VulkanFitter*>(fitter.get());
      vk != nullptr && range.end - range.begin >= 2) {
    const uint32_t depth = vulkan.chunks_in_flight > 0 ? vulkan.chunks_in_flight
                           : vk->software_device()     ? 1
                                                       : 2;
    if (depth == 2) {
      second_pending = std::async(std::launch::async, [backend, &options, &vulkan] {
        return CreateFitter(backend, options.threads, vulkan);
      });
    }
  }
  std::unique_ptr<Fitter> second;
  const auto second_fitter = [&]() -> Fitter* {
    StatusOr<std::unique_ptr<Fitter>> made = second_pending.get();
    if (!made.ok()) {
      REFLCAP_LOG(kWarning) << "fit: no second Vulkan fitter (" << made.status().ToString()
                            << "); fitting one chunk at a time";
      return nullptr;
    }
    second = std::move(made).value();
    return second.get();
  };
  pass.setup_seconds = Seconds(start);
  REFLCAP_RETURN_IF_ERROR(FitChunks(*store, range, fitter.get(),
                                    second_pending.valid() ? second_fitter
                                                           : std::function<Fitter*()>(),
                                    options, checkpoint, control.resume, &pass));
  // The fitters' per-worker workspaces and the chunk results are sized by the largest chunk;
  // nothing needs them past the fit. Released on a thread of their own while the post-fit passes
  // run (a Vulkan device's teardown: 0.06-0.1 s on an H200 host); FinishFit waits for it before
  // the maps, and the wait is `release_fitter`. A second fitter never asked for (< 2 chunks
  // fitted) is awaited there, then released.
  pass.released = std::async(std::launch::async, [first = std::move(fitter),
                                                  second = std::move(second),
                                                  pending = std::move(second_pending)]() mutable {
    pending = {};
    second.reset();
    first.reset();
    ReleaseFreeHeap();
  });

  if (sharded) {
    // The part: the checkpoint's chunk result files and the manifest with what this shard did.
    Json part = manifest.ToJson();
    part["device"] = device;
    part["fitted_chunks"] = pass.fitted_chunks;
    part["iso_chosen"] = pass.iso_chosen;  // --lobe-model auto: texels that kept the iso fit
    part["resumed_chunks"] = pass.resumed_chunks;
    part["timings_s"] = {{"read_wait", pass.read_seconds},
                         {"fit", pass.fit_seconds},
                         {"checkpoint_write", pass.checkpoint_seconds},
                         {"total", Seconds(start)}};
    for (uint32_t c = range.begin; c < range.end; ++c) {
      fs::rename(checkpoint / FitChunkFileName(c), staging.path() / FitChunkFileName(c), ec);
      if (ec) {
        return InternalError((checkpoint / FitChunkFileName(c)).string(), ": cannot move into ",
                             staging.path().string(), ": ", ec.message());
      }
    }
    REFLCAP_RETURN_IF_ERROR(WriteTextFileAtomic(staging.path() / kFitPartFile, part.dump(2) + "\n"));
    REFLCAP_RETURN_IF_ERROR(staging.Commit());
    fs::remove_all(checkpoint, ec);
    FitRunSummary summary;
    summary.texels = 0;
    for (uint32_t c = range.begin; c < range.end; ++c) summary.texels += ChunkTexelCount(info, c);
    summary.fit_seconds = pass.fit_seconds;
    summary.total_seconds = Seconds(start);
    summary.fits_per_second = pass.fit_seconds > 0
                                  ? double(summary.texels) * ProblemsPerTexel(options.lobe_model) / pass.fit_seconds
                                  : 0;
    summary.device = device;
    return summary;
  }
  Json extra = Json::object();
  if (pass.resumed_chunks > 0) extra["resumed_chunks"] = pass.resumed_chunks;
  REFLCAP_ASSIGN_OR_RETURN(FitRunSummary summary,
                           FinishFit(samples, *store, atlas, options, BackendName(backend), device,
                                     backend_choice, &pass, staging.path(), extra, start));
  REFLCAP_RETURN_IF_ERROR(staging.Commit());
  fs::remove_all(checkpoint, ec);
  if (ec) REFLCAP_LOG(kWarning) << checkpoint.string() << ": cannot remove: " << ec.message();
  return summary;
}

StatusOr<FitRunSummary> MergeFitParts(const std::vector<fs::path>& parts, const fs::path& out,
                                      bool overwrite, int threads, const fs::path& samples_override) {
  const auto start = std::chrono::steady_clock::now();
  if (parts.empty()) return InvalidArgumentError("merge: no parts given");
  // The manifests: one store, one set of options, every shard exactly once.
  std::vector<FitPartManifest> manifests;
  std::vector<Json> part_json;
  for (const fs::path& part : parts) {
    const fs::path file = part / kFitPartFile;
    auto text = ReadTextFile(file);
    if (!text.ok()) {
      return NotFoundError(part.string(), ": not a fit part (no ", kFitPartFile,
                           "; a shard that has not finished leaves only ",
                           CheckpointDir(part).filename().string(), ")");
    }
    Json json = Json::parse(*text, nullptr, false);
    if (json.is_discarded()) return DataLossError(file.string(), ": not valid JSON");
    REFLCAP_ASSIGN_OR_RETURN(FitPartManifest m, FitPartManifest::FromJson(json, file.string()));
    if (!manifests.empty()) {
      const std::string mismatch = manifests.front().Mismatch(m);
      if (!mismatch.empty()) {
        return FailedPreconditionError(file.string(), ": ", mismatch, " differs from ",
                                       (parts.front() / kFitPartFile).string(),
                                       ": the parts are not of one fit");
      }
    }
    manifests.push_back(std::move(m));
    part_json.push_back(std::move(json));
  }
  const FitPartManifest& first = manifests.front();
  std::vector<int> shard_of_part;
  std::vector<std::string> files;
  for (size_t i = 0; i < manifests.size(); ++i) {
    shard_of_part.push_back(manifests[i].shard.index);
    files.push_back((parts[i] / kFitPartFile).string());
  }
  REFLCAP_ASSIGN_OR_RETURN(const std::vector<int> part_of_shard,
                           PartOfEachShard(shard_of_part, first.shard.count, files, "fit"));
  uint32_t next_chunk = 0;
  for (int s = 0; s < first.shard.count; ++s) {
    const FitPartManifest& m = manifests[size_t(part_of_shard[size_t(s)])];
    const fs::path file = parts[size_t(part_of_shard[size_t(s)])] / kFitPartFile;
    REFLCAP_ASSIGN_OR_RETURN(ChunkRange expected, ShardChunks(m.shard, m.chunks));
    if (m.range.begin != next_chunk || m.range.begin != expected.begin || m.range.end != expected.end) {
      return DataLossError(file.string(), ": chunk_begin/chunk_end: ", m.range.begin, "..",
                           m.range.end, ", expected ", expected.begin, "..", expected.end,
                           " for shard ", s, "/", m.shard.count);
    }
    next_chunk = m.range.end;
  }
  // The store the parts were fitted from (its chunks feed lobe transfer and the clusters).
  const fs::path samples = samples_override.empty() ? fs::path(first.samples) : samples_override;
  REFLCAP_ASSIGN_OR_RETURN(std::unique_ptr<SampleStoreReader> store, SampleStoreReader::Open(samples));
  const std::string& fingerprint = store->fingerprint();
  if (fingerprint != first.fingerprint) {
    return FailedPreconditionError(samples.string(), ": store_fingerprint ", fingerprint,
                                   " is not the ", first.fingerprint, " the parts were fitted from");
  }
  const SampleStoreInfo& info = store->info();
  if (info.texels != first.texels || info.chunks != first.chunks) {
    return FailedPreconditionError(samples.string(), ": not the store the parts were fitted from");
  }
  REFLCAP_ASSIGN_OR_RETURN(TexelAtlas atlas, StoreAtlas(samples, info));
  FitOptions options;
  REFLCAP_RETURN_IF_ERROR(FitOptionsFromJson(first.options, (parts.front() / kFitPartFile).string(), &options));
  options.threads = threads;

  REFLCAP_ASSIGN_OR_RETURN(StagingDir staging, StagingDir::Create(out, overwrite));
  FitPass pass;
  pass.fits = std::make_unique<FitStore>(info.texels, options.lobes, options.threads);
  REFLCAP_ASSIGN_OR_RETURN(pass.sigma, SigmaSpill::Create(staging.path() / kSigmaScratchFile,
                                                          info.texels, options.lobes));
  pass.cached.resize(info.chunks);
  // Lobe transfer and the clusters test texels on their own samples, which a single run kept
  // from its fit pass: read the store's chunks (within the cache budget) while the parts' result
  // files are read, so that the transfer finds them in memory. A chunk that fails to read here
  // is left for the transfer to read again and report.
  std::atomic<bool> stop_prefetch{false};
  std::future<uint64_t> prefetch;
  if ((options.lobe_transfer.enabled || options.clusters.enabled) && options.lobes > 0) {
    // On every core: reading is the merge's critical path here (the parts' files are small).
    prefetch = std::async(std::launch::async, [&store, &pass, &stop_prefetch, &info, threads]() {
      const uint64_t budget = SampleCacheBudget();
      std::atomic<uint64_t> bytes{0};
      ParallelFor(
          0, info.chunks, 1,
          [&](int64_t b, int64_t e, int) {
            for (int64_t c = b; c < e && !stop_prefetch; ++c) {
              StatusOr<TexelSampleChunk> chunk = store->ReadChunk(uint32_t(c));
              if (!chunk.ok()) continue;
              const uint64_t size = DecodedBytes(*chunk);
              if (bytes.fetch_add(size) + size > budget) {  // over budget: not kept
                bytes -= size;
                continue;
              }
              pass.cached[size_t(c)] = std::move(chunk).value();
            }
          },
          threads);
      return bytes.load();
    });
  }
  // Stops the prefetch on an early return (the future's destructor then waits for it).
  struct StopOnExit {
    std::atomic<bool>* stop;
    ~StopOnExit() { *stop = true; }
  } stop_on_exit{&stop_prefetch};
  Json shard_list = Json::array();
  std::string device;
  const auto parts_start = std::chrono::steady_clock::now();
  for (int s = 0; s < first.shard.count; ++s) {
    const size_t i = size_t(part_of_shard[size_t(s)]);
    const Json& j = part_json[i];
    for (uint32_t c = manifests[i].range.begin; c < manifests[i].range.end; ++c) {
      REFLCAP_ASSIGN_OR_RETURN(std::vector<TexelFit> results,
                               ReadFitChunk(parts[i] / FitChunkFileName(c), ChunkFirstTexel(info, c),
                                            ChunkTexelCount(info, c), options.lobes));
      REFLCAP_RETURN_IF_ERROR(Keep(ChunkFirstTexel(info, c), results, &pass));
    }
    const double fit_s = j.contains("timings_s") ? j["timings_s"].value("fit", 0.0) : 0.0;
    const double read_s = j.contains("timings_s") ? j["timings_s"].value("read_wait", 0.0) : 0.0;
    pass.fit_seconds += fit_s;
    pass.read_seconds += read_s;
    pass.iso_chosen += j.value("iso_chosen", size_t{0});
    const std::string part_device = j.value("device", std::string());
    if (device.empty()) device = part_device;
    if (part_device != device) {
      // Different CPU kernels (x86-64-v3 / v4) or devices round differently: the merged maps
      // are then not bit-identical to any single run.
      REFLCAP_LOG(kWarning) << "merge: shard " << s << " ran on \"" << part_device
                            << "\", shard 0 on \"" << device << "\"";
    }
    shard_list.push_back({{"part", fs::absolute(parts[i]).lexically_normal().string()},
                          {"chunk_begin", manifests[i].range.begin},
                          {"chunk_end", manifests[i].range.end},
                          {"device", part_device},
                          {"fit_s", fit_s}});
  }
  const double parts_read_s = Seconds(parts_start);
  const auto wait_start = std::chrono::steady_clock::now();
  if (prefetch.valid()) pass.cached_bytes = prefetch.get();
  Json extra = {{"shards",
                 {{"count", first.shard.count},
                  {"parts", shard_list},
                  {"parts_read_s", parts_read_s},
                  {"store_prefetch_wait_s", Seconds(wait_start)}}}};
  REFLCAP_ASSIGN_OR_RETURN(FitRunSummary summary,
                           FinishFit(samples, *store, atlas, options, first.backend, device, "",
                                     &pass, staging.path(), extra, start));
  REFLCAP_RETURN_IF_ERROR(staging.Commit());
  return summary;
}

}  // namespace reflcap::fit
