#pragma once
// calib/1: the on-disk description of a calibration session (../shared/data/calib/*/README.md),
// in capture/1's conventions (world z up, metres, OpenCV cameras, turntable right-hand rule).
//   cameras[]            id, width, height; K and dist when the intrinsics are known (optional)
//   turntable.angles_deg the turntable readings used
//   images[]             photos of the checkerboard cuboid: file, camera, turntable_deg
//   intrinsics_images[]  photos of the planar board: file, camera
//   cuboid               the box: faces[] each with a checkerboard (normal, u_axis, v_axis,
//                        squares, inner_corners, square_m, board_margin_m, first_inner_corner_box)
//   intrinsics_board     the planar board (squares, inner_corners, square_m, margin_m)
//   ground_truth         optional: cam_from_world, turntable {axis, point}, world_from_box_at_0,
//                        intrinsics, cam_from_box per image (synthetic sessions only)
// ReadCalibFile validates every field it reads and the rule the board detector relies on (no two
// faces share an inner-corner grid, so a found grid names its face); each error names file and
// field. A board whose square counts are both even or both odd looks the same turned by 180
// degrees (a square one by 90): its corners can be numbered only with the help of the rest of the
// target (BoardSpec::Symmetry; calib/turntable.h resolves it).
#include <array>
#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "engine/core/status.h"
#include "engine/geometry/rigid3.h"
#include "engine/math/types.h"

namespace reflcap::calib {

// A planar checkerboard on a target (a cuboid face, or the planar board). Square (a, b) — a along
// u, b along v, seen from the printed side with u right and v down — is black when a + b is even.
// Inner corner (i, j) sits at origin + square_m * (i u + j v); corners are listed row-major
// (j outer, i inner), which is OpenCV's order for patternSize (corners_x, corners_y).
struct BoardSpec {
  std::string name;          // the face name ("+x") or "intrinsics_board"
  std::string field;         // where it came from in the file ("cuboid.faces[2]")
  int squares_x = 0;         // squares along u
  int squares_y = 0;         // squares along v
  int corners_x = 0;         // inner corners along u (= squares_x - 1)
  int corners_y = 0;         // inner corners along v
  double square_m = 0;       // square side, metres
  double margin_u_m = 0;     // plain white border beyond the outer squares along u (0: unknown)
  double margin_v_m = 0;     // ... along v
  Vec3d origin = Vec3d::Zero();   // inner corner (0, 0), target frame
  Vec3d u_axis = Vec3d::UnitX();  // unit, target frame
  Vec3d v_axis = Vec3d::UnitY();  // unit, target frame
  Vec3d normal = -Vec3d::UnitZ(); // unit, pointing out of the printed side (= -(u x v))

  int CornerCount() const { return corners_x * corners_y; }
  // How many numberings of the inner corners show the same colours: 1 when the square counts are
  // one odd and one even; 2 when both have the same parity (a 180-degree turn keeps every square's
  // colour); 4 for an odd square board (90-degree turns too).
  int Symmetry() const {
    if ((squares_x + squares_y) % 2 == 1) return 1;
    return squares_x == squares_y && squares_x % 2 == 1 ? 4 : 2;
  }
  // Target-frame point at board coordinates (i, j) in squares from inner corner (0, 0): inner
  // corners at integers, square (a, b)'s centre at (a - 0.5, b - 0.5).
  Vec3d Point(double i, double j) const { return origin + square_m * (i * u_axis + j * v_axis); }
  Vec3d Corner(int index) const { return Point(index % corners_x, index / corners_x); }
};

struct CalibCamera {
  std::string id;
  int width = 0;
  int height = 0;
  bool has_intrinsics = false;   // K (and dist, zeros when absent) were given
  Mat3d K = Mat3d::Identity();   // [[fx,0,cx],[0,fy,cy],[0,0,1]], pixels
  std::array<double, 5> dist{};  // k1, k2, p1, p2, k3 (OpenCV)
};

// One photo of the cuboid.
struct CuboidImage {
  std::string file;  // relative to the calib file's folder
  int camera = 0;    // index into CalibFile::cameras
  double turntable_deg = 0;
  int angle = 0;     // index into CalibFile::angles_deg
};

// One photo of the planar board.
struct BoardImage {
  std::string file;
  int camera = 0;
};

struct CalibGroundTruth {
  // Extrinsics (all present or none).
  bool has_extrinsics = false;
  std::vector<Rigid3> cam_from_world;  // per camera
  Vec3d axis = Vec3d::UnitZ();         // turntable axis, world
  Vec3d point = Vec3d::Zero();         // a point of the axis, world
  std::optional<Rigid3> world_from_box_at_0;
  // Intrinsics (per camera; present or not).
  bool has_intrinsics = false;
  std::vector<Mat3d> K;
  std::vector<std::array<double, 5>> dist;
  // Per photo (optional), keyed by file.
  std::map<std::string, Rigid3> cam_from_box;
  std::map<std::string, Rigid3> cam_from_board;
};

struct CalibFile {
  std::filesystem::path json_path;
  int minor_version = 0;
  std::vector<CalibCamera> cameras;
  std::vector<double> angles_deg;  // turntable readings (degrees)
  std::vector<CuboidImage> images;
  std::vector<BoardImage> board_images;
  std::vector<BoardSpec> faces;        // the cuboid's boards (empty: no cuboid)
  std::optional<BoardSpec> board;      // the planar intrinsics board
  std::optional<CalibGroundTruth> ground_truth;

  std::filesystem::path Folder() const { return json_path.parent_path(); }
  std::filesystem::path Resolve(const std::string& relative) const { return Folder() / relative; }
  int FindCamera(const std::string& id) const;  // -1 when absent
};

// Parses and validates a calib/1 file (fields only; no photo is opened).
StatusOr<CalibFile> ReadCalibFile(const std::filesystem::path& json_path);
// Same from text; `name` stands for the file in messages and resolves relative paths.
StatusOr<CalibFile> ParseCalibFile(const std::string& text, const std::filesystem::path& name);

// Opens the header of every photo the verb will read (cuboid photos, or board photos): each must
// exist, be readable and have its camera's size. Fails fast, before any detection, naming the
// field ("images[3].file") and the file.
Status CheckCuboidPhotos(const CalibFile& file);
Status CheckBoardPhotos(const CalibFile& file);

// The checks that make a cuboid session usable by `calibrate turntable` (images, angles, faces,
// at least two distinct angles); an error names the field.
Status CheckCuboidSession(const CalibFile& file);
// The checks that make a session usable by `calibrate intrinsics` (board, board images).
Status CheckBoardSession(const CalibFile& file);

}  // namespace reflcap::calib
