// Fit shards, checkpoints and parts (see fit_checkpoint.h).
#include "engine/fit/fit_checkpoint.h"

#include <cinttypes>
#include <cstdio>
#include <cstring>
#include <memory>

#include "engine/core/atomic_file.h"
#include "engine/fit/model.h"
#include "engine/fit/fit_store.h"
#include "engine/fit/problem.h"
#include "engine/texel/sample_store.h"

namespace reflcap::fit {
namespace fs = std::filesystem;
using Json = nlohmann::json;

namespace {

#pragma pack(push, 1)
struct FitChunkHeader {
  char magic[8];
  uint32_t version;
  uint32_t header_bytes;
  uint32_t lobes;
  uint32_t stride;
  uint32_t first_texel;
  uint32_t texel_count;
  uint32_t record_bytes;
  uint32_t reserved0;
  uint64_t payload_bytes;
  uint32_t payload_crc32;
  uint8_t reserved1[8];
  uint32_t header_crc32;
};
#pragma pack(pop)
static_assert(sizeof(FitChunkHeader) == 64, "the chunk result header is 64 bytes");
constexpr size_t kHeaderCrcBytes = 60;

struct FileCloser {
  void operator()(std::FILE* f) const {
    if (f) std::fclose(f);
  }
};
using File = std::unique_ptr<std::FILE, FileCloser>;

int Stride(int lobes) { return brdf::kChannels * brdf::ParamsPerChannel(lobes); }
size_t RecordBytes(int lobes) { return 8 * size_t(Stride(lobes)) + 20; }

template <typename T>
void Put(uint8_t** at, const T& value) {
  std::memcpy(*at, &value, sizeof(T));
  *at += sizeof(T);
}
template <typename T>
T Take(const uint8_t** at) {
  T value;
  std::memcpy(&value, *at, sizeof(T));
  *at += sizeof(T);
  return value;
}

}  // namespace

StatusOr<ChunkRange> ShardChunks(Shard shard, uint32_t chunks) {
  return ShardRange(shard, chunks, "chunks in the sample store");
}

std::string FitChunkFileName(uint32_t chunk) {
  char name[32];
  std::snprintf(name, sizeof name, "fits_%05u.rcf", chunk);
  return name;
}

Status WriteFitChunk(const fs::path& path, uint32_t first_texel, int lobes,
                     const std::vector<TexelFit>& results) {
  const int stride = Stride(lobes);
  const size_t record = RecordBytes(lobes);
  std::vector<uint8_t> payload(results.size() * record);
  std::vector<float> buffer(static_cast<size_t>(stride));
  uint8_t* at = payload.data();
  for (const TexelFit& f : results) {
    PackParams(f.params, lobes, buffer.data());
    std::memcpy(at, buffer.data(), stride * sizeof(float));
    at += stride * sizeof(float);
    PackParams(f.sigma, lobes, buffer.data());
    std::memcpy(at, buffer.data(), stride * sizeof(float));
    at += stride * sizeof(float);
    Put(&at, f.cost);
    Put(&at, int32_t(f.iterations));
    Put(&at, int32_t(f.samples));
    Put(&at, int32_t(f.residuals));
    Put(&at, uint8_t(f.status));
    Put(&at, uint8_t(f.lambert_only ? 1 : 0));
    Put(&at, uint16_t(0));
  }
  FitChunkHeader h{};
  std::memcpy(h.magic, kFitChunkMagic, 8);
  h.version = kFitChunkVersion;
  h.header_bytes = sizeof h;
  h.lobes = uint32_t(lobes);
  h.stride = uint32_t(stride);
  h.first_texel = first_texel;
  h.texel_count = uint32_t(results.size());
  h.record_bytes = uint32_t(record);
  h.payload_bytes = payload.size();
  h.payload_crc32 = Crc32(payload.data(), payload.size());
  h.header_crc32 = Crc32(&h, kHeaderCrcBytes);
  return WriteFileAtomic(path, [&](const fs::path& tmp) -> Status {
    File f(std::fopen(tmp.c_str(), "wb"));
    if (!f) return InternalError(path.string(), ": cannot create file");
    if (std::fwrite(&h, sizeof h, 1, f.get()) != 1 ||
        (!payload.empty() && std::fwrite(payload.data(), payload.size(), 1, f.get()) != 1)) {
      return InternalError(path.string(), ": write failed (disk full?)");
    }
    if (std::fclose(f.release()) != 0) return InternalError(path.string(), ": write failed");
    return OkStatus();
  });
}

StatusOr<std::vector<TexelFit>> ReadFitChunk(const fs::path& path, uint32_t first_texel,
                                             uint32_t texel_count, int lobes) {
  const std::string file = path.string();
  std::error_code ec;
  const uintmax_t size = fs::file_size(path, ec);
  if (ec) return NotFoundError(file, ": cannot open chunk result file");
  File f(std::fopen(path.c_str(), "rb"));
  if (!f) return NotFoundError(file, ": cannot open chunk result file");
  FitChunkHeader h{};
  if (size < sizeof h || std::fread(&h, sizeof h, 1, f.get()) != 1) {
    return DataLossError(file, ": truncated chunk result file (", size, " bytes)");
  }
  if (std::memcmp(h.magic, kFitChunkMagic, 8) != 0) {
    return DataLossError(file, ": not a reflcap chunk result file (bad magic)");
  }
  if (h.version != kFitChunkVersion) {
    return DataLossError(file, ": chunk result format version ", h.version,
                         " is not supported (this reflcap reads version ", kFitChunkVersion, ")");
  }
  if (Crc32(&h, kHeaderCrcBytes) != h.header_crc32) {
    return DataLossError(file, ": corrupt chunk result file (header checksum mismatch)");
  }
  const size_t record = RecordBytes(lobes);
  if (h.lobes != uint32_t(lobes) || h.stride != uint32_t(Stride(lobes)) || h.record_bytes != record) {
    return DataLossError(file, ": lobes: holds fits of ", h.lobes, " lobes, this fit has ", lobes);
  }
  if (h.first_texel != first_texel || h.texel_count != texel_count) {
    return DataLossError(file, ": first_texel/texel_count: holds texels ", h.first_texel, "..",
                         uint64_t(h.first_texel) + h.texel_count, ", expected ", first_texel, "..",
                         uint64_t(first_texel) + texel_count);
  }
  if (h.payload_bytes != uint64_t(texel_count) * record || size - sizeof h != h.payload_bytes) {
    return DataLossError(file, ": ", size - sizeof h < h.payload_bytes ? "truncated" : "corrupt",
                         " chunk result file (", size, " bytes, expected ",
                         sizeof h + uint64_t(texel_count) * record, ")");
  }
  std::vector<uint8_t> payload(size_t(h.payload_bytes));
  if (!payload.empty() && std::fread(payload.data(), payload.size(), 1, f.get()) != 1) {
    return DataLossError(file, ": truncated chunk result file (short read)");
  }
  if (Crc32(payload.data(), payload.size()) != h.payload_crc32) {
    return DataLossError(file, ": corrupt chunk result file (payload checksum mismatch)");
  }
  const int stride = Stride(lobes);
  std::vector<TexelFit> results(texel_count);
  std::vector<float> buffer(static_cast<size_t>(stride));
  const uint8_t* at = payload.data();
  for (uint32_t i = 0; i < texel_count; ++i) {
    TexelFit& fit = results[i];
    BeginTexel(lobes, &fit);
    std::memcpy(buffer.data(), at, stride * sizeof(float));
    at += stride * sizeof(float);
    UnpackParams(buffer.data(), lobes, &fit.params);
    std::memcpy(buffer.data(), at, stride * sizeof(float));
    at += stride * sizeof(float);
    UnpackParams(buffer.data(), lobes, &fit.sigma);
    fit.cost = Take<float>(&at);
    fit.iterations = Take<int32_t>(&at);
    fit.samples = Take<int32_t>(&at);
    fit.residuals = Take<int32_t>(&at);
    const uint8_t status = Take<uint8_t>(&at);
    const uint8_t lambert_only = Take<uint8_t>(&at);
    at += 2;
    if (status >= kFitStatusCount || lambert_only > 1) {
      return DataLossError(file, ": texel ", first_texel + i, ": status ", int(status),
                           " / lambert_only ", int(lambert_only), " out of range");
    }
    fit.status = FitStatus(status);
    fit.lambert_only = lambert_only != 0;
  }
  return results;
}

Json FitOptionsToJson(const FitOptions& o) {
  return Json{
      {"lobes", o.lobes},
      {"lobe_model", LobeModelName(o.lobe_model)},
      {"select_lobe_model", o.select_lobe_model},
      {"init", InitSchemeName(o.init)},
      {"loss", LossKindName(o.loss)},
      {"loss_scale", o.loss_scale},
      {"max_iterations", o.max_iterations},
      {"first_stage_iterations", o.first_stage_iterations},
      {"start_exponent", o.start_exponent},
      {"min_samples", o.min_samples},
      {"min_cos_theta", o.min_cos_theta},
      {"highlight_cone_deg", o.highlight_cone_deg},
      {"evidence_sigmas", o.evidence_sigmas},
      {"step_tolerance", o.step_tolerance},
      {"cost_tolerance", o.cost_tolerance},
      {"gradient_tolerance", o.gradient_tolerance},
      {"channel_retry", o.channel_retry},
      {"lobe_transfer",
       {{"enabled", o.lobe_transfer.enabled},
        {"radius", o.lobe_transfer.radius},
        {"albedo_tolerance", o.lobe_transfer.albedo_tolerance},
        {"max_cost_increase", o.lobe_transfer.max_cost_increase},
        {"rounds", o.lobe_transfer.rounds}}},
      {"clusters",
       {{"enabled", o.clusters.enabled},
        {"chroma_scale", o.clusters.chroma_scale},
        {"level_scale", o.clusters.level_scale},
        {"max_clusters", o.clusters.max_clusters},
        {"min_cluster_texels", o.clusters.min_cluster_texels},
        {"pool_texels", o.clusters.pool_texels},
        {"lobes_per_cluster", o.clusters.lobes_per_cluster},
        {"model_choice", ModelChoiceName(o.clusters.model_choice)},
        {"folds", o.clusters.folds}}},
      {"diffuse_falloff", o.diffuse_falloff},
      {"albedo_fill",
       {{"enabled", o.albedo_fill.enabled},
        {"radius", o.albedo_fill.radius},
        {"rounds", o.albedo_fill.rounds}}},
  };
}

namespace {

// Reads json[key] into *value; DataLoss naming the file and the field when absent or mistyped.
template <typename T>
Status Field(const Json& json, const char* key, const std::string& file, const std::string& where,
             T* value) {
  const auto it = json.find(key);
  if (it == json.end()) return DataLossError(file, ": ", where, key, ": missing");
  try {
    if constexpr (std::is_same_v<T, bool>) {
      if (!it->is_boolean()) return DataLossError(file, ": ", where, key, ": expected true or false");
    } else if constexpr (std::is_arithmetic_v<T>) {
      if (!it->is_number()) return DataLossError(file, ": ", where, key, ": expected a number");
    } else {
      if (!it->is_string()) return DataLossError(file, ": ", where, key, ": expected a string");
    }
    *value = it->get<T>();
  } catch (const Json::exception&) {
    return DataLossError(file, ": ", where, key, ": out of range");
  }
  return OkStatus();
}

}  // namespace

Status FitOptionsFromJson(const Json& json, const std::string& file, FitOptions* o) {
  if (!json.is_object()) return DataLossError(file, ": options: expected an object");
  const std::string w = "options.";
  std::string lobe_model, init, loss;
  REFLCAP_RETURN_IF_ERROR(Field(json, "lobes", file, w, &o->lobes));
  REFLCAP_RETURN_IF_ERROR(Field(json, "lobe_model", file, w, &lobe_model));
  REFLCAP_RETURN_IF_ERROR(Field(json, "select_lobe_model", file, w, &o->select_lobe_model));
  REFLCAP_RETURN_IF_ERROR(Field(json, "init", file, w, &init));
  REFLCAP_RETURN_IF_ERROR(Field(json, "loss", file, w, &loss));
  REFLCAP_RETURN_IF_ERROR(Field(json, "loss_scale", file, w, &o->loss_scale));
  REFLCAP_RETURN_IF_ERROR(Field(json, "max_iterations", file, w, &o->max_iterations));
  REFLCAP_RETURN_IF_ERROR(Field(json, "first_stage_iterations", file, w, &o->first_stage_iterations));
  REFLCAP_RETURN_IF_ERROR(Field(json, "start_exponent", file, w, &o->start_exponent));
  REFLCAP_RETURN_IF_ERROR(Field(json, "min_samples", file, w, &o->min_samples));
  REFLCAP_RETURN_IF_ERROR(Field(json, "min_cos_theta", file, w, &o->min_cos_theta));
  REFLCAP_RETURN_IF_ERROR(Field(json, "highlight_cone_deg", file, w, &o->highlight_cone_deg));
  REFLCAP_RETURN_IF_ERROR(Field(json, "evidence_sigmas", file, w, &o->evidence_sigmas));
  REFLCAP_RETURN_IF_ERROR(Field(json, "step_tolerance", file, w, &o->step_tolerance));
  REFLCAP_RETURN_IF_ERROR(Field(json, "cost_tolerance", file, w, &o->cost_tolerance));
  REFLCAP_RETURN_IF_ERROR(Field(json, "gradient_tolerance", file, w, &o->gradient_tolerance));
  REFLCAP_RETURN_IF_ERROR(Field(json, "channel_retry", file, w, &o->channel_retry));
  auto lobe_model_value = ParseLobeModel(lobe_model);
  if (!lobe_model_value.ok()) return DataLossError(file, ": options.lobe_model: \"", lobe_model, "\"");
  o->lobe_model = *lobe_model_value;
  auto init_value = ParseInitScheme(init);
  if (!init_value.ok()) return DataLossError(file, ": options.init: \"", init, "\"");
  o->init = *init_value;
  auto loss_value = ParseLossKind(loss);
  if (!loss_value.ok()) return DataLossError(file, ": options.loss: \"", loss, "\"");
  o->loss = *loss_value;
  for (const char* group : {"lobe_transfer", "clusters", "albedo_fill"}) {
    if (!json.contains(group) || !json[group].is_object()) {
      return DataLossError(file, ": options.", group, ": expected an object");
    }
  }
  const Json& t = json["lobe_transfer"];
  const std::string wt = "options.lobe_transfer.";
  REFLCAP_RETURN_IF_ERROR(Field(t, "enabled", file, wt, &o->lobe_transfer.enabled));
  REFLCAP_RETURN_IF_ERROR(Field(t, "radius", file, wt, &o->lobe_transfer.radius));
  REFLCAP_RETURN_IF_ERROR(Field(t, "albedo_tolerance", file, wt, &o->lobe_transfer.albedo_tolerance));
  REFLCAP_RETURN_IF_ERROR(Field(t, "max_cost_increase", file, wt, &o->lobe_transfer.max_cost_increase));
  REFLCAP_RETURN_IF_ERROR(Field(t, "rounds", file, wt, &o->lobe_transfer.rounds));
  const Json& c = json["clusters"];
  const std::string wc = "options.clusters.";
  REFLCAP_RETURN_IF_ERROR(Field(c, "enabled", file, wc, &o->clusters.enabled));
  REFLCAP_RETURN_IF_ERROR(Field(c, "chroma_scale", file, wc, &o->clusters.chroma_scale));
  REFLCAP_RETURN_IF_ERROR(Field(c, "level_scale", file, wc, &o->clusters.level_scale));
  REFLCAP_RETURN_IF_ERROR(Field(c, "max_clusters", file, wc, &o->clusters.max_clusters));
  REFLCAP_RETURN_IF_ERROR(Field(c, "min_cluster_texels", file, wc, &o->clusters.min_cluster_texels));
  REFLCAP_RETURN_IF_ERROR(Field(c, "pool_texels", file, wc, &o->clusters.pool_texels));
  REFLCAP_RETURN_IF_ERROR(Field(c, "lobes_per_cluster", file, wc, &o->clusters.lobes_per_cluster));
  // Absent in files written before the k-fold choice existed: those chose by the criterion.
  std::string choice = "bic";
  if (c.contains("model_choice")) {
    REFLCAP_RETURN_IF_ERROR(Field(c, "model_choice", file, wc, &choice));
  }
  auto parsed_choice = ParseModelChoice(choice);
  if (!parsed_choice.ok()) {
    return DataLossError(file, ": ", wc, "model_choice: \"", choice, "\" is not kfold or bic");
  }
  o->clusters.model_choice = *parsed_choice;
  if (c.contains("folds")) REFLCAP_RETURN_IF_ERROR(Field(c, "folds", file, wc, &o->clusters.folds));
  // Absent in files written before the fall-off lobe existed: those fits had none.
  o->diffuse_falloff = false;
  if (json.contains("diffuse_falloff")) {
    REFLCAP_RETURN_IF_ERROR(Field(json, "diffuse_falloff", file, w, &o->diffuse_falloff));
  }
  const Json& a = json["albedo_fill"];
  const std::string wa = "options.albedo_fill.";
  REFLCAP_RETURN_IF_ERROR(Field(a, "enabled", file, wa, &o->albedo_fill.enabled));
  REFLCAP_RETURN_IF_ERROR(Field(a, "radius", file, wa, &o->albedo_fill.radius));
  REFLCAP_RETURN_IF_ERROR(Field(a, "rounds", file, wa, &o->albedo_fill.rounds));
  const Status valid = o->Validate();
  if (!valid.ok()) return DataLossError(file, ": options: ", valid.message());
  return OkStatus();
}

Json FitPartManifest::ToJson() const {
  return Json{{"format", kFitPartFormat},
              {"samples", samples},
              {"store_fingerprint", fingerprint},
              {"texels", texels},
              {"chunks", chunks},
              {"chunk_texels", chunk_texels},
              {"shard", {{"index", shard.index}, {"count", shard.count}}},
              {"chunk_begin", range.begin},
              {"chunk_end", range.end},
              {"backend", backend},
              {"options", options}};
}

StatusOr<FitPartManifest> FitPartManifest::FromJson(const Json& json, const std::string& file) {
  if (!json.is_object()) return DataLossError(file, ": expected a JSON object");
  std::string format;
  REFLCAP_RETURN_IF_ERROR(Field(json, "format", file, "", &format));
  if (format != kFitPartFormat) {
    return DataLossError(file, ": format: \"", format, "\", expected \"", kFitPartFormat, "\"");
  }
  FitPartManifest m;
  REFLCAP_RETURN_IF_ERROR(Field(json, "samples", file, "", &m.samples));
  REFLCAP_RETURN_IF_ERROR(Field(json, "store_fingerprint", file, "", &m.fingerprint));
  REFLCAP_RETURN_IF_ERROR(Field(json, "texels", file, "", &m.texels));
  REFLCAP_RETURN_IF_ERROR(Field(json, "chunks", file, "", &m.chunks));
  REFLCAP_RETURN_IF_ERROR(Field(json, "chunk_texels", file, "", &m.chunk_texels));
  REFLCAP_RETURN_IF_ERROR(Field(json, "chunk_begin", file, "", &m.range.begin));
  REFLCAP_RETURN_IF_ERROR(Field(json, "chunk_end", file, "", &m.range.end));
  REFLCAP_RETURN_IF_ERROR(Field(json, "backend", file, "", &m.backend));
  if (!json.contains("shard") || !json["shard"].is_object()) {
    return DataLossError(file, ": shard: expected an object {index, count}");
  }
  REFLCAP_RETURN_IF_ERROR(Field(json["shard"], "index", file, "shard.", &m.shard.index));
  REFLCAP_RETURN_IF_ERROR(Field(json["shard"], "count", file, "shard.", &m.shard.count));
  if (m.shard.count < 1 || m.shard.index < 0 || m.shard.index >= m.shard.count) {
    return DataLossError(file, ": shard: ", m.shard.index, "/", m.shard.count, " is not I/N with 0 <= I < N");
  }
  if (m.range.begin > m.range.end || m.range.end > m.chunks) {
    return DataLossError(file, ": chunk_begin/chunk_end: ", m.range.begin, "..", m.range.end,
                         " outside the store's ", m.chunks, " chunks");
  }
  if (!json.contains("options")) return DataLossError(file, ": options: missing");
  m.options = json["options"];
  FitOptions check;
  REFLCAP_RETURN_IF_ERROR(FitOptionsFromJson(m.options, file, &check));
  return m;
}

std::string FitPartManifest::Mismatch(const FitPartManifest& o) const {
  if (fingerprint != o.fingerprint) return "store_fingerprint (another sample store)";
  if (texels != o.texels || chunks != o.chunks || chunk_texels != o.chunk_texels) {
    return "texels/chunks (another sample store)";
  }
  if (backend != o.backend) return "backend (" + backend + " vs " + o.backend + ")";
  if (options != o.options) {
    for (auto it = options.begin(); it != options.end(); ++it) {
      if (!o.options.contains(it.key()) || o.options[it.key()] != it.value()) {
        return "options." + it.key() + " (" + it.value().dump() + " vs " +
               (o.options.contains(it.key()) ? o.options[it.key()].dump() : "missing") + ")";
      }
    }
    return "options";
  }
  if (shard.count != o.shard.count) {
    return "shard count (" + std::to_string(shard.count) + " vs " + std::to_string(o.shard.count) + ")";
  }
  return "";
}

}  // namespace reflcap::fit
