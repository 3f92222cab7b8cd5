// End-to-end checks of the `reflcap` executable: exit codes, messages naming file and field for
// every malformed-input case, refusal to overwrite, and a synth → info round trip.
#include <gtest/gtest.h>

#include <fstream>
#include <sstream>

#include <nlohmann/json.hpp>

#include "engine/core/atomic_file.h"
#include "tests/support/test_support.h"

namespace reflcap {
namespace {
namespace fs = std::filesystem;
using Json = nlohmann::json;

using testing::CliResult;

CliResult RunCli(const std::string& args, const testing::ScratchDir& dir) {
  return testing::RunCommand(REFLCAP_BINARY, args, dir);
}

// A tiny synthetic capture shared by the tests of this file (made once).
const fs::path& TinyCapture() {
  static const testing::ScratchDir* dir = &reflcap::testing::NewProcessScratchDir();
  static const fs::path capture = [] {
    testing::ScratchDir logs;
    const fs::path out = *dir / "tiny";
    CliResult r = RunCli("synth --quiet --out " + out.string() +
                             " --texels 3000 --image-size 48 --cameras 2 --lights 2 --steps 4",
                         logs);
    REFLCAP_CHECK(r.exit_code == 0) << r.err;
    return out;
  }();
  return capture;
}

TEST(Cli, UsageErrorsExitWithOne) {
  testing::ScratchDir dir;
  EXPECT_EQ(RunCli("", dir).exit_code, 1);
  EXPECT_EQ(RunCli("frobnicate", dir).exit_code, 1);
  EXPECT_EQ(RunCli("info", dir).exit_code, 1);
  CliResult r = RunCli("synth --out x --noise banana", dir);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("--noise"), std::string::npos) << r.err;
  EXPECT_EQ(RunCli("synth --out x --preset huge", dir).exit_code, 1);
}

TEST(Cli, EveryVerbHasHelp) {
  testing::ScratchDir dir;
  for (const char* verb : {"info", "synth", "demo"}) {
    CliResult r = RunCli(std::string(verb) + " --help", dir);
    EXPECT_EQ(r.exit_code, 0) << verb;
    EXPECT_NE(r.out.find(std::string("usage: reflcap ") + verb), std::string::npos) << r.out;
  }
}

TEST(Cli, SynthThenInfoSummarisesTheCapture) {
  testing::ScratchDir dir;
  CliResult r = RunCli("info " + TinyCapture().string(), dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("images      16 (train"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("4 steps"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("texels at 512x512"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("ground truth yes"), std::string::npos) << r.out;
  // No staging leftovers beside the output.
  for (const auto& e : fs::directory_iterator(TinyCapture().parent_path())) {
    EXPECT_EQ(e.path().filename().string().find(".tmp"), std::string::npos) << e.path();
  }
}

TEST(Cli, SynthRefusesANonEmptyFolderAndKeepsItsContents) {
  testing::ScratchDir dir;
  testing::WriteText(dir / "mine/notes.txt", "precious");
  CliResult r = RunCli("synth --quiet --out " + (dir / "mine").string() + " --texels 500 "
                       "--image-size 16 --cameras 1 --lights 1 --steps 1", dir);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("not empty"), std::string::npos) << r.err;
  EXPECT_EQ(ReadTextFile(dir / "mine/notes.txt").value(), "precious");
}

// Copies the tiny capture, applies `edit` to its JSON (and files), runs info, and checks exit 2
// and a message naming capture.json and `field`.
void ExpectInfoError(const std::function<void(Json&, const fs::path&)>& edit,
                     const std::string& field) {
  testing::ScratchDir dir;
  const fs::path copy = dir / "capture";
  fs::copy(TinyCapture(), copy, fs::copy_options::recursive);
  Json json = Json::parse(ReadTextFile(copy / "capture.json").value());
  edit(json, copy);
  testing::WriteText(copy / "capture.json", json.dump(1));
  CliResult r = RunCli("info " + (copy / "capture.json").string(), dir);
  EXPECT_EQ(r.exit_code, 2) << field << ": " << r.err;
  EXPECT_NE(r.err.find("capture.json"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find(field), std::string::npos) << "expected " << field << " in: " << r.err;
}

TEST(Cli, InfoReportsEveryMalformedInputWithFileAndField) {
  ExpectInfoError([](Json& j, const fs::path&) { j["format"] = "capture/3"; }, "format");
  ExpectInfoError([](Json& j, const fs::path&) { j["images"][1]["file"] = "images/none.exr"; },
                  "images[1].file");
  ExpectInfoError([](Json&, const fs::path& d) { fs::resize_file(d / "images/0002.exr", 100); },
                  "images[2].file");
  ExpectInfoError([](Json& j, const fs::path&) { j["mesh"] = "missing.obj"; }, "mesh");
  ExpectInfoError([](Json&, const fs::path& d) { testing::WriteText(d / "mesh.obj", "v 1 2\n"); },
                  "mesh");
  ExpectInfoError([](Json& j, const fs::path&) { j["images"][0]["camera"] = "camX"; },
                  "images[0].camera");
  ExpectInfoError([](Json& j, const fs::path&) { j["images"][0]["light"] = "LX"; },
                  "images[0].light");
  ExpectInfoError([](Json& j, const fs::path&) { j["lights"][1]["id"] = "L0"; }, "lights[1].id");
  ExpectInfoError([](Json& j, const fs::path&) { j["cameras"][1]["id"] = "cam0"; },
                  "cameras[1].id");
  ExpectInfoError([](Json& j, const fs::path&) { j["turntable"]["axis"] = {0, 0.5, 0.5}; },
                  "turntable.axis");
  ExpectInfoError([](Json& j, const fs::path&) { j["images"][3]["exposure_s"] = -0.5; },
                  "images[3].exposure_s");
  ExpectInfoError([](Json& j, const fs::path&) { j["cameras"][0]["width"] = 49; }, "images[0].file");
  ExpectInfoError([](Json& j, const fs::path&) { j["cameras"][0]["K"][1][1] = 0; }, "cameras[0].K");
  ExpectInfoError([](Json& j, const fs::path&) { j["images"] = Json::array(); }, "images");
}

TEST(Cli, InfoReportsJsonSyntaxErrorsWithLineAndColumn) {
  testing::ScratchDir dir;
  testing::WriteText(dir / "capture.json", "{\n \"format\": \"capture/1\",\n \"cameras\": [,]\n}\n");
  CliResult r = RunCli("info " + (dir / "capture.json").string(), dir);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("capture.json:3:"), std::string::npos) << r.err;
}

}  // namespace
}  // namespace reflcap
