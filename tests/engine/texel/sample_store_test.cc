// Sample store I/O: chunk and store round trips, and every way a chunk file can be damaged
// (truncated, flipped bits in header or payload, bad magic, unknown version) ending in a clear
// error that names the file.
#include "engine/texel/sample_store.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cstring>
#include <fstream>
#include <random>
#include <thread>

#include <zlib.h>

#include "engine/core/atomic_file.h"
#include "tests/support/test_support.h"

namespace reflcap {
namespace {
namespace fs = std::filesystem;

// A chunk of `texels` texels starting at `first`, texel i holding (i * 7) % 5 samples of
// reproducible, distinct values.
TexelSampleChunk MakeChunk(uint32_t first, uint32_t texels, uint32_t seed = 1) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-1, 1);
  TexelSampleChunk chunk;
  chunk.first_texel = first;
  chunk.texel_count = texels;
  chunk.offsets.push_back(0);
  for (uint32_t i = 0; i < texels; ++i) {
    for (uint32_t k = 0; k < (i * 7) % 5; ++k) {
      BrdfSample s;
      for (int c = 0; c < 3; ++c) {
        s.wi[c] = u(rng);
        s.wo[c] = u(rng);
        s.value[c] = 0.5f + 0.5f * u(rng);
        s.weight[c] = 1 + u(rng);
      }
      s.image = i * 100 + k;
      chunk.samples.push_back(s);
    }
    chunk.offsets.push_back(chunk.samples.size());
  }
  return chunk;
}

void ExpectSameChunk(const TexelSampleChunk& a, const TexelSampleChunk& b) {
  EXPECT_EQ(a.first_texel, b.first_texel);
  EXPECT_EQ(a.texel_count, b.texel_count);
  EXPECT_EQ(a.offsets, b.offsets);
  ASSERT_EQ(a.samples.size(), b.samples.size());
  // memcmp on the null data() of empty vectors is undefined (UBSan, tests/sanitize.sh address).
  if (a.samples.empty()) return;
  EXPECT_EQ(std::memcmp(a.samples.data(), b.samples.data(), a.samples.size() * sizeof(BrdfSample)), 0);
}

std::string ReadBytes(const fs::path& path) { return ReadTextFile(path).value(); }
void WriteBytes(const fs::path& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out << bytes;
}

// Expects `status` to be `code` with a message starting with the file's path.
void ExpectError(const Status& status, StatusCode code, const fs::path& path,
                 const std::string& words) {
  EXPECT_EQ(status.code(), code) << status.ToString();
  EXPECT_EQ(status.message().rfind(path.string(), 0), 0u) << status.message();
  EXPECT_NE(status.message().find(words), std::string::npos) << status.message();
}

TEST(Crc32, MatchesTheZlibCheckValue) {
  // The standard check value of CRC-32/ISO-HDLC (zlib.crc32(b"123456789")).
  EXPECT_EQ(Crc32("123456789", 9), 0xCBF43926u);
  EXPECT_EQ(Crc32("", 0), 0u);
  // Continuation: crc(ab) = crc(b, crc(a)), also across the 8-byte slicing boundary.
  const std::string text = "The quick brown fox jumps over the lazy dog";
  EXPECT_EQ(Crc32(text.data(), text.size()), 0x414FA339u);
  EXPECT_EQ(Crc32(text.data() + 13, text.size() - 13, Crc32(text.data(), 13)), 0x414FA339u);
  // An empty continuation keeps the CRC, also from a null buffer (an empty vector's data()):
  // zlib alone answers that with 0, which made every chunk without samples "corrupt".
  EXPECT_EQ(Crc32(nullptr, 0, 0x414FA339u), 0x414FA339u);
}

