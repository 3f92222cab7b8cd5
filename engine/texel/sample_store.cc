// Sample store I/O (format in sample_store.h). Chunks are written with one header, the offsets
// and the records straight from memory (the host is little-endian, checked below), and read back
// the same way after every size has been checked against the file's real size, so a corrupt count
// can never make the reader allocate or read past the file.
#include "engine/texel/sample_store.h"

#include <zlib.h>

#include <algorithm>
#include <array>
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <mutex>

#include <nlohmann/json.hpp>

#include "engine/core/atomic_file.h"
#include "engine/core/parallel.h"

namespace reflcap {
namespace fs = std::filesystem;
using Json = nlohmann::json;

static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__,
              "the sample store writes little-endian records straight from memory");
static_assert(sizeof(float) == 4 && std::numeric_limits<float>::is_iec559, "IEEE float expected");

namespace {

// ---- Chunk header ------------------------------------------------------------------------------

struct ChunkHeader {
  char magic[8];
  uint32_t version;
  uint32_t header_bytes;
  uint32_t record_bytes;
  uint32_t first_texel;
  uint32_t texel_count;
  uint32_t reserved0;
  uint64_t sample_count;
  uint64_t payload_bytes;
  uint32_t payload_crc32;
  uint32_t reserved1;
  uint32_t reserved2;
  uint32_t header_crc32;
};
static_assert(sizeof(ChunkHeader) == kSampleChunkHeaderBytes, "chunk header is 64 bytes");
static_assert(offsetof(ChunkHeader, sample_count) == 32 && offsetof(ChunkHeader, payload_crc32) == 48 &&
                  offsetof(ChunkHeader, header_crc32) == 60,
              "chunk header layout as documented in sample_store.h");
constexpr size_t kHeaderCrcBytes = 60;

struct AtlasHeader {
  char magic[8];
  uint32_t version;
  uint32_t width;
  uint32_t height;
  uint32_t texels;
  uint32_t payload_crc32;
  uint32_t header_crc32;
};
static_assert(sizeof(AtlasHeader) == 32, "atlas.bin header is 32 bytes");
constexpr char kAtlasMagic[8] = {'R', 'F', 'L', 'C', 'A', 'T', 'L', 'S'};
constexpr uint32_t kAtlasVersion = 1;

// A std::FILE that closes itself.
struct FileCloser {
  void operator()(std::FILE* f) const {
    if (f != nullptr) std::fclose(f);
  }
};
using File = std::unique_ptr<std::FILE, FileCloser>;

Status WriteAll(std::FILE* f, const void* data, size_t size, const fs::path& path) {
  if (size == 0) return OkStatus();
  if (std::fwrite(data, 1, size, f) != size) return InternalError(path.string(), ": write failed");
  return OkStatus();
}

bool ReadAll(std::FILE* f, void* data, size_t size) {
  return size == 0 || std::fread(data, 1, size, f) == size;
}

bool IsFinite(const float* v, int n) {
  for (int i = 0; i < n; ++i) {
    if (!std::isfinite(v[i])) return false;
  }
  return true;
}

// Why a record is unacceptable, or nullptr.
const char* RecordProblem(const BrdfSample& s) {
  if (!IsFinite(s.wi, 3) || !IsFinite(s.wo, 3) || !IsFinite(s.value, 3) || !IsFinite(s.weight, 3)) {
    return "non-finite number";
  }
  for (float w : s.weight) {
    if (w < 0) return "negative weight";
  }
  return nullptr;
}

}  // namespace

std::string SampleChunkFileName(uint32_t index) {
  char name[32];
  std::snprintf(name, sizeof name, "chunk_%05u.rcs", index);
  return name;
}

