#pragma once
// The sample store: a folder written by `reflcap resample` and read by `reflcap fit`.
//
//   SAMPLES/store.json          what the store holds (see SampleStoreInfo; schema in README.md)
//   SAMPLES/atlas.bin           the texel layout: atlas width, height and pixel_of_texel
//   SAMPLES/chunk_NNNNN.rcs     TexelSampleChunk files, each self-describing: magic, version,
//                               counts, offsets, records, and checksums of header and payload
//   SAMPLES/resample_report.json, coverage.exr, coverage.png, domain.exr   (the resampler's
//                               report and maps; see acquire/resample/resample.h)
//
// A linked store (`reflcap merge --link` of a sharded resample) holds store.json and atlas.bin
// only; store.json's `parts` names the part stores whose chunks it joins as it reads them.
//
// Chunks hold a fixed number of consecutive texels (the last may hold fewer); every file is
// written atomically. Within a texel, samples are in the order the resampler processed the
// photographs: grouped by view (camera, turntable angle) in order of first appearance, then by
// image index — ascending image index for captures listed view by view, as synthetic ones are.
// Readers verify magic, version, sizes and checksums: a truncated or corrupted chunk is a
// DataLoss error naming the file, never a crash or silent garbage.
//
// ---- Chunk file (chunk_NNNNN.rcs, NNNNN = chunk index, zero-padded to 5 digits) -------------
// All integers and floats little-endian. A 64-byte header, then the payload:
//
//   offset size  field
//        0    8  magic            "RFLCSMPL"
//        8    4  version          u32, kSampleChunkVersion (= 1)
//       12    4  header_bytes     u32, 64
//       16    4  record_bytes     u32, 52 (sizeof(BrdfSample))
//       20    4  first_texel      u32
//       24    4  texel_count      u32
//       28    4  reserved         u32, 0
//       32    8  sample_count     u64
//       40    8  payload_bytes    u64, = 8 * (texel_count + 1) + 52 * sample_count
//       48    4  payload_crc32    u32, CRC-32 of the payload bytes
//       52    8  reserved         0
//       60    4  header_crc32     u32, CRC-32 of header bytes 0..59
//       64       payload: offsets  u64 x (texel_count + 1)   (offsets[0] = 0, non-decreasing,
//                                                             offsets[texel_count] = sample_count)
//                         records  BrdfSample x sample_count, 52 bytes each:
//                                  wi[3] wo[3] value[3] weight[3] as f32, then image as u32
//
// CRC-32 is the IEEE 802.3 / zlib polynomial (reflected 0xEDB88320, initial and final XOR
// 0xFFFFFFFF): Python's zlib.crc32 gives the same numbers. Bytes 0..11 (magic, version) keep
// their meaning in every version, so a reader can always say which version a file has.
// The file size must be exactly 64 + payload_bytes. Records are finite, weights >= 0.
//
// ---- atlas.bin ------------------------------------------------------------------------------
//   0  8  magic "RFLCATLS";  8  4  version u32 (1);  12 4 width u32;  16 4 height u32;
//  20  4  texels u32;  24  4  payload_crc32 u32 (of the pixel_of_texel bytes);
//  28  4  header_crc32 u32 (of bytes 0..27);  32  pixel_of_texel u32 x texels (y * width + x).
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <mutex>
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
  uint32_t images = 0;               // photographs resampled (BrdfSample::image indexes the
                                     // capture's full image list, not this count)
  std::string geometry;              // "mesh" or "normal_map"
  // A linked store (`reflcap merge --link`): no chunk files of its own; chunk c is the join
  // (JoinSampleChunks) of chunk c of each of these stores, in order — the parts of a sharded
  // resample. Each with its SampleStoreFingerprint when linked, so a part that changed later is
  // refused. Paths as written (absolute; a relative one is read against the store's folder).
  // A part's atlas.bin is checked by its header only (its layout, header CRC and the payload CRC
  // it records, which must be the linked store's): the linked store's own atlas is the one used.
  struct Part {
    std::string path;
    std::string fingerprint;
  };
  std::vector<Part> parts;
};