TEST(Crc32, EqualsZlibForEveryLengthAlignmentAndContinuation) {
  // The carry-less-multiplication path (>= 64 bytes, four lanes, then 16-byte blocks, then a
  // tail) against zlib's table loop: every length up to 1,100 bytes (all lane/block/tail
  // splits), odd alignments, continuations from arbitrary CRCs, and one large buffer.
  std::mt19937 rng(7);
  std::vector<uint8_t> bytes(3 << 20);
  for (uint8_t& b : bytes) b = uint8_t(rng());
  auto zlib = [](const uint8_t* p, size_t n, uint32_t crc) {
    return n == 0 ? crc : uint32_t(crc32_z(crc, p, n));
  };
  for (size_t n = 0; n <= 1100; ++n) {
    const size_t offset = n % 7;
    const uint32_t from = uint32_t(rng());
    ASSERT_EQ(Crc32(bytes.data() + offset, n, from), zlib(bytes.data() + offset, n, from)) << n;
  }
  EXPECT_EQ(Crc32(bytes.data() + 3, bytes.size() - 3), zlib(bytes.data() + 3, bytes.size() - 3, 0));
  const uint32_t half = Crc32(bytes.data(), 1 << 20);
  EXPECT_EQ(Crc32(bytes.data() + (1 << 20), 2 << 20, half), zlib(bytes.data(), 3 << 20, 0));
}

TEST(SampleChunk, RoundTripIsBitExact) {
  testing::ScratchDir dir;
  const TexelSampleChunk chunk = MakeChunk(4096, 300);
  ASSERT_GT(chunk.samples.size(), 100u);
  const fs::path path = dir / SampleChunkFileName(1);
  ASSERT_TRUE(WriteSampleChunk(path, chunk).ok());
  EXPECT_EQ(fs::file_size(path), kSampleChunkHeaderBytes + 8 * 301 + 52 * chunk.samples.size());
  auto back = ReadSampleChunk(path);
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  ExpectSameChunk(chunk, *back);
  EXPECT_EQ(back->SampleCount(1), 2u);  // (1 * 7) % 5
  EXPECT_EQ(back->SamplesOf(1)[1].image, 101u);
}

TEST(SampleChunk, EmptyChunkRoundTrips) {
  testing::ScratchDir dir;
  TexelSampleChunk chunk;
  chunk.first_texel = 7;
  chunk.texel_count = 3;
  chunk.offsets = {0, 0, 0, 0};
  ASSERT_TRUE(WriteSampleChunk(dir / "c.rcs", chunk).ok());
  auto back = ReadSampleChunk(dir / "c.rcs");
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  ExpectSameChunk(chunk, *back);
}

TEST(SampleChunk, FileNameIsZeroPadded) {
  EXPECT_EQ(SampleChunkFileName(42), "chunk_00042.rcs");
  EXPECT_EQ(SampleChunkFileName(123456), "chunk_123456.rcs");
}

TEST(SampleChunk, WriteRejectsInconsistentChunks) {
  testing::ScratchDir dir;
  TexelSampleChunk chunk = MakeChunk(0, 10);
  chunk.offsets.pop_back();
  EXPECT_EQ(WriteSampleChunk(dir / "a.rcs", chunk).code(), StatusCode::kInvalidArgument);
  chunk = MakeChunk(0, 10);
  std::swap(chunk.offsets[3], chunk.offsets[4]);
  EXPECT_EQ(WriteSampleChunk(dir / "b.rcs", chunk).code(), StatusCode::kInvalidArgument);
  chunk = MakeChunk(0, 10);
  chunk.samples[0].value[1] = std::nanf("");
  EXPECT_EQ(WriteSampleChunk(dir / "c.rcs", chunk).code(), StatusCode::kInvalidArgument);
  chunk = MakeChunk(0, 10);
  chunk.samples[0].weight[2] = -1;
  EXPECT_EQ(WriteSampleChunk(dir / "d.rcs", chunk).code(), StatusCode::kInvalidArgument);
  EXPECT_TRUE(fs::is_empty(dir.path())) << "nothing written, not even a temporary file";
}

