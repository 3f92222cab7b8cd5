// Board detection on rendered photos: a board is found, named and numbered by its colours, its
// corners land on the true projections (both refiners; the symmetry refinement five times closer
// than cornerSubPix, also under a light gradient and on sRGB-encoded photos); a symmetric board
// comes back with its other numbering; a grid that is part of a larger board is refused.
#include "calib/board_detect.h"

#include <gtest/gtest.h>

#include "engine/image/srgb.h"
#include "tests/calib/synthetic_session.h"

namespace reflcap::calib {
namespace {

using testing::MakeRig;
using testing::RenderBoardPhoto;
using testing::SyntheticRig;

// Refined corners of a box-filtered render with ~1 grey level of noise: cornerSubPix lands within
// a few hundredths of a pixel (0.02-0.04 px RMS measured); 0.1 px leaves room and still fails for
// a corner refined onto its neighbour's edge or a numbering off by one square (>= 10 px).
constexpr double kCornerTolerancePx = 0.1;
constexpr double kNoise = 0.004;  // ~1 grey level of 255
// The symmetry refinement on the same renders: 0.006-0.007 px RMS measured; 0.015 px fails a
// refinement that lost its precision advantage over cornerSubPix (0.03 px).
constexpr double kSymmetryTolerancePx = 0.015;

Vec2d Project(const SyntheticRig& rig, int camera, const Rigid3& pose, const Vec3d& p) {
  const Vec3d q = pose * p;
  double pixel[2];
  const double pc[3] = {q.x(), q.y(), q.z()};
  ProjectToPixel(rig.intrinsics[camera].data(), pc, pixel);
  return {pixel[0], pixel[1]};
}

// A board tilted by 25 degrees about x and 15 about y, 0.5 m in front of the camera.
Rigid3 TiltedPose(const BoardSpec& b, double roll_deg = 10) {
  const Mat3d r = AxisAngleRotation(Vec3d::UnitX(), DegToRad(25)) * AxisAngleRotation(Vec3d::UnitY(), DegToRad(-15)) *
                  AxisAngleRotation(Vec3d::UnitZ(), DegToRad(roll_deg));
  const Vec3d centre(0.5 * (b.squares_x - 2) * b.square_m, 0.5 * (b.squares_y - 2) * b.square_m, 0);
  return {r, Vec3d(0.004, -0.003, 0.5) - r * centre};
}

TEST(BoardDetect, FindsNamesAndNumbersABoard) {
  SyntheticRig rig = MakeRig(1, 1);
  const Rigid3 pose = TiltedPose(rig.board);
  const Image photo = RenderBoardPhoto(rig, 0, pose, kNoise, 1);
  // The board among two candidates: the other one has a different grid.
  BoardSpec other = rig.board;
  other.name = "other";
  other.squares_x = 5;
  other.corners_x = 4;
  const std::vector<BoardSpec> boards = {other, rig.board};
  std::vector<std::string> refused;
  const auto found = FindBoards(photo, boards, 0, DetectOptions(), &refused);
  ASSERT_EQ(found.size(), 1u);
  EXPECT_EQ(found[0].board, 1);
  EXPECT_TRUE(found[0].alternatives.empty());
  EXPECT_GT(found[0].contrast, 0.5);
  ASSERT_EQ(int(found[0].corners.size()), rig.board.CornerCount());
  double worst = 0;
  for (int k = 0; k < rig.board.CornerCount(); ++k) {
    EXPECT_TRUE(found[0].valid[k]);
    worst = std::max(worst, (found[0].corners[k] - Project(rig, 0, pose, rig.board.Corner(k))).norm());
  }
  EXPECT_LT(worst, kCornerTolerancePx);
}

TEST(BoardDetect, NumbersABoardTurnedUpsideDown) {
  SyntheticRig rig = MakeRig(1, 1);
  const Rigid3 pose = TiltedPose(rig.board, 170);
  const Image photo = RenderBoardPhoto(rig, 0, pose, kNoise, 2);
  const auto found = FindBoards(photo, {rig.board}, 1, DetectOptions(), nullptr);
  ASSERT_EQ(found.size(), 1u);
  // Corner (0, 0) is where the board's first corner projects, however the board is turned.
  EXPECT_LT((found[0].corners[0] - Project(rig, 0, pose, rig.board.Corner(0))).norm(), kCornerTolerancePx);
}

TEST(BoardDetect, ASymmetricBoardComesWithItsOtherNumbering) {
  SyntheticRig rig = MakeRig(1, 1);
  rig.board.squares_x = 8;  // 8 x 6 squares: the same colours turned by 180 degrees
  rig.board.corners_x = 7;
  ASSERT_EQ(rig.board.Symmetry(), 2);
  const Rigid3 pose = TiltedPose(rig.board);
  const Image photo = RenderBoardPhoto(rig, 0, pose, kNoise, 3);
  const auto found = FindBoards(photo, {rig.board}, 1, DetectOptions(), nullptr);
  ASSERT_EQ(found.size(), 1u);
  ASSERT_EQ(found[0].alternatives.size(), 1u);
  // One of the two numberings puts corner 0 on the true first corner, the other on the last.
  const Vec2d first = Project(rig, 0, pose, rig.board.Corner(0));
  const Vec2d last = Project(rig, 0, pose, rig.board.Corner(rig.board.CornerCount() - 1));
  const Vec2d a = found[0].corners[0];
  const Vec2d b = found[0].corners[found[0].alternatives[0][0]];
  EXPECT_LT(std::min((a - first).norm(), (b - first).norm()), kCornerTolerancePx);
  EXPECT_LT(std::min((a - last).norm(), (b - last).norm()), kCornerTolerancePx);
}

TEST(BoardDetect, RefusesAGridThatIsPartOfALargerBoard) {
  SyntheticRig rig = MakeRig(1, 1);
  const Rigid3 pose = TiltedPose(rig.board);
  const Image photo = RenderBoardPhoto(rig, 0, pose, kNoise, 4);
  // A 7x4-square board fits inside the 9x6 one; its white margin is not there.
  BoardSpec smaller = rig.board;
  smaller.squares_x = 7;
  smaller.squares_y = 4;
  smaller.corners_x = 6;
  smaller.corners_y = 3;
  std::vector<std::string> refused;
  const auto found = FindBoards(photo, {smaller}, 0, DetectOptions(), &refused);
  EXPECT_TRUE(found.empty());
}

TEST(BoardDetect, FindsABoardInsideItsPredictedOutlineOnly) {
  SyntheticRig rig = MakeRig(1, 1);
  const Rigid3 pose = TiltedPose(rig.board);
  const Image photo = RenderBoardPhoto(rig, 0, pose, kNoise, 5);
  std::vector<Vec2d> outline, predicted;
  for (const Vec2d& q : BoardOutline(rig.board, 0.5)) {
    outline.push_back(Project(rig, 0, pose, rig.board.Point(q.x(), q.y())));
  }
  for (int k = 0; k < rig.board.CornerCount(); ++k) predicted.push_back(Project(rig, 0, pose, rig.board.Corner(k)));
  std::string why;
  auto found = FindBoardInRegion(photo, {rig.board}, 0, outline, &predicted, DetectOptions(), &why);
  ASSERT_TRUE(found.has_value()) << why;
  EXPECT_LT((found->corners[7] - predicted[7]).norm(), kCornerTolerancePx);
  // The same search one board-width to the side finds nothing.
  std::vector<Vec2d> elsewhere;
  for (const Vec2d& p : outline) elsewhere.push_back(p + Vec2d(150, 0));
  EXPECT_FALSE(FindBoardInRegion(photo, {rig.board}, 0, elsewhere, nullptr, DetectOptions(), &why).has_value());
  EXPECT_FALSE(why.empty());
}

class RefinerTest : public ::testing::TestWithParam<CornerRefiner> {};

TEST_P(RefinerTest, PullsPerturbedCornersBackAndDropsLostOnes) {
  SyntheticRig rig = MakeRig(1, 1);
  const Rigid3 pose = TiltedPose(rig.board);
  const Image photo = RenderBoardPhoto(rig, 0, pose, kNoise, 6);
  std::vector<Vec2d> corners, truth;
  for (int k = 0; k < rig.board.CornerCount(); ++k) {
    truth.push_back(Project(rig, 0, pose, rig.board.Corner(k)));
    corners.push_back(truth.back() + Vec2d(k % 2 ? 0.7 : -0.6, k % 3 ? 0.5 : -0.7));
  }
  corners[0] = Vec2d(-50, -50);  // outside the photo: cannot be refined
  std::vector<uint8_t> valid;
  std::vector<int> window;
  double shift = 0;
  DetectOptions options;
  options.refiner = GetParam();
  RefineCorners(photo, rig.board, options, &corners, &valid, &window, &shift);
  EXPECT_EQ(valid[0], 0);
  EXPECT_EQ(corners[0], Vec2d(-50, -50));  // a dropped corner keeps its start
  for (int k = 1; k < rig.board.CornerCount(); ++k) {
    EXPECT_EQ(valid[k], 1) << k;
    EXPECT_LT((corners[k] - truth[k]).norm(), kCornerTolerancePx) << k;
    EXPECT_GE(window[k], options.min_half_window);
    if (options.refiner == CornerRefiner::kCornerSubPix) {
      EXPECT_LE(window[k], options.max_half_window);
    }
  }
  EXPECT_GT(shift, 0.5);
}

INSTANTIATE_TEST_SUITE_P(BoardDetect, RefinerTest,
                         ::testing::Values(CornerRefiner::kSymmetry, CornerRefiner::kCornerSubPix),
                         [](const auto& info) { return std::string(CornerRefinerName(info.param)); });

// RMS distance of refined corners from the true projections, started 0.3 px off (deterministic
// pattern), on `photo` of rig.board at `pose`.
double RefinedRms(const SyntheticRig& rig, const Rigid3& pose, const Image& photo, const DetectOptions& options) {
  std::vector<Vec2d> corners, truth;
  for (int k = 0; k < rig.board.CornerCount(); ++k) {
    truth.push_back(Project(rig, 0, pose, rig.board.Corner(k)));
    corners.push_back(truth.back() + Vec2d(k % 2 ? 0.3 : -0.3, k % 3 ? 0.2 : -0.3));
  }
  std::vector<uint8_t> valid;
  std::vector<int> window;
  double shift = 0;
  RefineCorners(photo, rig.board, options, &corners, &valid, &window, &shift);
  double sum = 0;
  for (int k = 0; k < rig.board.CornerCount(); ++k) {
    EXPECT_EQ(valid[k], 1) << k;
    sum += (corners[k] - truth[k]).squaredNorm();
  }
  return std::sqrt(sum / rig.board.CornerCount());
}

TEST(BoardDetect, SymmetryRefinementIsMoreAccurateThanCornerSubPix) {
  SyntheticRig rig = MakeRig(1, 1);
  DetectOptions subpix;
  subpix.refiner = CornerRefiner::kCornerSubPix;
  DetectOptions symmetry;
  symmetry.photos_srgb = false;  // the test renders linear values
  double sum_sub = 0, sum_sym = 0;
  for (int view = 0; view < 4; ++view) {
    const Rigid3 pose = TiltedPose(rig.board, 10 + 25 * view);
    const Image photo = RenderBoardPhoto(rig, 0, pose, kNoise, 20 + view);
    const double sub = RefinedRms(rig, pose, photo, subpix), sym = RefinedRms(rig, pose, photo, symmetry);
    sum_sub += sub * sub;
    sum_sym += sym * sym;
  }
  // Measured: cornerSubPix 0.030 px RMS, the symmetry refinement 0.006 px (0.0056-0.0067 per view).
  EXPECT_LT(std::sqrt(sum_sym / 4), kSymmetryTolerancePx);
  EXPECT_LT(std::sqrt(sum_sym / 4), 0.5 * std::sqrt(sum_sub / 4));
}

TEST(BoardDetect, ShadingTermsFollowALightGradient) {
  SyntheticRig rig = MakeRig(1, 1);
  const Rigid3 pose = TiltedPose(rig.board);
  Image photo = RenderBoardPhoto(rig, 0, pose, kNoise, 31);
  // Light from 0.25 to 0.95 of full over the frame, with a cubic term, as towards a turntable plate.
  for (int y = 0; y < photo.height; ++y) {
    for (int x = 0; x < photo.width; ++x) {
      const double u = (x - 0.5 * photo.width) / photo.width, v = (y - 0.5 * photo.height) / photo.height;
      photo.at(x, y) *= float(0.6 + 0.5 * v + 0.8 * v * v * v + 0.2 * u);
    }
  }
  DetectOptions flat;
  flat.photos_srgb = false;
  flat.symmetry_shading = false;
  DetectOptions shaded = flat;
  shaded.symmetry_shading = true;
  // Measured: 0.044 px RMS with a symmetric light assumed, 0.007 px with the shading terms.
  const double flat_rms = RefinedRms(rig, pose, photo, flat), shaded_rms = RefinedRms(rig, pose, photo, shaded);
  EXPECT_LT(shaded_rms, kSymmetryTolerancePx);
  EXPECT_GT(flat_rms, 2 * shaded_rms);
}

TEST(BoardDetect, SrgbPhotosAreDecoded) {
  SyntheticRig rig = MakeRig(1, 1);
  const Rigid3 pose = TiltedPose(rig.board);
  Image photo = RenderBoardPhoto(rig, 0, pose, kNoise, 41);
  for (float& v : photo.data) v = LinearToSrgb(std::clamp(v, 0.0f, 1.0f));
  // Measured 0.007 px RMS (as on the linear photo): the decoding restores the linear values.
  EXPECT_LT(RefinedRms(rig, pose, photo, DetectOptions()), kSymmetryTolerancePx);
}

TEST(BoardDetect, OptionsAreValidated) {
  DetectOptions o;
  EXPECT_TRUE(o.Validate().ok());
  o.window_fraction = 0.5;
  EXPECT_FALSE(o.Validate().ok());
  o = DetectOptions();
  o.max_half_window = 1;
  EXPECT_FALSE(o.Validate().ok());
}

}  // namespace
}  // namespace reflcap::calib
