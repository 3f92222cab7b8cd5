// calib/1 reader: a valid file parses completely; every malformed field is reported with the file
// and the field's JSON path.
#include "calib/calib_file.h"

#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

namespace reflcap::calib {
namespace {

using Json = nlohmann::json;

Json ValidFile() {
  return Json::parse(R"({
    "format": "calib/1",
    "cameras": [
      {"id": "cam0", "width": 640, "height": 480,
       "K": [[1500, 0, 320], [0, 1500, 240], [0, 0, 1]], "dist": [-0.1, 0.05, 0, 0, 0]},
      {"id": "cam1", "width": 640, "height": 480}
    ],
    "turntable": {"angles_deg": [0, 90, 180, 270]},
    "images": [
      {"file": "images/a.png", "camera": "cam0", "turntable_deg": 0, "target": "cuboid"},
      {"file": "images/b.png", "camera": "cam0", "turntable_deg": 90},
      {"file": "images/c.png", "camera": "cam1", "turntable_deg": 270}
    ],
    "intrinsics_images": [{"file": "intrinsics/a.png", "camera": "cam1", "target": "intrinsics_board"}],
    "cuboid": {"faces": [
      {"name": "+x", "normal": [1, 0, 0], "u_axis": [0, 1, 0], "v_axis": [0, 0, -1],
       "squares": [5, 8], "inner_corners": [4, 7], "square_m": 0.012, "board_margin_m": [0.01, 0.012],
       "first_inner_corner_box": [0.05, -0.018, 0.096],
       "corners_box": [[0.05, -0.018, 0.096], [0.05, -0.006, 0.096], [0.05, 0.006, 0.096], [0.05, 0.018, 0.096],
                       [0.05, -0.018, 0.084], [0.05, -0.006, 0.084], [0.05, 0.006, 0.084], [0.05, 0.018, 0.084],
                       [0.05, -0.018, 0.072], [0.05, -0.006, 0.072], [0.05, 0.006, 0.072], [0.05, 0.018, 0.072],
                       [0.05, -0.018, 0.060], [0.05, -0.006, 0.060], [0.05, 0.006, 0.060], [0.05, 0.018, 0.060],
                       [0.05, -0.018, 0.048], [0.05, -0.006, 0.048], [0.05, 0.006, 0.048], [0.05, 0.018, 0.048],
                       [0.05, -0.018, 0.036], [0.05, -0.006, 0.036], [0.05, 0.006, 0.036], [0.05, 0.018, 0.036],
                       [0.05, -0.018, 0.024], [0.05, -0.006, 0.024], [0.05, 0.006, 0.024], [0.05, 0.018, 0.024]]},
      {"name": "+z", "normal": [0, 0, 1], "u_axis": [1, 0, 0], "v_axis": [0, -1, 0],
       "squares": [8, 6], "inner_corners": [7, 5], "square_m": 0.009,
       "first_inner_corner_box": [-0.027, 0.018, 0.12]}
    ]},
    "intrinsics_board": {"squares": [9, 6], "inner_corners": [8, 5], "square_m": 0.012, "margin_m": 0.01},
    "ground_truth": {
      "cam_from_world": {"cam0": [[1,0,0,0],[0,1,0,0],[0,0,1,1],[0,0,0,1]],
                         "cam1": [[1,0,0,0],[0,1,0,0],[0,0,1,2],[0,0,0,1]]},
      "turntable": {"axis": [0, 0, 1], "point": [0.001, 0, 0]}
    }
  })");
}

// The error message of parsing `j`; empty when it parses.
std::string ErrorOf(const Json& j) {
  auto file = ParseCalibFile(j.dump(), "session/calib.json");
  return file.ok() ? std::string() : file.status().message();
}

TEST(CalibFile, ParsesAValidSession) {
  auto file = ParseCalibFile(ValidFile().dump(), "session/calib.json");
  ASSERT_TRUE(file.ok()) << file.status().ToString();
  EXPECT_EQ(file->cameras.size(), 2u);
  EXPECT_TRUE(file->cameras[0].has_intrinsics);
  EXPECT_FALSE(file->cameras[1].has_intrinsics);
  EXPECT_DOUBLE_EQ(file->cameras[0].dist[0], -0.1);
  ASSERT_EQ(file->images.size(), 3u);
  EXPECT_EQ(file->images[1].angle, 1);
  EXPECT_EQ(file->images[2].camera, 1);
  EXPECT_EQ(file->images[2].angle, 3);
  ASSERT_EQ(file->faces.size(), 2u);
  EXPECT_EQ(file->faces[0].CornerCount(), 28);
  EXPECT_EQ(file->faces[0].Symmetry(), 1);
  EXPECT_EQ(file->faces[1].Symmetry(), 2);  // 8x6 squares: a 180-degree turn keeps the colours
  // Inner corner (3, 1) of +x by the corner rule.
  EXPECT_NEAR((file->faces[0].Corner(1 * 4 + 3) - Vec3d(0.05, 0.018, 0.084)).norm(), 0, 1e-12);
  EXPECT_NEAR(file->faces[0].margin_v_m, 0.012, 1e-12);
  ASSERT_TRUE(file->board.has_value());
  EXPECT_EQ(file->board->CornerCount(), 40);
  EXPECT_EQ(file->board->normal, -Vec3d::UnitZ());
  ASSERT_TRUE(file->ground_truth.has_value());
  EXPECT_TRUE(file->ground_truth->has_extrinsics);
  EXPECT_FALSE(file->ground_truth->has_intrinsics);
  EXPECT_EQ(file->Resolve("images/a.png"), std::filesystem::path("session/images/a.png"));
  EXPECT_TRUE(CheckCuboidSession(*file).ok());
  EXPECT_TRUE(CheckBoardSession(*file).ok());
}

TEST(CalibFile, ReportsEveryMalformedFieldWithFileAndPath) {
  struct Case {
    std::string what;
    std::function<void(Json&)> mutate;
    std::string expected;
  };
  const std::vector<Case> cases = {
      {"format", [](Json& j) { j["format"] = "capture/1"; }, "session/calib.json: format:"},
      {"version", [](Json& j) { j["format"] = "calib/2"; }, "format: unsupported major version"},
      {"no cameras", [](Json& j) { j.erase("cameras"); }, "cameras: missing"},
      {"width", [](Json& j) { j["cameras"][1]["width"] = -3; }, "cameras[1].width: must be a positive integer"},
      {"K", [](Json& j) { j["cameras"][0]["K"][0][0] = 0; }, "cameras[0].K: focal lengths"},
      {"dist", [](Json& j) { j["cameras"][0]["dist"] = {1, 2}; }, "cameras[0].dist:"},
      {"duplicate id", [](Json& j) { j["cameras"][1]["id"] = "cam0"; }, "cameras[1].id: duplicate"},
      {"unknown camera", [](Json& j) { j["images"][1]["camera"] = "cam9"; }, "images[1].camera: unknown camera id"},
      {"angle not listed", [](Json& j) { j["images"][2]["turntable_deg"] = 45; },
       "images[2].turntable_deg: 45 is not one of turntable.angles_deg"},
      {"same camera and angle", [](Json& j) { j["images"][1]["turntable_deg"] = 360; }, "images[1]: camera \"cam0\""},
      {"repeated angle", [](Json& j) { j["turntable"]["angles_deg"][3] = -360; }, "turntable.angles_deg[3]:"},
      {"wrong target", [](Json& j) { j["images"][0]["target"] = "board"; }, "images[0].target:"},
      {"photo listed twice", [](Json& j) { j["intrinsics_images"].push_back(j["intrinsics_images"][0]); },
       "intrinsics_images[1].file: \"intrinsics/a.png\" is listed twice"},
      {"inner corners", [](Json& j) { j["cuboid"]["faces"][1]["inner_corners"] = {7, 6}; },
       "cuboid.faces[1].inner_corners: must be squares - 1"},
      {"normal", [](Json& j) { j["cuboid"]["faces"][0]["normal"] = {-1, 0, 0}; }, "cuboid.faces[0].normal:"},
      {"not unit", [](Json& j) { j["cuboid"]["faces"][0]["u_axis"] = {0, 2, 0}; },
       "cuboid.faces[0].u_axis: must be a unit vector"},
      {"corner rule", [](Json& j) { j["cuboid"]["faces"][0]["corners_box"][5][2] = 0.1; },
       "cuboid.faces[0].corners_box[5]: does not follow the corner rule"},
      {"same grid", [](Json& j) {
         j["cuboid"]["faces"][1]["squares"] = {8, 5};
         j["cuboid"]["faces"][1]["inner_corners"] = {7, 4};
       }, "cuboid.faces[1].inner_corners: 7x4 is also face \"+x\"'s grid"},
      {"negative margin", [](Json& j) { j["cuboid"]["faces"][0]["board_margin_m"] = {0.01, -1}; },
       "cuboid.faces[0].board_margin_m:"},
      {"square size", [](Json& j) { j["intrinsics_board"]["square_m"] = 0; }, "intrinsics_board.square_m: must be positive"},
      {"truth rotation", [](Json& j) { j["ground_truth"]["cam_from_world"]["cam1"][0][0] = 2; },
       "ground_truth.cam_from_world.cam1: rotation part"},
      {"truth axis", [](Json& j) { j["ground_truth"]["turntable"]["axis"] = {0, 0, 3}; },
       "ground_truth.turntable.axis: must be a unit vector"},
  };
  for (const Case& c : cases) {
    Json j = ValidFile();
    c.mutate(j);
    const std::string error = ErrorOf(j);
    EXPECT_NE(error.find(c.expected), std::string::npos) << c.what << ": got \"" << error << "\"";
  }
}

TEST(CalibFile, NamesTheFieldOfANonFiniteNumberAndReportsSyntaxErrorsWithLine) {
  std::string text = ValidFile().dump(2);
  const std::string needle = "\"square_m\": 0.012";
  text.replace(text.find(needle), needle.size(), "\"square_m\": 1e999");
  auto file = ParseCalibFile(text, "c.json");
  ASSERT_FALSE(file.ok());
  EXPECT_NE(file.status().message().find("cuboid.faces[0].square_m: must be finite (got 1e999)"), std::string::npos)
      << file.status().message();
  auto broken = ParseCalibFile("{\n  \"format\": \"calib/1\",\n  \"cameras\": [\n}", "c.json");
  ASSERT_FALSE(broken.ok());
  EXPECT_NE(broken.status().message().find("c.json:4:"), std::string::npos) << broken.status().message();
}

TEST(CalibFile, SessionChecksNameWhatIsMissing) {
  Json one_angle = ValidFile();
  one_angle["images"] = Json::array({one_angle["images"][0]});
  auto file = ParseCalibFile(one_angle.dump(), "c.json");
  ASSERT_TRUE(file.ok());
  const Status s = CheckCuboidSession(*file);
  EXPECT_FALSE(s.ok());
  EXPECT_NE(s.message().find("c.json: images: every photo was taken at turntable angle 0"), std::string::npos)
      << s.message();

  Json no_board = ValidFile();
  no_board.erase("intrinsics_board");
  auto board_file = ParseCalibFile(no_board.dump(), "c.json");
  ASSERT_TRUE(board_file.ok());
  EXPECT_NE(CheckBoardSession(*board_file).message().find("intrinsics_board: missing"), std::string::npos);

  Json no_cuboid = ValidFile();
  no_cuboid.erase("cuboid");
  auto cuboid_file = ParseCalibFile(no_cuboid.dump(), "c.json");
  ASSERT_TRUE(cuboid_file.ok());
  EXPECT_NE(CheckCuboidSession(*cuboid_file).message().find("cuboid: missing"), std::string::npos);
}

TEST(CalibFile, MissingFileIsNotFound) {
  auto file = ReadCalibFile("/nonexistent/calib.json");
  ASSERT_FALSE(file.ok());
  EXPECT_EQ(file.status().code(), StatusCode::kNotFound);
  EXPECT_NE(file.status().message().find("/nonexistent/calib.json"), std::string::npos);
}

}  // namespace
}  // namespace reflcap::calib
