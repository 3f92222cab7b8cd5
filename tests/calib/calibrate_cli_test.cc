// `reflcap calibrate` through its command line: usage errors exit 1; bad input exits 2 with the
// file and the field named and leaves no output behind; a rendered session calibrates end to end,
// and with --capture the output is a capture that `reflcap info` accepts.
#include <gtest/gtest.h>

#include <fstream>

#include <nlohmann/json.hpp>

#include "engine/core/atomic_file.h"
#include "tests/calib/synthetic_session.h"
#include "tests/support/test_support.h"

namespace reflcap {
namespace {

namespace fs = std::filesystem;
using Json = nlohmann::json;
using reflcap::testing::CliResult;
using reflcap::testing::ScratchDir;

CliResult RunCli(const std::string& args, const ScratchDir& dir) {
  return reflcap::testing::RunCommand(REFLCAP_BINARY, args, dir);
}

// One rendered session (2 cameras x 4 angles, 4 board photos per camera) shared by the tests.
const fs::path& Session() {
  static const ScratchDir* dir = &reflcap::testing::NewProcessScratchDir();
  static const fs::path path = [] {
    calib::testing::SyntheticRig rig = calib::testing::MakeRig(2, 4);
    calib::testing::SessionOptions o;
    o.board_photos_per_camera = 4;
    return calib::testing::WriteSession(&rig, dir->path(), o);
  }();
  return path;
}

// A copy of the session's calib.json with `mutate` applied, written into `dir` (photo paths made
// absolute so that they still resolve).
fs::path Mutated(const ScratchDir& dir, const std::function<void(Json&)>& mutate) {
  std::ifstream in(Session());
  Json j = Json::parse(in);
  const fs::path folder = Session().parent_path();
  for (const char* list : {"images", "intrinsics_images"}) {
    for (Json& im : j[list]) im["file"] = (folder / im["file"].get<std::string>()).string();
  }
  mutate(j);
  const fs::path out = dir / "calib.json";
  reflcap::testing::WriteText(out, j.dump());
  return out;
}

bool Empty(const fs::path& dir) {
  return !fs::exists(dir) || fs::is_empty(dir);
}

TEST(CalibrateCli, UsageErrorsExitWithOne) {
  ScratchDir dir;
  EXPECT_EQ(RunCli("calibrate", dir).exit_code, 1);
  EXPECT_EQ(RunCli("calibrate rig x.json --out y.json", dir).exit_code, 1);
  EXPECT_EQ(RunCli("calibrate turntable x.json", dir).exit_code, 1);  // no --out
  EXPECT_EQ(RunCli("calibrate turntable x.json --out y.json --min-cos 2", dir).exit_code, 1);
  EXPECT_EQ(RunCli("calibrate turntable x.json --out y.json --intrinsics-params f", dir).exit_code, 1);
  EXPECT_EQ(RunCli("calibrate intrinsics x.json --out y.json --intrinsics-params fx,q", dir).exit_code, 1);
  const CliResult refiner = RunCli("calibrate intrinsics x.json --out y.json --corner-refiner banana", dir);
  EXPECT_EQ(refiner.exit_code, 1);
  EXPECT_NE(refiner.err.find("--corner-refiner"), std::string::npos) << refiner.err;
  const CliResult help = RunCli("calibrate turntable --help", dir);
  EXPECT_EQ(help.exit_code, 0);
  EXPECT_NE(help.out.find("--refine-intrinsics"), std::string::npos);
  EXPECT_EQ(RunCli("calibrate intrinsics --help", dir).exit_code, 0);
}

TEST(CalibrateCli, BadInputExitsWithTwoNamingFileAndFieldAndWritesNothing) {
  struct Case {
    std::string what;
    std::string verb;
    std::function<void(Json&)> mutate;
    std::string expected;
  };
  const std::vector<Case> cases = {
      {"missing photo", "turntable", [](Json& j) { j["images"][2]["file"] = "/nonexistent/photo.png"; },
       "images[2].file"},
      {"missing board photo", "intrinsics",
       [](Json& j) { j["intrinsics_images"][1]["file"] = "/nonexistent/b.png"; }, "intrinsics_images[1].file"},
      {"inconsistent angle", "turntable", [](Json& j) { j["images"][1]["turntable_deg"] = 45; },
       "images[1].turntable_deg: 45 is not one of turntable.angles_deg"},
      {"one angle", "turntable",
       [](Json& j) {
         Json kept = Json::array();
         for (const Json& im : j["images"]) {
           if (im["turntable_deg"].get<double>() == 0) kept.push_back(im);
         }
         j["images"] = kept;
       },
       "images: every photo was taken at turntable angle 0"},
      {"board never found", "intrinsics",
       [](Json& j) {
         // A different board: its grid is in none of the photos.
         j["intrinsics_board"]["squares"] = {7, 4};
         j["intrinsics_board"]["inner_corners"] = {6, 3};
       },
       "intrinsics_images: camera \"cam0\": the board was found in 0 of its 4 photos"},
      {"no intrinsics", "turntable",
       [](Json& j) {
         j["cameras"][1].erase("K");
         j["cameras"][1].erase("dist");
       },
       "cameras[1].K: missing"},
      {"bad field", "turntable", [](Json& j) { j["cuboid"]["faces"][2]["square_m"] = -1; },
       "cuboid.faces[2].square_m: must be positive"},
  };
  for (const Case& c : cases) {
    ScratchDir dir;
    const fs::path calib = Mutated(dir, c.mutate);
    const fs::path out = dir / "out" / "result.json";
    fs::create_directories(out.parent_path());
    const CliResult r = RunCli(StrCat("calibrate ", c.verb, " ", calib.string(), " --out ", out.string()), dir);
    EXPECT_EQ(r.exit_code, 2) << c.what << ": " << r.err;
    EXPECT_NE(r.err.find(calib.string()), std::string::npos) << c.what << ": " << r.err;
    EXPECT_NE(r.err.find(c.expected), std::string::npos) << c.what << ": " << r.err;
    EXPECT_TRUE(Empty(dir / "out")) << c.what << ": left output behind";
  }
}

TEST(CalibrateCli, CalibratesARenderedSessionEndToEnd) {
  ScratchDir dir;
  const fs::path intrinsics = dir / "intrinsics.json";
  CliResult r = RunCli(StrCat("calibrate intrinsics --quiet ", Session().string(), " --out ", intrinsics.string()), dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_TRUE(fs::exists(dir / "intrinsics_report" / "index.html"));
  EXPECT_TRUE(fs::exists(dir / "intrinsics_report" / "residuals_cam0.png"));

  const fs::path rig = dir / "rig.json";
  r = RunCli(StrCat("calibrate turntable --quiet ", Session().string(), " --out ", rig.string(), " --intrinsics ",
                    intrinsics.string(), " --refine-intrinsics --angle-offsets"),
             dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("against ground truth"), std::string::npos) << r.out;
  std::ifstream in(rig);
  const Json j = Json::parse(in);
  EXPECT_EQ(j["format"], "capture/1");
  EXPECT_EQ(j["cameras"].size(), 2u);
  EXPECT_EQ(j["turntable"]["axis"].size(), 3u);
  EXPECT_LT(j["calibration"]["reprojection"]["rms_px"].get<double>(), 0.1);
  EXPECT_TRUE(j["calibration"].contains("ground_truth_comparison"));
  for (const char* f : {"index.html", "report.json", "residuals_cam0.png", "residuals_cam1.png"}) {
    EXPECT_TRUE(fs::exists(dir / "rig_report" / f)) << f;
  }
  // The skeleton: `info` checks and summarises it as a rig (exit 0); `resample` refuses it (exit
  // 2), saying what it is.
  r = RunCli("info " + rig.string(), dir);
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("skeleton"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("cameras     2"), std::string::npos) << r.out;
  r = RunCli("resample " + rig.string() + " --out " + (dir / "samples").string(), dir);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("rig skeleton"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir / "samples"));
  // An existing output is kept unless --overwrite.
  r = RunCli(StrCat("calibrate turntable ", Session().string(), " --out ", rig.string()), dir);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("exists"), std::string::npos) << r.err;
}

TEST(CalibrateCli, WithACaptureTheOutputIsACaptureThatInfoAccepts) {
  ScratchDir dir;
  // A capture of the same two cameras: a triangle mesh and one photo per camera.
  const fs::path capture = dir / "capture";
  fs::create_directories(capture / "images");
  reflcap::testing::WriteText(capture / "mesh.obj",
                              "v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n");
  const fs::path photo = Session().parent_path() / "images" / "cam0_000.png";
  fs::copy_file(photo, capture / "images" / "0.png");
  fs::copy_file(photo, capture / "images" / "1.png");
  reflcap::testing::WriteText(capture / "capture.json", R"({"format": "capture/1", "mesh": "mesh.obj",
    "cameras": [
      {"id": "cam0", "width": 400, "height": 400, "K": [[900,0,200],[0,900,200],[0,0,1]],
       "cam_from_world": [[1,0,0,0],[0,1,0,0],[0,0,1,1],[0,0,0,1]]},
      {"id": "cam1", "width": 400, "height": 400, "K": [[900,0,200],[0,900,200],[0,0,1]],
       "cam_from_world": [[1,0,0,0],[0,1,0,0],[0,0,1,1],[0,0,0,1]]}],
    "lights": [{"id": "L0", "type": "point", "position": [0, 0, 1], "intensity": [1, 1, 1]}],
    "turntable": {"axis": [0, 0, 1], "point": [0, 0, 0]},
    "images": [{"file": "images/0.png", "camera": "cam0", "light": "L0", "turntable_deg": 0},
               {"file": "images/1.png", "camera": "cam1", "light": "L0", "turntable_deg": 90}]})");
  fs::create_directories(dir / "out");
  const fs::path out = dir / "out" / "capture.json";
  CliResult r = RunCli(StrCat("calibrate turntable --quiet ", Session().string(), " --out ", out.string(),
                              " --capture ", (capture / "capture.json").string()),
                       dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  r = RunCli("info " + out.string(), dir);
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("cameras     2"), std::string::npos) << r.out;
}

}  // namespace
}  // namespace reflcap