TEST(SampleChunk, MissingFileIsNotFound) {
  testing::ScratchDir dir;
  ExpectError(ReadSampleChunk(dir / "none.rcs").status(), StatusCode::kNotFound, dir / "none.rcs",
              "cannot open");
}

TEST(SampleChunk, TruncatedFileIsDataLossNamingTheFile) {
  testing::ScratchDir dir;
  const fs::path path = dir / "c.rcs";
  ASSERT_TRUE(WriteSampleChunk(path, MakeChunk(0, 50)).ok());
  const std::string bytes = ReadBytes(path);
  // Inside the payload, inside the header, and an empty file.
  for (size_t keep : {bytes.size() - 1, bytes.size() - 52, size_t(100), size_t(40), size_t(0)}) {
    WriteBytes(path, bytes.substr(0, keep));
    ExpectError(ReadSampleChunk(path).status(), StatusCode::kDataLoss, path, "truncated");
  }
  // Trailing garbage is corruption too.
  WriteBytes(path, bytes + "xyz");
  ExpectError(ReadSampleChunk(path).status(), StatusCode::kDataLoss, path, "corrupt");
}

TEST(SampleChunk, FlippedBitsAreCaughtByTheChecksums) {
  testing::ScratchDir dir;
  const fs::path path = dir / "c.rcs";
  ASSERT_TRUE(WriteSampleChunk(path, MakeChunk(0, 50)).ok());
  const std::string bytes = ReadBytes(path);
  // Header fields (texel_count, sample_count, payload crc), an offset, a record's value.
  for (size_t at : {size_t(24), size_t(33), size_t(49), size_t(64 + 8 * 3), bytes.size() - 20}) {
    std::string damaged = bytes;
    damaged[at] ^= 0x10;
    WriteBytes(path, damaged);
    const Status s = ReadSampleChunk(path).status();
    EXPECT_EQ(s.code(), StatusCode::kDataLoss) << "byte " << at << ": " << s.ToString();
    EXPECT_EQ(s.message().rfind(path.string(), 0), 0u) << s.message();
  }
}

TEST(SampleChunk, BadMagicAndUnknownVersionAreRejected) {
  testing::ScratchDir dir;
  const fs::path path = dir / "c.rcs";
  ASSERT_TRUE(WriteSampleChunk(path, MakeChunk(0, 5)).ok());
  const std::string bytes = ReadBytes(path);
  std::string damaged = bytes;
  damaged.replace(0, 8, "NOTACHNK");
  WriteBytes(path, damaged);
  ExpectError(ReadSampleChunk(path).status(), StatusCode::kDataLoss, path, "bad magic");
  damaged = bytes;
  damaged[8] = 2;  // version 2
  WriteBytes(path, damaged);
  ExpectError(ReadSampleChunk(path).status(), StatusCode::kFailedPrecondition, path,
              "version 2 is not supported");
  // A PNG is not a chunk either.
  WriteBytes(path, std::string("\x89PNG\r\n\x1a\n", 8) + std::string(100, '\0'));
  ExpectError(ReadSampleChunk(path).status(), StatusCode::kDataLoss, path, "bad magic");
}

SampleStoreInfo MakeInfo(uint32_t texels, uint32_t chunk_texels) {
  SampleStoreInfo info;
  info.texels = texels;
  info.chunk_texels = chunk_texels;
  info.chunks = (texels + chunk_texels - 1) / chunk_texels;
  info.atlas_width = 40;
  info.atlas_height = 30;
  for (uint32_t t = 0; t < texels; ++t) info.pixel_of_texel.push_back(t * 3);
  info.capture = "/data/capture.json";
  info.split = "train";
  info.min_cos = 0.15;
  info.images = 12;
  info.geometry = "mesh";
  return info;
}

