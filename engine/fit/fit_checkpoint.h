#pragma once
// Fit shards, checkpoints and parts: what lets `reflcap fit` run as N independent jobs (texel
// shards on a Slurm job array or a Kubernetes indexed job) and continue after a kill.
//
// A fit is two phases. The per-texel LM fit of every sample chunk (the bulk of the work, each
// chunk independent of the others) and the post-fit stages that need the whole atlas (lobe
// transfer, albedo fill, material clusters; then the maps). Shard I of N runs the first phase for
// a contiguous range of chunks and writes a *part*; `reflcap merge` reads the N parts and runs the
// second phase once, exactly as a single run does, so its maps are bit-identical to a single
// run's (the global reduce is the whole post-fit phase, in the merge job: README.md "Shards").
//
// A checkpoint is the same thing seen while it is being built: every chunk's results go to a
// chunk result file as soon as the chunk is fitted (atomically, with checksums), in a folder
// beside the output named OUT.checkpoint. `--resume` after a kill reads the chunk files that are
// there and fits only the rest; the output is bit-identical to an uninterrupted run. A finished
// shard's checkpoint folder, with its manifest, is moved into place as the part.
//
//   OUT.checkpoint/checkpoint.json   manifest: store, options, backend, shard (FitPartManifest)
//   OUT.checkpoint/fits_NNNNN.rcf    chunk result files, NNNNN = the sample chunk's index
//   PART/fit_part.json               a finished shard: the manifest plus its timings and device
//   PART/fits_NNNNN.rcf
//
// ---- Chunk result file (fits_NNNNN.rcf) -----------------------------------------------------
// Little-endian. A 64-byte header, then one record per texel of the chunk:
//
//   offset size  field
//        0    8  magic           "RFLCFITS"
//        8    4  version         u32, kFitChunkVersion (= 1)
//       12    4  header_bytes    u32, 64
//       16    4  lobes           u32, 0..3
//       20    4  stride          u32, floats per parameter vector = 3 + 12 lobes
//       24    4  first_texel     u32
//       28    4  texel_count     u32
//       32    4  record_bytes    u32, = 8 stride + 20
//       36    4  reserved        0
//       40    8  payload_bytes   u64, = texel_count * record_bytes
//       48    4  payload_crc32   u32 (engine/texel/sample_store.h Crc32)
//       52    8  reserved        0
//       60    4  header_crc32    u32, of bytes 0..59
//   record: params f32 x stride, sigma f32 x stride (fit_store.h layout), cost f32,
//           iterations i32, samples i32, residuals i32, status u8, lambert_only u8, 2 bytes 0.
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "engine/core/shard.h"
#include "engine/core/status.h"
#include "engine/fit/fitter.h"

namespace reflcap::fit {

constexpr char kFitChunkMagic[8] = {'R', 'F', 'L', 'C', 'F', 'I', 'T', 'S'};
constexpr uint32_t kFitChunkVersion = 1;
constexpr const char* kFitPartFormat = "reflcap-fit-part/1";
constexpr const char* kFitPartFile = "fit_part.json";
constexpr const char* kFitCheckpointFile = "checkpoint.json";

// Chunks [begin, end) of shard `shard` among `chunks` (ShardRange): InvalidArgument when N >
// chunks (a shard would be empty).
using ChunkRange = ItemRange;
StatusOr<ChunkRange> ShardChunks(Shard shard, uint32_t chunks);

// "fits_00042.rcf".
std::string FitChunkFileName(uint32_t chunk);

// Writes the first `lobes` lobes of every result (parameters, sigmas and scalars) atomically.
Status WriteFitChunk(const std::filesystem::path& path, uint32_t first_texel, int lobes,
                     const std::vector<TexelFit>& results);
// Reads one back into TexelFits that FitStore::Set and SigmaSpill::Write store exactly as the
// originals. DataLoss naming the file when it is truncated, corrupted, not a chunk result file,
// or holds other texels or lobes than expected; NotFound when missing.
StatusOr<std::vector<TexelFit>> ReadFitChunk(const std::filesystem::path& path,
                                             uint32_t first_texel, uint32_t texel_count, int lobes);

// Every option that changes a fit's result, as JSON (not `threads`: results do not depend on
// it), and back. FitOptionsFromJson: DataLoss naming `file` and the field.
nlohmann::json FitOptionsToJson(const FitOptions& options);
Status FitOptionsFromJson(const nlohmann::json& json, const std::string& file, FitOptions* options);


// What a checkpoint or part is of: written as checkpoint.json / fit_part.json.
struct FitPartManifest {
  std::string samples;      // the store's absolute path
  std::string fingerprint;  // SampleStoreFingerprint
  uint32_t texels = 0, chunks = 0, chunk_texels = 0;
  Shard shard;
  ChunkRange range;
  std::string backend;      // fit::BackendName
  nlohmann::json options;   // FitOptionsToJson
  nlohmann::json ToJson() const;
  // DataLoss naming `file` and the field.
  static StatusOr<FitPartManifest> FromJson(const nlohmann::json& json, const std::string& file);
  // The first field in which `other` differs from this one ("" when none): what makes two
  // manifests belong to different runs.
  std::string Mismatch(const FitPartManifest& other) const;
};

}  // namespace reflcap::fit
