// MergeResampleParts: the parts of `reflcap resample --shard I/N` -> the store, maps and report
// of one run (see resample.h).
#include <algorithm>
#include <atomic>
#include <chrono>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "acquire/resample/coverage.h"
#include "acquire/resample/resample.h"
#include "acquire/resample/resample_outputs.h"
#include "engine/core/atomic_file.h"
#include "engine/core/log.h"
#include "engine/core/parallel.h"
#include "engine/texel/sample_store.h"

namespace reflcap::resample {
namespace fs = std::filesystem;
using Json = nlohmann::json;

namespace {

struct Part {
  fs::path dir;
  Json manifest;
  Shard shard;
  uint32_t view_begin = 0, view_end = 0, views_total = 0;
  Tally tally;
  std::unique_ptr<SampleStoreReader> store;
};

StatusOr<Part> ReadPart(const fs::path& dir) {
  Part part;
  part.dir = dir;
  const fs::path file = dir / kResamplePartFile;
  auto text = ReadTextFile(file);
  if (!text.ok()) {
    return NotFoundError(dir.string(), ": not a resample part (no ", kResamplePartFile,
                         "; a shard that has not finished leaves only ",
                         CheckpointDir(dir).filename().string(), ")");
  }
  part.manifest = Json::parse(*text, nullptr, false);
  const Json& m = part.manifest;
  const std::string name = file.string();
  if (!m.is_object() || m.value("format", "") != kResamplePartFormat) {
    return DataLossError(name, ": format: expected \"", kResamplePartFormat, "\"");
  }
  try {
    part.shard.index = m.at("shard").at("index").get<int>();
    part.shard.count = m.at("shard").at("count").get<int>();
    part.view_begin = m.at("views").at(0).get<uint32_t>();
    part.view_end = m.at("views").at(1).get<uint32_t>();
    part.views_total = m.at("views_total").get<uint32_t>();
  } catch (const Json::exception&) {
    return DataLossError(name, ": shard/views/views_total: missing or malformed");
  }
  if (!m.contains("identity") || !m["identity"].is_object() || !m.contains("report") ||
      !m["report"].is_object()) {
    return DataLossError(name, ": identity/report: missing or not an object");
  }
  if (part.shard.count < 1 || part.shard.index < 0 || part.shard.index >= part.shard.count ||
      part.view_begin >= part.view_end || part.view_end > part.views_total) {
    return DataLossError(name, ": shard ", part.shard.index, "/", part.shard.count, " with views ",
                         part.view_begin, "..", part.view_end, " of ", part.views_total,
                         " is inconsistent");
  }
  if (!m.contains("tally") || !part.tally.FromJson(m["tally"])) {
    return DataLossError(name, ": tally: missing or malformed");
  }
  REFLCAP_ASSIGN_OR_RETURN(part.store, SampleStoreReader::Open(dir));
  return part;
}

}  // namespace

StatusOr<ResampleSummary> MergeResampleParts(const std::vector<fs::path>& dirs,
                                             const fs::path& out_dir, int threads, bool link) {
  const auto start = std::chrono::steady_clock::now();
  if (dirs.empty()) return InvalidArgumentError("merge: no parts given");
  std::vector<Part> parts;
  for (const fs::path& dir : dirs) {
    REFLCAP_ASSIGN_OR_RETURN(Part part, ReadPart(dir));
    parts.push_back(std::move(part));
  }
  // One run: the same identity (capture bytes, options, atlas, photographs), the same N.
  const Part& first = parts.front();
  const std::string first_file = (first.dir / kResamplePartFile).string();
  for (const Part& p : parts) {
    const std::string file = (p.dir / kResamplePartFile).string();
    const std::string differs = FirstDifference(first.manifest["identity"], p.manifest["identity"]);
    if (!differs.empty()) {
      return FailedPreconditionError(file, ": identity.", differs, " differs from ", first_file,
                                     ": the parts are not of one resample");
    }
    if (p.shard.count != first.shard.count || p.views_total != first.views_total) {
      return FailedPreconditionError(file, ": shard count (", p.shard.count, " vs ",
                                     first.shard.count, ") differs from ", first_file);
    }
  }
  std::vector<int> shard_of_part;
  std::vector<std::string> files;
  for (const Part& p : parts) {
    shard_of_part.push_back(p.shard.index);
    files.push_back((p.dir / kResamplePartFile).string());
  }
  REFLCAP_ASSIGN_OR_RETURN(const std::vector<int> of_shard,
                           PartOfEachShard(shard_of_part, first.shard.count, files, "resample"));
  uint32_t next_view = 0;
  for (int s = 0; s < first.shard.count; ++s) {
    const Part& p = parts[size_t(of_shard[size_t(s)])];
    REFLCAP_ASSIGN_OR_RETURN(ItemRange expected, ShardRange(p.shard, p.views_total, "views"));
    if (p.view_begin != next_view || p.view_begin != expected.begin || p.view_end != expected.end) {
      return DataLossError((p.dir / kResamplePartFile).string(), ": views: ", p.view_begin, "..",
                           p.view_end, ", expected ", expected.begin, "..", expected.end,
                           " for shard ", s, "/", p.shard.count);
    }
    next_view = p.view_end;
  }
  const SampleStoreInfo& base = first.store->info();
  for (const Part& p : parts) {
    const SampleStoreInfo& info = p.store->info();
    if (info.texels != base.texels || info.chunks != base.chunks ||
        info.chunk_texels != base.chunk_texels || info.pixel_of_texel != base.pixel_of_texel) {
      return DataLossError((p.dir / "store.json").string(),
                           ": texels/chunks/atlas differ from ", (first.dir / "store.json").string());
    }
  }

  // Chunks: each texel's samples, shard after shard (the order one run appends them in).
  SampleStoreInfo info = base;
  info.samples = 0;
  info.images = 0;
  Tally tally;
  for (int s = 0; s < first.shard.count; ++s) {
    const Part& p = parts[size_t(of_shard[size_t(s)])];
    info.images += p.store->info().images;
    tally.Add(p.tally);
  }
  // One chunk per task, `threads` at a time: reading, joining and writing a chunk is independent
  // of the others (the store's reader is thread-safe).
  std::mutex mutex;
  Status first_error;
  std::atomic<bool> failed{false};
  std::atomic<uint64_t> samples{0};
  auto merge_chunk = [&](uint32_t c) -> Status {
    std::vector<TexelSampleChunk> pieces;
    for (int s = 0; s < first.shard.count; ++s) {
      REFLCAP_ASSIGN_OR_RETURN(TexelSampleChunk piece,
                               parts[size_t(of_shard[size_t(s)])].store->ReadChunk(c));
      pieces.push_back(std::move(piece));
    }
    REFLCAP_ASSIGN_OR_RETURN(const TexelSampleChunk merged, JoinSampleChunks(pieces));
    samples += merged.samples.size();
    return WriteSampleChunk(out_dir / SampleChunkFileName(c), merged);
  };
  if (link) {
    // The parts stay where they are; the store names them in shard order.
    for (int s = 0; s < first.shard.count; ++s) {
      const Part& p = parts[size_t(of_shard[size_t(s)])];
      const fs::path dir = fs::absolute(p.dir).lexically_normal();
      info.parts.push_back({dir.string(), p.store->fingerprint()});
      samples += p.store->info().samples;
    }
  } else {
    ParallelFor(
        0, base.chunks, 1,
        [&](int64_t b, int64_t e, int) {
          for (int64_t c = b; c < e && !failed; ++c) {
            Status st = merge_chunk(uint32_t(c));
            if (!st.ok()) {
              std::lock_guard<std::mutex> lock(mutex);
              if (first_error.ok()) first_error = st;
              failed = true;
            }
          }
        },
        threads);
  }
  REFLCAP_RETURN_IF_ERROR(first_error);
  info.samples = samples;
  REFLCAP_RETURN_IF_ERROR(WriteSampleStoreInfo(out_dir, info));

  // Coverage: the shards' views are disjoint, so counts add up and sets unite.
  TexelCoverage coverage(base.texels);
  for (int s = 0; s < first.shard.count; ++s) {
    const Part& p = parts[size_t(of_shard[size_t(s)])];
    REFLCAP_ASSIGN_OR_RETURN(TexelCoverage piece,
                             TexelCoverage::Load(p.dir / kPartCoverageFile, base.texels));
    coverage.Merge(piece);
  }
  TexelAtlas atlas;
  atlas.width = base.atlas_width;
  atlas.height = base.atlas_height;
  atlas.pixel_of_texel = base.pixel_of_texel;

  // The report: shard 0's, with every counted field recomputed from the sums.
  const auto outputs_start = std::chrono::steady_clock::now();
  Json report = parts[size_t(of_shard[0])].manifest["report"];
  REFLCAP_ASSIGN_OR_RETURN(Counted counted,
                           WriteCountedOutputs(out_dir, atlas, coverage, tally, info.images,
                                               info.samples, &report));
  report["views"] = first.views_total;
  Json shards = Json::array();
  double setup_s = 0, reorder_s = 0, total_s = 0;
  uint64_t spilled = 0;
  for (int s = 0; s < first.shard.count; ++s) {
    const Part& p = parts[size_t(of_shard[size_t(s)])];
    const Json& r = p.manifest["report"];
    const Json t = r.value("timings", Json::object());
    setup_s += t.value("setup_s", 0.0);
    reorder_s += t.value("reorder_s", 0.0);
    total_s += t.value("total_s", 0.0);
    spilled += r.contains("store") ? r["store"].value("spilled_bytes", uint64_t{0}) : 0;
    if (r.contains("vulkan") && report.contains("vulkan") && s > 0) {
      report["vulkan"]["gpu_s"] = report["vulkan"]["gpu_s"].get<double>() + r["vulkan"].value("gpu_s", 0.0);
    }
    shards.push_back({{"part", fs::absolute(p.dir).lexically_normal().string()},
                      {"views", {p.view_begin, p.view_end}},
                      {"images", p.store->info().images},
                      {"device", r.value("device", "")},
                      {"total_s", t.value("total_s", 0.0)}});
  }
  const double merge_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  report["timings"] = {{"setup_s", setup_s},
                       {"read_wait_s", tally.read_wait_s},
                       {"resample_s", tally.resample_s},
                       {"stream_s", tally.stream_s},
                       {"reorder_s", reorder_s},
                       {"outputs_s", std::chrono::duration<double>(std::chrono::steady_clock::now() -
                                                                   outputs_start).count()},
                       {"total_s", total_s},
                       {"merge_s", merge_s},
                       {"texel_image_pairs_per_s",
                        tally.resample_s > 0 ? double(counted.pairs) / tally.resample_s : 0.0}};
  report["store"]["spilled_bytes"] = spilled;
  report["shards"] = {{"count", first.shard.count}, {"parts", shards}, {"linked", link}};
  const std::string report_text = report.dump(2) + "\n";
  REFLCAP_RETURN_IF_ERROR(WriteTextFileAtomic(out_dir / "resample_report.json", report_text));

  ResampleSummary summary;
  summary.texels = base.texels;
  summary.texels_seen = counted.texels_seen;
  summary.texels_with_samples = counted.texels_with_samples;
  summary.images = info.images;
  summary.samples_kept = counted.kept;
  summary.samples_rejected = counted.rejected_total;
  summary.seconds = merge_s;
  summary.report_json = report_text;
  summary.text = SummaryText(report, total_s);
  return summary;
}

}  // namespace reflcap::resample
