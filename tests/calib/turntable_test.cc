// The turntable calibration: recovery of a known rig from exact corner projections with Gaussian
// noise (the adjustment, its sigmas, the baseline, angle offsets, intrinsics, outliers), errors for
// degenerate sessions, and the whole pipeline on rendered photos.
#include "calib/turntable.h"

#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include "calib/rig_io.h"
#include "engine/capture/capture.h"
#include "tests/calib/synthetic_session.h"
#include "tests/support/test_support.h"

namespace reflcap::calib {
namespace {

using testing::MakeRig;
using testing::ProjectedCorners;
using testing::SyntheticRig;

// Corner noise of the synthetic corners, per axis: the shared cuboid photos' detected corners sit
// 0.06 px RMS (0.042 per axis) from their true projections.
constexpr double kNoisePx = 0.045;
// An estimate more than this many of its own sigmas from the truth means the sigma or the
// estimate is wrong (Gaussian: P(|z| > 4.5) < 1e-5 per quantity).
constexpr double kMaxSigmas = 4.5;

// A calib/1 session for `rig` (photos listed, not written), parsed back.
CalibFile SessionFile(SyntheticRig* rig, const std::filesystem::path& dir) {
  testing::SessionOptions o;
  o.render_photos = false;
  auto path = testing::WriteSession(rig, dir, o);
  auto file = ReadCalibFile(path);
  REFLCAP_CHECK(file.ok()) << file.status().ToString();
  return *file;
}

std::vector<IntrinsicParams> Truth(const SyntheticRig& rig) { return rig.intrinsics; }

class TurntableFromCorners : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new reflcap::testing::ScratchDir();
    rig_ = new SyntheticRig(MakeRig(3, 8));
    file_ = new CalibFile(SessionFile(rig_, dir_->path()));
  }
  static void TearDownTestSuite() {
    delete file_;
    delete rig_;
    delete dir_;
  }
  static reflcap::testing::ScratchDir* dir_;
  static SyntheticRig* rig_;
  static CalibFile* file_;
};
reflcap::testing::ScratchDir* TurntableFromCorners::dir_ = nullptr;
SyntheticRig* TurntableFromCorners::rig_ = nullptr;
CalibFile* TurntableFromCorners::file_ = nullptr;

TEST_F(TurntableFromCorners, ExactCornersGiveTheExactRig) {
  const auto corners = ProjectedCorners(*rig_, *file_, 0.0, 0.35, 1);
  auto r = CalibrateTurntableFromCorners(*file_, Truth(*rig_), corners, TurntableOptions());
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  ASSERT_TRUE(r->truth.has_value());
  // Exact data: what is left is the solver's tolerance (1e-12 relative) and double rounding.
  EXPECT_LT(r->total.rms_px, 1e-5);
  EXPECT_LT(r->truth->axis_deg, 1e-6);
  EXPECT_LT(r->truth->point_mm, 1e-5);
  EXPECT_LT(r->truth->max_camera_rotation_deg, 1e-6);
  EXPECT_LT(r->truth->max_camera_centre_mm, 1e-5);
  EXPECT_LT(r->truth->box_translation_max_mm, 1e-5);
  // The output gauge: z along the axis, origin on it, camera 0 in the xz half-plane x > 0.
  EXPECT_LT((r->rig.axis - Vec3d::UnitZ()).norm(), 1e-12);
  EXPECT_LT(r->rig.point.norm(), 1e-12);
  const Vec3d centre0 = r->rig.cam_from_world[0].Inverse().translation;
  EXPECT_NEAR(centre0.y(), 0, 1e-9);
  EXPECT_GT(centre0.x(), 0);
}

TEST_F(TurntableFromCorners, NoisyCornersStayWithinTheirSigmas) {
  const auto corners = ProjectedCorners(*rig_, *file_, kNoisePx, 0.35, 2);
  auto r = CalibrateTurntableFromCorners(*file_, Truth(*rig_), corners, TurntableOptions());
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  const TruthComparison& t = *r->truth;
  EXPECT_LT(t.axis_deg, kMaxSigmas * r->sigma.axis_deg);
  EXPECT_LT(t.point_mm, kMaxSigmas * r->sigma.point_mm);
  for (size_t c = 1; c < rig_->cam_from_world.size(); ++c) {
    EXPECT_LT(t.camera_rotation_deg[c], kMaxSigmas * r->sigma.camera_rotation_deg[c].norm()) << c;
    EXPECT_LT(t.camera_centre_mm[c], kMaxSigmas * r->sigma.camera_centre_mm[c].norm()) << c;
  }
  // The residual RMS estimates the corner noise: sqrt(2) kNoisePx per corner, less the parameters'
  // share (a few percent at these counts).
  EXPECT_NEAR(r->total.rms_px, std::sqrt(2.0) * kNoisePx, 0.1 * kNoisePx);
}

