#pragma once
// The rig from photos of the checkerboard cuboid on the turntable (`reflcap calibrate turntable`):
// every camera's pose (fixed on the arm), the turntable's axis and the cuboid's pose, estimated
// together so that the cuboid's poses lie on the circles the turntable describes (the seed
// paper's section 3.3, done by one bundle adjustment instead of averaging).
//
// Detection (per photo): a full-image search finds one board whose numbering is unambiguous
// (board_detect.h); PnP with the camera's intrinsics gives the cuboid's pose; every other face
// that pose shows at cos >= min_cos is searched inside its predicted outline (faster, and no
// look-alike grid elsewhere can be taken for it). A face whose board is symmetric (BoardSpec::
// Symmetry) gets its numbering from the other faces of its photo, else from the rig (below).
//
// Start (the seed's baseline, reported beside the adjustment): per camera, the cuboid's pose at
// each angle by PnP; the axis from the mean of the rotation axes of every pair of poses and the
// axis point by least squares on their screw motions; a turntable frame per camera (z = axis,
// origin where the axis meets the cuboid's bottom plane, x = the cuboid's x at angle 0); the
// cameras' relative poses follow from those frames. Photos whose only boards are symmetric are
// numbered by the hypothesis that agrees with their camera's pose from the other photos.
//
// Bundle adjustment (Ceres, Huber loss): residual = projected - detected corner, pixels, for every
// corner of every face view; parameters: each camera's pose (camera 0 fixes the gauge), the axis
// direction (2 DOF), the axis point (2 DOF: where the axis crosses a plane), the cuboid's pose at
// angle 0 (6 DOF), optionally one angle offset per turntable angle (stepper backlash; the first
// angle's is 0: a common offset is the cuboid's yaw) and each camera's intrinsics (fx, fy, cx, cy,
// k1, k2, p1, p2; k3 on request). Corners beyond outlier_sigmas robust sigmas and face views far
// worse than the median are rejected and the adjustment repeated. The covariance gives the
// standard deviation of every parameter.
//
// Output gauge: world = the turntable frame: origin where the axis meets the cuboid's bottom face
// (the plate's top), z along the axis (right-hand rule: the turntable turns counter-clockwise
// seen from +z), x towards camera 0 (its centre's component perpendicular to the axis).
#include <array>
#include <optional>
#include <string>
#include <vector>

#include "calib/board_detect.h"
#include "calib/calib_file.h"
#include "calib/camera_model.h"
#include "calib/intrinsics.h"
#include "engine/camera/camera.h"
#include "engine/core/status.h"
#include "engine/geometry/rigid3.h"

namespace reflcap::calib {

struct TurntableOptions {
  bool refine_intrinsics = false;  // adjust every camera's intrinsics with the rig
  // With refine_intrinsics: which; the others are held at their start.
  // Default: one focal length (square pixels), the principal point, k1, k2, p1 and p2; k3 held
  // (a narrow lens cannot separate it from k1 and k2). The tangential terms trade against the
  // principal point (its sigma halves without them) but holding them at anything but their true
  // value moves it by pixels (the shared cuboid session: 4 px with p1 = p2 = 0 held).
  IntrinsicsModel intrinsics_model{{kFx, kFy, kCx, kCy, kK1, kK2, kP1, kP2}, true};
  // With refine_intrinsics: the file's planar-board photos (intrinsics_images) join the
  // adjustment, each with a pose of its own. A camera looking straight at the cuboid's top sees a
  // plane, whose focal length trades against its distance; the tilted boards pin it.
  bool board_photos = true;
  bool angle_offsets = false;      // one offset per turntable angle (stepper backlash)
  // Face views seen more obliquely than this (cosine between the face normal and the direction to
  // the camera) are not used, in (0, 1). Corner noise grows below ~0.35: on the shared cuboid
  // photos (true start) the symmetry refinement errs 0.023-0.031 px RMS at cos >= 0.35 but 0.056 px
  // at 0.2-0.35 (cornerSubPix 0.05-0.07 and 0.21 px); 0.2 adds 7 of 89 face views there.
  double min_cos = 0.35;
  // Weight each face view (and board photo) by its own corner noise, estimated from its residuals
  // and re-estimated every round: a foreshortened or badly lit board's corners are noisier (0.04 to
  // 0.09 px RMS per view on the shared cuboid photos with cornerSubPix).
  bool weight_views = true;
  double loss_scale_px = 0.5;      // Huber scale, pixels (> 0); as IntrinsicsOptions
  double outlier_sigmas = 5;       // corner rejection, robust sigmas (> 0); as IntrinsicsOptions
  double view_rms_factor = 3;      // face-view rejection; as IntrinsicsOptions
  double min_rejected_view_rms_px = 0.25;
  int threads = 0;                 // 0: all cores
  DetectOptions detect;

  Status Validate() const;
};

// The turntable model in one gauge: cameras, axis, cuboid pose at angle 0, angle offsets.
struct RigModel {
  std::vector<IntrinsicParams> intrinsics;  // per camera
  std::vector<Rigid3> cam_from_world;       // per camera
  Vec3d axis = Vec3d::UnitZ();              // unit, world
  Vec3d point = Vec3d::Zero();              // where the axis meets the cuboid's bottom plane at 0
  Rigid3 world_from_box0;                   // the cuboid at turntable angle 0
  std::vector<double> angle_offset_deg;     // per turntable angle (zeros when not estimated)

