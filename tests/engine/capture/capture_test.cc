#include "engine/capture/capture.h"

#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <functional>
#include <limits>

#include <nlohmann/json.hpp>

#include "engine/core/atomic_file.h"
#include "engine/image/exr_io.h"
#include "engine/image/png_io.h"
#include "tests/engine/capture/raw_exr.h"
#include "tests/support/test_support.h"

namespace reflcap {
namespace {
namespace fs = std::filesystem;
using Json = nlohmann::json;

constexpr char kSquareObj[] =
    "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
    "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
    "vn 0 0 1\n"
    "f 1/1/1 2/2/1 3/3/1\nf 1/1/1 3/3/1 4/4/1\n";

// A valid two-camera, two-light, three-image capture on disk, as JSON that tests then break.
class CaptureFixture : public ::testing::Test {
 protected:
  void SetUp() override {
    testing::WriteText(dir_ / "mesh.obj", kSquareObj);
    fs::create_directories(dir_ / "images");
    for (int i = 0; i < 3; ++i) {
      ASSERT_TRUE(WriteExr(dir_ / ("images/" + std::to_string(i) + ".exr"), Image(8, 6, 3, 0.5f),
                           ExrPixelType::kHalf).ok());
    }
    json_ = Json::parse(R"({
      "format": "capture/1",
      "mesh": "mesh.obj",
      "cameras": [
        {"id": "cam0", "width": 8, "height": 6, "K": [[10,0,3.5],[0,10,2.5],[0,0,1]],
         "dist": [0.01,0,0,0,0],
         "cam_from_world": [[1,0,0,0],[0,-1,0,0],[0,0,-1,2],[0,0,0,1]]},
        {"id": "cam1", "width": 8, "height": 6, "K": [[12,0,3.5],[0,12,2.5],[0,0,1]],
         "dist": [0,0,0,0,0],
         "cam_from_world": [[1,0,0,0],[0,-1,0,0],[0,0,-1,3],[0,0,0,1]]}
      ],
      "lights": [
        {"id": "L0", "type": "point", "position": [0,0,2], "intensity": [1,1,1]},
        {"id": "L1", "type": "directional", "direction": [0,0.6,0.8], "intensity": [2,2,2]}
      ],
      "turntable": {"axis": [0,0,1], "point": [0,0,0]},
      "images": [
        {"file": "images/0.exr", "camera": "cam0", "light": "L0", "turntable_deg": 0,
         "exposure_s": 1, "split": "train"},
        {"file": "images/1.exr", "camera": "cam1", "light": "L1", "turntable_deg": 30,
         "exposure_s": 0.5, "split": "holdout", "saturation": 100},
        {"file": "images/2.exr", "camera": "cam0", "light": "L1", "turntable_deg": 60,
         "exposure_s": 2, "split": "train"}
      ],
      "ground_truth": {"note": "test", "values": [1, 2]}
    })");
  }

  // Writes json_ and reads it back, with files validated too.
  Status WriteAndValidate() {
    testing::WriteText(path(), json_.dump(2));
    auto capture = ReadCapture(path());
    if (!capture.ok()) return capture.status();
    return ValidateCaptureFiles(*capture, nullptr);
  }

  // Expects failure whose message names the capture file and every string in `needles`.
  void ExpectError(const std::vector<std::string>& needles) {
    Status s = WriteAndValidate();
    ASSERT_FALSE(s.ok()) << "expected an error mentioning " << needles[0];
    EXPECT_NE(s.message().find(path().string()), std::string::npos) << s.message();
    for (const auto& n : needles) EXPECT_NE(s.message().find(n), std::string::npos) << s.message();
    EXPECT_NE(ExitCodeFor(s), 0);
  }

  fs::path path() const { return dir_ / "capture.json"; }

