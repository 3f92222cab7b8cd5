// brackets/1 parsing and image reading: every error names the file and the field.
#include "acquire/radiometry/brackets.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include "engine/core/atomic_file.h"
#include "engine/image/png_io.h"
#include "tests/acquire/radiometry/synthetic_brackets.h"
#include "tests/support/test_support.h"

namespace reflcap::radiometry {
namespace {
using Json = nlohmann::json;
using ::testing::HasSubstr;

class BracketsTest : public ::testing::Test {
 protected:
  void SetUp() override {
    testing::SyntheticBracketsOptions o;
    o.object_size = 16;
    o.object_photos = 2;
    o.chart = false;
    o.response = testing::LogLogisticResponse;
    data_ = testing::WriteSyntheticBrackets(dir_.path(), o);
    json_ = Json::parse(*ReadTextFile(data_.json));
  }
  // Parses the (modified) JSON as if it were the brackets file.
  StatusOr<BracketSet> Parse() { return ParseBrackets(json_.dump(), data_.json); }
  std::string Error() {
    auto set = Parse();
    EXPECT_FALSE(set.ok());
    return set.ok() ? "" : set.status().message();
  }

  reflcap::testing::ScratchDir dir_;
  testing::SyntheticBrackets data_;
  Json json_;
};

TEST_F(BracketsTest, ReadsTheRigPhotosAndTruth) {
  auto set = ReadBrackets(data_.json);
  ASSERT_TRUE(set.ok()) << set.status().ToString();
  EXPECT_EQ(set->rig.cameras.size(), 2u);
  EXPECT_EQ(set->rig.lights.size(), 1u);
  ASSERT_EQ(set->photos.size(), 2u);
  EXPECT_EQ(set->photos[1].id, "p01");
  EXPECT_EQ(set->photos[1].exposures.size(), 5u);
  EXPECT_EQ(set->photos[1].exposures[4].exposure_s, 32.0);
  EXPECT_EQ(set->ChartPhoto(), -1);
  EXPECT_EQ(set->truth.x_of_code.size(), 256u);
  ASSERT_TRUE(set->truth.wb_gains.has_value());
  EXPECT_EQ((*set->truth.wb_gains)[0], 1.25);
  auto images = ReadBracketImages(*set, 1);
  ASSERT_TRUE(images.ok()) << images.status().ToString();
  EXPECT_EQ(images->codes.size(), 5u);
  EXPECT_EQ(images->codes[0].size(), 16u * 16u * 3u);
}

TEST_F(BracketsTest, RejectsADuplicatedExposure) {
  json_["photos"][1]["exposures"][2]["exposure_s"] = 0.5;
  const std::string e = Error();
  EXPECT_THAT(e, HasSubstr("brackets.json: photos[1].exposures[2].exposure_s: duplicates"));
}

TEST_F(BracketsTest, RejectsANonMonotoneExposureList) {
  json_["photos"][0]["exposures"][3]["exposure_s"] = 1.0;
  EXPECT_THAT(Error(), HasSubstr("photos[0].exposures[3].exposure_s: must exceed the previous exposure (2 s)"));
}

TEST_F(BracketsTest, RejectsBadFields) {
  Json original = json_;
  json_["photos"][0]["camera"] = "camX";
  EXPECT_THAT(Error(), HasSubstr("photos[0].camera: unknown camera id \"camX\""));
  json_ = original;
  json_["photos"][0]["exposures"] = Json::array({original["photos"][0]["exposures"][0]});
  EXPECT_THAT(Error(), HasSubstr("photos[0].exposures: needs at least 2 exposures"));
  json_ = original;
  json_["photos"][1]["id"] = "p00";
  EXPECT_THAT(Error(), HasSubstr("photos[1].id: duplicate photo id \"p00\""));
  json_ = original;
  json_["photos"][0]["id"] = "../x";
  EXPECT_THAT(Error(), HasSubstr("photos[0].id: \"../x\" must use only"));
  json_ = original;
  json_["photos"][0]["exposures"][1]["exposure_s"] = -1;
  EXPECT_THAT(Error(), HasSubstr("photos[0].exposures[1].exposure_s: must be positive"));
  json_ = original;
  json_["photos"][0]["subject"] = "person";
  EXPECT_THAT(Error(), HasSubstr("photos[0].subject: unknown subject \"person\""));
  json_ = original;
  json_["format"] = "capture/1";
  EXPECT_THAT(Error(), HasSubstr("format: \"capture/1\" is not brackets/1"));
  json_ = original;
  json_["cameras"][0]["K"] = Json::array({Json::array({0, 0, 0}), Json::array({0, 0, 0}), Json::array({0, 0, 1})});
  EXPECT_THAT(Error(), HasSubstr("brackets.json: cameras[0].K"));
  json_ = original;
  json_["ground_truth"]["response"]["x_of_code"] = Json::array({1, 2});
  EXPECT_THAT(Error(), HasSubstr("ground_truth.response.x_of_code: must be an array of 256 numbers"));
}

TEST_F(BracketsTest, ImageErrorsNameTheFieldAndTheFile) {
  auto set = ReadBrackets(data_.json);
  ASSERT_TRUE(set.ok());
  // A different size.
  const auto path = set->Resolve(set->photos[1].exposures[2].file);
  ASSERT_TRUE(WritePng(path, Image(12, 16, 3, 0.5f)).ok());
  auto images = ReadBracketImages(*set, 1);
  ASSERT_FALSE(images.ok());
  EXPECT_EQ(images.status().code(), StatusCode::kInvalidArgument);
  EXPECT_THAT(images.status().message(),
              HasSubstr("brackets.json: photos[1].exposures[2].file: " + path.string() + " is 12x16, camera cam0 is 16x16"));
  // A 16-bit PNG whose values are off the 8-bit grid.
  ASSERT_TRUE(WritePng(path, Image(16, 16, 3, 0.1234f), 16).ok());
  images = ReadBracketImages(*set, 1);
  ASSERT_FALSE(images.ok());
  EXPECT_THAT(images.status().message(), HasSubstr("is not an 8-bit PNG"));
  // A missing file.
  std::filesystem::remove(path);
  images = ReadBracketImages(*set, 1);
  ASSERT_FALSE(images.ok());
  EXPECT_EQ(images.status().code(), StatusCode::kNotFound);
  EXPECT_THAT(images.status().message(), HasSubstr("photos[1].exposures[2].file"));
}

}  // namespace
}  // namespace reflcap::radiometry
