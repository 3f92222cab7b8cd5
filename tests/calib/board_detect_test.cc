// Board detection on rendered photos: a board is found, named and numbered by its colours, its
// corners land on the true projections; a symmetric board comes back with its other numbering; a
// grid that is part of a larger board is refused.
#include "calib/board_detect.h"

#include <gtest/gtest.h>

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

TEST(BoardDetect, RefinementPullsPerturbedCornersBackAndDropsLostOnes) {
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
  RefineCorners(photo, rig.board, DetectOptions(), &corners, &valid, &window, &shift);
  EXPECT_EQ(valid[0], 0);
  for (int k = 1; k < rig.board.CornerCount(); ++k) {
    EXPECT_EQ(valid[k], 1) << k;
    EXPECT_LT((corners[k] - truth[k]).norm(), kCornerTolerancePx) << k;
    EXPECT_GE(window[k], DetectOptions().min_half_window);
    EXPECT_LE(window[k], DetectOptions().max_half_window);
  }
  EXPECT_GT(shift, 0.5);
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
