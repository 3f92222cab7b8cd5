// `reflcap resample` end to end: exit codes and messages for bad input, refusal to overwrite, and
// no half-written output or staging leftovers after a failure.
#include <gtest/gtest.h>

#include <cstdlib>
#include <string>

#include <nlohmann/json.hpp>

#include "engine/core/atomic_file.h"
#include "tests/support/test_support.h"

namespace reflcap {
namespace {
namespace fs = std::filesystem;

using testing::CliResult;

CliResult RunCli(const std::string& args, const testing::ScratchDir& dir) {
  return testing::RunCommand(REFLCAP_BINARY, args, dir);
}

// A tiny noise-free synthetic capture shared by these tests (made once, removed at exit).
testing::ScratchDir* g_dir = nullptr;
class Cleanup : public ::testing::Environment {
 public:
  void TearDown() override {
    delete g_dir;
    g_dir = nullptr;
  }
};
::testing::Environment* const g_cleanup = ::testing::AddGlobalTestEnvironment(new Cleanup);

const fs::path& TinyCapture() {
  static const fs::path capture = [] {
    g_dir = new testing::ScratchDir();
    testing::ScratchDir logs;
    const fs::path out = *g_dir / "tiny";
    CliResult r = RunCli("synth --quiet --out " + out.string() +
                             " --texels 1500 --image-size 48 --cameras 2 --lights 2 --steps 4 "
                             "--noise 0",
                         logs);
    REFLCAP_CHECK(r.exit_code == 0) << r.err;
    return out;
  }();
  return capture;
}

// Names in `dir` that look like staging or temporary leftovers.
std::vector<std::string> Leftovers(const fs::path& dir) {
  std::vector<std::string> found;
  for (const auto& e : fs::directory_iterator(dir)) {
    const std::string name = e.path().filename().string();
    if (name.find(".tmp") != std::string::npos || name.find(".spill") != std::string::npos) {
      found.push_back(name);
    }
  }
  return found;
}

TEST(ResampleCli, WritesAStoreReportAndMaps) {
  testing::ScratchDir dir;
  const fs::path out = dir / "samples";
  CliResult r = RunCli("resample " + TinyCapture().string() + " --out " + out.string(), dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("samples kept"), std::string::npos) << r.out;
  for (const char* name : {"store.json", "atlas.bin", "chunk_00000.rcs", "resample_report.json",
                           "coverage.exr", "coverage.png", "domain.exr"}) {
    EXPECT_TRUE(fs::exists(out / name)) << name;
  }
  EXPECT_TRUE(Leftovers(out).empty());
  EXPECT_TRUE(Leftovers(dir.path()).empty());
  const auto report = nlohmann::json::parse(ReadTextFile(out / "resample_report.json").value());
  EXPECT_GT(report["samples_kept"].get<int>(), 0);
  EXPECT_EQ(report["split"], "train");
  EXPECT_EQ(report["sample_point"], "pixel");
  // --sample-point texel is recorded, and measures the same pairs through other pixels.
  const fs::path texel = dir / "texel";
  r = RunCli("resample --quiet " + TinyCapture().string() + " --out " + texel.string() +
                 " --sample-point texel",
             dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const auto texel_report =
      nlohmann::json::parse(ReadTextFile(texel / "resample_report.json").value());
  EXPECT_EQ(texel_report["sample_point"], "texel");
  EXPECT_GT(texel_report["samples_kept"].get<int>(), 0);
  // The synth's cameras declare point pixels; --pixel-filter area overrides them, is recorded,
  // and measures the pairs whose pixels all hit other texels at the nearest one instead.
  EXPECT_EQ(report["pixel_filter"]["cameras"]["cam0"], "point");
  const uint64_t rejected = report["samples_rejected_detail"]["edge_other_texel"].get<uint64_t>();
  EXPECT_GT(rejected, 0u);
  const fs::path area = dir / "area";
  r = RunCli("resample --quiet " + TinyCapture().string() + " --out " + area.string() +
                 " --pixel-filter area",
             dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const auto area_report =
      nlohmann::json::parse(ReadTextFile(area / "resample_report.json").value());
  EXPECT_EQ(area_report["pixel_filter"]["cameras"]["cam0"], "area");
  EXPECT_EQ(area_report["samples_rejected_detail"]["edge_other_texel"].get<uint64_t>(), 0u);
  // Those pairs then meet the nearest hit's own grazing and pixel tests, so not all are kept.
  EXPECT_GT(area_report["samples_kept"].get<uint64_t>(), report["samples_kept"].get<uint64_t>());
  EXPECT_LE(area_report["samples_kept"].get<uint64_t>(),
            report["samples_kept"].get<uint64_t>() + rejected);
}

TEST(ResampleCli, MissingCaptureExitsTwoNamingIt) {
  testing::ScratchDir dir;
  const fs::path missing = dir / "nowhere" / "capture.json";
  CliResult r = RunCli("resample " + missing.string() + " --out " + (dir / "a/b").string(), dir);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find(missing.string()), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir / "a")) << "nothing is created for a capture that cannot be read";
}

// Without any Vulkan driver (the loader pointed at none), --backend vulkan exits 3 before
// anything is created. (With one: tests/acquire/resample/vulkan_masks_test.cc.)
TEST(ResampleCli, VulkanBackendWithoutADriverExits3) {
  testing::ScratchDir dir;
  const char* saved_icd = std::getenv("VK_ICD_FILENAMES");
  const char* saved_drivers = std::getenv("VK_DRIVER_FILES");
  const std::string icd = saved_icd ? saved_icd : "", drivers = saved_drivers ? saved_drivers : "";
  setenv("VK_ICD_FILENAMES", "/nonexistent/reflcap_no_icd.json", 1);
  setenv("VK_DRIVER_FILES", "/nonexistent/reflcap_no_icd.json", 1);
  CliResult r = RunCli("resample " + TinyCapture().string() + " --out " + (dir / "s").string() +
                           " --backend vulkan",
                       dir);
  if (saved_icd) setenv("VK_ICD_FILENAMES", icd.c_str(), 1); else unsetenv("VK_ICD_FILENAMES");
  if (saved_drivers) setenv("VK_DRIVER_FILES", drivers.c_str(), 1); else unsetenv("VK_DRIVER_FILES");
  EXPECT_EQ(r.exit_code, 3) << r.err;
  EXPECT_NE(r.err.find("vulkan"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir / "s"));
}

TEST(ResampleCli, CrossCheckNeedsTheVulkanBackend) {
  testing::ScratchDir dir;
  CliResult r = RunCli("resample " + TinyCapture().string() + " --out " + (dir / "s").string() +
                           " --cross-check",
                       dir);
  EXPECT_EQ(r.exit_code, 1) << r.err;  // a usage error
  EXPECT_NE(r.err.find("--cross-check"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir / "s"));
}

TEST(ResampleCli, BadOptionsAreUsageErrors) {
  testing::ScratchDir dir;
  const std::string base = "resample " + TinyCapture().string() + " --out " + (dir / "s").string();
  for (const std::string bad : {" --min-cos 1.5", " --min-cos -0.1", " --min-cos banana",
                                 " --split test", " --backend cuda", " --atlas-res -3",
                                 " --read-sigma -2", " --frobnicate", " --sample-point centre",
                                 " --sample-point", " --pixel-filter gaussian"}) {
    CliResult r = RunCli(base + bad, dir);
    EXPECT_EQ(r.exit_code, 1) << bad << ": " << r.err;
    EXPECT_FALSE(r.err.empty()) << bad;
  }
  CliResult r = RunCli("resample " + TinyCapture().string(), dir);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("--out"), std::string::npos) << r.err;
  r = RunCli("resample --help", dir);
  EXPECT_EQ(r.exit_code, 0);
  EXPECT_NE(r.out.find("usage: reflcap resample"), std::string::npos) << r.out;
  EXPECT_FALSE(fs::exists(dir / "s"));
}

TEST(ResampleCli, RefusesANonEmptyFolderAndKeepsItsContents) {
  testing::ScratchDir dir;
  testing::WriteText(dir / "mine/notes.txt", "precious");
  CliResult r = RunCli("resample " + TinyCapture().string() + " --out " + (dir / "mine").string(), dir);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("not empty"), std::string::npos) << r.err;
  EXPECT_EQ(ReadTextFile(dir / "mine/notes.txt").value(), "precious");
  EXPECT_TRUE(Leftovers(dir.path()).empty());
  r = RunCli("resample --quiet " + TinyCapture().string() + " --out " + (dir / "mine").string() +
                 " --overwrite",
             dir);
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_FALSE(fs::exists(dir / "mine/notes.txt"));
  EXPECT_TRUE(fs::exists(dir / "mine/store.json"));
  EXPECT_TRUE(Leftovers(dir.path()).empty());
}