Status WriteSampleChunk(const fs::path& path, const TexelSampleChunk& chunk) {
  const std::string file = path.string();
  if (chunk.offsets.size() != size_t(chunk.texel_count) + 1) {
    return InvalidArgumentError(file, ": chunk has ", chunk.offsets.size(), " offsets for ",
                                chunk.texel_count, " texels (need texel_count + 1)");
  }
  if (chunk.offsets.front() != 0 || chunk.offsets.back() != chunk.samples.size()) {
    return InvalidArgumentError(file, ": chunk offsets must run from 0 to the sample count ",
                                chunk.samples.size());
  }
  for (size_t i = 0; i + 1 < chunk.offsets.size(); ++i) {
    if (chunk.offsets[i + 1] < chunk.offsets[i]) {
      return InvalidArgumentError(file, ": chunk offsets decrease at texel ", i);
    }
  }
  for (size_t i = 0; i < chunk.samples.size(); ++i) {
    if (const char* problem = RecordProblem(chunk.samples[i])) {
      return InvalidArgumentError(file, ": sample ", i, ": ", problem);
    }
  }
  const size_t offsets_bytes = chunk.offsets.size() * sizeof(uint64_t);
  const size_t records_bytes = chunk.samples.size() * sizeof(BrdfSample);
  ChunkHeader h{};
  std::memcpy(h.magic, kSampleChunkMagic, 8);
  h.version = kSampleChunkVersion;
  h.header_bytes = kSampleChunkHeaderBytes;
  h.record_bytes = sizeof(BrdfSample);
  h.first_texel = chunk.first_texel;
  h.texel_count = chunk.texel_count;
  h.sample_count = chunk.samples.size();
  h.payload_bytes = offsets_bytes + records_bytes;
  h.payload_crc32 = Crc32(chunk.samples.data(), records_bytes,
                          Crc32(chunk.offsets.data(), offsets_bytes));
  h.header_crc32 = Crc32(&h, kHeaderCrcBytes);
  return WriteFileAtomic(path, [&](const fs::path& tmp) -> Status {
    File f(std::fopen(tmp.c_str(), "wb"));
    if (!f) return InternalError(file, ": cannot create file");
    REFLCAP_RETURN_IF_ERROR(WriteAll(f.get(), &h, sizeof h, path));
    REFLCAP_RETURN_IF_ERROR(WriteAll(f.get(), chunk.offsets.data(), offsets_bytes, path));
    REFLCAP_RETURN_IF_ERROR(WriteAll(f.get(), chunk.samples.data(), records_bytes, path));
    if (std::fclose(f.release()) != 0) return InternalError(file, ": write failed");
    return OkStatus();
  });
}

StatusOr<TexelSampleChunk> ReadSampleChunk(const fs::path& path) {
  TexelSampleChunk chunk;
  REFLCAP_RETURN_IF_ERROR(ReadSampleChunkInto(path, &chunk));
  return chunk;
}

