// The `render`, `validate` and `import-diligent` verbs of the reflcap executable: exit codes
// (1 usage, 2 bad input naming the file, 3 unavailable backend), staging, and a synth -> render ->
// validate and an import-diligent -> info round trip.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>

#include <nlohmann/json.hpp>

#include "engine/core/atomic_file.h"
#include "engine/image/exr_io.h"
#include "engine/image/png_io.h"
#include "engine/texel/sample_store.h"
#include "tests/support/test_support.h"

namespace reflcap {
namespace {
namespace fs = std::filesystem;

using testing::CliResult;

CliResult RunCli(const std::string& args, const testing::ScratchDir& dir) {
  return testing::RunCommand(REFLCAP_BINARY, args, dir);
}

// A tiny noisy synthetic capture, made once for this file.
const fs::path& TinyCapture() {
  static const testing::ScratchDir* dir = &reflcap::testing::NewProcessScratchDir();
  static const fs::path capture = [] {
    testing::ScratchDir logs;
    const fs::path out = *dir / "tiny";
    CliResult r = RunCli("synth --quiet --out " + out.string() +
                             " --texels 3000 --image-size 48 --cameras 2 --lights 2 --steps 4 --noise 0.02",
                         logs);
    REFLCAP_CHECK(r.exit_code == 0) << r.err;
    return out;
  }();
  return capture;
}

// A 9x9 DiLiGenT-like object in `obj`: a flat disc facing the camera under 4 lights, 8-bit
// images; image i's pixels read `level(i, x, y)`.
bool InDisc(int x, int y) { return (x - 4) * (x - 4) + (y - 4) * (y - 4) <= 12; }

template <typename Level>
void WriteDisc(const fs::path& obj, Level level) {
  fs::create_directories(obj);
  Image normals(9, 9, 3, 0.0f), mask(9, 9, 3, 0.0f);
  for (int y = 0; y < 9; ++y) {
    for (int x = 0; x < 9; ++x) {
      if (!InDisc(x, y)) continue;
      normals.at(x, y, 2) = 1;
      for (int c = 0; c < 3; ++c) mask.at(x, y, c) = 1;
    }
  }
  ASSERT_TRUE(WriteExr(obj / "normals.exr", normals).ok());
  ASSERT_TRUE(WritePng(obj / "mask.png", mask).ok());
  std::string names, dirs, ints;
  for (int i = 1; i <= 4; ++i) {
    Image photo(9, 9, 3, 0.0f);
    for (int y = 0; y < 9; ++y) {
      for (int x = 0; x < 9; ++x) {
        for (int c = 0; c < 3; ++c) photo.at(x, y, c) = InDisc(x, y) ? level(i, x, y) : 0.0f;
      }
    }
    char name[16];
    std::snprintf(name, sizeof name, "%03d.png", i);
    ASSERT_TRUE(WritePng(obj / name, photo).ok());
    names += std::string(name) + "\n";
    dirs += "0 0.6 0.8\n";
    ints += "1 1 1\n";
  }
  testing::WriteText(obj / "filenames.txt", names);
  testing::WriteText(obj / "light_directions.txt", dirs);
  testing::WriteText(obj / "light_intensities.txt", ints);
}

TEST(VerbsCli, HelpAndUsageErrors) {
  testing::ScratchDir dir;
  for (const char* verb : {"render", "validate", "import-diligent"}) {
    CliResult r = RunCli(std::string(verb) + " --help", dir);
    EXPECT_EQ(r.exit_code, 0) << verb;
    EXPECT_NE(r.out.find(std::string("usage: reflcap ") + verb), std::string::npos) << r.out;
    EXPECT_EQ(RunCli(verb, dir).exit_code, 1) << verb << ": missing positionals";
  }
  const std::string cap = TinyCapture().string();
  EXPECT_EQ(RunCli("render " + cap + " " + cap + "/gt", dir).exit_code, 1) << "no --out";
  CliResult r = RunCli("render " + cap + " " + cap + "/gt --out x --split sometimes", dir);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("--split"), std::string::npos) << r.err;
  EXPECT_EQ(RunCli("render " + cap + " " + cap + "/gt --out x --supersample 0", dir).exit_code, 1);
  EXPECT_EQ(RunCli("render " + cap + " " + cap + "/gt --out x --backend metal", dir).exit_code, 1);
  r = RunCli("render " + cap + " " + cap + "/gt --out x --indirect sometimes", dir);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("--indirect"), std::string::npos) << r.err;
  EXPECT_EQ(RunCli("render " + cap + " " + cap + "/gt --out x --indirect-bounces 9", dir).exit_code, 1);
  EXPECT_EQ(RunCli("render " + cap + " " + cap + "/gt --out x --indirect-rays 0", dir).exit_code, 1);
  EXPECT_EQ(RunCli("run " + cap + " --out x --indirect-rays 2000", dir).exit_code, 1);
  EXPECT_EQ(RunCli("render " + cap + " " + cap + "/gt --out x --supersample many", dir).exit_code, 1);
  r = RunCli("run " + cap + " --out x --supersample 17", dir);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("--supersample"), std::string::npos) << r.err;
  r = RunCli("run " + cap + " --out x --sample-point centre", dir);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("--sample-point"), std::string::npos) << r.err;
  EXPECT_EQ(RunCli("validate " + cap + " r --out x --max-figures -1", dir).exit_code, 1);
  EXPECT_EQ(RunCli("import-diligent d --out x --holdout-every 1", dir).exit_code, 1);
  EXPECT_FALSE(fs::exists("x"));
}

