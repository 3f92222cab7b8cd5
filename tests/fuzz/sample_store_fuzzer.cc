// Fuzz target: a whole sample store folder (engine/texel: SampleStoreReader::Open, then
// ReadChunk(0)). The input is split into three files:
//   u16 n1 (little-endian) | store.json (n1 bytes) | u16 n2 | atlas.bin (n2 bytes) | chunk_00000.rcs
// (a part missing from a short input is written empty). The target rewrites the CRC-32s of
// atlas.bin and of the chunk so mutations reach the checks behind them (sample_chunk_fuzzer
// fuzzes the checksums themselves). On success every texel's pixel must lie in the atlas.
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <vector>

#include "engine/texel/sample_store.h"
#include "tests/fuzz/fuzz_util.h"

namespace {

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
    if (first.ok()) FUZZ_CHECK(first->first_texel == 0 && first->texel_count <= info.chunk_texels);
  }
  return 0;
}
