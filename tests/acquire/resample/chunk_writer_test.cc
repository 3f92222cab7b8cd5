// The streaming reorder (image-major appends -> texel-major chunk files through spill files) must
// give exactly the chunks an in-memory stable sort gives, whatever the buffer budget.
#include "acquire/resample/chunk_writer.h"

#include <gtest/gtest.h>

#include <cstring>
#include <random>

#include "engine/texel/sample_store.h"
#include "tests/support/test_support.h"

namespace reflcap::resample {
namespace {
namespace fs = std::filesystem;

// `images` rounds of appends, each holding a random subset of texels in ascending order (as the
// resampler appends them); values encode (image, texel) so any misplacement shows.
std::vector<std::vector<TexelSample>> MakeRounds(uint32_t texels, int images, uint32_t seed) {
  std::mt19937 rng(seed);
  std::bernoulli_distribution keep(0.3);
  std::vector<std::vector<TexelSample>> rounds(images);
  for (int i = 0; i < images; ++i) {
    for (uint32_t t = 0; t < texels; ++t) {
      if (!keep(rng)) continue;
      TexelSample s{};
      s.texel = t;
      for (int c = 0; c < 3; ++c) {
        s.sample.wi[c] = float(t) * 1e-3f + float(c);
        s.sample.wo[c] = float(i);
        s.sample.value[c] = float(t * 1000 + i);
        s.sample.weight[c] = 1;
      }
      s.sample.image = uint32_t(i);
      rounds[i].push_back(s);
    }
  }
  return rounds;
}

void ExpectStreamingEqualsReference(uint32_t texels, uint32_t chunk_texels, size_t budget,
                                    int images, bool expect_spills) {
  testing::ScratchDir dir;
  const auto rounds = MakeRounds(texels, images, texels + chunk_texels);
  auto writer = ChunkedSampleWriter::Create(dir / "spill", texels, chunk_texels, budget);
  ASSERT_TRUE(writer.ok()) << writer.status().ToString();
  std::vector<TexelSample> all;
  for (const auto& r : rounds) {
    ASSERT_TRUE((*writer)->Append(r.data(), r.size()).ok());
    all.insert(all.end(), r.begin(), r.end());
  }
  EXPECT_EQ((*writer)->samples(), all.size());
  ASSERT_TRUE((*writer)->Finish(dir.path(), 2).ok());
  EXPECT_FALSE(fs::exists(dir / "spill")) << "spill files are removed";
  const auto reference = BuildChunksInMemory(all, texels, chunk_texels);
  ASSERT_EQ(reference.size(), (*writer)->chunks());
  for (uint32_t c = 0; c < reference.size(); ++c) {
    auto chunk = ReadSampleChunk(dir / SampleChunkFileName(c));
    ASSERT_TRUE(chunk.ok()) << chunk.status().ToString();
    EXPECT_EQ(chunk->first_texel, reference[c].first_texel);
    EXPECT_EQ(chunk->texel_count, reference[c].texel_count);
    ASSERT_EQ(chunk->offsets, reference[c].offsets) << "chunk " << c;
    ASSERT_EQ(chunk->samples.size(), reference[c].samples.size());
    EXPECT_EQ(std::memcmp(chunk->samples.data(), reference[c].samples.data(),
                          chunk->samples.size() * sizeof(BrdfSample)),
              0)
        << "chunk " << c;
    // Within a texel, samples keep the order they were appended in (image order here).
    for (uint32_t i = 0; i < chunk->texel_count; ++i) {
      for (uint64_t k = chunk->offsets[i] + 1; k < chunk->offsets[i + 1]; ++k) {
        EXPECT_LT(chunk->samples[k - 1].image, chunk->samples[k].image);
      }
    }
  }
  if (expect_spills) {
    EXPECT_GT((*writer)->spilled_bytes(), 0u) << "the small budget forced spills";
  } else {
    EXPECT_EQ((*writer)->spilled_bytes(), 0u) << "everything fitted in the buffers";
  }
}

TEST(ChunkedSampleWriter, StreamingReorderEqualsInMemoryReferenceWithManySpills) {
  // Budget 0: every chunk flushes at kMinFlushBytes (~1170 records), many times per chunk.
  ExpectStreamingEqualsReference(/*texels=*/5000, /*chunk_texels=*/700, /*budget=*/0, /*images=*/40,
                                 /*expect_spills=*/true);
}

TEST(ChunkedSampleWriter, StreamingReorderEqualsInMemoryReferenceWithoutSpills) {
  ExpectStreamingEqualsReference(1000, 333, size_t(64) << 20, 10, false);
}

TEST(ChunkedSampleWriter, OneChunkAndOneTexelPerChunk) {
  // 1800 records of 56 bytes overflow the one chunk's 64 KiB buffer once.
  ExpectStreamingEqualsReference(300, 1000, 0, 20, true);
  // 37 chunks of ~6 records each never reach their flush size.
  ExpectStreamingEqualsReference(37, 1, 0, 20, false);
}

TEST(ChunkedSampleWriter, RejectsTexelsOutOfRangeAndBadSizes) {
  testing::ScratchDir dir;
  EXPECT_FALSE(ChunkedSampleWriter::Create(dir / "s", 0, 10, 0).ok());
  EXPECT_FALSE(ChunkedSampleWriter::Create(dir / "s", 10, 0, 0).ok());
  auto writer = ChunkedSampleWriter::Create(dir / "s", 10, 4, 0);
  ASSERT_TRUE(writer.ok());
  TexelSample s{};
  s.texel = 10;
  EXPECT_FALSE((*writer)->Append(&s, 1).ok());
}

}  // namespace
}  // namespace reflcap::resample