// What the adjustment buys over averaging per-angle poses, on average over noise draws (in one
// draw the baseline can be luckier on one quantity).
TEST_F(TurntableFromCorners, BeatsTheAveragedPosesBaselineOnAverage) {
  constexpr int kDraws = 8;
  double ba[5] = {}, base[5] = {};
  for (int d = 0; d < kDraws; ++d) {
    const auto corners = ProjectedCorners(*rig_, *file_, kNoisePx, 0.35, 100 + d);
    auto r = CalibrateTurntableFromCorners(*file_, Truth(*rig_), corners, TurntableOptions());
    ASSERT_TRUE(r.ok()) << r.status().ToString();
    for (const auto& [sum, t, rms] : {std::tuple{ba, &*r->truth, r->total.rms_px},
                                      std::tuple{base, &*r->baseline_truth, r->baseline_total.rms_px}}) {
      sum[0] += t->max_axis_deg * t->max_axis_deg;
      sum[1] += t->max_point_mm * t->max_point_mm;
      sum[2] += t->max_camera_rotation_deg * t->max_camera_rotation_deg;
      sum[3] += t->max_camera_centre_mm * t->max_camera_centre_mm;
      sum[4] += rms * rms;
    }
  }
  const char* names[5] = {"axis", "axis point", "camera rotation", "camera centre", "reprojection"};
  for (int q = 0; q < 5; ++q) EXPECT_LT(ba[q], base[q]) << names[q];
}

TEST_F(TurntableFromCorners, AngleOffsetsAreRecovered) {
  SyntheticRig rig = *rig_;
  // Stepper backlash: a few hundredths of a degree, different at every angle.
  for (size_t a = 0; a < rig.angle_offsets_deg.size(); ++a) rig.angle_offsets_deg[a] = 0.03 * std::sin(1.7 * a + 0.4);
  const auto corners = ProjectedCorners(rig, *file_, kNoisePx, 0.35, 3);
  TurntableOptions options;
  auto without = CalibrateTurntableFromCorners(*file_, Truth(rig), corners, options);
  options.angle_offsets = true;
  auto with = CalibrateTurntableFromCorners(*file_, Truth(rig), corners, options);
  ASSERT_TRUE(without.ok() && with.ok());
  EXPECT_LT(with->total.rms_px, without->total.rms_px);
  // Offsets relative to the first angle's (the gauge: a common offset is the cuboid's yaw).
  for (size_t a = 1; a < rig.angles_deg.size(); ++a) {
    const double truth = rig.angle_offsets_deg[a] - rig.angle_offsets_deg[0];
    EXPECT_NEAR(with->rig.angle_offset_deg[a], truth, kMaxSigmas * with->sigma.angle_offset_deg[a]) << a;
    EXPECT_GT(with->sigma.angle_offset_deg[a], 0) << a;
  }
  EXPECT_EQ(with->rig.angle_offset_deg[0], 0.0);
}

TEST_F(TurntableFromCorners, RefinedIntrinsicsMoveToTheTruth) {
  std::vector<IntrinsicParams> start = Truth(*rig_);
  for (IntrinsicParams& p : start) {
    p[kFx] += 6;
    p[kFy] += 6;
    p[kCx] -= 4;
    p[kCy] += 3;
    p[kK1] += 0.01;
  }
  const auto corners = ProjectedCorners(*rig_, *file_, kNoisePx, 0.35, 4);
  TurntableOptions options;
  options.refine_intrinsics = true;
  auto r = CalibrateTurntableFromCorners(*file_, start, corners, options);
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  for (size_t c = 0; c < start.size(); ++c) {
    const IntrinsicParams& e = r->truth->intrinsics_error[c];
    const IntrinsicParams& s = r->sigma.intrinsics[c];
    EXPECT_LT(std::abs(e[kFx]), kMaxSigmas * s[kFx]) << c;
    EXPECT_LT(std::abs(e[kCx]), kMaxSigmas * s[kCx]) << c;
    EXPECT_LT(std::abs(e[kCy]), kMaxSigmas * s[kCy]) << c;
    // Moved most of the way from the 6 px start error.
    EXPECT_LT(std::abs(e[kFx]), 3.0) << c;
    // Held terms stay at their start; tied focal lengths stay equal.
    EXPECT_EQ(r->rig.intrinsics[c][kK3], start[c][kK3]);
    EXPECT_EQ(r->rig.intrinsics[c][kFx], r->rig.intrinsics[c][kFy]);
  }
}