TEST(ResampleCli, AnUnreadablePhotographLeavesNothingBehind) {
  testing::ScratchDir dir;
  const fs::path copy = dir / "capture";
  fs::copy(TinyCapture(), copy, fs::copy_options::recursive);
  // Keep the EXR header (so the up-front header check passes) but cut the pixels short: the
  // failure comes mid-run, after the output folder has been staged.
  const fs::path image = copy / "images/0000.exr";  // a train image
  fs::resize_file(image, fs::file_size(image) * 6 / 10);
  CliResult r = RunCli("resample " + copy.string() + " --out " + (dir / "samples").string(), dir);
  EXPECT_EQ(r.exit_code, 2) << r.err;
  EXPECT_NE(r.err.find("images[0].file"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("capture.json"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir / "samples"));
  EXPECT_TRUE(Leftovers(dir.path()).empty());
}

TEST(ResampleCli, ResumeAfterSigkillGivesTheUninterruptedStore) {
  testing::ScratchDir dir;
  // ~64 train photographs of a small capture, a checkpoint after every one: the kill lands
  // between checkpoints, after at least three.
  CliResult r = RunCli("synth --quiet --out " + (dir / "cap").string() +
                           " --texels 1500 --image-size 64 --cameras 2 --lights 3 --steps 16",
                       dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const std::string capture = (dir / "cap").string();
  const std::string common = " --quiet --chunk-texels 300";
  r = RunCli("resample " + capture + " --out " + (dir / "whole").string() + common + " --no-checkpoint", dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;

  const fs::path out = dir / "killed", checkpoint = dir / "killed.checkpoint";
  auto images_done = [&]() -> int {
    auto text = ReadTextFile(checkpoint / "checkpoint.json");
    if (!text.ok()) return 0;
    const nlohmann::json state = nlohmann::json::parse(*text, nullptr, false);
    return state.is_object() ? state.value("images_done", 0) : 0;
  };
  ASSERT_TRUE(testing::KillWhen(REFLCAP_BINARY,
                                {"resample", capture, "--out", out.string(), "--quiet",
                                 "--chunk-texels", "300", "--checkpoint-seconds", "0"},
                                dir / "killed.log", [&] { return images_done() >= 3; }))
      << "the resample finished before it could be killed";
  EXPECT_FALSE(fs::exists(out));
  const int done = images_done();
  EXPECT_GE(done, 3);

  // Refused without --resume, and with options that change the samples.
  r = RunCli("resample " + capture + " --out " + out.string() + common, dir);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("--resume"), std::string::npos) << r.err;
  r = RunCli("resample " + capture + " --out " + out.string() + common + " --min-cos 0.2 --resume", dir);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("identity.min_cos"), std::string::npos) << r.err;
  r = RunCli("resample " + capture + " --out " + out.string() + common +
                 " --sample-point texel --resume",
             dir);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("identity.sample_point"), std::string::npos) << r.err;

  // A corrupt checkpoint is named, and nothing is written.
  {
    const nlohmann::json state =
        nlohmann::json::parse(ReadTextFile(checkpoint / "checkpoint.json").value());
    const fs::path coverage = checkpoint / state["coverage_file"].get<std::string>();
    const std::string good = ReadTextFile(coverage).value();
    std::string bad = good;
    bad[bad.size() / 2] ^= 0x40;
    testing::WriteText(coverage, bad);
    r = RunCli("resample " + capture + " --out " + out.string() + common + " --resume", dir);
    EXPECT_EQ(r.exit_code, 2);
    EXPECT_NE(r.err.find(coverage.filename().string()), std::string::npos) << r.err;
    EXPECT_NE(r.err.find("corrupt"), std::string::npos) << r.err;
    EXPECT_FALSE(fs::exists(out));
    testing::WriteText(coverage, good);
  }
  r = RunCli("resample " + capture + " --out " + out.string() + " --chunk-texels 300 --resume", dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.err.find("resumed after " + std::to_string(done)), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(checkpoint));
  // Every file of the store and the maps, byte for byte (the report differs in its timings).
  int compared = 0;
  for (const auto& e : fs::directory_iterator(dir / "whole")) {
    const std::string name = e.path().filename().string();
    if (name == "resample_report.json") continue;
    EXPECT_EQ(ReadTextFile(e.path()).value(), ReadTextFile(out / name).value()) << name;
    ++compared;
  }
  EXPECT_GE(compared, 10);  // store.json, atlas.bin, 5 chunks, 3 maps
}