TEST(SampleStore, ReaderOpensWhatWasWrittenAndChecksChunkPlacement) {
  testing::ScratchDir dir;
  SampleStoreInfo info = MakeInfo(250, 100);
  std::vector<TexelSampleChunk> chunks = {MakeChunk(0, 100, 1), MakeChunk(100, 100, 2),
                                          MakeChunk(200, 50, 3)};
  for (const auto& c : chunks) info.samples += c.samples.size();
  ASSERT_TRUE(WriteSampleStoreInfo(dir.path(), info).ok());
  for (uint32_t i = 0; i < 3; ++i) {
    ASSERT_TRUE(WriteSampleChunk(dir / SampleChunkFileName(i), chunks[i]).ok());
  }
  auto reader = SampleStoreReader::Open(dir.path());
  ASSERT_TRUE(reader.ok()) << reader.status().ToString();
  const SampleStoreInfo& back = (*reader)->info();
  EXPECT_EQ(back.texels, 250u);
  EXPECT_EQ(back.chunk_texels, 100u);
  EXPECT_EQ(back.chunks, 3u);
  EXPECT_EQ(back.samples, info.samples);
  EXPECT_EQ(back.atlas_width, 40);
  EXPECT_EQ(back.atlas_height, 30);
  EXPECT_EQ(back.pixel_of_texel, info.pixel_of_texel);
  EXPECT_EQ(back.capture, info.capture);
  EXPECT_EQ(back.split, "train");
  EXPECT_DOUBLE_EQ(back.min_cos, 0.15);
  EXPECT_EQ(back.images, 12u);
  EXPECT_EQ(back.geometry, "mesh");
  for (uint32_t i = 0; i < 3; ++i) {
    auto chunk = (*reader)->ReadChunk(i);
    ASSERT_TRUE(chunk.ok()) << chunk.status().ToString();
    ExpectSameChunk(chunks[i], *chunk);
  }
  EXPECT_EQ((*reader)->ReadChunk(3).status().code(), StatusCode::kInvalidArgument);
  // A chunk file in the wrong place (chunk 1's texels in chunk 2's file) is caught.
  ASSERT_TRUE(WriteSampleChunk(dir / SampleChunkFileName(2), chunks[1]).ok());
  ExpectError((*reader)->ReadChunk(2).status(), StatusCode::kDataLoss,
              dir / SampleChunkFileName(2), "store.json puts texels 200");
}

TEST(SampleStore, DamagedStoreFilesAreReportedByName) {
  testing::ScratchDir dir;
  EXPECT_EQ(SampleStoreReader::Open(dir.path()).status().code(), StatusCode::kNotFound);
  const SampleStoreInfo info = MakeInfo(10, 4);
  ASSERT_TRUE(WriteSampleStoreInfo(dir.path(), info).ok());
  const std::string atlas = ReadBytes(dir / "atlas.bin");
  WriteBytes(dir / "atlas.bin", atlas.substr(0, atlas.size() - 4));
  ExpectError(SampleStoreReader::Open(dir.path()).status(), StatusCode::kDataLoss,
              dir / "atlas.bin", "bytes");
  WriteBytes(dir / "atlas.bin", atlas);
  ASSERT_TRUE(SampleStoreReader::Open(dir.path()).ok());
  testing::WriteText(dir / "store.json", "{\"format\": \"reflcap-samples/1\", \"texels\": 10}");
  ExpectError(SampleStoreReader::Open(dir.path()).status(), StatusCode::kDataLoss,
              dir / "store.json", "chunk_texels: missing");
  testing::WriteText(dir / "store.json", "{not json");
  ExpectError(SampleStoreReader::Open(dir.path()).status(), StatusCode::kDataLoss,
              dir / "store.json", "not valid JSON");
}