  testing::ScratchDir dir_;
  Json json_;
};

TEST_F(CaptureFixture, ValidCaptureReadsAllFields) {
  ASSERT_TRUE(WriteAndValidate().ok()) << WriteAndValidate().ToString();
  auto c = ReadCapture(dir_.path());  // a folder resolves to its capture.json
  ASSERT_TRUE(c.ok()) << c.status().ToString();
  EXPECT_EQ(c->cameras.size(), 2u);
  EXPECT_DOUBLE_EQ(c->cameras[0].dist[0], 0.01);
  EXPECT_EQ(c->lights[1].type, LightType::kDirectional);
  EXPECT_EQ(c->images[1].camera, 1);
  EXPECT_EQ(c->images[1].split, Split::kHoldout);
  EXPECT_DOUBLE_EQ(c->images[1].saturation, 100);
  EXPECT_EQ(c->CountSplit(Split::kTrain), 2u);
  EXPECT_NE(c->ground_truth_json.find("\"note\""), std::string::npos);
  CaptureFilesReport report;
  ASSERT_TRUE(ValidateCaptureFiles(*c, &report).ok());
  EXPECT_EQ(report.mesh_triangles, 2u);
  EXPECT_EQ(report.images_checked, 3u);
}

TEST_F(CaptureFixture, RoundTripPreservesEverything) {
  ASSERT_TRUE(WriteAndValidate().ok());
  auto first = ReadCapture(path());
  ASSERT_TRUE(first.ok());
  const fs::path copy = dir_ / "copy.json";
  ASSERT_TRUE(WriteCapture(*first, copy).ok());
  auto second = ReadCapture(copy);
  ASSERT_TRUE(second.ok()) << second.status().ToString();
  EXPECT_EQ(CaptureToJson(*first), CaptureToJson(*second));
  EXPECT_EQ(second->cameras[1].K, first->cameras[1].K);
  EXPECT_EQ(second->cameras[0].cam_from_world.ToMatrix(), first->cameras[0].cam_from_world.ToMatrix());
  EXPECT_EQ(second->lights[0].position, first->lights[0].position);
  EXPECT_EQ(second->images[2].exposure_s, 2.0);
  EXPECT_EQ(second->ground_truth_json, first->ground_truth_json);
}

TEST_F(CaptureFixture, UnknownMajorVersionIsRejected) {
  json_["format"] = "capture/2";
  ExpectError({"format", "unsupported major version 2"});
}

TEST_F(CaptureFixture, MinorVersionIsAccepted) {
  json_["format"] = "capture/1.3";
  EXPECT_TRUE(WriteAndValidate().ok());
}

TEST_F(CaptureFixture, MissingImageNamesFileAndField) {
  json_["images"][2]["file"] = "images/missing.exr";
  ExpectError({"images[2].file", "missing.exr"});
}

TEST_F(CaptureFixture, CorruptImageNamesFileAndField) {
  testing::WriteText(dir_ / "images/1.exr", "this is not an EXR file");
  ExpectError({"images[1].file", "1.exr"});
}

// The skeleton `reflcap calibrate turntable` writes without --capture: cameras, turntable and a
// calibration block. ReadRig checks what it has; ReadCapture refuses it, saying what it is.
TEST_F(CaptureFixture, RigSkeletonReadsAsARigNotAsACapture) {
  json_.erase("lights");
  json_.erase("images");
  json_.erase("mesh");
  json_["calibration"] = {{"format", "reflcap-rig/1"}};
  testing::WriteText(path(), json_.dump(2));
  auto rig = ReadRig(dir_.path());
  ASSERT_TRUE(rig.ok()) << rig.status().ToString();
  EXPECT_TRUE(rig->IsRig());
  EXPECT_EQ(rig->cameras.size(), 2u);
  ASSERT_TRUE(rig->turntable.has_value());
  EXPECT_TRUE(rig->lights.empty() && rig->images.empty() && rig->mesh.empty());
  ExpectError({"lights", "rig skeleton", "--capture"});
  // Whatever the rig has is checked as in a capture.
  json_["cameras"][1]["K"] = Json::parse("[[0,0,3.5],[0,12,2.5],[0,0,1]]");
  testing::WriteText(path(), json_.dump(2));
  auto bad = ReadRig(path());
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.status().message().find("cameras[1].K"), std::string::npos) << bad.status().message();
  // A full capture read as a rig is not a rig.
  SetUp();
  testing::WriteText(path(), json_.dump(2));
  auto full = ReadRig(path());
  ASSERT_TRUE(full.ok()) << full.status().ToString();
  EXPECT_FALSE(full->IsRig());
}

TEST_F(CaptureFixture, MissingMeshNamesField) {
  json_["mesh"] = "nope.obj";
  ExpectError({"mesh", "nope.obj"});
}

TEST_F(CaptureFixture, UnreadableMeshNamesField) {
  testing::WriteText(dir_ / "mesh.obj", "v 0 0 0\nf 1 2 3\n");
  ExpectError({"mesh"});
}

TEST_F(CaptureFixture, UnknownCameraId) {
  json_["images"][0]["camera"] = "cam7";
  ExpectError({"images[0].camera", "cam7"});
}

TEST_F(CaptureFixture, UnknownLightId) {
  json_["images"][1]["light"] = "L9";
  ExpectError({"images[1].light", "L9"});
}

TEST_F(CaptureFixture, DuplicateCameraId) {
  json_["cameras"][1]["id"] = "cam0";
  ExpectError({"cameras[1].id", "duplicate"});
}

