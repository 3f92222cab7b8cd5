// Streaming reorder into chunk files (see chunk_writer.h).
#include "acquire/resample/chunk_writer.h"

#include <algorithm>
#include <atomic>
#include <mutex>

#include <fcntl.h>
#include <unistd.h>

#include "engine/core/parallel.h"
#include "engine/texel/sample_store.h"

namespace reflcap::resample {
namespace fs = std::filesystem;

namespace {

struct FileCloser {
  void operator()(std::FILE* f) const {
    if (f != nullptr) std::fclose(f);
  }
};
using File = std::unique_ptr<std::FILE, FileCloser>;

// Records read back from a spill file per fread: 1 MiB.
constexpr size_t kReadBlockRecords = (size_t(1) << 20) / sizeof(TexelSample);

}  // namespace

StatusOr<std::unique_ptr<ChunkedSampleWriter>> ChunkedSampleWriter::Create(
    const fs::path& spill_dir, uint32_t texels, uint32_t chunk_texels, size_t buffer_bytes) {
  if (texels == 0 || chunk_texels == 0) {
    return InvalidArgumentError("ChunkedSampleWriter: texels (", texels, ") and chunk_texels (",
                                chunk_texels, ") must be positive");
  }
  std::error_code ec;
  fs::create_directories(spill_dir, ec);
  if (ec) return InternalError(spill_dir.string(), ": cannot create folder: ", ec.message());
  std::unique_ptr<ChunkedSampleWriter> w(new ChunkedSampleWriter());
  w->spill_dir_ = spill_dir;
  w->texels_ = texels;
  w->chunk_texels_ = chunk_texels;
  w->chunks_ = uint32_t((uint64_t(texels) + chunk_texels - 1) / chunk_texels);
  const size_t per_chunk = std::max(kMinFlushBytes, buffer_bytes / w->chunks_);
  w->flush_records_ = std::max<size_t>(1, per_chunk / sizeof(TexelSample));
  w->buffers_.resize(w->chunks_);
  w->spilled_records_.assign(w->chunks_, 0);
  w->texel_counts_.assign(texels, 0);
  return w;
}

ChunkedSampleWriter::~ChunkedSampleWriter() {
  if (keep_spill_ && !finished_) return;
  std::error_code ec;
  fs::remove_all(spill_dir_, ec);
}

fs::path ChunkedSampleWriter::SpillPath(uint32_t chunk) const {
  return spill_dir_ / ("spill_" + std::to_string(chunk) + ".bin");
}

Status ChunkedSampleWriter::Append(const TexelSample* samples, size_t count) {
  REFLCAP_CHECK(!finished_) << "Append after Finish";
  for (size_t i = 0; i < count; ++i) {
    const uint32_t texel = samples[i].texel;
    if (texel >= texels_) {
      return InternalError("ChunkedSampleWriter: texel ", texel, " out of range (", texels_, ")");
    }
    const uint32_t chunk = texel / chunk_texels_;
    std::vector<TexelSample>& buffer = buffers_[chunk];
    if (buffer.capacity() == 0) buffer.reserve(flush_records_);
    buffer.push_back(samples[i]);
    ++texel_counts_[texel];
    if (buffer.size() >= flush_records_) REFLCAP_RETURN_IF_ERROR(Flush(chunk));
  }
  samples_ += count;
  return OkStatus();
}

Status ChunkedSampleWriter::Flush(uint32_t chunk) {
  std::vector<TexelSample>& buffer = buffers_[chunk];
  if (buffer.empty()) return OkStatus();
  const fs::path path = SpillPath(chunk);
  File f(std::fopen(path.c_str(), "ab"));
  if (!f) return InternalError(path.string(), ": cannot open spill file");
  const size_t bytes = buffer.size() * sizeof(TexelSample);
  if (std::fwrite(buffer.data(), 1, bytes, f.get()) != bytes || std::fclose(f.release()) != 0) {
    return InternalError(path.string(), ": cannot write spill file (disk full?)");
  }
  spilled_records_[chunk] += buffer.size();
  spilled_bytes_ += bytes;
  buffer.clear();  // keeps the capacity: this chunk will fill again
  return OkStatus();
}

StatusOr<std::vector<uint64_t>> ChunkedSampleWriter::FlushAll() {
  for (uint32_t c = 0; c < chunks_; ++c) {
    REFLCAP_RETURN_IF_ERROR(Flush(c));
    if (spilled_records_[c] == 0) continue;
    // The records must be on disk before a checkpoint names their count.
    const fs::path path = SpillPath(c);
    const int fd = ::open(path.c_str(), O_RDONLY);
    if (fd < 0 || ::fsync(fd) != 0) {
      if (fd >= 0) ::close(fd);
      return InternalError(path.string(), ": cannot sync spill file");
    }
    ::close(fd);
  }
  return spilled_records_;
}

Status ChunkedSampleWriter::Restore(const std::vector<uint64_t>& spilled_records,
                                    std::vector<uint32_t> texel_counts) {
  REFLCAP_CHECK(samples_ == 0 && spilled_records.size() == chunks_ && texel_counts.size() == texels_);
  for (uint32_t c = 0; c < chunks_; ++c) {
    const fs::path path = SpillPath(c);
    const uint64_t bytes = spilled_records[c] * sizeof(TexelSample);
    std::error_code ec;
    const uintmax_t size = fs::exists(path, ec) ? fs::file_size(path, ec) : 0;
    if (ec || size < bytes) {
      return DataLossError(path.string(), ": spill file holds ", size / sizeof(TexelSample),
                           " records, the checkpoint counts ", spilled_records[c]);
    }
    if (size > bytes) {
      fs::resize_file(path, bytes, ec);
      if (ec) return InternalError(path.string(), ": cannot truncate spill file: ", ec.message());
    }
    spilled_bytes_ += bytes;
  }
  spilled_records_ = spilled_records;
  uint64_t total = 0;
  std::vector<uint64_t> per_chunk(chunks_, 0);
  for (uint32_t t = 0; t < texels_; ++t) {
    total += texel_counts[t];
    per_chunk[t / chunk_texels_] += texel_counts[t];
  }
  if (per_chunk != spilled_records) {
    return DataLossError(spill_dir_.string(), ": the checkpoint's per-texel counts do not add up to "
                                              "its spill files' records");
  }
  texel_counts_ = std::move(texel_counts);
  samples_ = total;
  return OkStatus();
}

Status ChunkedSampleWriter::FinishChunk(uint32_t chunk, const fs::path& out_dir) {
  TexelSampleChunk out;
  out.first_texel = chunk * chunk_texels_;
  out.texel_count = std::min(chunk_texels_, texels_ - out.first_texel);
  out.offsets.resize(size_t(out.texel_count) + 1);
  out.offsets[0] = 0;
  for (uint32_t i = 0; i < out.texel_count; ++i) {
    out.offsets[i + 1] = out.offsets[i] + texel_counts_[out.first_texel + i];
  }
  const uint64_t total = out.offsets.back();
  if (total != spilled_records_[chunk] + buffers_[chunk].size()) {
    return InternalError("ChunkedSampleWriter: chunk ", chunk, " counts ", total,
                         " samples but holds ", spilled_records_[chunk] + buffers_[chunk].size());
  }
  out.samples.resize(total);
  std::vector<uint64_t> cursor(out.offsets.begin(), out.offsets.end() - 1);
  auto place = [&](const TexelSample* records, size_t n) {
    for (size_t i = 0; i < n; ++i) {
      out.samples[cursor[records[i].texel - out.first_texel]++] = records[i].sample;
    }
  };
  // Spilled records were appended before the ones still buffered: read them first.
  if (spilled_records_[chunk] > 0) {
    const fs::path path = SpillPath(chunk);
    File f(std::fopen(path.c_str(), "rb"));
    if (!f) return InternalError(path.string(), ": cannot open spill file");
    std::vector<TexelSample> block(std::min<uint64_t>(kReadBlockRecords, spilled_records_[chunk]));
    uint64_t left = spilled_records_[chunk];
    while (left > 0) {
      const size_t n = size_t(std::min<uint64_t>(left, block.size()));
      if (std::fread(block.data(), sizeof(TexelSample), n, f.get()) != n) {
        return InternalError(path.string(), ": spill file is shorter than written");
      }
      place(block.data(), n);
      left -= n;
    }
    f.reset();
    std::error_code ec;
    fs::remove(path, ec);
  }
  place(buffers_[chunk].data(), buffers_[chunk].size());
  std::vector<TexelSample>().swap(buffers_[chunk]);
  return WriteSampleChunk(out_dir / SampleChunkFileName(chunk), out);
}

Status ChunkedSampleWriter::Finish(const fs::path& out_dir, int threads) {
  REFLCAP_CHECK(!finished_) << "Finish called twice";
  finished_ = true;
  std::mutex mutex;
  Status first_error;
  std::atomic<bool> failed{false};
  ParallelFor(
      0, chunks_, 1,
      [&](int64_t begin, int64_t end, int) {
        for (int64_t c = begin; c < end && !failed; ++c) {
          Status s = FinishChunk(uint32_t(c), out_dir);
          if (!s.ok()) {
            std::lock_guard<std::mutex> lock(mutex);
            if (first_error.ok()) first_error = s;
            failed = true;
          }
        }
      },
      threads);
  if (!first_error.ok()) return first_error;
  std::error_code ec;
  fs::remove_all(spill_dir_, ec);
  return OkStatus();
}

std::vector<TexelSampleChunk> BuildChunksInMemory(const std::vector<TexelSample>& samples,
                                                  uint32_t texels, uint32_t chunk_texels) {
  std::vector<TexelSample> sorted = samples;
  std::stable_sort(sorted.begin(), sorted.end(),
                   [](const TexelSample& a, const TexelSample& b) { return a.texel < b.texel; });
  std::vector<TexelSampleChunk> chunks;
  size_t next = 0;
  for (uint32_t first = 0; first < texels; first += chunk_texels) {
    TexelSampleChunk chunk;
    chunk.first_texel = first;
    chunk.texel_count = std::min(chunk_texels, texels - first);
    chunk.offsets.push_back(0);
    for (uint32_t t = first; t < first + chunk.texel_count; ++t) {
      while (next < sorted.size() && sorted[next].texel == t) {
        chunk.samples.push_back(sorted[next++].sample);
      }
      chunk.offsets.push_back(chunk.samples.size());
    }
    chunks.push_back(std::move(chunk));
  }
  return chunks;
}

}  // namespace reflcap::resample