TEST(ResampleCli, MergedShardsEqualOneRunAndForeignPartsAreRefused) {
  testing::ScratchDir dir;
  const std::string capture = TinyCapture().string();
  const std::string common = " --quiet --chunk-texels 400";
  CliResult r = RunCli("resample " + capture + " --out " + (dir / "whole").string() + common, dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  // The tiny capture has 2 cameras x 4 steps = 8 views: 3 shards of 2-3 views.
  std::string p[3];
  for (int i : {2, 0, 1}) {
    p[i] = (dir / ("part" + std::to_string(i))).string();
    r = RunCli("resample " + capture + " --out " + p[i] + common + " --shard " + std::to_string(i) + "/3", dir);
    ASSERT_EQ(r.exit_code, 0) << r.err;
  }
  // A part alone is not a store to fit.
  r = RunCli("fit " + p[0] + " --out " + (dir / "fit").string(), dir);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("reflcap merge"), std::string::npos) << r.err;

  const fs::path merged = dir / "merged";
  r = RunCli("merge " + p[1] + " " + p[2] + " " + p[0] + " --out " + merged.string(), dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  int compared = 0;
  for (const auto& e : fs::directory_iterator(dir / "whole")) {
    const std::string name = e.path().filename().string();
    if (name == "resample_report.json") continue;
    EXPECT_EQ(ReadTextFile(e.path()).value(), ReadTextFile(merged / name).value()) << name;
    ++compared;
  }
  EXPECT_GE(compared, 9);  // store.json, atlas.bin, 4 chunks, 3 maps
  const nlohmann::json whole = nlohmann::json::parse(ReadTextFile(dir / "whole/resample_report.json").value());
  const nlohmann::json joined = nlohmann::json::parse(ReadTextFile(merged / "resample_report.json").value());
  for (const char* key : {"samples_kept", "samples_rejected", "samples_per_texel", "domain", "images",
                          "views", "texels_seen", "observations"}) {
    EXPECT_EQ(whole[key], joined[key]) << key;
  }
  EXPECT_EQ(joined["shards"]["count"], 3);
  // A part writes no maps: the merge does, once.
  EXPECT_FALSE(fs::exists(fs::path(p[0]) / "coverage.png"));
  EXPECT_FALSE(fs::exists(fs::path(p[0]) / "domain.exr"));

  // --link: the store names the parts instead of joining their chunks; its maps are the run's
  // and a fit of it is the fit of the whole run, byte for byte.
  const fs::path linked = dir / "linked";
  r = RunCli("merge " + p[2] + " " + p[0] + " " + p[1] + " --out " + linked.string() + " --link", dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_FALSE(fs::exists(linked / "chunk_00000.rcs"));
  for (const char* name : {"atlas.bin", "coverage.exr", "coverage.png", "domain.exr"}) {
    EXPECT_EQ(ReadTextFile(dir / "whole" / name).value(), ReadTextFile(linked / name).value()) << name;
  }
  const nlohmann::json store = nlohmann::json::parse(ReadTextFile(linked / "store.json").value());
  ASSERT_EQ(store["parts"].size(), 3u);
  EXPECT_EQ(fs::path(store["parts"][0]["path"].get<std::string>()).filename(), "part0");  // shard order
  for (const char* from : {"whole", "linked"}) {
    r = RunCli(std::string("fit ") + (dir / from).string() + " --quiet --out " + (dir / (std::string("fit_") + from)).string(), dir);
    ASSERT_EQ(r.exit_code, 0) << r.err;
  }
  for (const char* name : {"params.exr", "sigma.exr", "status.exr"}) {
    EXPECT_EQ(ReadTextFile(dir / "fit_whole" / name).value(), ReadTextFile(dir / "fit_linked" / name).value())
        << name;
  }
  // Only resample parts link.
  r = RunCli("merge " + (dir / "fit_whole").string() + " --out " + (dir / "nolink").string() + " --link", dir);
  EXPECT_EQ(r.exit_code, 1) << r.err;
  EXPECT_FALSE(fs::exists(dir / "nolink"));

  // Parts that do not belong together: nothing is written.
  const std::string other = (dir / "other").string();
  r = RunCli("resample " + capture + " --out " + other + common + " --shard 2/3 --min-cos 0.3", dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  struct Case {
    std::string parts, message;
  };
  const std::vector<Case> cases = {{p[0] + " " + p[1], "shard 2 is missing"},
                                   {p[0] + " " + p[1] + " " + p[1], "shard 1 is also"},
                                   {p[0] + " " + p[1] + " " + other, "identity.min_cos"}};
  const fs::path out = dir / "refused";
  for (const Case& c : cases) {
    r = RunCli("merge " + c.parts + " --out " + out.string(), dir);
    EXPECT_EQ(r.exit_code, 2) << c.parts;
    EXPECT_NE(r.err.find(c.message), std::string::npos) << r.err;
    EXPECT_FALSE(fs::exists(out));
  }
  // A corrupt coverage file is named.
  std::string bytes = ReadTextFile(fs::path(p[2]) / "coverage.bin").value();
  bytes[bytes.size() / 2] ^= 0x10;
  testing::WriteText(fs::path(p[2]) / "coverage.bin", bytes);
  r = RunCli("merge " + p[0] + " " + p[1] + " " + p[2] + " --out " + out.string(), dir);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("coverage.bin"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(out));
  EXPECT_TRUE(Leftovers(dir.path()).empty());
}

}  // namespace
}  // namespace reflcap
