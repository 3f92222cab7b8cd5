#pragma once
// Camera intrinsics from photos of a planar checkerboard (`reflcap calibrate intrinsics`).
//
// Per camera: every board photo is searched (board_detect.h: SB detection, identification by
// colours, corners refined by point symmetry); OpenCV's calibrateCamera (Zhang 2000) gives the
// start; each view is checked by PnP reprojection with that start (a wrong detection reprojects
// far worse than the rest); then one Ceres adjustment over K (fx, fy, cx, cy), distortion (k1,
// k2, p1, p2, and k3 when asked) and every view's pose, with a Huber loss, refines all. Corners beyond
// outlier_sigmas robust sigmas and views far worse than the median are rejected and the adjustment
// repeated. The covariance (Ceres, J^T J inverse scaled by the residual variance) gives the
// standard deviation of every parameter; coverage says how much of the frame the corners reached.
//
// What planar views cannot do: with a narrow field of view the principal point and k2 trade off
// against the board poses, so they scatter by several pixels between sessions (calib/1 README:
// calibrateCamera misses c by up to 7.5 px on 18 views). The sigmas say so; `calibrate turntable
// --refine-intrinsics` pins them down with the cuboid's 3-D corners.
#include <array>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "calib/board_detect.h"
#include "calib/calib_file.h"
#include "calib/camera_model.h"
#include "engine/core/status.h"
#include "engine/geometry/rigid3.h"

namespace reflcap::calib {

// One camera's intrinsics with their uncertainty: what INTRINSICS.json holds per camera.
struct CameraIntrinsics {
  std::string id;
  int width = 0;
  int height = 0;
  IntrinsicParams params{};  // fx, fy, cx, cy, k1, k2, p1, p2, k3
  // Standard deviations (same order); 0 for a parameter held fixed; all 0 when unknown.
  IntrinsicParams sigma{};
  // Full covariance (same order, pixels² etc.), when estimated.
  std::optional<Eigen::Matrix<double, kIntrinsicCount, kIntrinsicCount>> covariance;
};

struct IntrinsicsOptions {
  // What is estimated (fx, fy, cx, cy always; default also k1, k2, p1, p2; k3 held at 0 because a
  // narrow lens cannot separate it from k1 and k2). Held distortion terms are 0.
  IntrinsicsModel model;
  // Huber loss scale, pixels (> 0): residuals beyond it count linearly. Detected corners are good
  // to ~0.1 px; a wrong one is off by pixels.
  double loss_scale_px = 0.5;
  // A corner whose residual exceeds this many robust sigmas (1.4826 MAD of all residual
  // components) is rejected (> 0; 5 rejects a Gaussian corner with probability 4e-6).
  double outlier_sigmas = 5;
  // A view whose RMS exceeds view_rms_factor x the median view RMS and min_rejected_view_rms_px is
  // rejected (factor > 1). The floor keeps a merely noisier view: corner noise of 8-bit photos is
  // 0.05-0.1 px, so a view under 0.25 px RMS is not a wrong detection.
  double view_rms_factor = 3;
  double min_rejected_view_rms_px = 0.25;
  int min_views = 3;  // views a camera needs (>= 3: Zhang's method needs three planes)
  int threads = 0;    // 0: all cores
  DetectOptions detect;

  Status Validate() const;
};

// One board photo: what was found and how it fitted.
struct BoardViewResult {
  std::string file;
  int camera = 0;
  bool found = false;
  bool used = false;
  std::string status;                   // "used", or why not ("board not found: ...")
  std::vector<Vec2d> corners;           // detected (board order)
  std::vector<uint8_t> valid;           // per corner: 1 used
  std::vector<Vec2d> residuals;         // projected - detected, pixels (valid corners only; else 0)
  Rigid3 cam_from_board;
  double rms_px = 0;
  double max_px = 0;
  int corners_used = 0;
  int corners_rejected = 0;             // outliers (beyond outlier_sigmas)
  double weight = 1;                    // in the turntable adjustment: reference noise / its noise
};

struct IntrinsicsCameraResult {
  CameraIntrinsics intrinsics;
  int views_found = 0;
  int views_used = 0;
  int corners_used = 0;
  double rms_px = 0;
  double max_px = 0;
  double residual_sigma_px = 0;   // sqrt(sum r^2 / (residuals - parameters)): scales the covariance
  double coverage_cells = 0;      // fraction of an 8x8 grid over the frame holding a used corner
  double coverage_hull = 0;       // area of the used corners' convex hull / frame area
  double coverage_radius = 0;     // farthest used corner from the centre / half diagonal
  int iterations = 0;
  // Against ground truth, when the file has it: estimate - truth.
  std::optional<IntrinsicParams> error;
};

struct IntrinsicsResult {
  std::vector<IntrinsicsCameraResult> cameras;
  std::vector<BoardViewResult> views;  // in the file's order
  double detect_s = 0;
  double solve_s = 0;
};

// Searches every board photo of the file (intrinsics_images) in parallel; found views carry their
// refined corners (status "found"), the others why not. Errors: a photo missing, unreadable or of
// the wrong size (names the file and field).
StatusOr<std::vector<BoardViewResult>> DetectBoardPhotos(const CalibFile& file, const DetectOptions& detect,
                                                         int threads);

// Calibrates every camera that has board photos. Errors (exit 2): a photo missing or unreadable
// (names the file and field), a camera whose board was found in fewer than min_views photos.
StatusOr<IntrinsicsResult> CalibrateIntrinsics(const CalibFile& file, const IntrinsicsOptions& options);

// INTRINSICS.json ("reflcap-intrinsics/1"): cameras[] {id, width, height, K, dist, sigma {fx..k3},
// covariance (9x9, order fx fy cx cy k1 k2 p1 p2 k3)} plus the calibration's report fields.
std::string IntrinsicsToJson(const CalibFile& file, const IntrinsicsResult& result,
                             const IntrinsicsOptions& options);
// Reads the cameras of an INTRINSICS.json; errors name the file and field.
StatusOr<std::vector<CameraIntrinsics>> ReadIntrinsicsFile(const std::filesystem::path& path);

}  // namespace reflcap::calib