TEST_F(TurntableFromCorners, OutlierCornersAreRejected) {
  auto corners = ProjectedCorners(*rig_, *file_, kNoisePx, 0.35, 5);
  int displaced = 0;
  for (auto& photo : corners) {
    if (photo.empty() || displaced >= 6) continue;
    photo[0].corners[3] += Vec2d(2.0, -1.5);
    ++displaced;
  }
  auto r = CalibrateTurntableFromCorners(*file_, Truth(*rig_), corners, TurntableOptions());
  ASSERT_TRUE(r.ok());
  int rejected = 0;
  for (const FaceView& v : r->views) rejected += v.corners_rejected;
  EXPECT_GE(rejected, displaced);
  EXPECT_LT(r->total.max_px, 2.0);
  EXPECT_LT(r->truth->point_mm, kMaxSigmas * r->sigma.point_mm);
}

TEST_F(TurntableFromCorners, ACameraThatSawNothingIsAnErrorNamingIt) {
  auto corners = ProjectedCorners(*rig_, *file_, kNoisePx, 0.35, 6);
  for (size_t i = 0; i < file_->images.size(); ++i) {
    if (file_->images[i].camera == 2) corners[i].clear();
  }
  auto r = CalibrateTurntableFromCorners(*file_, Truth(*rig_), corners, TurntableOptions());
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("camera \"cam2\": the cuboid was found in none of its 8 photos"),
            std::string::npos)
      << r.status().message();
}

TEST_F(TurntableFromCorners, TheCuboidAtOneAngleOnlyIsAnError) {
  auto corners = ProjectedCorners(*rig_, *file_, kNoisePx, 0.35, 7);
  for (size_t i = 0; i < file_->images.size(); ++i) {
    if (file_->images[i].angle != 0) corners[i].clear();
  }
  auto r = CalibrateTurntableFromCorners(*file_, Truth(*rig_), corners, TurntableOptions());
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("images:"), std::string::npos) << r.status().message();
}

TEST(TurntableOptions, AreValidated) {
  TurntableOptions o;
  EXPECT_TRUE(o.Validate().ok());
  o.min_cos = 1.2;
  EXPECT_FALSE(o.Validate().ok());
  o = TurntableOptions();
  o.view_rms_factor = 1;
  EXPECT_FALSE(o.Validate().ok());
  o = TurntableOptions();
  o.intrinsics_model.tie_focal = true;
  o.intrinsics_model.free = {kCx};
  EXPECT_FALSE(o.Validate().ok());
}

TEST(IntrinsicsModel, ParsesListsAndTiesTheFocalLength) {
  auto m = IntrinsicsModel::Parse("f,cx,cy,k1");
  ASSERT_TRUE(m.ok());
  EXPECT_TRUE(m->tie_focal);
  EXPECT_EQ(m->TangentSize(), 4);
  EXPECT_EQ(m->ToString(), "f,cx,cy,k1");
  const Eigen::MatrixXd basis = m->Basis();
  EXPECT_EQ(basis(kFx, 0), 1);
  EXPECT_EQ(basis(kFy, 0), 1);
  EXPECT_EQ(basis(kK2, 3), 0);
  EXPECT_FALSE(IntrinsicsModel::Parse("fx,q").ok());
  EXPECT_FALSE(IntrinsicsModel::Parse("fx,fx").ok());
}