Status ReadSampleChunkInto(const fs::path& path, TexelSampleChunk* out) {
  TexelSampleChunk& chunk = *out;
  const std::string file = path.string();
  std::error_code ec;
  const uintmax_t file_size = fs::file_size(path, ec);
  if (ec) return NotFoundError(file, ": cannot open sample chunk");
  File f(std::fopen(path.c_str(), "rb"));
  if (!f) return NotFoundError(file, ": cannot open sample chunk");
  ChunkHeader h{};
  if (file_size < sizeof h || !ReadAll(f.get(), &h, sizeof h)) {
    return DataLossError(file, ": truncated sample chunk (", file_size, " bytes; the header alone is ",
                         sizeof h, ")");
  }
  if (std::memcmp(h.magic, kSampleChunkMagic, 8) != 0) {
    return DataLossError(file, ": not a reflcap sample chunk (bad magic)");
  }
  if (h.version != kSampleChunkVersion) {
    return FailedPreconditionError(file, ": sample chunk format version ", h.version,
                                   " is not supported (this reflcap reads version ",
                                   kSampleChunkVersion, ")");
  }
  if (Crc32(&h, kHeaderCrcBytes) != h.header_crc32) {
    return DataLossError(file, ": corrupt sample chunk (header checksum mismatch)");
  }
  if (h.header_bytes != kSampleChunkHeaderBytes || h.record_bytes != sizeof(BrdfSample)) {
    return DataLossError(file, ": corrupt sample chunk (header_bytes ", h.header_bytes,
                         ", record_bytes ", h.record_bytes, "; expected 64 and 52)");
  }
  // The counts must agree with payload_bytes (the division keeps sample_count * 52 from
  // overflowing), and payload_bytes with the file's real size, before anything is allocated.
  const uint64_t offsets_bytes = (uint64_t(h.texel_count) + 1) * sizeof(uint64_t);
  const uint64_t available = file_size - sizeof h;
  if (h.sample_count > (std::numeric_limits<uint64_t>::max() - offsets_bytes) / sizeof(BrdfSample) ||
      h.payload_bytes != offsets_bytes + h.sample_count * sizeof(BrdfSample)) {
    return DataLossError(file, ": corrupt sample chunk (payload_bytes ", h.payload_bytes,
                         " does not match ", h.texel_count, " texels and ", h.sample_count,
                         " samples)");
  }
  if (available != h.payload_bytes) {
    return DataLossError(file, ": ", available < h.payload_bytes ? "truncated" : "corrupt",
                         " sample chunk (", file_size, " bytes, expected ",
                         sizeof h + h.payload_bytes, ")");
  }
  chunk.first_texel = h.first_texel;
  chunk.texel_count = h.texel_count;
  chunk.offsets.resize(size_t(h.texel_count) + 1);
  chunk.samples.resize(size_t(h.sample_count));
  if (!ReadAll(f.get(), chunk.offsets.data(), size_t(offsets_bytes)) ||
      !ReadAll(f.get(), chunk.samples.data(), chunk.samples.size() * sizeof(BrdfSample))) {
    return DataLossError(file, ": truncated sample chunk (read failed)");
  }
  const uint32_t crc = Crc32(chunk.samples.data(), chunk.samples.size() * sizeof(BrdfSample),
                             Crc32(chunk.offsets.data(), size_t(offsets_bytes)));
  if (crc != h.payload_crc32) {
    return DataLossError(file, ": corrupt sample chunk (payload checksum mismatch)");
  }
  if (chunk.offsets.front() != 0 || chunk.offsets.back() != h.sample_count) {
    return DataLossError(file, ": corrupt sample chunk (offsets do not span the samples)");
  }
  for (size_t i = 0; i + 1 < chunk.offsets.size(); ++i) {
    if (chunk.offsets[i + 1] < chunk.offsets[i]) {
      return DataLossError(file, ": corrupt sample chunk (offsets decrease at texel ", i, ")");
    }
  }
  for (size_t i = 0; i < chunk.samples.size(); ++i) {
    if (const char* problem = RecordProblem(chunk.samples[i])) {
      return DataLossError(file, ": corrupt sample chunk (sample ", i, ": ", problem, ")");
    }
  }
  return OkStatus();
}

Status WriteSampleStoreInfo(const fs::path& dir, const SampleStoreInfo& info) {
  const fs::path json_path = dir / "store.json";
  if (info.pixel_of_texel.size() != info.texels) {
    return InvalidArgumentError(json_path.string(), ": pixel_of_texel has ",
                                info.pixel_of_texel.size(), " entries for ", info.texels, " texels");
  }
  if (info.chunk_texels == 0 ||
      info.chunks != (uint64_t(info.texels) + info.chunk_texels - 1) / info.chunk_texels) {
    return InvalidArgumentError(json_path.string(), ": ", info.chunks, " chunks of ",
                                info.chunk_texels, " texels do not cover ", info.texels, " texels");
  }
  const uint64_t atlas_pixels = uint64_t(std::max(info.atlas_width, 0)) * uint64_t(std::max(info.atlas_height, 0));
  for (uint32_t p : info.pixel_of_texel) {
    if (p >= atlas_pixels) {
      return InvalidArgumentError(json_path.string(), ": pixel_of_texel entry ", p,
                                  " outside the ", info.atlas_width, "x", info.atlas_height, " atlas");
    }
  }
  const Json json = {
      {"format", kSampleStoreFormat},
      {"texels", info.texels},
      {"chunk_texels", info.chunk_texels},
      {"chunks", info.chunks},
      {"samples", info.samples},
      {"atlas", {{"width", info.atlas_width}, {"height", info.atlas_height}, {"file", "atlas.bin"}}},
      {"chunk_file", "chunk_{index:05d}.rcs"},
      {"record", {{"bytes", sizeof(BrdfSample)},
                  {"layout", "wi[3] wo[3] value[3] weight[3] float32, image uint32; little-endian"}}},
      {"capture", info.capture},
      {"split", info.split},
      {"min_cos", info.min_cos},
      {"images", info.images},
      {"geometry", info.geometry}};
  Json root = json;
  if (!info.parts.empty()) {
    Json parts = Json::array();
    for (const SampleStoreInfo::Part& part : info.parts) {
      parts.push_back({{"path", part.path}, {"fingerprint", part.fingerprint}});
    }
    root["parts"] = parts;
  }
  REFLCAP_RETURN_IF_ERROR(WriteTextFileAtomic(json_path, root.dump(2) + "\n"));

  const fs::path atlas_path = dir / "atlas.bin";
  AtlasHeader h{};
  std::memcpy(h.magic, kAtlasMagic, 8);
  h.version = kAtlasVersion;
  h.width = uint32_t(info.atlas_width);
  h.height = uint32_t(info.atlas_height);
  h.texels = info.texels;
  const size_t payload = info.pixel_of_texel.size() * sizeof(uint32_t);
  h.payload_crc32 = Crc32(info.pixel_of_texel.data(), payload);
  h.header_crc32 = Crc32(&h, offsetof(AtlasHeader, header_crc32));
  return WriteFileAtomic(atlas_path, [&](const fs::path& tmp) -> Status {
    File f(std::fopen(tmp.c_str(), "wb"));
    if (!f) return InternalError(atlas_path.string(), ": cannot create file");
    REFLCAP_RETURN_IF_ERROR(WriteAll(f.get(), &h, sizeof h, atlas_path));
    REFLCAP_RETURN_IF_ERROR(WriteAll(f.get(), info.pixel_of_texel.data(), payload, atlas_path));
    if (std::fclose(f.release()) != 0) return InternalError(atlas_path.string(), ": write failed");
    return OkStatus();
  });
}

