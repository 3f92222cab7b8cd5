// Fuzz target: sample chunk files (engine/texel: ReadSampleChunk). The chunk format carries
// CRC-32s of its header and payload, which random mutations almost never keep valid; so when
// the first input byte is odd the target rewrites both checksums before writing the file, and
// the structural checks behind them (counts, sizes, offsets, records) get fuzzed too. On success
// the chunk must be self-consistent: offsets from 0, non-decreasing, ending at the sample count,
// every record finite with weights >= 0.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <vector>

#include "engine/texel/sample_store.h"
#include "tests/fuzz/fuzz_util.h"

namespace {

// Header layout (engine/texel/sample_store.h): payload CRC at 48, header CRC at 60 over 0..59.
constexpr size_t kPayloadCrcOffset = 48;
constexpr size_t kHeaderCrcOffset = 60;

void FixChunkCrcs(std::vector<uint8_t>* bytes) {
  if (bytes->size() < reflcap::kSampleChunkHeaderBytes) return;
  uint8_t* b = bytes->data();
  const uint32_t payload_crc = reflcap::Crc32(b + reflcap::kSampleChunkHeaderBytes,
                                              bytes->size() - reflcap::kSampleChunkHeaderBytes);
  std::memcpy(b + kPayloadCrcOffset, &payload_crc, 4);
  const uint32_t header_crc = reflcap::Crc32(b, kHeaderCrcOffset);
  std::memcpy(b + kHeaderCrcOffset, &header_crc, 4);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const bool quiet = (reflcap::fuzz::QuietLogs(), true);
  (void)quiet;
  if (size == 0) return 0;
  const bool fix_crcs = (data[0] & 1) != 0;
  std::vector<uint8_t> bytes(data + 1, data + size);
  if (fix_crcs) FixChunkCrcs(&bytes);
  const auto path = reflcap::fuzz::WriteScratch("chunk_00000.rcs", bytes.data(), bytes.size());
  auto chunk = reflcap::ReadSampleChunk(path);
  if (!chunk.ok()) {
    reflcap::fuzz::Rejected(chunk.status());
    return 0;
  }
  FUZZ_CHECK(chunk->offsets.size() == size_t(chunk->texel_count) + 1);
  FUZZ_CHECK(chunk->offsets.front() == 0);
  FUZZ_CHECK(chunk->offsets.back() == chunk->samples.size());
  for (uint32_t i = 0; i < chunk->texel_count; ++i) FUZZ_CHECK(chunk->offsets[i] <= chunk->offsets[i + 1]);
  for (const auto& s : chunk->samples) {
    for (int c = 0; c < 3; ++c) {
      FUZZ_CHECK(std::isfinite(s.wi[c]) && std::isfinite(s.wo[c]));
      FUZZ_CHECK(std::isfinite(s.value[c]) && std::isfinite(s.weight[c]) && s.weight[c] >= 0);
    }
  }
  return 0;
}
