// `reflcap hdr` end to end: the pipeline on synthetic brackets (accuracy against their known camera,
// the capture it writes), its command line (bad input: exit 2, the file and field named, nothing
// written), and the shared suzanne_a000 brackets when ../shared is present.
#include "acquire/radiometry/hdr.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include "engine/capture/capture.h"
#include "engine/core/atomic_file.h"
#include "engine/image/exr_io.h"
#include "engine/image/png_io.h"
#include "tests/acquire/radiometry/synthetic_brackets.h"
#include "tests/support/test_support.h"

namespace reflcap::radiometry {
namespace {
namespace fs = std::filesystem;
using Json = nlohmann::json;
using ::testing::HasSubstr;

// The goals (issue 16, "Done when"): inverse response within 0.01 max |log error| over
// codes 20–235, merged HDR within 1 % median and 3 % p95 relative error, gains within 0.3 %.
constexpr double kResponseGoal = 0.01;
constexpr double kHdrMedianGoal = 0.01;
constexpr double kHdrP95Goal = 0.03;
constexpr double kGainsGoal = 0.003;
// p95 of the merge when the response's toe lies below the noise floor (measured 4.0 %).
constexpr double kToeP95Tolerance = 0.06;

testing::SyntheticBracketsOptions SmallSet() {
  testing::SyntheticBracketsOptions o;
  o.object_size = 64;
  o.object_photos = 4;
  o.response = testing::LogLogisticResponse;
  return o;
}

TEST(HdrPipeline, SyntheticBracketsMeetTheGoalsAndWriteACapture) {
  reflcap::testing::ScratchDir dir;
  const auto data = testing::WriteSyntheticBrackets(dir / "in", SmallSet());
  HdrOptions options;
  options.holdout_lights = {};
  fs::create_directories(dir / "out");
  auto summary = RunHdrPipeline(data.json, dir / "out", options);
  ASSERT_TRUE(summary.ok()) << summary.status().ToString();
  EXPECT_EQ(summary->chart_method, "mcc");
  EXPECT_EQ(summary->object_photos, 4u);
  EXPECT_LT(summary->response_max_log_error, kResponseGoal);
  EXPECT_GE(summary->hdr_median_rel_error, 0);
  EXPECT_LT(summary->hdr_median_rel_error, kHdrMedianGoal);
  EXPECT_LT(summary->hdr_p95_rel_error, kHdrP95Goal);
  EXPECT_LT(summary->gains_max_rel_error, kGainsGoal);
  EXPECT_LT(summary->mean_delta_e_after, summary->mean_delta_e_before);

  // The capture reads back, every file valid.
  auto capture = ReadCapture(dir / "out/capture.json");
  ASSERT_TRUE(capture.ok()) << capture.status().ToString();
  CaptureFilesReport files;
  ASSERT_TRUE(ValidateCaptureFiles(*capture, &files).ok());
  ASSERT_EQ(capture->images.size(), 4u);
  const CaptureImage& image = capture->images[0];
  EXPECT_EQ(image.exposure_s, 1.0);
  EXPECT_GT(image.saturation, 0.0);
  const Json json = Json::parse(*ReadTextFile(dir / "out/capture.json"));
  ASSERT_EQ(json["images"][0]["variance"], "variance/p00.exr");
  auto value = ReadExrRgb(capture->Resolve(image.file));
  auto variance = ReadExrRgb(dir / "out/variance/p00.exr");
  ASSERT_TRUE(value.ok() && variance.ok());
  // Saturation: pixels clipped in every exposure sit exactly at it; every other value is below.
  size_t saturated = 0, below = 0;
  for (size_t p = 0; p < value->PixelCount(); ++p) {
    const float* v = &value->data[p * 3];
    if (v[0] >= image.saturation || v[1] >= image.saturation || v[2] >= image.saturation) {
      ++saturated;
      for (int c = 0; c < 3; ++c) EXPECT_FLOAT_EQ(v[c], float(image.saturation));
    } else {
      ++below;
      for (int c = 0; c < 3; ++c) EXPECT_GE(variance->data[p * 3 + size_t(c)], 0.0f);
    }
  }
  EXPECT_GT(saturated, 0u) << "the synthetic photos hold pixels clipped in every exposure";
  EXPECT_GT(below, saturated);
  // The report.
  for (const char* f : {"radiometry/report.json", "radiometry/report.html", "radiometry/response.json",
                        "radiometry/weights.png", "radiometry/chart_detection.png", "mesh.obj"}) {
    EXPECT_TRUE(fs::is_regular_file(dir / "out" / f)) << f;
  }
}

TEST(HdrPipeline, AResponseNoFamilyFitsIsRecoveredThroughTheChartAnchors) {
  reflcap::testing::ScratchDir dir;
  testing::SyntheticBracketsOptions o = SmallSet();
  o.response = testing::RippledResponse;
  const auto data = testing::WriteSyntheticBrackets(dir / "in", o);
  fs::create_directories(dir / "out");
  auto summary = RunHdrPipeline(data.json, dir / "out", HdrOptions());
  ASSERT_TRUE(summary.ok()) << summary.status().ToString();
  EXPECT_EQ(summary->response_model, "debevec");
  // This gamma-like camera's toe (codes < 44) lies below the estimation's noise floor (SNR 20 at
  // read σ = 0.001): the curve is judged where the data measure it, and the merge's p95 includes
  // the pixels only that toe measures (there the noise itself is several %).
  const Json response = Json::parse(*ReadTextFile(dir / "out/radiometry/response.json"));
  InverseResponse r;
  for (int c = 0; c < 3; ++c) {
    for (int z = 0; z < kCodeCount; ++z) r.log_x[size_t(c)][size_t(z)] = response["log_x_of_code"][c][z];
    r.first_code[size_t(c)] = response["codes_with_data"][c][0];
  }
  EXPECT_LT(CompareResponse(r, data.x_of_code, std::max(20, r.first_code[1])).max_over_channels, kResponseGoal);
  EXPECT_LT(summary->hdr_median_rel_error, kHdrMedianGoal);
  EXPECT_LT(summary->hdr_p95_rel_error, kToeP95Tolerance);
}

// ---- Command line ----

reflcap::testing::CliResult Hdr(const std::string& args, const reflcap::testing::ScratchDir& dir) {
  return reflcap::testing::RunCommand(REFLCAP_BINARY, "hdr " + args, dir);
}

class HdrCli : public ::testing::Test {
 protected:
  void SetUp() override {
    data_ = testing::WriteSyntheticBrackets(dir_ / "in", SmallSet());
    json_ = Json::parse(*ReadTextFile(data_.json));
  }
  void Rewrite() { reflcap::testing::WriteText(data_.json, json_.dump(1)); }
  // Runs hdr into dir/out and expects exit 2, `message` on stderr and no output folder.
  void ExpectBadInput(const std::string& message) {
    const auto r = Hdr(data_.json.string() + " --out " + (dir_ / "out").string(), dir_);
    EXPECT_EQ(r.exit_code, 2) << r.err;
    EXPECT_THAT(r.err, HasSubstr(message));
    EXPECT_FALSE(fs::exists(dir_ / "out"));
    // Nor a staging folder beside it.
    for (const auto& entry : fs::directory_iterator(dir_.path())) {
      const std::string name = entry.path().filename().string();
      EXPECT_TRUE(name.rfind("out", 0) != 0 && name.rfind(".out", 0) != 0) << entry.path();
    }
  }
  reflcap::testing::ScratchDir dir_;
  testing::SyntheticBrackets data_;
  Json json_;
};

TEST_F(HdrCli, WritesTheCaptureAndReportsAccuracy) {
  const auto r = Hdr(data_.json.string() + " --out " + (dir_ / "out").string() + " --holdout-lights L0 --quiet", dir_);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("merged 4 photos (train 0, holdout 4)"));
  EXPECT_THAT(r.out, HasSubstr("chart: found by mcc"));
  EXPECT_THAT(r.out, HasSubstr("vs truth: response max |log error|"));
  EXPECT_TRUE(fs::is_regular_file(dir_ / "out/capture.json"));
  // An existing output is refused without --overwrite.
  const auto again = Hdr(data_.json.string() + " --out " + (dir_ / "out").string(), dir_);
  EXPECT_NE(again.exit_code, 0);
}

TEST_F(HdrCli, UsageErrors) {
  EXPECT_EQ(Hdr(data_.json.string(), dir_).exit_code, 1);  // no --out
  EXPECT_EQ(Hdr(data_.json.string() + " --out x --response spline", dir_).exit_code, 1);
}

TEST_F(HdrCli, BracketsOfDifferentSizes) {
  ASSERT_TRUE(WritePng(dir_ / "in" / json_["photos"][2]["exposures"][3]["file"].get<std::string>(),
                       Image(32, 64, 3, 0.5f)).ok());
  ExpectBadInput("brackets.json: photos[2].exposures[3].file:");
}

TEST_F(HdrCli, DuplicatedExposure) {
  json_["photos"][1]["exposures"][1]["exposure_s"] = 0.125;
  Rewrite();
  ExpectBadInput("brackets.json: photos[1].exposures[1].exposure_s: duplicates the previous exposure");
}

TEST_F(HdrCli, NonMonotoneExposures) {
  json_["photos"][0]["exposures"][4]["exposure_s"] = 4.0;
  Rewrite();
  ExpectBadInput("brackets.json: photos[0].exposures[4].exposure_s: must exceed the previous exposure");
}

TEST_F(HdrCli, AllClippedBracket) {
  for (const auto& e : json_["photos"][3]["exposures"]) {
    ASSERT_TRUE(WritePng(dir_ / "in" / e["file"].get<std::string>(), Image(64, 64, 3, 1.0f)).ok());
  }
  ExpectBadInput("brackets.json: photos[3].exposures: every exposure is clipped");
}

TEST_F(HdrCli, AllDarkBracket) {
  for (const auto& e : json_["photos"][0]["exposures"]) {
    ASSERT_TRUE(WritePng(dir_ / "in" / e["file"].get<std::string>(), Image(64, 64, 3, 0.0f)).ok());
  }
  ExpectBadInput("brackets.json: photos[0].exposures: every exposure is black");
}

TEST_F(HdrCli, MissingChartPhoto) {
  json_["photos"].erase(4);  // the colorchecker
  Rewrite();
  ExpectBadInput("brackets.json: photos: no photo has subject \"colorchecker\"");
}

TEST_F(HdrCli, ChartNotFound) {
  // The chart photo shows no chart, and no geometry declares one.
  for (const auto& e : json_["photos"][4]["exposures"]) {
    ASSERT_TRUE(WritePng(dir_ / "in" / e["file"].get<std::string>(), Image(320, 240, 3, 0.3f)).ok());
  }
  json_["photos"][4].erase("chart");
  json_["ground_truth"].erase("chart");
  Rewrite();
  ExpectBadInput("brackets.json: photos[4] (\"chart\"): no ColorChecker found");
}

// ---- Shared data ----

TEST(HdrSharedData, SuzanneBracketsMeetTheGoals) {
  const auto shared = reflcap::testing::SharedDataDir();
  if (!shared) GTEST_SKIP() << "../shared/data not present";
  const fs::path source = *shared / "brackets/suzanne_a000/brackets.json";
  if (!fs::is_regular_file(source)) GTEST_SKIP() << source << " not present";
  // A quarter of the object photos (every fourth) and the chart, paths made absolute: the whole set
  // takes ~7 s on two quiet cores, this ~2 s, and the goals hold for either (bench/RESULTS.md).
  Json json = Json::parse(*ReadTextFile(source));
  const fs::path base = source.parent_path();
  Json photos = Json::array();
  int k = 0;
  for (Json p : json["photos"]) {
    if (p["subject"] == "object" && k++ % 4 != 0) continue;
    for (auto& e : p["exposures"]) e["file"] = (base / e["file"].get<std::string>()).string();
    p["source_hdr"] = (base / p["source_hdr"].get<std::string>()).lexically_normal().string();
    photos.push_back(p);
  }
  json["photos"] = photos;
  json["source_capture"] = (base / json["source_capture"].get<std::string>()).lexically_normal().string();
  for (const char* key : {"hdr", "geometry"}) {
    json["ground_truth"]["chart"][key] = (base / json["ground_truth"]["chart"][key].get<std::string>()).string();
  }
  reflcap::testing::ScratchDir dir;
  reflcap::testing::WriteText(dir / "brackets.json", json.dump());
  fs::create_directories(dir / "out");
  auto summary = RunHdrPipeline(dir / "brackets.json", dir / "out", HdrOptions());
  ASSERT_TRUE(summary.ok()) << summary.status().ToString();
  EXPECT_EQ(summary->chart_method, "mcc");
  EXPECT_LT(summary->response_max_log_error, kResponseGoal);
  EXPECT_LT(summary->hdr_median_rel_error, kHdrMedianGoal);
  EXPECT_LT(summary->hdr_p95_rel_error, kHdrP95Goal);
  EXPECT_LT(summary->gains_max_rel_error, kGainsGoal);
}

}  // namespace
}  // namespace reflcap::radiometry