class SampleStoreReader {
 public:
  // Reads store.json and atlas.bin; chunks are read on demand. NotFound when either file is
  // missing; DataLoss (naming the file and field) when one is malformed or they disagree.
  static StatusOr<std::unique_ptr<SampleStoreReader>> Open(const std::filesystem::path& dir);
  const SampleStoreInfo& info() const { return info_; }
  // SampleStoreFingerprint of the files as this reader read them.
  const std::string& fingerprint() const { return fingerprint_; }
  // Reads and verifies chunk `index` (0 .. info().chunks - 1), including that it holds the texels
  // store.json says it does; of a linked store, reads the parts' chunks and joins them.
  // Thread-safe (no shared state).
  StatusOr<TexelSampleChunk> ReadChunk(uint32_t index) const;
  // The same into `chunk`, reusing its buffers' memory (of a store with chunk files).
  Status ReadChunkInto(uint32_t index, TexelSampleChunk* chunk) const;
  // The chunk's file (of a linked store: the first part's, for messages).
  std::filesystem::path ChunkPath(uint32_t index) const;

 private:
  // Open; a store opened as a linked store's part (`as_part`) must not be linked itself.
  static StatusOr<std::unique_ptr<SampleStoreReader>> OpenStore(const std::filesystem::path& dir,
                                                                bool as_part);

  std::filesystem::path dir_;
  SampleStoreInfo info_;
  std::string fingerprint_;
  uint32_t atlas_payload_crc_ = 0;  // atlas.bin's recorded payload CRC
  std::vector<std::unique_ptr<SampleStoreReader>> parts_;  // a linked store's parts, in order
  // Piece buffers of a linked store's reads, kept for the next read (sample_store.cc).
  mutable std::unique_ptr<std::mutex> spare_mutex_ = std::make_unique<std::mutex>();
  mutable std::vector<std::vector<TexelSampleChunk>> spare_pieces_;

  // DataLoss naming `path` unless `chunk` holds the texels store.json puts in chunk `index`.
  Status CheckPlacement(const std::filesystem::path& path, uint32_t index,
                        const TexelSampleChunk& chunk) const;
};

// The chunk of the same texels holding, for each texel, the samples of `pieces[0]`, then those of
// `pieces[1]`, ...: the chunk one resample writes from the photographs that its shards took in
// order. InvalidArgument when the pieces are not of the same texels.
StatusOr<TexelSampleChunk> JoinSampleChunks(const std::vector<TexelSampleChunk>& pieces);

// Identity of a sample store: CRC-32 of store.json and of atlas.bin, as "xxxxxxxx-xxxxxxxx".
// Fit parts and checkpoints of one store carry the same, as a linked store its parts'; the chunk
// files are checked one by one as they are read.
StatusOr<std::string> SampleStoreFingerprint(const std::filesystem::path& dir);

constexpr char kSampleChunkMagic[8] = {'R', 'F', 'L', 'C', 'S', 'M', 'P', 'L'};
constexpr uint32_t kSampleChunkVersion = 1;
constexpr size_t kSampleChunkHeaderBytes = 64;
// "reflcap-samples/1": the store.json format string.
constexpr const char* kSampleStoreFormat = "reflcap-samples/1";

// "chunk_00042.rcs" for index 42 (more digits when the index needs them).
std::string SampleChunkFileName(uint32_t index);

// Writes one chunk file atomically. InvalidArgument when the chunk is inconsistent (offsets not
// texel_count + 1 entries, not starting at 0, decreasing, or not ending at samples.size()) or a
// record holds a non-finite number or a negative weight; Internal on I/O failure.
Status WriteSampleChunk(const std::filesystem::path& path, const TexelSampleChunk& chunk);
// Reads and verifies one chunk file. NotFound when missing; DataLoss (message starting with the
// path) when truncated, corrupted, or not a chunk (bad magic); FailedPrecondition for a version
// this reader does not know.
StatusOr<TexelSampleChunk> ReadSampleChunk(const std::filesystem::path& path);
// The same into `chunk`, reusing the memory its vectors hold (contents undefined on error).
Status ReadSampleChunkInto(const std::filesystem::path& path, TexelSampleChunk* chunk);
// Writes store.json and atlas.bin for `info` into `dir` (chunks are written separately, or, with
// info.parts, read from the parts), each atomically. InvalidArgument when pixel_of_texel.size() !=
// texels or chunks does not match ceil(texels / chunk_texels).
Status WriteSampleStoreInfo(const std::filesystem::path& dir, const SampleStoreInfo& info);

// CRC-32 (IEEE 802.3 / zlib) of `size` bytes, continuing from `crc` (0 to start): equal to
// zlib.crc32(data, crc). Carry-less multiplication (PCLMULQDQ) where the CPU has it, else zlib
// (crc32.cc).
uint32_t Crc32(const void* data, size_t size, uint32_t crc = 0);

}  // namespace reflcap
