// `reflcap scan` through its command line: a successful run on the synthetic sphere, and bad
// input (missing pattern image, wrong size, a projector that lights nothing, an angle list that
// does not match) -> exit 2 naming the file and field, with no output folder left behind.
#include <fstream>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "engine/core/atomic_file.h"
#include "engine/image/png_io.h"
#include "tests/acquire/scan/synthetic_scan.h"
#include "tests/support/test_support.h"

namespace reflcap::scan {
namespace {

namespace fs = std::filesystem;
using reflcap::testing::CliResult;
using reflcap::testing::RunCommand;
using reflcap::testing::ScratchDir;
using Json = nlohmann::json;

struct Fixture {
  ScratchDir dir;
  testing::SyntheticScan scan;
  Fixture() {
    testing::SyntheticScanOptions o;
    o.angles_deg = {0, 180};
    scan = testing::WriteSyntheticScan(dir / "scan", o);
  }
  CliResult Run(const std::string& args) { return RunCommand(REFLCAP_BINARY, "scan " + args, dir); }
  // scan.json rewritten by `edit` (image paths made absolute so the copy may live anywhere).
  fs::path Edited(const std::function<void(Json*)>& edit) {
    Json j = Json::parse(*ReadTextFile(scan.json));
    for (auto& im : j["images"]) im["file"] = (scan.json.parent_path() / im["file"].get<std::string>()).string();
    j["mesh"] = (scan.json.parent_path() / "sphere.obj").string();
    edit(&j);
    const fs::path path = dir / "edited.json";
    reflcap::testing::WriteText(path, j.dump());
    return path;
  }
};

Fixture& Shared() {
  static Fixture* f = [] {
    auto* made = new Fixture();
    // Removed after the last test: ctest runs each test in a process of its own.
    reflcap::testing::ReleaseBeforeExit([made] { delete made; });
    return made;
  }();
  return *f;
}

TEST(ScanCli, WritesTheMeshAndReport) {
  Fixture& f = Shared();
  const fs::path out = f.dir / "out_ok";
  CliResult r = f.Run(f.scan.json.string() + " --out " + out.string() +
                      " --no-clouds --distance-samples 5000 --target-triangles 5000");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  for (const char* file : {"mesh.obj", "mesh.gltf", "scan_report.json", "preview.png", "atlas.png"}) {
    EXPECT_TRUE(fs::exists(out / file)) << file;
  }
  EXPECT_FALSE(fs::exists(out / "points_000.ply"));
  EXPECT_NE(r.out.find("vs reference"), std::string::npos) << r.out;
  // An existing output is refused without --overwrite.
  r = f.Run(f.scan.json.string() + " --out " + out.string());
  EXPECT_EQ(r.exit_code, 2) << r.err;
}

TEST(ScanCli, UsageErrorsExitOne) {
  Fixture& f = Shared();
  EXPECT_EQ(f.Run(f.scan.json.string()).exit_code, 1);  // no --out
  EXPECT_EQ(f.Run(f.scan.json.string() + " --out x --atlas-res 3").exit_code, 1);
  EXPECT_EQ(f.Run("--help").exit_code, 0);
}

void ExpectBadInput(Fixture& f, const fs::path& json, const std::string& name, const std::string& expect) {
  const fs::path out = f.dir / ("out_" + name);
  const CliResult r = f.Run(json.string() + " --out " + out.string());
  EXPECT_EQ(r.exit_code, 2) << name << ": " << r.err;
  EXPECT_NE(r.err.find(expect), std::string::npos) << name << ": " << r.err;
  EXPECT_FALSE(fs::exists(out)) << name << ": output left behind";
  // Nothing half-written beside it either (staging folders are removed).
  for (const auto& entry : fs::directory_iterator(f.dir.path())) {
    EXPECT_EQ(entry.path().filename().string().find("out_" + name), std::string::npos) << entry.path();
  }
}

TEST(ScanCli, MissingPatternImageExitsTwoNamingTheFile) {
  Fixture& f = Shared();
  const fs::path json = f.Edited([&](Json* j) {
    (*j)["images"][7]["file"] = (f.scan.json.parent_path() / "images/000/not_there.png").string();
  });
  ExpectBadInput(f, json, "missing", "not_there.png");
}

TEST(ScanCli, WrongImageSizeExitsTwoNamingTheFile) {
  Fixture& f = Shared();
  const fs::path small = f.dir / "tiny.png";
  ASSERT_TRUE(WritePng(small, Image(8, 6, 1, 0.5f)).ok());
  const fs::path json = f.Edited([&](Json* j) { (*j)["images"][4]["file"] = small.string(); });
  ExpectBadInput(f, json, "size", "tiny.png");
}

TEST(ScanCli, AProjectorThatLightsNothingExitsTwo) {
  Fixture& f = Shared();
  // Angle 180's white photograph replaced by its black one.
  const fs::path json = f.Edited([&](Json* j) {
    std::string black;
    for (auto& im : (*j)["images"]) {
      if (im["turntable_deg"] == 180.0 && im["pattern"] == "black") black = im["file"];
    }
    for (auto& im : (*j)["images"]) {
      if (im["turntable_deg"] == 180.0 && im["pattern"] == "white") im["file"] = black;
    }
  });
  ExpectBadInput(f, json, "dark", "lights nothing at turntable 180");
}

TEST(ScanCli, AnAngleListThatDoesNotMatchExitsTwo) {
  Fixture& f = Shared();
  const fs::path json = f.Edited([](Json* j) { (*j)["turntable_angles_deg"] = {0.0, 90.0}; });
  ExpectBadInput(f, json, "angles", "turntable_deg: 180 is not one of turntable_angles_deg");
}

}  // namespace
}  // namespace reflcap::scan