  // The cuboid's pose at a turntable reading (angle index, for its offset).
  Rigid3 WorldFromBox(double angle_deg, int angle) const;
  Rigid3 CamFromBox(int camera, double angle_deg, int angle) const;
  // Pixel of a cuboid point; false when behind the camera.
  bool Project(int camera, double angle_deg, int angle, const Vec3d& p_box, Vec2d* pixel) const;
  // The same model in another world frame: new_from_old maps old world points to new ones.
  RigModel Transformed(const Rigid3& new_from_old) const;
};

// One face's board in one photo.
struct FaceView {
  int image = 0;                 // index into CalibFile::images
  int face = 0;                  // index into CalibFile::faces
  std::string found_by;          // "full-image search" or "predicted outline"
  std::vector<Vec2d> corners;    // pixels, board order
  std::vector<uint8_t> valid;    // 1: used
  double cos_view = 0;           // from the start pose
  double weight = 1;             // reference noise / this view's noise (TurntableOptions::weight_views)
  bool used = false;
  std::string status;            // "used" or why not
  std::vector<Vec2d> residuals;  // projected - detected (pixels) for the final model; 0 where unused
  std::vector<Vec2d> baseline_residuals;  // the same for the baseline model
  double rms_px = 0, max_px = 0;
  double baseline_rms_px = 0;
  int corners_used = 0;
  int corners_rejected = 0;
};

struct ImageResult {
  std::string file;
  int camera = 0;
  int angle = 0;
  std::string status;                   // summary: faces used / why nothing
  std::vector<std::string> refused;     // grids found and refused, with reasons
};

// Standard deviations, in the adjustment's gauge (camera 0 fixed: the other cameras' sigmas are
// relative to it).
struct RigSigmas {
  std::vector<Vec3d> camera_rotation_deg;  // about the camera's own x, y, z
  std::vector<Vec3d> camera_centre_mm;     // along camera 0's x, y, z
  std::vector<IntrinsicParams> intrinsics; // 0 where held
  double axis_deg = 0;                     // total direction sigma (sqrt of the 2 tangent variances)
  Vec2d axis_components_deg = Vec2d::Zero();
  double point_mm = 0;                     // total, perpendicular to the axis
  Vec3d box_rotation_deg = Vec3d::Zero();
  Vec3d box_translation_mm = Vec3d::Zero();
  std::vector<double> angle_offset_deg;
};

// Gauge-free errors against the file's ground truth (calib/1 README): the axis and its point in
// camera 0's frame, each camera's pose relative to camera 0, the cuboid's pose in every photo.
struct TruthComparison {
  double axis_deg = 0;        // angle between the axes, in camera 0's frame
  double point_mm = 0;        // distance from the true point to the estimated axis line (camera 0)
  std::vector<double> axis_deg_per_camera;   // the same in each camera's frame
  std::vector<double> point_mm_per_camera;
  double max_axis_deg = 0;    // over the cameras
  double max_point_mm = 0;
  std::vector<double> camera_rotation_deg;  // cam_i_from_cam0 rotation error (0 for camera 0)
  std::vector<double> camera_centre_mm;     // camera i's centre in camera 0's frame
  double max_camera_rotation_deg = 0;
  double max_camera_centre_mm = 0;
  double box_rotation_median_deg = 0, box_rotation_max_deg = 0;       // cam_from_box per photo
  double box_translation_median_mm = 0, box_translation_max_mm = 0;
  std::vector<IntrinsicParams> intrinsics_error;  // estimate - truth
};

struct RmsStat {
  double rms_px = 0;
  double max_px = 0;
  int corners = 0;
};

struct TurntableResult {
  std::vector<BoardViewResult> board_views;  // board photos in the adjustment (refine_intrinsics)
  RmsStat board_total;
  RigModel rig;             // output gauge (the turntable frame)
  RigModel baseline;        // the seed's averaged-poses model, output gauge
  RigModel rig_cam0;        // the adjustment's gauge (world = camera 0), for comparisons
  RigModel baseline_cam0;
  RigSigmas sigma;
  std::vector<FaceView> views;
  std::vector<ImageResult> images;
  RmsStat total, baseline_total;
  std::vector<RmsStat> per_camera, per_angle, per_face;
  std::vector<RmsStat> baseline_per_camera;
  double residual_sigma_px = 0;  // sqrt(sum r^2 / (residuals - parameters))
  int parameters = 0;
  int iterations = 0;
  int rejection_rounds = 0;
  std::optional<TruthComparison> truth, baseline_truth;
  double detect_s = 0, solve_s = 0;
};

// Runs detection, the baseline and the adjustment. `start` holds every camera's intrinsics (in
// the file's camera order): fixed unless options.refine_intrinsics. Errors (exit 2) name the file
// and field: a missing or unreadable photo, a camera in none of whose photos the cuboid was found,
// the cuboid found at a single angle, geometry the adjustment cannot determine.
StatusOr<TurntableResult> CalibrateTurntable(const CalibFile& file,
                                             const std::vector<IntrinsicParams>& start,
                                             const TurntableOptions& options);

// One numbered board in one photo, for callers with corners of their own (tests, another
// detector): face index into CalibFile::faces, corners in the board's order (pixels), valid flags
// (empty: all valid).
struct FaceCorners {
  int face = 0;
  std::vector<Vec2d> corners;
  std::vector<uint8_t> valid;
};

// CalibrateTurntable from given corners (`corners[i]`: the boards of CalibFile::images[i]): no
// photo is opened, so there is no second, rig-guided search and no board photo joins.
StatusOr<TurntableResult> CalibrateTurntableFromCorners(const CalibFile& file,
                                                        const std::vector<IntrinsicParams>& start,
                                                        const std::vector<std::vector<FaceCorners>>& corners,
                                                        const TurntableOptions& options);

// Rotation angle of a rotation matrix, degrees.
double RotationAngleDeg(const Mat3d& r);

}  // namespace reflcap::calib