namespace {

// SampleStoreFingerprint's form: "xxxxxxxx-xxxxxxxx".
std::string FingerprintOf(uint32_t store_json_crc, uint32_t atlas_crc) {
  char text[18];
  std::snprintf(text, sizeof text, "%08" PRIx32 "-%08" PRIx32, store_json_crc, atlas_crc);
  return text;
}

// store.json field readers: DataLoss "store.json: field: problem".
template <typename T>
Status JsonField(const Json& root, const char* name, const std::string& file, T* out) {
  auto it = root.find(name);
  if (it == root.end()) return DataLossError(file, ": ", name, ": missing");
  try {
    *out = it->get<T>();
  } catch (const Json::exception& e) {
    return DataLossError(file, ": ", name, ": wrong type (", e.what(), ")");
  }
  return OkStatus();
}

// Also sets *file_crc to the CRC-32 of the whole file (for the store's fingerprint) and
// *payload_crc to the header's payload CRC. With `header_only` (a linked store's part, whose atlas
// is never used: the linked store's own is) only the header is read and checked, and the file's
// CRC is derived from the header's and the recorded payload CRC: the fingerprint still names
// exactly the part that was linked, and its payload CRC must equal the linked store's (checked
// by the caller). Reading and checking every part's 4 MB at 10^6 texels cost each fit shard of a
// linked store 28 ms.
StatusOr<std::vector<uint32_t>> ReadAtlasBin(const fs::path& path, const SampleStoreInfo& info,
                                             bool header_only, uint32_t* file_crc,
                                             uint32_t* payload_crc) {
  const std::string file = path.string();
  std::error_code ec;
  const uintmax_t file_size = fs::file_size(path, ec);
  if (ec) return NotFoundError(file, ": cannot open the store's atlas");
  File f(std::fopen(path.c_str(), "rb"));
  if (!f) return NotFoundError(file, ": cannot open the store's atlas");
  AtlasHeader h{};
  if (file_size < sizeof h || !ReadAll(f.get(), &h, sizeof h)) {
    return DataLossError(file, ": truncated (", file_size, " bytes)");
  }
  if (std::memcmp(h.magic, kAtlasMagic, 8) != 0) return DataLossError(file, ": bad magic");
  if (h.version != kAtlasVersion) {
    return FailedPreconditionError(file, ": atlas format version ", h.version, " is not supported");
  }
  if (Crc32(&h, offsetof(AtlasHeader, header_crc32)) != h.header_crc32) {
    return DataLossError(file, ": header checksum mismatch");
  }
  if (h.texels != info.texels || int(h.width) != info.atlas_width || int(h.height) != info.atlas_height) {
    return DataLossError(file, ": holds a ", h.width, "x", h.height, " atlas of ", h.texels,
                         " texels but store.json says ", info.atlas_width, "x", info.atlas_height,
                         " and ", info.texels);
  }
  if (file_size != sizeof h + uint64_t(h.texels) * sizeof(uint32_t)) {
    return DataLossError(file, ": ", file_size, " bytes, expected ",
                         sizeof h + uint64_t(h.texels) * sizeof(uint32_t));
  }
  const size_t payload_bytes = size_t(h.texels) * sizeof(uint32_t);
  *payload_crc = h.payload_crc32;
  // CRC(header ++ payload) from the two parts' CRCs (zlib's crc32_combine: the same CRC-32).
  *file_crc = uint32_t(crc32_combine(Crc32(&h, sizeof h), h.payload_crc32, z_off_t(payload_bytes)));
  if (header_only) return std::vector<uint32_t>();
  std::vector<uint32_t> pixels(h.texels);
  if (!ReadAll(f.get(), pixels.data(), payload_bytes)) {
    return DataLossError(file, ": truncated (read failed)");
  }
  if (Crc32(pixels.data(), payload_bytes) != h.payload_crc32) {
    return DataLossError(file, ": payload checksum mismatch");
  }
  const uint64_t atlas_pixels = uint64_t(h.width) * h.height;
  for (uint32_t p : pixels) {
    if (p >= atlas_pixels) return DataLossError(file, ": texel pixel ", p, " outside the atlas");
  }
  return pixels;
}

}  // namespace

