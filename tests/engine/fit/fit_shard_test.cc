// `reflcap fit --shard I/N` + `reflcap merge`, and `reflcap fit --resume` after SIGKILL, end to
// end through the executable: the merged and the resumed maps must be bit-identical to one
// uninterrupted run's, and parts or checkpoints of another run must be refused with nothing
// written. Also the chunk result file format (fit_checkpoint.h) on its own.
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include "engine/core/atomic_file.h"
#include "engine/fit/fit_checkpoint.h"
#include "engine/fit/problem.h"
#include "engine/fit/synthetic_samples.h"
#include "engine/texel/sample_store.h"
#include "tests/support/test_support.h"

namespace reflcap::fit {
namespace {
namespace fs = std::filesystem;
using Json = nlohmann::json;
using reflcap::testing::ScratchDir;

// A 48 x 48 atlas fully covered by texels in row-major order, so lobe transfer, albedo fill and
// the material clusters (the stages that need the whole atlas) all have neighbours to work on.
constexpr int kAtlasSize = 48;
constexpr uint32_t kTexels = kAtlasSize * kAtlasSize;
// 12 chunks of 192 texels: enough for 5 uneven shards and for a kill between chunks.
constexpr uint32_t kChunkTexels = 192;
// Every 29th texel has no sample (albedo fill's work), every 7th of the rest only its first half.
constexpr uint32_t kUnseenEvery = 29;

using reflcap::testing::CliResult;

CliResult RunCli(const std::string& args, const ScratchDir& dir) {
  return reflcap::testing::RunCommand(REFLCAP_BINARY, args, dir);
}

void WriteStore(const fs::path& dir) {
  fs::create_directories(dir);
  const std::vector<brdf::BrdfParams> truth = SynthMaterialTexels(kTexels, 11);
  SampleStoreInfo info;
  info.texels = kTexels;
  info.chunk_texels = kChunkTexels;
  info.chunks = (kTexels + kChunkTexels - 1) / kChunkTexels;
  info.atlas_width = info.atlas_height = kAtlasSize;
  for (uint32_t t = 0; t < kTexels; ++t) info.pixel_of_texel.push_back(t);
  info.capture = "synthetic";
  info.split = "train";
  info.geometry = "mesh";
  SyntheticSampleOptions so;
  so.seed = 11;
  for (uint32_t c = 0; c < info.chunks; ++c) {
    const uint32_t first = c * kChunkTexels, count = std::min(kChunkTexels, kTexels - first);
    const std::vector<brdf::BrdfParams> part(truth.begin() + first, truth.begin() + first + count);
    const TexelSampleChunk full = MakeSyntheticChunk(part, so, first);
    TexelSampleChunk chunk;
    chunk.first_texel = full.first_texel;
    chunk.texel_count = full.texel_count;
    chunk.offsets.push_back(0);
    for (uint32_t i = 0; i < count; ++i) {
      const uint32_t t = first + i;
      uint64_t b = full.offsets[i], e = full.offsets[i + 1];
      if (t % kUnseenEvery == 0) e = b;
      else if (t % 7 == 0) e = b + (e - b) / 2;
      chunk.samples.insert(chunk.samples.end(), full.samples.begin() + b, full.samples.begin() + e);
      chunk.offsets.push_back(chunk.samples.size());
    }
    info.samples += chunk.samples.size();
    REFLCAP_CHECK(WriteSampleChunk(dir / SampleChunkFileName(c), chunk).ok());
  }
  REFLCAP_CHECK(WriteSampleStoreInfo(dir, info).ok());
}

// The three maps of two FIT folders are byte for byte the same.
void ExpectSameMaps(const fs::path& a, const fs::path& b) {
  for (const char* name : {"params.exr", "sigma.exr", "status.exr"}) {
    auto x = ReadTextFile(a / name), y = ReadTextFile(b / name);
    ASSERT_TRUE(x.ok() && y.ok()) << name;
    EXPECT_TRUE(*x == *y) << name << " differs between " << a << " and " << b;
  }
}

class FitShardCli : public ::testing::Test {
 protected:
  void SetUp() override {
    WriteStore(dir_ / "samples");
    samples_ = (dir_ / "samples").string();
  }
  ScratchDir dir_;
  std::string samples_;
};

TEST_F(FitShardCli, MergedShardsEqualOneRunBitForBit) {
  const CliResult single = RunCli("fit " + samples_ + " --out " + (dir_ / "single").string() +
                                      " --backend cpu --quiet", dir_);
  ASSERT_EQ(single.exit_code, 0) << single.err;
  const Json report = Json::parse(ReadTextFile(dir_ / "single" / "fit_report.json").value());
  // The post-fit stages did work that crosses shard edges, so the equality below means something.
  ASSERT_GT(report["lobe_transfer"]["transferred"].get<int>(), 0);
  ASSERT_GT(report["albedo_fill"]["filled"].get<int>(), 0);
  ASSERT_GT(report["clusters"]["clusters"].get<int>(), 0);
  // The checkpoint of a finished run is gone.
  EXPECT_FALSE(fs::exists(dir_ / "single.checkpoint"));

  // 5 shards of 12 chunks: 2 or 3 chunks each; merged in a shuffled order.
  constexpr int kShards = 5;
  std::string parts;
  for (int i : {3, 0, 4, 1, 2}) {
    const fs::path part = dir_ / ("part" + std::to_string(i));
    const CliResult r = RunCli("fit " + samples_ + " --out " + part.string() + " --backend cpu --shard " +
                                   std::to_string(i) + "/" + std::to_string(kShards),
                               dir_);
    ASSERT_EQ(r.exit_code, 0) << r.err;
    // The last line on stdout is the shard's JSON summary, for the batch system's log.
    const std::string line = "reflcap-shard-summary {";
    ASSERT_NE(r.out.find(line), std::string::npos) << r.out;
    const Json summary = Json::parse(r.out.substr(r.out.find(line) + line.size() - 1));
    EXPECT_EQ(summary["stage"], "fit");
    EXPECT_EQ(summary["shard"], std::to_string(i) + "/" + std::to_string(kShards));
    EXPECT_GT(summary["texels"].get<double>(), 0);
    EXPECT_TRUE(fs::exists(part / kFitPartFile));
    EXPECT_FALSE(fs::exists(part / "params.exr"));  // a part holds fits, not maps
    parts += " " + part.string();
  }
  const CliResult merged = RunCli("merge" + parts + " --out " + (dir_ / "merged").string(), dir_);
  ASSERT_EQ(merged.exit_code, 0) << merged.err;
  ExpectSameMaps(dir_ / "single", dir_ / "merged");
  const Json merged_report = Json::parse(ReadTextFile(dir_ / "merged" / "fit_report.json").value());
  EXPECT_EQ(merged_report["shards"]["count"], kShards);
  EXPECT_EQ(merged_report["texels"], kTexels);
  EXPECT_EQ(merged_report["status_counts"], report["status_counts"]);
}

TEST_F(FitShardCli, MergeRefusesPartsThatDoNotBelongTogether) {
  auto part = [&](int i, int n, const std::string& extra = "") {
    const fs::path p = dir_ / ("p" + std::to_string(i) + "of" + std::to_string(n) + extra.substr(0, 4));
    const CliResult r = RunCli("fit " + samples_ + " --out " + p.string() + " --backend cpu --shard " +
                                   std::to_string(i) + "/" + std::to_string(n) + " --quiet " + extra,
                               dir_);
    EXPECT_EQ(r.exit_code, 0) << r.err;
    return p.string();
  };
  const std::string p0 = part(0, 3), p1 = part(1, 3), p2 = part(2, 3);
  const std::string other_options = part(2, 3, "--no-lobe-transfer");
  const std::string other_count = part(1, 2);
  const fs::path out = dir_ / "merged";
  struct Case {
    std::string parts, message;
  };
  const std::vector<Case> cases = {
      {p0 + " " + p1, "shard 2 is missing"},
      {p0 + " " + p1 + " " + p1, "shard 1 is also"},
      {p0 + " " + p1 + " " + other_options, "options.lobe_transfer"},
      {p0 + " " + p1 + " " + other_count, "shard count"},
      {p0 + " " + p1 + " " + (dir_ / "samples").string(), "not a fit part"},
  };
  for (const Case& c : cases) {
    const CliResult r = RunCli("merge " + c.parts + " --out " + out.string(), dir_);
    EXPECT_EQ(r.exit_code, 2) << c.parts;
    EXPECT_NE(r.err.find(c.message), std::string::npos) << r.err;
    EXPECT_FALSE(fs::exists(out)) << c.parts;
  }
  // A corrupt chunk result file is named; nothing is merged.
  {
    auto bytes = ReadTextFile(fs::path(p1) / FitChunkFileName(4)).value();
    bytes[100] ^= 0x5a;
    ASSERT_TRUE(WriteTextFileAtomic(fs::path(p1) / FitChunkFileName(4), bytes).ok());
    const CliResult r = RunCli("merge " + p0 + " " + p1 + " " + p2 + " --out " + out.string(), dir_);
    EXPECT_EQ(r.exit_code, 2);
    EXPECT_NE(r.err.find(FitChunkFileName(4)), std::string::npos) << r.err;
    EXPECT_NE(r.err.find("checksum"), std::string::npos) << r.err;
    EXPECT_FALSE(fs::exists(out));
  }
  // Usage: more shards than chunks, a malformed --shard.
  EXPECT_EQ(RunCli("fit " + samples_ + " --out " + (dir_ / "x").string() + " --shard 0/13", dir_).exit_code, 2);
  EXPECT_EQ(RunCli("fit " + samples_ + " --out " + (dir_ / "x").string() + " --shard 3/3", dir_).exit_code, 1);
  EXPECT_EQ(RunCli("merge --out " + out.string(), dir_).exit_code, 1);
}

TEST_F(FitShardCli, ResumeAfterSigkillEqualsAnUninterruptedRun) {
  // The Ceres reference backend is slow enough (~0.1 s per chunk) that the kill lands between
  // chunks; one thread keeps the chunk order and the timing steady.
  const std::string common = " --backend ceres --threads 1 --quiet";
  const CliResult whole = RunCli("fit " + samples_ + " --out " + (dir_ / "whole").string() + common, dir_);
  ASSERT_EQ(whole.exit_code, 0) << whole.err;

  const fs::path out = dir_ / "killed", checkpoint = dir_ / "killed.checkpoint";
  // Kill as soon as the second chunk's results are on disk.
  ASSERT_TRUE(reflcap::testing::KillWhen(
      REFLCAP_BINARY,
      {"fit", samples_, "--out", out.string(), "--backend", "ceres", "--threads", "1", "--quiet"},
      dir_ / "killed.log", [&] { return fs::exists(checkpoint / FitChunkFileName(1)); }))
      << "the fit finished before it could be killed";
  EXPECT_FALSE(fs::exists(out));  // no half-written output
  int done = 0;
  for (const auto& e : fs::directory_iterator(checkpoint)) {
    done += e.path().extension() == ".rcf";
  }
  EXPECT_GE(done, 2);
  EXPECT_LT(done, int(kTexels / kChunkTexels));

  // Without --resume the checkpoint is not silently discarded or reused.
  CliResult r = RunCli("fit " + samples_ + " --out " + out.string() + common, dir_);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("--resume"), std::string::npos) << r.err;
  // Nor continued with other options.
  r = RunCli("fit " + samples_ + " --out " + out.string() + common + " --lobes 2 --resume", dir_);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("options.lobes"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find(kFitCheckpointFile), std::string::npos) << r.err;