TEST(SampleStore, WriteRejectsInconsistentInfo) {
  testing::ScratchDir dir;
  SampleStoreInfo info = MakeInfo(10, 4);
  info.chunks = 2;  // 10 texels need 3 chunks of 4
  EXPECT_EQ(WriteSampleStoreInfo(dir.path(), info).code(), StatusCode::kInvalidArgument);
  info = MakeInfo(10, 4);
  info.pixel_of_texel.pop_back();
  EXPECT_EQ(WriteSampleStoreInfo(dir.path(), info).code(), StatusCode::kInvalidArgument);
  info = MakeInfo(10, 4);
  info.pixel_of_texel[3] = 40 * 30;  // outside the atlas
  EXPECT_EQ(WriteSampleStoreInfo(dir.path(), info).code(), StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace reflcap

namespace reflcap {
namespace {

// Two part stores of the same 250 texels (as two shards of a resample write them) and a linked
// store naming them: its chunks are the parts' chunks joined texel by texel, part 0 first.
struct LinkedStores {
  testing::ScratchDir dir;
  SampleStoreInfo info = MakeInfo(250, 100);
  std::vector<std::vector<TexelSampleChunk>> parts;
  fs::path linked = dir / "linked";

  LinkedStores() {
    fs::create_directories(linked);
    SampleStoreInfo link = info;
    for (uint32_t p = 0; p < 2; ++p) {
      const fs::path part = dir / ("part" + std::to_string(p));
      fs::create_directories(part);
      std::vector<TexelSampleChunk> chunks = {MakeChunk(0, 100, 1 + 3 * p),
                                              MakeChunk(100, 100, 2 + 3 * p),
                                              MakeChunk(200, 50, 3 + 3 * p)};
      SampleStoreInfo part_info = info;
      for (uint32_t c = 0; c < 3; ++c) {
        part_info.samples += chunks[c].samples.size();
        EXPECT_TRUE(WriteSampleChunk(part / SampleChunkFileName(c), chunks[c]).ok());
      }
      EXPECT_TRUE(WriteSampleStoreInfo(part, part_info).ok());
      link.samples += part_info.samples;
      link.parts.push_back({part.string(), SampleStoreFingerprint(part).value()});
      parts.push_back(std::move(chunks));
    }
    EXPECT_TRUE(WriteSampleStoreInfo(linked, link).ok());
  }
};

TEST(LinkedSampleStore, ReadsEachChunkAsThePartsJoinedInOrder) {
  LinkedStores stores;
  auto reader = SampleStoreReader::Open(stores.linked);
  ASSERT_TRUE(reader.ok()) << reader.status().ToString();
  ASSERT_EQ((*reader)->info().parts.size(), 2u);
  EXPECT_TRUE(fs::exists(stores.linked / "store.json"));
  EXPECT_FALSE(fs::exists(stores.linked / SampleChunkFileName(0)));  // no chunk of its own
  for (uint32_t c = 0; c < 3; ++c) {
    auto chunk = (*reader)->ReadChunk(c);
    ASSERT_TRUE(chunk.ok()) << chunk.status().ToString();
    const TexelSampleChunk& a = stores.parts[0][c];
    const TexelSampleChunk& b = stores.parts[1][c];
    ASSERT_EQ(chunk->texel_count, a.texel_count);
    for (uint32_t t = 0; t < a.texel_count; ++t) {
      // Texel t: part 0's samples, then part 1's.
      ASSERT_EQ(chunk->SampleCount(t), a.SampleCount(t) + b.SampleCount(t)) << "texel " << t;
      for (uint64_t k = 0; k < chunk->SampleCount(t); ++k) {
        const BrdfSample& want = k < a.SampleCount(t) ? a.SamplesOf(t)[k]
                                                      : b.SamplesOf(t)[k - a.SampleCount(t)];
        EXPECT_EQ(std::memcmp(&chunk->SamplesOf(t)[k], &want, sizeof want), 0);
      }
    }
  }
}

TEST(LinkedSampleStore, ConcurrentReadersGetTheSameChunks) {
  // Readers on several threads share the reader's spare piece buffers (a fit merge prefetches
  // on every core): each must get its own chunk, whole. Also run under TSan
  // (tests/sanitize.sh thread).
  LinkedStores stores;
  auto reader = SampleStoreReader::Open(stores.linked);
  ASSERT_TRUE(reader.ok()) << reader.status().ToString();
  std::vector<TexelSampleChunk> expected;
  for (uint32_t c = 0; c < 3; ++c) expected.push_back((*reader)->ReadChunk(c).value());
  constexpr int kThreads = 4, kRounds = 25;
  std::vector<std::thread> threads;
  std::atomic<int> mismatches{0};
  for (int k = 0; k < kThreads; ++k) {
    threads.emplace_back([&, k] {
      for (int r = 0; r < kRounds; ++r) {
        const uint32_t c = uint32_t((k + r) % 3);
        auto chunk = (*reader)->ReadChunk(c);
        if (!chunk.ok() || chunk->offsets != expected[c].offsets ||
            chunk->samples.size() != expected[c].samples.size() ||
            (!chunk->samples.empty() &&
             std::memcmp(chunk->samples.data(), expected[c].samples.data(),
                         chunk->samples.size() * sizeof(BrdfSample)) != 0)) {
          ++mismatches;
        }
      }
    });
  }
  for (std::thread& t : threads) t.join();
  EXPECT_EQ(mismatches.load(), 0);
}

TEST(LinkedSampleStore, RefusesAPartThatChangedOrWentMissingNamingIt) {
  {
    LinkedStores stores;
    // Part 1 rewritten after the link (another resample's store in its place).
    SampleStoreInfo changed = stores.info;
    changed.split = "holdout";
    for (const auto& c : stores.parts[1]) changed.samples += c.samples.size();
    ASSERT_TRUE(WriteSampleStoreInfo(stores.dir / "part1", changed).ok());
    const Status status = SampleStoreReader::Open(stores.linked).status();
    EXPECT_EQ(status.code(), StatusCode::kFailedPrecondition) << status.ToString();
    EXPECT_NE(status.message().find("parts[1]"), std::string::npos) << status.message();
    EXPECT_NE(status.message().find("changed since it was linked"), std::string::npos);
  }
  {
    LinkedStores stores;
    fs::remove_all(stores.dir / "part0");
    const Status status = SampleStoreReader::Open(stores.linked).status();
    EXPECT_EQ(status.code(), StatusCode::kNotFound) << status.ToString();
    EXPECT_EQ(status.message().rfind((stores.linked / "store.json").string(), 0), 0u)
        << status.message();
    EXPECT_NE(status.message().find((stores.dir / "part0").string()), std::string::npos);
  }
  {
    LinkedStores stores;
    // A damaged chunk of a part is reported by the part's file name when it is read.
    const fs::path chunk = stores.dir / "part1" / SampleChunkFileName(1);
    std::string bytes = ReadBytes(chunk);
    bytes[bytes.size() - 3] ^= 0x10;
    WriteBytes(chunk, bytes);
    auto reader = SampleStoreReader::Open(stores.linked);
    ASSERT_TRUE(reader.ok()) << reader.status().ToString();
    ExpectError((*reader)->ReadChunk(1).status(), StatusCode::kDataLoss, chunk, "checksum");
  }
}

TEST(LinkedSampleStore, APartsAtlasIsCheckedByItsHeader) {
  // The fingerprint read from a part's atlas header equals the one the link recorded (which
  // SampleStoreFingerprint computes from every byte); the linked store's own atlas is the one
  // used, so a part's atlas is checked by its header only.
  {
    LinkedStores stores;
    // Another atlas in part 1 (pixels reversed; store.json unchanged): another payload CRC in
    // the header, so another fingerprint.
    SampleStoreInfo other = stores.info;
    for (const auto& c : stores.parts[1]) other.samples += c.samples.size();
    std::reverse(other.pixel_of_texel.begin(), other.pixel_of_texel.end());
    const fs::path scratch = stores.dir / "scratch";
    fs::create_directories(scratch);
    ASSERT_TRUE(WriteSampleStoreInfo(scratch, other).ok());
    fs::copy_file(scratch / "atlas.bin", stores.dir / "part1" / "atlas.bin",
                  fs::copy_options::overwrite_existing);
    const Status status = SampleStoreReader::Open(stores.linked).status();
    EXPECT_EQ(status.code(), StatusCode::kFailedPrecondition) << status.ToString();
    EXPECT_NE(status.message().find("parts[1]"), std::string::npos) << status.message();
    EXPECT_NE(status.message().find("changed since it was linked"), std::string::npos);
  }
  {
    LinkedStores stores;
    // A damaged header is reported by the part's atlas file.
    const fs::path atlas = stores.dir / "part0" / "atlas.bin";
    std::string bytes = ReadBytes(atlas);
    bytes[12] ^= 0x01;  // width
    WriteBytes(atlas, bytes);
    const Status status = SampleStoreReader::Open(stores.linked).status();
    EXPECT_EQ(status.code(), StatusCode::kDataLoss) << status.ToString();
    EXPECT_NE(status.message().find(atlas.string()), std::string::npos) << status.message();
    EXPECT_NE(status.message().find("header checksum"), std::string::npos) << status.message();
  }
  {
    LinkedStores stores;
    // A damaged payload byte of a part's atlas: never read, so the store opens and reads as
    // before (the linked store's own atlas is intact and is what readers use).
    const fs::path atlas = stores.dir / "part0" / "atlas.bin";
    std::string bytes = ReadBytes(atlas);
    bytes[bytes.size() - 2] ^= 0x40;
    WriteBytes(atlas, bytes);
    auto reader = SampleStoreReader::Open(stores.linked);
    ASSERT_TRUE(reader.ok()) << reader.status().ToString();
    EXPECT_EQ((*reader)->info().pixel_of_texel, stores.info.pixel_of_texel);
    EXPECT_TRUE((*reader)->ReadChunk(2).ok());
    // Opened on its own, the part is checked whole.
    ExpectError(SampleStoreReader::Open(stores.dir / "part0").status(), StatusCode::kDataLoss,
                atlas, "payload checksum");
  }
}

TEST(LinkedSampleStore, APartThatIsItselfLinkedIsRefusedWithoutRecursion) {
  LinkedStores stores;
  // A part naming the linked store's own folder (relative "."), as a hand-edited or hostile
  // store.json might: refused when the part is opened, not followed round and round.
  auto text = ReadTextFile(stores.linked / "store.json").value();
  const std::string part0 = (stores.dir / "part0").string();
  const size_t at = text.find(part0);
  ASSERT_NE(at, std::string::npos);
  text.replace(at, part0.size(), ".");
  testing::WriteText(stores.linked / "store.json", text);
  const Status status = SampleStoreReader::Open(stores.linked).status();
  EXPECT_EQ(status.code(), StatusCode::kDataLoss) << status.ToString();
  EXPECT_NE(status.message().find("itself a linked store"), std::string::npos) << status.message();
}

TEST(LinkedSampleStore, SampleCountMustBeThePartsSum) {
  LinkedStores stores;
  auto text = ReadTextFile(stores.linked / "store.json").value();
  const std::string key = "\"samples\": ";
  const size_t at = text.find(key);
  ASSERT_NE(at, std::string::npos);
  const size_t end = text.find_first_of(",\n", at + key.size());
  text.replace(at + key.size(), end - at - key.size(), "7");
  testing::WriteText(stores.linked / "store.json", text);
  ExpectError(SampleStoreReader::Open(stores.linked).status(), StatusCode::kDataLoss,
              stores.linked / "store.json", "parts hold");
}

}  // namespace
}  // namespace reflcap