StatusOr<std::unique_ptr<SampleStoreReader>> SampleStoreReader::Open(const fs::path& dir) {
  return OpenStore(dir, /*as_part=*/false);
}

StatusOr<std::unique_ptr<SampleStoreReader>> SampleStoreReader::OpenStore(const fs::path& dir,
                                                                          bool as_part) {
  const fs::path json_path = dir / "store.json";
  const std::string file = json_path.string();
  auto text = ReadTextFile(json_path);
  if (!text.ok()) return NotFoundError(file, ": cannot open (is ", dir.string(), " a sample store?)");
  Json root = Json::parse(*text, nullptr, /*allow_exceptions=*/false);
  if (root.is_discarded() || !root.is_object()) return DataLossError(file, ": not valid JSON");
  std::string format;
  REFLCAP_RETURN_IF_ERROR(JsonField(root, "format", file, &format));
  if (format != kSampleStoreFormat) {
    return FailedPreconditionError(file, ": format: \"", format, "\" is not supported (expected \"",
                                   kSampleStoreFormat, "\")");
  }
  std::unique_ptr<SampleStoreReader> reader(new SampleStoreReader());
  reader->dir_ = dir;
  SampleStoreInfo& info = reader->info_;
  REFLCAP_RETURN_IF_ERROR(JsonField(root, "texels", file, &info.texels));
  REFLCAP_RETURN_IF_ERROR(JsonField(root, "chunk_texels", file, &info.chunk_texels));
  REFLCAP_RETURN_IF_ERROR(JsonField(root, "chunks", file, &info.chunks));
  REFLCAP_RETURN_IF_ERROR(JsonField(root, "samples", file, &info.samples));
  REFLCAP_RETURN_IF_ERROR(JsonField(root, "capture", file, &info.capture));
  REFLCAP_RETURN_IF_ERROR(JsonField(root, "split", file, &info.split));
  REFLCAP_RETURN_IF_ERROR(JsonField(root, "min_cos", file, &info.min_cos));
  // Optional (descriptive only): absent in stores written before they existed.
  if (root.contains("images")) REFLCAP_RETURN_IF_ERROR(JsonField(root, "images", file, &info.images));
  if (root.contains("geometry")) {
    REFLCAP_RETURN_IF_ERROR(JsonField(root, "geometry", file, &info.geometry));
  }
  Json atlas;
  REFLCAP_RETURN_IF_ERROR(JsonField(root, "atlas", file, &atlas));
  if (!atlas.is_object()) return DataLossError(file, ": atlas: must be an object");
  REFLCAP_RETURN_IF_ERROR(JsonField(atlas, "width", file + ": atlas", &info.atlas_width));
  REFLCAP_RETURN_IF_ERROR(JsonField(atlas, "height", file + ": atlas", &info.atlas_height));
  if (info.atlas_width < 1 || info.atlas_height < 1) {
    return DataLossError(file, ": atlas: width and height must be positive");
  }
  if (info.chunk_texels == 0) return DataLossError(file, ": chunk_texels: must be positive");
  if (info.chunks != (uint64_t(info.texels) + info.chunk_texels - 1) / info.chunk_texels) {
    return DataLossError(file, ": chunks: ", info.chunks, " chunks of ", info.chunk_texels,
                         " texels do not cover ", info.texels, " texels");
  }
  uint32_t atlas_crc = 0;
  REFLCAP_ASSIGN_OR_RETURN(info.pixel_of_texel,
                           ReadAtlasBin(dir / "atlas.bin", info, /*header_only=*/as_part,
                                        &atlas_crc, &reader->atlas_payload_crc_));
  reader->fingerprint_ = FingerprintOf(Crc32(text->data(), text->size()), atlas_crc);
  if (root.contains("parts") && as_part) {
    // Checked before its parts are opened: a part naming its own folder must not recurse.
    return DataLossError(file, ": is itself a linked store (a part must hold its chunks)");
  }
  if (root.contains("parts")) {
    const Json& parts = root["parts"];
    if (!parts.is_array() || parts.empty()) {
      return DataLossError(file, ": parts: must be a non-empty array");
    }
    uint64_t samples = 0;
    for (size_t i = 0; i < parts.size(); ++i) {
      const std::string where = StrCat(file, ": parts[", i, "]");
      if (!parts[i].is_object()) return DataLossError(where, ": must be an object");
      SampleStoreInfo::Part part;
      REFLCAP_RETURN_IF_ERROR(JsonField(parts[i], "path", where, &part.path));
      REFLCAP_RETURN_IF_ERROR(JsonField(parts[i], "fingerprint", where, &part.fingerprint));
      fs::path part_dir(part.path);
      if (part_dir.is_relative()) part_dir = dir / part_dir;
      auto opened = OpenStore(part_dir, /*as_part=*/true);
      if (!opened.ok()) {
        return Status(opened.status().code(),
                      StrCat(where, ": ", part.path, ": ", opened.status().message()));
      }
      std::unique_ptr<SampleStoreReader> reader_of_part = std::move(*opened);
      const SampleStoreInfo& p = reader_of_part->info();
      // The part must be the store that was linked: its identity, then its layout.
      const std::string& fingerprint = reader_of_part->fingerprint();
      if (fingerprint != part.fingerprint) {
        return FailedPreconditionError(where, ": ", part.path, " has changed since it was linked (",
                                       "fingerprint ", fingerprint, ", linked ", part.fingerprint,
                                       ")");
      }
      if (p.texels != info.texels || p.chunk_texels != info.chunk_texels ||
          p.chunks != info.chunks || p.atlas_width != info.atlas_width ||
          p.atlas_height != info.atlas_height ||
          reader_of_part->atlas_payload_crc_ != reader->atlas_payload_crc_) {
        return DataLossError(where, ": ", part.path, ": texels/chunks/atlas differ from the store's");
      }
      samples += p.samples;
      info.parts.push_back(std::move(part));
      reader->parts_.push_back(std::move(reader_of_part));
    }
    if (samples != info.samples) {
      return DataLossError(file, ": samples: ", info.samples, " but its parts hold ", samples);
    }
  }
  return reader;
}