TEST(VerbsCli, UnavailableVulkanDeviceExitsThree) {
  // A device that is not there (or a build or machine without Vulkan): exit 3, nothing written.
  // tests/render/vulkan covers --backend vulkan rendering.
  testing::ScratchDir dir;
  const std::string cap = TinyCapture().string();
  CliResult r = RunCli("render " + cap + " " + cap + "/gt --out " + (dir / "r").string() +
                           " --backend vulkan --device no-such-device", dir);
  EXPECT_EQ(r.exit_code, 3);
  EXPECT_NE(r.err.find("--backend vulkan"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir / "r"));
}

TEST(VerbsCli, MissingInputsExitWithTwoAndNameTheFile) {
  testing::ScratchDir dir;
  const std::string cap = TinyCapture().string();
  CliResult r = RunCli("render " + (dir / "none").string() + " " + cap + "/gt --out " + (dir / "r").string(), dir);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("none"), std::string::npos) << r.err;
  r = RunCli("render " + cap + " " + (dir / "nofit").string() + " --out " + (dir / "r").string(), dir);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("params.exr"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir / "r"));
  r = RunCli("validate " + cap + " " + (dir / "norenders").string() + " --out " + (dir / "v").string(), dir);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("norenders"), std::string::npos) << r.err;
  fs::create_directories(dir / "empty_renders");
  r = RunCli("validate " + cap + " " + (dir / "empty_renders").string() + " --out " + (dir / "v").string(), dir);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("empty_renders/images/"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir / "v"));
  r = RunCli("import-diligent " + (dir / "noobject").string() + " --out " + (dir / "c").string(), dir);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("noobject"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir / "c"));
}

TEST(VerbsCli, RenderThenValidatePrintsTheNoiseBound) {
  testing::ScratchDir dir;
  const std::string cap = TinyCapture().string();
  const std::string renders = (dir / "renders").string(), report = (dir / "report").string();
  CliResult r = RunCli("render --quiet " + cap + " " + cap + "/gt --out " + renders, dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("on the cpu"), std::string::npos) << r.out;
  EXPECT_TRUE(fs::is_regular_file(dir / "renders/render_report.json"));
  EXPECT_TRUE(fs::is_directory(dir / "renders/aux"));
  // A non-empty output is refused without --overwrite, and kept.
  r = RunCli("render --quiet " + cap + " " + cap + "/gt --out " + renders, dir);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("not empty"), std::string::npos) << r.err;
  EXPECT_TRUE(fs::is_regular_file(dir / "renders/render_report.json"));
  r = RunCli("render --quiet " + cap + " " + cap + "/gt/params.exr --out " + renders + " --overwrite", dir);
  EXPECT_EQ(r.exit_code, 0) << r.err;

  r = RunCli("validate --quiet " + cap + " " + renders + " --out " + report, dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("noise bound PSNR"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("LS-scaled"), std::string::npos) << r.out;
  const auto metrics = nlohmann::json::parse(ReadTextFile(dir / "report/metrics.json").value());
  EXPECT_EQ(metrics["split"], "holdout");
  EXPECT_TRUE(fs::is_regular_file(dir / "report/report.html"));
  // No staging leftovers beside the outputs.
  for (const auto& e : fs::directory_iterator(dir.path())) {
    EXPECT_EQ(e.path().filename().string().find(".tmp"), std::string::npos) << e.path();
  }
}