TEST_F(CaptureFixture, DuplicateLightId) {
  json_["lights"][1]["id"] = "L0";
  ExpectError({"lights[1].id", "duplicate"});
}

TEST_F(CaptureFixture, NonUnitDirection) {
  json_["lights"][1]["direction"] = {0, 1, 1};
  ExpectError({"lights[1].direction", "unit"});
}

TEST_F(CaptureFixture, NonFiniteDirection) {
  // JSON has no NaN literal; a huge exponent parses to infinity.
  std::string text = json_.dump();
  const std::string from = "\"direction\":[0,0.6,0.8]";
  const size_t at = text.find(from);
  ASSERT_NE(at, std::string::npos) << text;
  text.replace(at, from.size(), "\"direction\":[0,1e999,0.8]");
  testing::WriteText(path(), text);
  auto c = ReadCapture(path());
  ASSERT_FALSE(c.ok());
  EXPECT_NE(c.status().message().find("lights[1].direction"), std::string::npos) << c.status().message();
  EXPECT_NE(c.status().message().find("finite"), std::string::npos) << c.status().message();
}

TEST_F(CaptureFixture, NonUnitTurntableAxis) {
  json_["turntable"]["axis"] = {0, 0, 2};
  ExpectError({"turntable.axis", "unit"});
}

TEST_F(CaptureFixture, NegativeExposure) {
  json_["images"][0]["exposure_s"] = -1;
  ExpectError({"images[0].exposure_s", "positive"});
}

TEST_F(CaptureFixture, ImageSizeDiffersFromCamera) {
  ASSERT_TRUE(WriteExr(dir_ / "images/2.exr", Image(9, 6, 3)).ok());
  ExpectError({"images[2].file", "9x6", "cam0", "8x6"});
}

TEST_F(CaptureFixture, SingularK) {
  json_["cameras"][1]["K"] = {{0, 0, 3.5}, {0, 12, 2.5}, {0, 0, 1}};
  ExpectError({"cameras[1].K", "not invertible"});
}

TEST_F(CaptureFixture, EmptyImageList) {
  json_["images"] = Json::array();
  ExpectError({"images", "empty"});
}

TEST_F(CaptureFixture, JsonSyntaxErrorGivesLineAndColumn) {
  testing::WriteText(path(), "{\n  \"format\": \"capture/1\",\n  \"mesh\": mesh.obj\n}\n");
  auto c = ReadCapture(path());
  ASSERT_FALSE(c.ok());
  EXPECT_NE(c.status().message().find(path().string() + ":3:"), std::string::npos)
      << c.status().message();
  EXPECT_NE(c.status().message().find("JSON syntax error"), std::string::npos);
}

TEST_F(CaptureFixture, MissingRequiredFieldIsNamed) {
  json_["cameras"][0].erase("cam_from_world");
  ExpectError({"cameras[0].cam_from_world", "missing"});
}

TEST_F(CaptureFixture, NonRotationPoseIsRejected) {
  json_["cameras"][0]["cam_from_world"][0][0] = 2;
  ExpectError({"cameras[0].cam_from_world", "rotation"});
}

// cameras[].pixel_filter: optional, "area" when absent, read back as written; anything else is
// named with its field.
TEST_F(CaptureFixture, PixelFilterIsReadWrittenAndChecked) {
  json_["cameras"][1]["pixel_filter"] = "point";
  ASSERT_TRUE(WriteAndValidate().ok());
  auto c = ReadCapture(path());
  ASSERT_TRUE(c.ok()) << c.status().ToString();
  EXPECT_EQ(c->cameras[0].pixel_filter, PixelFilter::kArea);
  EXPECT_EQ(c->cameras[1].pixel_filter, PixelFilter::kPoint);
  const fs::path copy = dir_ / "copy.json";
  ASSERT_TRUE(WriteCapture(*c, copy).ok());
  const Json written = Json::parse(*ReadTextFile(copy));
  EXPECT_FALSE(written["cameras"][0].contains("pixel_filter")) << "the default is not written";
  EXPECT_EQ(written["cameras"][1]["pixel_filter"], "point");
  json_["cameras"][1]["pixel_filter"] = "gaussian";
  ExpectError({"cameras[1].pixel_filter", "gaussian"});
  json_["cameras"][1]["pixel_filter"] = 3;
  ExpectError({"cameras[1].pixel_filter"});
}

TEST_F(CaptureFixture, UnknownSplitAndLightType) {
  json_["images"][0]["split"] = "test";
  ExpectError({"images[0].split", "test"});
  SetUp();
  json_["lights"][0]["type"] = "spot";
  ExpectError({"lights[0].type", "spot"});
}