fs::path SampleStoreReader::ChunkPath(uint32_t index) const {
  if (!parts_.empty()) return parts_.front()->ChunkPath(index);
  return dir_ / SampleChunkFileName(index);
}

StatusOr<TexelSampleChunk> JoinSampleChunks(const std::vector<TexelSampleChunk>& pieces) {
  if (pieces.empty()) return InvalidArgumentError("JoinSampleChunks: no pieces");
  TexelSampleChunk joined;
  joined.first_texel = pieces.front().first_texel;
  joined.texel_count = pieces.front().texel_count;
  size_t total = 0;
  for (const TexelSampleChunk& piece : pieces) {
    if (piece.first_texel != joined.first_texel || piece.texel_count != joined.texel_count ||
        piece.offsets.size() != size_t(joined.texel_count) + 1) {
      return InvalidArgumentError("JoinSampleChunks: pieces of texels ", piece.first_texel, "..+",
                                  piece.texel_count, " and ", joined.first_texel, "..+",
                                  joined.texel_count);
    }
    total += piece.samples.size();
  }
  joined.samples.reserve(total);
  joined.offsets.reserve(size_t(joined.texel_count) + 1);
  joined.offsets.push_back(0);
  for (uint32_t i = 0; i < joined.texel_count; ++i) {
    for (const TexelSampleChunk& piece : pieces) {
      joined.samples.insert(joined.samples.end(), piece.samples.begin() + piece.offsets[i],
                            piece.samples.begin() + piece.offsets[i + 1]);
    }
    joined.offsets.push_back(joined.samples.size());
  }
  return joined;
}

