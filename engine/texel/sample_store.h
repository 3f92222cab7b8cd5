#pragma once
// The sample store: a folder written by `reflcap resample` and read by `reflcap fit`.
//
//   SAMPLES/store.json          what the store holds (see SampleStoreInfo; schema in README.md)
//   SAMPLES/atlas.bin           the texel layout: atlas width, height and pixel_of_texel
//   SAMPLES/chunk_NNNNN.rcs     TexelSampleChunk files, each self-describing: magic, version,
//                               counts, offsets, records, and checksums of header and payload
//   SAMPLES/resample_report.json, coverage.exr, coverage.png   (the resampler's report)
//
// Chunks hold a fixed number of consecutive texels (the last may hold fewer); every file is
// written atomically. Readers verify magic, version, sizes and checksums: a truncated or
// corrupted chunk is a DataLoss error naming the file, never a crash or silent garbage.
#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "engine/core/status.h"
#include "engine/texel/samples.h"

namespace reflcap {

struct SampleStoreInfo {
  uint32_t texels = 0;               // texels in the atlas (with or without samples)
  uint32_t chunk_texels = 0;         // texels per chunk (last chunk may hold fewer)
  uint32_t chunks = 0;
  uint64_t samples = 0;              // total samples kept
  int atlas_width = 0;
  int atlas_height = 0;
  std::vector<uint32_t> pixel_of_texel;  // y * atlas_width + x, as TexelAtlas
  std::string capture;               // path of the capture.json it was resampled from
  std::string split;                 // "train", "holdout" or "all"
  double min_cos = 0;                // the --min-cos it was made with
};

class SampleStoreReader {
 public:
  // Reads store.json and atlas.bin; chunks are read on demand.
  static StatusOr<std::unique_ptr<SampleStoreReader>> Open(const std::filesystem::path& dir);
  const SampleStoreInfo& info() const { return info_; }
  // Reads and verifies chunk `index` (0 .. info().chunks - 1).
  StatusOr<TexelSampleChunk> ReadChunk(uint32_t index) const;
  std::filesystem::path ChunkPath(uint32_t index) const;

 private:
  std::filesystem::path dir_;
  SampleStoreInfo info_;
};

// Writes one chunk file atomically.
Status WriteSampleChunk(const std::filesystem::path& path, const TexelSampleChunk& chunk);
// Reads and verifies one chunk file.
StatusOr<TexelSampleChunk> ReadSampleChunk(const std::filesystem::path& path);
// Writes store.json and atlas.bin for `info` into `dir` (chunks are written separately).
Status WriteSampleStoreInfo(const std::filesystem::path& dir, const SampleStoreInfo& info);

}  // namespace reflcap
