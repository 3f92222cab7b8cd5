// Intrinsics from rendered planar-board photos: K and distortion within their sigmas of the truth,
// a wrong photo rejected, too few views an error naming the camera, INTRINSICS.json round trip.
#include "calib/intrinsics.h"

#include <gtest/gtest.h>

#include "engine/image/png_io.h"
#include "tests/calib/synthetic_session.h"
#include "tests/support/test_support.h"

namespace reflcap::calib {
namespace {

using testing::MakeRig;
using testing::SyntheticRig;

// As in turntable_test: an estimate beyond this many of its own sigmas is wrong (or its sigma is).
constexpr double kMaxSigmas = 4.5;

class IntrinsicsRendered : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new reflcap::testing::ScratchDir();
    rig_ = new SyntheticRig(MakeRig(1, 2));
    testing::SessionOptions o;
    o.board_photos_per_camera = 10;
    path_ = new std::filesystem::path(testing::WriteSession(rig_, dir_->path(), o));
  }
  static void TearDownTestSuite() {
    delete path_;
    delete rig_;
    delete dir_;
  }
  static reflcap::testing::ScratchDir* dir_;
  static SyntheticRig* rig_;
  static std::filesystem::path* path_;
};
reflcap::testing::ScratchDir* IntrinsicsRendered::dir_ = nullptr;
SyntheticRig* IntrinsicsRendered::rig_ = nullptr;
std::filesystem::path* IntrinsicsRendered::path_ = nullptr;

TEST_F(IntrinsicsRendered, RecoversKAndDistortionWithinTheirSigmas) {
  auto file = ReadCalibFile(*path_);
  ASSERT_TRUE(file.ok()) << file.status().ToString();
  IntrinsicsOptions options;
  auto r = CalibrateIntrinsics(*file, options);
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  ASSERT_EQ(r->cameras.size(), 1u);
  const IntrinsicsCameraResult& c = r->cameras[0];
  EXPECT_EQ(c.views_used, 10);
  // Box-filtered renders, one grey level of noise.
  EXPECT_LT(c.rms_px, 0.06);
  ASSERT_TRUE(c.error.has_value());
  for (int k : {kFx, kFy, kCx, kCy, kK1, kK2, kP1, kP2}) {
    EXPECT_GT(c.intrinsics.sigma[k], 0) << IntrinsicName(k);
    EXPECT_LT(std::abs((*c.error)[k]), kMaxSigmas * c.intrinsics.sigma[k]) << IntrinsicName(k);
  }
  EXPECT_EQ(c.intrinsics.sigma[kK3], 0);  // held
  EXPECT_EQ(c.intrinsics.params[kK3], 0);
  EXPECT_GT(c.coverage_cells, 0.2);
  EXPECT_GT(c.coverage_hull, 0.1);
  ASSERT_TRUE(c.intrinsics.covariance.has_value());
  EXPECT_NEAR((*c.intrinsics.covariance)(kFx, kFx), c.intrinsics.sigma[kFx] * c.intrinsics.sigma[kFx], 1e-9);

  // INTRINSICS.json round trip.
  reflcap::testing::ScratchDir out;
  reflcap::testing::WriteText(out / "intrinsics.json", IntrinsicsToJson(*file, *r, options));
  auto back = ReadIntrinsicsFile(out / "intrinsics.json");
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  ASSERT_EQ(back->size(), 1u);
  EXPECT_EQ((*back)[0].id, "cam0");
  for (int k = 0; k < kIntrinsicCount; ++k) {
    EXPECT_DOUBLE_EQ((*back)[0].params[k], c.intrinsics.params[k]);
    EXPECT_DOUBLE_EQ((*back)[0].sigma[k], c.intrinsics.sigma[k]);
  }
  ASSERT_TRUE((*back)[0].covariance.has_value());
}

TEST_F(IntrinsicsRendered, AWrongPhotoIsRejectedAndTheRestCalibrates) {
  // One photo replaced by a board rendered through another lens (strong barrel distortion): its
  // board is found, but it cannot agree with the others.
  reflcap::testing::ScratchDir dir;
  SyntheticRig rig = *rig_;
  for (const auto& entry : std::filesystem::recursive_directory_iterator(dir_->path())) {
    const auto rel = std::filesystem::relative(entry.path(), dir_->path());
    if (entry.is_directory()) {
      std::filesystem::create_directories(dir / rel.string());
    } else {
      std::filesystem::copy_file(entry.path(), dir / rel.string());
    }
  }
  SyntheticRig other = rig;
  other.intrinsics[0][kK1] = -1.2;  // strong barrel: no pose of a plane explains its corners
  const Image bad = testing::RenderBoardPhoto(other, 0, rig.cam_from_board[0][3], 0.004, 77);
  ASSERT_TRUE(WritePng(dir / "intrinsics/cam0_03.png", bad).ok());
  auto file = ReadCalibFile(dir / "calib.json");
  ASSERT_TRUE(file.ok());
  auto r = CalibrateIntrinsics(*file, IntrinsicsOptions());
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  EXPECT_EQ(r->cameras[0].views_used, 9);
  EXPECT_FALSE(r->views[3].used);
  EXPECT_EQ(r->views[3].status.rfind("rejected:", 0), 0u) << r->views[3].status;
  EXPECT_LT(std::abs((*r->cameras[0].error)[kFx]), kMaxSigmas * r->cameras[0].intrinsics.sigma[kFx]);
}

TEST_F(IntrinsicsRendered, TooFewBoardsIsAnErrorNamingTheCamera) {
  auto file = ReadCalibFile(*path_);
  ASSERT_TRUE(file.ok());
  file->board_images.resize(2);
  auto r = CalibrateIntrinsics(*file, IntrinsicsOptions());
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), StatusCode::kFailedPrecondition);
  EXPECT_NE(r.status().message().find("intrinsics_images: camera \"cam0\": the board was found in 2 of its 2 photos"),
            std::string::npos)
      << r.status().message();
}

TEST(IntrinsicsFile, ReportsMalformedFieldsWithFileAndPath) {
  reflcap::testing::ScratchDir dir;
  reflcap::testing::WriteText(dir / "i.json", R"({"format": "reflcap-intrinsics/1", "cameras": [
      {"id": "cam0", "width": 640, "height": 480, "K": [[1, 0, 2], [0, -1, 3], [0, 0, 1]]}]})");
  auto r = ReadIntrinsicsFile(dir / "i.json");
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("i.json: cameras[0].K: focal lengths"), std::string::npos) << r.status().message();
  reflcap::testing::WriteText(dir / "j.json", R"({"format": "capture/1", "cameras": []})");
  EXPECT_NE(ReadIntrinsicsFile(dir / "j.json").status().message().find("format:"), std::string::npos);
}

}  // namespace
}  // namespace reflcap::calib