// The whole pipeline on rendered photos: detection (with the symmetric +z board), the baseline,
// the adjustment, RIG.json merged into a capture.
TEST(TurntableRendered, CalibratesTheRigFromPhotos) {
  reflcap::testing::ScratchDir dir;
  SyntheticRig rig = MakeRig(2, 6);
  testing::SessionOptions o;
  const auto path = testing::WriteSession(&rig, dir.path(), o);
  auto file = ReadCalibFile(path);
  ASSERT_TRUE(file.ok()) << file.status().ToString();
  TurntableOptions options;
  options.threads = 2;
  auto r = CalibrateTurntable(*file, rig.intrinsics, options);
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  // Every face the true pose shows at cos >= min_cos was found, numbered and used (+z, the
  // symmetric board, included).
  int expected = 0, used = 0;
  for (size_t i = 0; i < file->images.size(); ++i) {
    const Rigid3 pose = rig.CamFromBox(file->images[i].camera, file->images[i].angle);
    for (const BoardSpec& f : rig.faces) {
      const Vec3d centre = pose * f.Point(0.5 * (f.corners_x - 1), 0.5 * (f.corners_y - 1));
      expected += -(pose.rotation * f.normal).dot(centre.normalized()) >= options.min_cos;
    }
  }
  for (const FaceView& v : r->views) used += v.used;
  EXPECT_EQ(used, expected);
  // Blurred renders with one grey level of noise: 0.02-0.09 px per face view (axis-aligned and
  // foreshortened boards are the noisier ones).
  EXPECT_LT(r->total.rms_px, 0.1);
  const TruthComparison& t = *r->truth;
  EXPECT_LT(t.axis_deg, kMaxSigmas * r->sigma.axis_deg);
  EXPECT_LT(t.point_mm, kMaxSigmas * r->sigma.point_mm);
  EXPECT_LT(t.camera_rotation_deg[1], kMaxSigmas * r->sigma.camera_rotation_deg[1].norm());
  EXPECT_LT(t.camera_centre_mm[1], kMaxSigmas * r->sigma.camera_centre_mm[1].norm());

  // RIG.json merged into a capture of the same cameras is a valid capture/1.
  const std::string capture_json = R"({"format": "capture/1", "mesh": "mesh.obj",
    "cameras": [{"id": "cam1", "width": 400, "height": 400, "K": [[900,0,200],[0,900,200],[0,0,1]],
                 "cam_from_world": [[1,0,0,0],[0,1,0,0],[0,0,1,1],[0,0,0,1]]}],
    "lights": [{"id": "L0", "type": "point", "position": [0, 0, 1], "intensity": [1, 1, 1]}],
    "turntable": {"axis": [0, 0, 1], "point": [0, 0, 0]},
    "images": [{"file": "img/0.exr", "camera": "cam1", "light": "L0", "turntable_deg": 30}]})";
  auto capture = ParseCapture(capture_json, dir.path() / "capture" / "capture.json");
  ASSERT_TRUE(capture.ok()) << capture.status().ToString();
  auto merged = MergeRigIntoCapture(*capture, *file, *r, options, {"test", ""}, dir.path() / "out");
  ASSERT_TRUE(merged.ok()) << merged.status().ToString();
  auto back = ParseCapture(*merged, dir.path() / "out" / "capture.json");
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  EXPECT_EQ(back->mesh, "../capture/mesh.obj");
  EXPECT_EQ(back->images[0].file, "../capture/img/0.exr");
  EXPECT_LT((back->cameras[0].cam_from_world.rotation - r->rig.cam_from_world[1].rotation).norm(), 1e-12);
  EXPECT_LT((back->turntable->axis - r->rig.axis).norm(), 1e-12);
  EXPECT_NE(merged->find("\"calibration\""), std::string::npos);
  // A capture camera the calibration does not know is an error naming it.
  std::string foreign_json = capture_json;
  for (size_t at = foreign_json.find("\"cam1\""); at != std::string::npos; at = foreign_json.find("\"cam1\"")) {
    foreign_json.replace(at, 6, "\"camX\"");
  }
  auto foreign = ParseCapture(foreign_json, dir.path() / "capture" / "capture.json");
  ASSERT_TRUE(foreign.ok());
  auto refused = MergeRigIntoCapture(*foreign, *file, *r, options, {"test", ""}, dir.path() / "out");
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.status().message().find("cameras[0].id: camera \"camX\""), std::string::npos);
}

}  // namespace
}  // namespace reflcap::calib