TEST_F(CaptureFixture, MissingCaptureFileIsNotFound) {
  auto c = ReadCapture(dir_ / "absent.json");
  ASSERT_FALSE(c.ok());
  EXPECT_EQ(c.status().code(), StatusCode::kNotFound);
  EXPECT_NE(c.status().message().find("absent.json"), std::string::npos);
}

// ---- images[].variance ------------------------------------------------------------------------

// The fixture with a valid variance image for images[1] (camera cam1, 8x6).
class VarianceFixture : public CaptureFixture {
 protected:
  void SetUp() override {
    CaptureFixture::SetUp();
    fs::create_directories(dir_ / "variance");
    ASSERT_TRUE(WriteExr(dir_ / "variance/1.exr", Image(8, 6, 3, 1e-4f)).ok());
    json_["images"][1]["variance"] = "variance/1.exr";
  }
  // Reads the capture (files validated) and its variance image; the read's status.
  Status ReadVariance() {
    REFLCAP_RETURN_IF_ERROR(WriteAndValidate());
    REFLCAP_ASSIGN_OR_RETURN(Capture c, ReadCapture(path()));
    return ReadVarianceImage(c, 1).status();
  }
  // Expects ReadVariance to fail with exit code 2, naming the capture, the field, the file and
  // every string in `needles`.
  void ExpectReadError(const std::vector<std::string>& needles) {
    const Status s = ReadVariance();
    ASSERT_FALSE(s.ok()) << "expected an error mentioning " << needles[0];
    EXPECT_EQ(ExitCodeFor(s), 2) << s.ToString();
    for (const std::string& n : std::vector<std::string>{path().string(), "images[1].variance",
                                                          "variance/1.exr"}) {
      EXPECT_NE(s.message().find(n), std::string::npos) << s.message();
    }
    for (const auto& n : needles) EXPECT_NE(s.message().find(n), std::string::npos) << s.message();
  }
};

TEST_F(VarianceFixture, IsReadCheckedAndWrittenBack) {
  ASSERT_TRUE(WriteAndValidate().ok()) << WriteAndValidate().ToString();
  auto c = ReadCapture(path());
  ASSERT_TRUE(c.ok());
  EXPECT_EQ(c->images[1].variance, "variance/1.exr");
  EXPECT_TRUE(c->images[0].variance.empty());
  CaptureFilesReport report;
  ASSERT_TRUE(ValidateCaptureFiles(*c, &report).ok());
  EXPECT_EQ(report.variance_images_checked, 1u);
  auto variance = ReadVarianceImage(*c, 1);
  ASSERT_TRUE(variance.ok()) << variance.status().ToString();
  EXPECT_EQ(variance->width, 8);
  EXPECT_FLOAT_EQ(variance->at(3, 2, 1), 1e-4f);
  // Written back by the capture's writer, and only where given.
  const Json written = Json::parse(CaptureToJson(*c));
  EXPECT_EQ(written["images"][1]["variance"], "variance/1.exr");
  EXPECT_FALSE(written["images"][0].contains("variance"));
  EXPECT_FALSE(ReadVarianceImage(*c, 0).ok()) << "images[0] has none";
}

TEST_F(CaptureFixture, WithoutVarianceNothingChanges) {
  ASSERT_TRUE(WriteAndValidate().ok());
  auto c = ReadCapture(path());
  ASSERT_TRUE(c.ok());
  for (const CaptureImage& image : c->images) EXPECT_TRUE(image.variance.empty());
  CaptureFilesReport report;
  ASSERT_TRUE(ValidateCaptureFiles(*c, &report).ok());
  EXPECT_EQ(report.variance_images_checked, 0u);
  // The document must outlive the loop: a range-for over a member of a temporary iterates freed
  // memory (ASan, tests/sanitize.sh address).
  const Json written = Json::parse(CaptureToJson(*c));
  for (const Json& image : written["images"]) {
    EXPECT_FALSE(image.contains("variance"));
  }
}

TEST_F(VarianceFixture, BadFieldValuesAreNamed) {
  json_["images"][1]["variance"] = 3;
  ExpectError({"images[1].variance", "string"});
  SetUp();
  json_["images"][1]["variance"] = "";
  ExpectError({"images[1].variance", "empty"});
  SetUp();
  json_["images"][1]["variance"] = "variance/1.png";
  ExpectError({"images[1].variance", "OpenEXR"});
  SetUp();
  json_["images"][1]["variance"] = "images/1.exr";
  ExpectError({"images[1].variance", "the photograph itself"});
}