  r = RunCli("fit " + samples_ + " --out " + out.string() + common + " --resume", dir_);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  ExpectSameMaps(dir_ / "whole", out);
  const Json report = Json::parse(ReadTextFile(out / "fit_report.json").value());
  EXPECT_EQ(report["resumed_chunks"].get<int>(), done);
  EXPECT_FALSE(fs::exists(checkpoint));
}

TEST(FitCheckpoint, ChunkResultsRoundTripExactlyAndCorruptionIsNamed) {
  ScratchDir dir;
  std::vector<TexelFit> fits(3);
  for (int i = 0; i < 3; ++i) {
    BeginTexel(1, &fits[i]);
    fits[i].params.rho_d = {0.1f * i, 0.2f, 0.3f};
    fits[i].params.lobes[0][1] = brdf::LobeParams{-0.7f, -0.7f, 0.9f + i, 31.5f};
    fits[i].sigma.rho_d = {1e-3f, -1, 2e-3f};
    fits[i].status = FitStatus(i);
    fits[i].cost = 12.5f + i;
    fits[i].iterations = 7 + i;
    fits[i].samples = 40;
    fits[i].residuals = 120;
    fits[i].lambert_only = i == 2;
  }
  const fs::path file = dir / FitChunkFileName(7);
  ASSERT_TRUE(WriteFitChunk(file, 700, 1, fits).ok());
  auto back = ReadFitChunk(file, 700, 3, 1);
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  for (int i = 0; i < 3; ++i) {
    const TexelFit& a = fits[i];
    const TexelFit& b = (*back)[i];
    EXPECT_EQ(a.params.rho_d, b.params.rho_d);
    EXPECT_EQ(a.params.lobes[0][1].cz, b.params.lobes[0][1].cz);
    EXPECT_EQ(a.params.lobes[0][1].n, b.params.lobes[0][1].n);
    EXPECT_EQ(a.sigma.rho_d, b.sigma.rho_d);
    EXPECT_EQ(a.status, b.status);
    EXPECT_EQ(a.cost, b.cost);
    EXPECT_EQ(a.iterations, b.iterations);
    EXPECT_EQ(a.lambert_only, b.lambert_only);
  }
  // Other texels or lobes than the reader expects, truncation, a flipped payload byte.
  EXPECT_EQ(ReadFitChunk(file, 0, 3, 1).status().code(), StatusCode::kDataLoss);
  EXPECT_EQ(ReadFitChunk(file, 700, 3, 2).status().code(), StatusCode::kDataLoss);
  std::string bytes = ReadTextFile(file).value();
  ASSERT_TRUE(WriteTextFileAtomic(dir / "short.rcf", bytes.substr(0, bytes.size() - 5)).ok());
  auto truncated = ReadFitChunk(dir / "short.rcf", 700, 3, 1);
  EXPECT_NE(truncated.status().message().find("truncated"), std::string::npos) << truncated.status().message();
  bytes[80] ^= 1;
  ASSERT_TRUE(WriteTextFileAtomic(dir / "flip.rcf", bytes).ok());
  auto flipped = ReadFitChunk(dir / "flip.rcf", 700, 3, 1);
  EXPECT_NE(flipped.status().message().find("flip.rcf"), std::string::npos);
  EXPECT_NE(flipped.status().message().find("checksum"), std::string::npos);
  EXPECT_EQ(ReadFitChunk(dir / "none.rcf", 700, 3, 1).status().code(), StatusCode::kNotFound);
}

TEST(FitCheckpoint, ShardsTileTheChunksAndOptionsRoundTrip) {
  for (uint32_t chunks : {1u, 7u, 62u}) {
    for (int n = 1; n <= int(std::min<uint32_t>(chunks, 9)); ++n) {
      uint32_t next = 0;
      for (int i = 0; i < n; ++i) {
        auto r = ShardChunks(Shard{i, n}, chunks);
        ASSERT_TRUE(r.ok());
        EXPECT_EQ(r->begin, next);
        EXPECT_GT(r->end, r->begin);  // no empty shard
        next = r->end;
      }
      EXPECT_EQ(next, chunks);
    }
  }
  EXPECT_FALSE(ShardChunks(Shard{0, 8}, 7).ok());
  EXPECT_TRUE(ParseShard("7/8").ok());
  EXPECT_EQ(ParseShard("").value().count, 1);  // no --shard: the whole work
  for (const char* bad : {"8/8", "-1/8", "1/0", "1", "1/2/3", "a/b", "1/2x"}) {
    EXPECT_FALSE(ParseShard(bad).ok()) << bad;
  }
  FitOptions o;
  o.lobes = 2;
  o.lobe_model = LobeModel::kIso;
  o.loss = LossKind::kCauchy;
  o.loss_scale = 0.1 + 0.2;  // not exactly representable: JSON must keep every bit
  o.lobe_transfer.enabled = false;
  o.clusters.max_clusters = 9;
  o.albedo_fill.rounds = 3;
  FitOptions back;
  ASSERT_TRUE(FitOptionsFromJson(Json::parse(FitOptionsToJson(o).dump()), "x.json", &back).ok());
  EXPECT_EQ(FitOptionsToJson(back), FitOptionsToJson(o));
  EXPECT_EQ(back.loss_scale, o.loss_scale);
  Json broken = FitOptionsToJson(o);
  broken["clusters"].erase("pool_texels");
  const Status s = FitOptionsFromJson(broken, "x.json", &back);
  EXPECT_NE(s.message().find("x.json: options.clusters.pool_texels"), std::string::npos) << s.message();
}

}  // namespace
}  // namespace reflcap::fit
