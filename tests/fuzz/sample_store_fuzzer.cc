// Fuzz target: a whole sample store folder (engine/texel: SampleStoreReader::Open, then
// ReadChunk(0)). The input is split into three files:
//   u16 n1 (little-endian) | store.json (n1 bytes) | u16 n2 | atlas.bin (n2 bytes) | chunk_00000.rcs
// (a part missing from a short input is written empty). The target rewrites the CRC-32s of
// atlas.bin and of the chunk so mutations reach the checks behind them (sample_chunk_fuzzer
// fuzzes the checksums themselves). On success every texel's pixel must lie in the atlas.
// Linked stores (`merge --link`): when store.json is an object with `parts`, the same three files
// are also written to the folder `part` (its store.json without `parts`), and every part entry
// that is an object gets that folder's fingerprint, so mutations reach the join behind the
// identity check; the joined chunk must hold the part chunk's samples once per part.
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <vector>

#include <nlohmann/json.hpp>

#include "engine/texel/sample_store.h"
#include "tests/fuzz/fuzz_util.h"

namespace {

using Json = nlohmann::json;

// atlas.bin (engine/texel/sample_store.h): payload CRC at 24 over bytes 32.., header CRC at 28
// over bytes 0..27.
constexpr size_t kAtlasHeaderBytes = 32;
constexpr size_t kAtlasPayloadCrcOffset = 24;
constexpr size_t kAtlasHeaderCrcOffset = 28;
// Chunk: payload CRC at 48 over bytes 64.., header CRC at 60 over bytes 0..59.
constexpr size_t kChunkPayloadCrcOffset = 48;
constexpr size_t kChunkHeaderCrcOffset = 60;

void FixCrcs(std::vector<uint8_t>* bytes, size_t header_bytes, size_t payload_crc_at,
             size_t header_crc_at) {
  if (bytes->size() < header_bytes) return;
  uint8_t* b = bytes->data();
  const uint32_t payload_crc = reflcap::Crc32(b + header_bytes, bytes->size() - header_bytes);
  std::memcpy(b + payload_crc_at, &payload_crc, 4);
  const uint32_t header_crc = reflcap::Crc32(b, header_crc_at);
  std::memcpy(b + header_crc_at, &header_crc, 4);
}

// Takes a u16-length-prefixed part off the front of [*data, *data + *size).
std::vector<uint8_t> TakePart(const uint8_t** data, size_t* size) {
  if (*size < 2) {
    *data += *size;
    *size = 0;
    return {};
  }
  size_t n = size_t((*data)[0]) | (size_t((*data)[1]) << 8);
  *data += 2;
  *size -= 2;
  n = n < *size ? n : *size;
  std::vector<uint8_t> part(*data, *data + n);
  *data += n;
  *size -= n;
  return part;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const bool quiet = (reflcap::fuzz::QuietLogs(), true);
  (void)quiet;
  std::vector<uint8_t> json = TakePart(&data, &size);
  std::vector<uint8_t> atlas = TakePart(&data, &size);
  std::vector<uint8_t> chunk(data, data + size);
  FixCrcs(&atlas, kAtlasHeaderBytes, kAtlasPayloadCrcOffset, kAtlasHeaderCrcOffset);
  FixCrcs(&chunk, reflcap::kSampleChunkHeaderBytes, kChunkPayloadCrcOffset, kChunkHeaderCrcOffset);
  const std::filesystem::path part_dir = reflcap::fuzz::ScratchDir() / "part";
  std::error_code ec;
  std::filesystem::remove_all(part_dir, ec);
  Json root = Json::parse(json.begin(), json.end(), nullptr, /*allow_exceptions=*/false);
  size_t linked_parts = 0;
  if (root.is_object() && root.contains("parts") && root["parts"].is_array()) {
    Json part_json = root;
    part_json.erase("parts");
    const std::string part_text = part_json.dump();
    std::filesystem::create_directories(part_dir, ec);
    auto write = [&](const char* name, const void* bytes, size_t n) {
      std::ofstream out(part_dir / name, std::ios::binary | std::ios::trunc);
      out.write(static_cast<const char*>(bytes), std::streamsize(n));
    };
    write("store.json", part_text.data(), part_text.size());
    write("atlas.bin", atlas.data(), atlas.size());
    write("chunk_00000.rcs", chunk.data(), chunk.size());
    auto fingerprint = reflcap::SampleStoreFingerprint(part_dir);
    for (Json& p : root["parts"]) {
      if (!p.is_object()) continue;
      if (fingerprint.ok()) p["fingerprint"] = *fingerprint;
      ++linked_parts;
    }
    const std::string text = root.dump();
    json.assign(text.begin(), text.end());
  }
  reflcap::fuzz::WriteScratch("store.json", json.data(), json.size());
  reflcap::fuzz::WriteScratch("atlas.bin", atlas.data(), atlas.size());
  reflcap::fuzz::WriteScratch("chunk_00000.rcs", chunk.data(), chunk.size());
  auto reader = reflcap::SampleStoreReader::Open(reflcap::fuzz::ScratchDir());
  if (!reader.ok()) {
    reflcap::fuzz::Rejected(reader.status());
    return 0;
  }
  const auto& info = (*reader)->info();
  FUZZ_CHECK(info.pixel_of_texel.size() == info.texels);
  const uint64_t atlas_pixels = uint64_t(info.atlas_width) * uint64_t(info.atlas_height);
  for (uint32_t p : info.pixel_of_texel) FUZZ_CHECK(p < atlas_pixels);
  if (info.chunks > 0) {
    auto first = (*reader)->ReadChunk(0);
    if (first.ok()) {
      FUZZ_CHECK(first->first_texel == 0 && first->texel_count <= info.chunk_texels);
      FUZZ_CHECK(first->offsets.size() == size_t(first->texel_count) + 1);
      FUZZ_CHECK(first->offsets.back() == first->samples.size());
      if (!info.parts.empty()) {
        // Every part is the same folder here: the join holds its chunk once per part.
        FUZZ_CHECK(info.parts.size() <= linked_parts);
        auto piece = reflcap::ReadSampleChunk(part_dir / "chunk_00000.rcs");
        FUZZ_CHECK(piece.ok());
        FUZZ_CHECK(first->samples.size() == piece->samples.size() * info.parts.size());
      }
    }
  }
  return 0;
}