// `reflcap run` scores each holdout image while its re-render is in memory
// (validate::StreamingValidation); the report must be the one `reflcap validate` makes from the
// written files: the same metrics (every number, every worst pixel) and the same figures.
TEST(VerbsCli, RunScoresWhileRenderingAsValidateDoesFromTheFiles) {
  testing::ScratchDir dir;
  const std::string cap = TinyCapture().string();
  const fs::path run = dir / "run";
  CliResult r = RunCli("run --quiet " + cap + " --out " + run.string(), dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  r = RunCli("validate --quiet " + cap + " " + (run / "renders").string() + " --out " +
                 (dir / "again").string() + " --fit " + (run / "fit").string() + " --samples " +
                 (run / "samples").string(),
             dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  auto streamed = nlohmann::json::parse(ReadTextFile(run / "report/metrics.json").value());
  auto from_files = nlohmann::json::parse(ReadTextFile(dir / "again/metrics.json").value());
  const size_t images = streamed["images"].size();
  ASSERT_GT(images, 0u);
  EXPECT_EQ(streamed["timings"]["images_scored_while_rendering"].get<size_t>(), images);
  EXPECT_EQ(from_files["timings"]["images_scored_while_rendering"].get<size_t>(), 0u);
  streamed.erase("timings");
  from_files.erase("timings");
  EXPECT_EQ(streamed, from_files) << "metrics differ";
  size_t figures = 0;
  for (const auto& e : fs::directory_iterator(run / "report/figures")) {
    const fs::path other = dir / "again/figures" / e.path().filename();
    ASSERT_TRUE(fs::is_regular_file(other)) << other;
    EXPECT_EQ(ReadTextFile(e.path()).value(), ReadTextFile(other).value()) << e.path();
    ++figures;
  }
  EXPECT_GT(figures, 0u);
}

// The auto settings' evidence reads train photographs ahead of their renders
// (render::EvidencePhotographs); one it cannot read is left out with a warning naming it, and
// the render (of the holdout split, which does not need it) goes on.
TEST(VerbsCli, RenderLeavesOutAnEvidencePhotographItCannotRead) {
  testing::ScratchDir dir;
  const fs::path cap = dir / "cap";
  fs::copy(TinyCapture(), cap, fs::copy_options::recursive);
  const auto capture = nlohmann::json::parse(ReadTextFile(cap / "capture.json").value());
  std::string first_train;  // every evidence takes the first train photograph
  for (const auto& image : capture["images"]) {
    if (image["split"] == "train") {
      first_train = image["file"];
      break;
    }
  }
  ASSERT_FALSE(first_train.empty());
  testing::WriteText(cap / first_train, "not an OpenEXR file");
  CliResult r = RunCli("render " + cap.string() + " " + (cap / "gt").string() + " --out " +
                           (dir / "renders").string(),
                       dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.err.find("pixel-model evidence leaves out"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("interreflection evidence leaves out"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find(first_train), std::string::npos) << r.err;
  const auto report =
      nlohmann::json::parse(ReadTextFile(dir / "renders/render_report.json").value());
  EXPECT_EQ(report["pixel_model"]["evidence"]["skipped_images"].get<int>(), 1);
  EXPECT_EQ(report["indirect"]["evidence"]["skipped_images"].get<int>(), 1);
  EXPECT_GT(report["pixel_model"]["evidence"]["images"].get<int>(), 0);
}

TEST(VerbsCli, ValidateNamesTheTexelBehindEachWorstPixel) {
  // resample -> fit -> render (one ray per pixel, direct light only) -> validate with the fit and
  // the store: every worst pixel names its texel, the model it ended with and its train samples.
  // The texel is checked physically: brightening that one texel's albedo in the fit changes the
  // pixel in a re-render, and no more than a few other pixels of the image.
  testing::ScratchDir dir;
  const std::string cap = TinyCapture().string();
  const fs::path samples = dir / "samples", fit = dir / "fit", renders = dir / "renders";
  ASSERT_EQ(RunCli("resample --quiet " + cap + " --out " + samples.string(), dir).exit_code, 0);
  ASSERT_EQ(RunCli("fit --quiet " + samples.string() + " --out " + fit.string(), dir).exit_code, 0);
  const std::string render_args = " --supersample 1 --indirect off --quiet";
  ASSERT_EQ(RunCli("render " + cap + " " + fit.string() + " --out " + renders.string() + render_args,
                   dir).exit_code, 0);
  CliResult r = RunCli("validate --quiet " + cap + " " + renders.string() + " --out " +
                           (dir / "report").string() + " --fit " + fit.string() + " --samples " +
                           samples.string(), dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const auto metrics = nlohmann::json::parse(ReadTextFile(dir / "report/metrics.json").value());
  const nlohmann::json& worst = metrics["overall"]["worst_pixels"];
  ASSERT_FALSE(worst.empty());
  auto store = SampleStoreReader::Open(samples);
  ASSERT_TRUE(store.ok()) << store.status().ToString();
  const SampleStoreInfo& info = (*store)->info();
  int checked = 0;
  std::string file;
  int x = -1, y = -1;
  int64_t texel = -1;
  for (const auto& w : worst) {
    const nlohmann::json& t = w["texel"];
    ASSERT_TRUE(t.is_object()) << w.dump();
    if (t["index"].is_null()) continue;  // a pixel whose centre ray misses (a silhouette)
    const int64_t index = t["index"].get<int64_t>();
    ASSERT_GE(index, 0);
    ASSERT_LT(index, int64_t(info.texels));
    EXPECT_TRUE(t["model_name"].is_string()) << t.dump();
    EXPECT_TRUE(t["status_name"].is_string()) << t.dump();
    // The train samples, as the store holds them.
    const uint32_t chunk_index = uint32_t(uint64_t(index) / info.chunk_texels);
    const TexelSampleChunk chunk = (*store)->ReadChunk(chunk_index).value();
    const uint32_t i = uint32_t(uint64_t(index) - chunk.first_texel);
    EXPECT_EQ(t["train_samples"].get<int64_t>(), int64_t(chunk.SampleCount(i)));
    float brightest = 0;
    for (uint64_t k = 0; k < chunk.SampleCount(i); ++k) {
      brightest = std::max(brightest, chunk.SamplesOf(i)[k].value[1]);
    }
    EXPECT_EQ(t["brightest_train"][1].get<float>(), brightest);
    ++checked;
    if (texel < 0 && w["render"][1].get<double>() > 0) {  // lit: the texel's albedo shows
      file = w["file"].get<std::string>();
      x = w["x"].get<int>(), y = w["y"].get<int>();
      texel = index;
    }
  }
  ASSERT_GT(checked, 0);
  ASSERT_GE(texel, 0) << "no lit worst pixel";
  // The fit with that texel's albedo raised by 0.5 in every channel, rendered again.
  std::vector<std::string> names;
  Image params = ReadExrChannels(fit / "params.exr", &names).value();
  const uint32_t atlas_pixel = info.pixel_of_texel[size_t(texel)];
  for (size_t c = 0; c < names.size(); ++c) {
    if (names[c].rfind("rho_d.", 0) == 0) params.data[atlas_pixel * params.channels + c] += 0.5f;
  }
  fs::create_directories(dir / "brighter");
  ASSERT_TRUE(WriteExrChannels(dir / "brighter/params.exr", params, names).ok());
  ASSERT_EQ(RunCli("render " + cap + " " + (dir / "brighter").string() + " --out " +
                       (dir / "renders2").string() + render_args, dir).exit_code, 0);
  const fs::path exr = fs::path(file).replace_extension(".exr");
  const Image before = ReadExrRgb(renders / exr).value(), after = ReadExrRgb(dir / "renders2" / exr).value();
  // The renders are deterministic: every pixel not showing the texel is bit-identical, and the
  // pixel that does gains 0.5 / pi of its irradiance (well above float noise at 1e-3).
  EXPECT_GT(after.at(x, y, 1) - before.at(x, y, 1), 1e-3f) << file << " " << x << "," << y;
  int changed = 0;
  for (size_t k = 0; k < before.data.size(); k += 3) changed += after.data[k + 1] != before.data[k + 1];
  // One texel covers about a pixel of these 48-px views (3,000 texels, the object a third of
  // the frame); a 3x3 neighbourhood bounds it.
  EXPECT_LE(changed, 9);
}

TEST(VerbsCli, ValidateNamesTheNormalMapTexelOfEachWorstPixel) {
  // A normal-map capture's texel is its camera pixel: the worst pixels' texels must be the
  // masked pixels' row-major indices (BuildNormalMapAtlas's order, counted here independently).
  // The held-out photographs (every 2nd) read brighter than the train ones, so pixels err.
  testing::ScratchDir dir;
  const fs::path obj = dir / "disc";
  WriteDisc(obj, [](int i, int x, int y) { return (i % 2 ? 0.4f : 0.6f) + 0.02f * float(x + y); });
  const std::string cap = (dir / "capture").string();
  ASSERT_EQ(RunCli("import-diligent --quiet " + obj.string() + " --out " + cap + " --holdout-every 2",
                   dir).exit_code, 0);
  CliResult r = RunCli("run --quiet " + cap + " --out " + (dir / "run").string(), dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const auto metrics = nlohmann::json::parse(ReadTextFile(dir / "run/report/metrics.json").value());
  const nlohmann::json& worst = metrics["overall"]["worst_pixels"];
  ASSERT_FALSE(worst.empty());
  for (const auto& w : worst) {
    const int x = w["x"].get<int>(), y = w["y"].get<int>();
    ASSERT_TRUE(InDisc(x, y)) << x << "," << y;
    int64_t index = 0;
    for (int k = 0; k < y * 9 + x; ++k) index += InDisc(k % 9, k / 9);
    EXPECT_EQ(w["texel"]["index"].get<int64_t>(), index) << x << "," << y;
    EXPECT_EQ(w["texel"]["train_samples"].get<int64_t>(), 2) << "one per train photograph";
  }
}

TEST(VerbsCli, RenderShardsMergeIntoTheSameFiles) {
  testing::ScratchDir dir;
  const std::string cap = TinyCapture().string(), fit = cap + "/gt";
  CliResult r = RunCli("render --quiet " + cap + " " + fit + " --out " + (dir / "whole").string(), dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  std::string parts;
  for (int i : {1, 2, 0}) {
    const std::string part = (dir / ("part" + std::to_string(i))).string();
    r = RunCli("render --quiet " + cap + " " + fit + " --out " + part + " --shard " + std::to_string(i) + "/3", dir);
    ASSERT_EQ(r.exit_code, 0) << r.err;
    parts += " " + part;
  }
  // A part of another render (other options) and a missing shard are refused, nothing written.
  r = RunCli("render --quiet " + cap + " " + fit + " --out " + (dir / "other").string() +
                 " --shard 2/3 --no-shadows", dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const fs::path out = dir / "merged";
  r = RunCli("merge " + (dir / "part0").string() + " " + (dir / "part1").string() + " " +
                 (dir / "other").string() + " --out " + out.string(), dir);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("shard.identity.cast_shadows"), std::string::npos) << r.err;
  r = RunCli("merge " + (dir / "part0").string() + " " + (dir / "part1").string() + " --out " + out.string(), dir);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("shard 2 is missing"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(out));

  r = RunCli("merge" + parts + " --out " + out.string(), dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  int compared = 0;
  for (const auto& e : fs::recursive_directory_iterator(dir / "whole")) {
    if (!e.is_regular_file() || e.path().filename() == "render_report.json") continue;
    const fs::path rel = fs::relative(e.path(), dir / "whole");
    EXPECT_EQ(ReadTextFile(e.path()).value(), ReadTextFile(out / rel).value()) << rel;
    ++compared;
  }
  const nlohmann::json whole = nlohmann::json::parse(ReadTextFile(dir / "whole/render_report.json").value());
  const nlohmann::json merged = nlohmann::json::parse(ReadTextFile(out / "render_report.json").value());
  ASSERT_EQ(merged["images"].size(), whole["images"].size());
  EXPECT_EQ(compared, 3 * int(whole["images"].size()));  // image, mask and aux of each
  for (size_t i = 0; i < whole["images"].size(); ++i) {
    EXPECT_EQ(merged["images"][i]["file"], whole["images"][i]["file"]);
  }
  // validate reads the merged folder like a single render.
  r = RunCli("validate --quiet " + cap + " " + out.string() + " --out " + (dir / "report").string(), dir);
  EXPECT_EQ(r.exit_code, 0) << r.err;
}

TEST(VerbsCli, ImportDiligentThenInfo) {
  testing::ScratchDir dir;
  const fs::path obj = dir / "disc";
  WriteDisc(obj, [](int, int, int) { return 1.0f; });
  const std::string out = (dir / "capture").string();
  CliResult r = RunCli("import-diligent --quiet " + obj.string() + " --out " + out + " --holdout-every 2", dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("train 2, holdout 2"), std::string::npos) << r.out;
  r = RunCli("info " + out, dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("orthographic"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("normal map"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("lights      4 (0 point, 4 directional)"), std::string::npos) << r.out;
}

}  // namespace
}  // namespace reflcap