TEST_F(VarianceFixture, MissingFileIsNamed) {
  fs::remove(dir_ / "variance/1.exr");
  ExpectError({"images[1].variance", "variance/1.exr", "cannot open"});
  EXPECT_EQ(ExitCodeFor(WriteAndValidate()), 2);
}

TEST_F(VarianceFixture, WrongSizeIsNamed) {
  ASSERT_TRUE(WriteExr(dir_ / "variance/1.exr", Image(8, 5, 3)).ok());
  ExpectError({"images[1].variance", "variance/1.exr", "8x5", "cam1", "8x6"});
}

TEST_F(VarianceFixture, WrongChannelCountIsNamed) {
  ASSERT_TRUE(WriteExr(dir_ / "variance/1.exr", Image(8, 6, 1)).ok());
  ExpectError({"images[1].variance", "variance/1.exr", "1 channel (Y)", "R, G and B"});
  ASSERT_TRUE(WriteExr(dir_ / "variance/1.exr", Image(8, 6, 4)).ok());
  ExpectError({"images[1].variance", "4 channels (A, B, G, R)"});
}

TEST_F(VarianceFixture, CorruptFileIsNamed) {
  testing::WriteText(dir_ / "variance/1.exr", "not an EXR");
  ExpectError({"images[1].variance", "variance/1.exr"});
}

// The header is fine; the values are read and checked whole (a file from another program may
// hold NaN, Inf or negative values).
TEST_F(VarianceFixture, NonFiniteOrNegativeValuesAreNamed) {
  Image v(8, 6, 3, 1e-4f);
  v.at(5, 4, 1) = std::nanf("");
  v.at(6, 4, 2) = std::nanf("");
  testing::WriteRawExr(dir_ / "variance/1.exr", v);
  ExpectReadError({"pixel (5, 4) channel G is NaN", "2 bad values", "finite and >= 0"});
  v = Image(8, 6, 3, 1e-4f);
  v.at(0, 1, 0) = -1e-6f;
  testing::WriteRawExr(dir_ / "variance/1.exr", v);
  ExpectReadError({"pixel (0, 1) channel R is negative"});
  v.at(0, 1, 0) = std::numeric_limits<float>::infinity();
  testing::WriteRawExr(dir_ / "variance/1.exr", v);
  ExpectReadError({"pixel (0, 1) channel R is infinite"});
  // The same checks on an image in memory (what the resampler applies to what it is given).
  ASSERT_TRUE(WriteAndValidate().ok());
  auto c = ReadCapture(path());
  ASSERT_TRUE(c.ok());
  const Status s = CheckVarianceImage(*c, 1, Image(8, 6, 1));
  EXPECT_NE(s.message().find("expected 8x6 RGB"), std::string::npos) << s.message();
  EXPECT_TRUE(CheckVarianceImage(*c, 1, Image(8, 6, 3, 0.0f)).ok()) << "zero variance is valid";
}

TEST(CaptureNormalMap, ValidatesNormalsAndMaskAgainstCamera) {
  testing::ScratchDir dir;
  Image normals(4, 3, 3);
  for (size_t p = 0; p < normals.PixelCount(); ++p) normals.data[p * 3 + 2] = 1;
  ASSERT_TRUE(WriteExr(dir / "normals.exr", normals).ok());
  Image mask(4, 3, 1, 1.0f);
  mask.at(0, 0) = 0;
  ASSERT_TRUE(WritePng(dir / "mask.png", mask).ok());
  ASSERT_TRUE(WriteExr(dir / "001.exr", Image(4, 3, 3)).ok());
  testing::WriteText(dir / "capture.json", R"({
    "format": "capture/1",
    "normal_map": {"camera": "cam", "normals": "normals.exr", "mask": "mask.png"},
    "cameras": [{"id": "cam", "model": "orthographic", "width": 4, "height": 3,
                 "cam_from_world": [[1,0,0,0],[0,-1,0,0],[0,0,-1,0],[0,0,0,1]]}],
    "lights": [{"id": "L", "type": "directional", "direction": [0,0,1], "intensity": [1,1,1]}],
    "images": [{"file": "001.exr", "camera": "cam", "light": "L"}]
  })");
  auto c = ReadCapture(dir / "capture.json");
  ASSERT_TRUE(c.ok()) << c.status().ToString();
  EXPECT_FALSE(c->turntable.has_value());
  EXPECT_EQ(c->cameras[0].model, CameraModel::kOrthographic);
  CaptureFilesReport report;
  ASSERT_TRUE(ValidateCaptureFiles(*c, &report).ok());
  EXPECT_EQ(report.normal_map_texels, 11u);
}

}  // namespace
}  // namespace reflcap
