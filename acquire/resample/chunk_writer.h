#pragma once
// Streaming reorder of BRDF samples from image-major (the order the resampler produces them: one
// photograph at a time) to texel-major chunk files (the order a fitter reads them), without
// holding all samples in memory.
//
// Append() routes each (texel, sample) record to its chunk's in-memory buffer; a buffer that
// reaches its share of the memory budget is appended to that chunk's spill file. Finish() then
// builds each chunk in turn: the per-texel counts, kept since the first Append(), give the CSR
// offsets; the spill file is streamed back in fixed-size blocks and every record is placed at its
// texel's cursor (a counting sort, stable: a texel's samples keep their append order); the
// chunk is written with WriteSampleChunk and its spill file deleted. Peak memory is the buffers'
// budget plus, per chunk being finished, the chunk itself and one read block.
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <vector>

#include "engine/core/status.h"
#include "engine/texel/samples.h"

namespace reflcap::resample {

// One kept sample and the texel it belongs to: the spill-file record (56 bytes, host order; spill
// files are private to one run and never outlive it).
struct TexelSample {
  uint32_t texel;
  BrdfSample sample;
};
static_assert(sizeof(TexelSample) == 56, "spill record is packed");

class ChunkedSampleWriter {
 public:
  // `spill_dir` is created and holds one spill file per chunk until Finish(); texels > 0,
  // chunk_texels > 0. buffer_bytes: memory budget of all in-memory buffers together (each chunk's
  // buffer flushes at budget / chunks, at least kMinFlushBytes).
  static StatusOr<std::unique_ptr<ChunkedSampleWriter>> Create(
      const std::filesystem::path& spill_dir, uint32_t texels, uint32_t chunk_texels,
      size_t buffer_bytes);
  ~ChunkedSampleWriter();

  // Records in any texel order; texel < texels (checked). Not thread-safe.
  Status Append(const TexelSample* samples, size_t count);

  // Writes out_dir/chunk_NNNNN.rcs for every chunk (also the empty ones), `threads` chunks at a
  // time (0 = all cores), then removes the spill folder. Call once.
  Status Finish(const std::filesystem::path& out_dir, int threads = 0);

  // Checkpoint support (resample --resume). FlushAll writes every buffer to its spill file and
  // syncs the files to disk, so the spill files hold every record appended so far; it returns
  // each chunk's record count. Restore, on a writer just created over the same spill folder,
  // takes the state of such a point back: each spill file is cut to its count (records appended
  // after the checkpoint are dropped) and the per-texel counts are `texel_counts` (the kept
  // samples per texel at that point). DataLoss naming the file when a spill file holds fewer
  // records than its count.
  StatusOr<std::vector<uint64_t>> FlushAll();
  Status Restore(const std::vector<uint64_t>& spilled_records, std::vector<uint32_t> texel_counts);
  // Leave the spill folder in place when the writer is destroyed before Finish (a checkpointed
  // run that fails can be resumed); Finish removes it in any case.
  void KeepSpillOnError() { keep_spill_ = true; }

  uint32_t chunks() const { return chunks_; }
  uint64_t samples() const { return samples_; }
  // Samples of texel t appended so far.
  uint32_t TexelCount(uint32_t t) const { return texel_counts_[t]; }
  uint64_t spilled_bytes() const { return spilled_bytes_; }

  // A flush writes at least this much (fewer, larger writes; 64 KiB is past the point where the
  // per-call cost of open/append/close matters).
  static constexpr size_t kMinFlushBytes = size_t(64) << 10;

 private:
  ChunkedSampleWriter() = default;
  Status Flush(uint32_t chunk);
  std::filesystem::path SpillPath(uint32_t chunk) const;
  Status FinishChunk(uint32_t chunk, const std::filesystem::path& out_dir);

  std::filesystem::path spill_dir_;
  uint32_t texels_ = 0;
  uint32_t chunk_texels_ = 0;
  uint32_t chunks_ = 0;
  size_t flush_records_ = 0;
  std::vector<std::vector<TexelSample>> buffers_;
  std::vector<uint64_t> spilled_records_;  // per chunk, records in its spill file
  std::vector<uint32_t> texel_counts_;
  uint64_t samples_ = 0;
  uint64_t spilled_bytes_ = 0;
  bool finished_ = false;
  bool keep_spill_ = false;
};

// The chunks ChunkedSampleWriter writes for `samples` appended in this order, built in memory by a
// stable sort (the reference the streaming path is tested against).
std::vector<TexelSampleChunk> BuildChunksInMemory(const std::vector<TexelSample>& samples,
                                                  uint32_t texels, uint32_t chunk_texels);

}  // namespace reflcap::resample