StatusOr<std::string> SampleStoreFingerprint(const fs::path& dir) {
  uint32_t crc[2];
  const char* names[2] = {"store.json", "atlas.bin"};
  for (int i = 0; i < 2; ++i) {
    REFLCAP_ASSIGN_OR_RETURN(std::string bytes, ReadTextFile(dir / names[i]));
    crc[i] = Crc32(bytes.data(), bytes.size());
  }
  return FingerprintOf(crc[0], crc[1]);
}

Status SampleStoreReader::ReadChunkInto(uint32_t index, TexelSampleChunk* chunk) const {
  if (!parts_.empty()) {
    REFLCAP_ASSIGN_OR_RETURN(*chunk, ReadChunk(index));
    return OkStatus();
  }
  if (index >= info_.chunks) {
    return InvalidArgumentError("sample store ", dir_.string(), ": chunk ", index,
                                " does not exist (", info_.chunks, " chunks)");
  }
  const fs::path path = ChunkPath(index);
  REFLCAP_RETURN_IF_ERROR(ReadSampleChunkInto(path, chunk));
  return CheckPlacement(path, index, *chunk);
}

Status SampleStoreReader::CheckPlacement(const fs::path& path, uint32_t index,
                                         const TexelSampleChunk& chunk) const {
  const uint32_t first = index * info_.chunk_texels;
  const uint32_t count = std::min(info_.chunk_texels, info_.texels - first);
  if (chunk.first_texel != first || chunk.texel_count != count) {
    return DataLossError(path.string(), ": holds texels ", chunk.first_texel, "..+",
                         chunk.texel_count, " but store.json puts texels ", first, "..+", count,
                         " in chunk ", index);
  }
  return OkStatus();
}

StatusOr<TexelSampleChunk> SampleStoreReader::ReadChunk(uint32_t index) const {
  if (index >= info_.chunks) {
    return InvalidArgumentError("sample store ", dir_.string(), ": chunk ", index,
                                " does not exist (", info_.chunks, " chunks)");
  }
  if (!parts_.empty()) {
    // The pieces' buffers go back to the reader for the next chunk: fresh ones cost a page
    // fault and the kernel's clearing per 4 KiB, as much as reading the bytes (a fit merge
    // reads 1.8 GB through them on the million preset). One set per concurrent reader.
    std::vector<TexelSampleChunk> pieces;
    {
      std::lock_guard<std::mutex> lock(*spare_mutex_);
      if (!spare_pieces_.empty()) {
        pieces = std::move(spare_pieces_.back());
        spare_pieces_.pop_back();
      }
    }
    pieces.resize(parts_.size());
    // The parts' files on every core: a fit shard waits for its first chunk with nothing else
    // to do (45 ms of each million-preset shard read one part after the other). The first
    // failure in part order is reported, whichever thread met it.
    std::vector<Status> reads(parts_.size());
    ParallelFor(0, int64_t(parts_.size()), 1, [&](int64_t b, int64_t e, int) {
      for (int64_t i = b; i < e; ++i) {
        reads[size_t(i)] = parts_[size_t(i)]->ReadChunkInto(index, &pieces[size_t(i)]);
      }
    });
    Status read;
    for (const Status& r : reads) {
      if (!r.ok()) {
        read = r;
        break;
      }
    }
    StatusOr<TexelSampleChunk> joined =
        read.ok() ? JoinSampleChunks(pieces) : StatusOr<TexelSampleChunk>(read);
    std::lock_guard<std::mutex> lock(*spare_mutex_);
    spare_pieces_.push_back(std::move(pieces));
    return joined;
  }
  const fs::path path = ChunkPath(index);
  REFLCAP_ASSIGN_OR_RETURN(TexelSampleChunk chunk, ReadSampleChunk(path));
  REFLCAP_RETURN_IF_ERROR(CheckPlacement(path, index, chunk));
  return chunk;
}

}  // namespace reflcap
