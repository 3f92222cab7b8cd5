#pragma once
// Synthetic calibration sessions for calib/'s tests: a rig with known cameras (OpenCV distortion),
// a tilted and offset turntable axis, a checkerboard cuboid like the shared one (five boards, one
// of them symmetric) and a planar board; rendered photos (a ray per sub-sample through the exact
// inverse distortion, 3x3 box-filtered, blurred, 8-bit with noise) and exact corner projections, written as
// a calib/1 session with ground truth.
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "calib/calib_file.h"
#include "calib/camera_model.h"
#include "calib/turntable.h"
#include "engine/geometry/rigid3.h"
#include "engine/image/image.h"

namespace reflcap::calib::testing {

struct SyntheticRig {
  int width = 400;
  int height = 400;
  std::vector<IntrinsicParams> intrinsics;  // per camera
  std::vector<Rigid3> cam_from_world;       // per camera
  Vec3d axis = Vec3d::UnitZ();
  Vec3d point = Vec3d::Zero();
  Rigid3 world_from_box0;
  std::vector<double> angles_deg;           // turntable readings
  std::vector<double> angle_offsets_deg;    // true offsets (backlash), per angle
  std::vector<BoardSpec> faces;             // the cuboid's boards
  BoardSpec board;                          // the planar board
  std::vector<std::vector<Rigid3>> cam_from_board;  // per camera: poses of its board photos

  // The true cuboid pose in a photo (reading angle index a).
  Rigid3 CamFromBox(int camera, int angle) const;
};

// `cameras` cameras on an arc (elevations 15..65 degrees), `angles` readings over 360 degrees; the
// axis tilted 1 degree and offset by a few millimetres; the cuboid off the axis and yawed.
SyntheticRig MakeRig(int cameras, int angles);
// The shared data's cuboid: 0.10 x 0.08 x 0.12 m, boards on +x, -x, +y, -y, +z (+z symmetric).
std::vector<BoardSpec> CuboidFaces();
// 9x6 squares of 12 mm with a 10 mm margin.
BoardSpec PlanarBoard();

// Renders one photo of the cuboid / the planar board (grey, 0..1) with additive Gaussian noise.
Image RenderCuboidPhoto(const SyntheticRig& rig, int camera, int angle, double noise, uint64_t seed);
Image RenderBoardPhoto(const SyntheticRig& rig, int camera, const Rigid3& cam_from_board, double noise,
                       uint64_t seed);

struct SessionOptions {
  bool with_intrinsics = true;   // cameras[].K, dist in the file
  bool with_truth = true;        // ground_truth block
  int board_photos_per_camera = 0;
  double noise = 0.004;          // image noise (0..1 scale), ~1 grey level
  bool render_photos = true;     // false: calib.json only (for tests on given corners)
};

// Writes calib.json and the photos (images/camN_AAA.png, intrinsics/camN_XX.png) into `dir`;
// returns calib.json's path. Board poses are generated when the rig has none.
std::filesystem::path WriteSession(SyntheticRig* rig, const std::filesystem::path& dir, const SessionOptions& options);

// Exact projections of every face seen at cos >= min_cos in every photo of `file` (which must
// list the rig's photos), plus Gaussian noise of noise_px per axis.
std::vector<std::vector<FaceCorners>> ProjectedCorners(const SyntheticRig& rig, const CalibFile& file,
                                                       double noise_px, double min_cos, uint64_t seed);

}  // namespace reflcap::calib::testing
