#include "calib/intrinsics.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <memory>

#include <ceres/ceres.h>
#include <ceres/rotation.h>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "calib/board_cost.h"
#include "engine/capture/json_fields.h"
#include "calib/solver_util.h"
#include "engine/core/atomic_file.h"
#include "engine/core/log.h"
#include "engine/core/parallel.h"
#include "engine/core/progress.h"

namespace reflcap::calib {
namespace {

using internal::BoardCornerCost;
using jsonio::FieldReader;
using internal::ProjectBoardCorner;
using jsonio::Json;

// Rounds of adjust -> reject outliers -> adjust; rejections stop long before (each round removes
// only what is far out, and the survivors fit better).
constexpr int kMaxRejectionRounds = 6;
constexpr double kMinOutlierPx = 0.05;
constexpr int kMaxIterations = 200;
// Coverage grid over the frame (cells per side).
constexpr int kCoverageCells = 8;

struct DetectJob {
  Status status;
  std::optional<BoardDetection> detection;
  std::vector<std::string> refused;
};

// Per-camera working state of the adjustment.
struct CameraSolve {
  IntrinsicParams intr{};
  std::vector<BoardViewResult*> views;    // found views of this camera
  std::vector<std::array<double, 6>> poses;
};

// Solves the adjustment over the views marked used; returns the summary's iteration count.
int Solve(const BoardSpec& board, const IntrinsicsOptions& options, CameraSolve* s) {
  ceres::Problem problem;
  int blocks = 0;
  for (size_t v = 0; v < s->views.size(); ++v) {
    BoardViewResult& view = *s->views[v];
    if (!view.used) continue;
    for (int k = 0; k < board.CornerCount(); ++k) {
      if (!view.valid[k]) continue;
      problem.AddResidualBlock(BoardCornerCost::Create(board.Corner(k), view.corners[k]),
                               new ceres::HuberLoss(options.loss_scale_px), s->intr.data(),
                               s->poses[v].data());
      ++blocks;
    }
  }
  if (blocks == 0) return 0;
  internal::SetIntrinsicsManifold(options.model, s->intr.data(), &problem);
  ceres::Solver::Summary summary;
  ceres::Solve(internal::SolverOptions(options.threads, kMaxIterations, true), &problem, &summary);
  return int(summary.iterations.size());
}

// Fills each used view's residuals, RMS and max from the current parameters.
void Evaluate(const BoardSpec& board, CameraSolve* s) {
  for (size_t v = 0; v < s->views.size(); ++v) {
    BoardViewResult& view = *s->views[v];
    view.residuals.assign(board.CornerCount(), Vec2d::Zero());
    view.cam_from_board = ParamsToPose(s->poses[v].data());
    double sum = 0, mx = 0;
    int n = 0;
    for (int k = 0; k < board.CornerCount(); ++k) {
      if (!view.valid[k]) continue;
      const Vec2d r = ProjectBoardCorner(s->intr, s->poses[v].data(), board.Corner(k)) - view.corners[k];
      view.residuals[k] = r;
      sum += r.squaredNorm();
      mx = std::max(mx, r.norm());
      ++n;
    }
    view.corners_used = n;
    view.rms_px = n > 0 ? std::sqrt(sum / n) : 0;
    view.max_px = mx;
  }
}

// Marks outlier corners and views; true when anything changed.
bool RejectOutliers(const BoardSpec& board, const IntrinsicsOptions& options, CameraSolve* s) {
  std::vector<double> components, view_rms;
  for (BoardViewResult* view : s->views) {
    if (!view->used) continue;
    view_rms.push_back(view->rms_px);
    for (int k = 0; k < board.CornerCount(); ++k) {
      if (!view->valid[k]) continue;
      components.push_back(view->residuals[k].x());
      components.push_back(view->residuals[k].y());
    }
  }
  // No corner within kMinOutlierPx of its projection is an outlier (noise-free data: sigma -> 0).
  const double limit = std::max(options.outlier_sigmas * internal::RobustSigma(components), kMinOutlierPx);
  bool changed = false;
  for (BoardViewResult* view : s->views) {
    if (!view->used) continue;
    for (int k = 0; k < board.CornerCount(); ++k) {
      if (view->valid[k] && view->residuals[k].norm() > limit) {
        view->valid[k] = 0;
        ++view->corners_rejected;
        changed = true;
      }
    }
  }
  // A view is judged on the corners it keeps, in a later round.
  if (changed) return true;
  const double view_limit = std::max(options.view_rms_factor * internal::Median(view_rms),
                                     options.min_rejected_view_rms_px);
  for (BoardViewResult* view : s->views) {
    if (view->used && view->rms_px > view_limit) {
      view->used = false;
      view->status = StrCat("rejected: reprojection RMS ", view->rms_px, " px > ", view_limit,
                            " px (", options.view_rms_factor, "x the median view)");
      changed = true;
    }
  }
  return changed;
}

double Coverage(const std::vector<Vec2d>& pts, int width, int height, double* hull, double* radius) {
  std::vector<uint8_t> cells(kCoverageCells * kCoverageCells, 0);
  std::vector<cv::Point2f> cv_pts;
  const Vec2d centre(0.5 * (width - 1), 0.5 * (height - 1));
  const double half_diag = centre.norm();
  *radius = 0;
  for (const Vec2d& p : pts) {
    const int cx = std::clamp(int(p.x() / width * kCoverageCells), 0, kCoverageCells - 1);
    const int cy = std::clamp(int(p.y() / height * kCoverageCells), 0, kCoverageCells - 1);
    cells[cy * kCoverageCells + cx] = 1;
    cv_pts.emplace_back(float(p.x()), float(p.y()));
    *radius = std::max(*radius, (p - centre).norm() / half_diag);
  }
  *hull = 0;
  if (cv_pts.size() >= 3) {
    std::vector<cv::Point2f> h;
    cv::convexHull(cv_pts, h);
    *hull = cv::contourArea(h) / (double(width) * height);
  }
  return double(std::count(cells.begin(), cells.end(), 1)) / cells.size();
}

StatusOr<IntrinsicsCameraResult> CalibrateCamera(const CalibFile& file, int cam,
                                                 std::vector<BoardViewResult*> views,
                                                 const IntrinsicsOptions& options) {
  const BoardSpec& board = *file.board;
  const CalibCamera& camera = file.cameras[cam];
  IntrinsicsCameraResult result;
  result.intrinsics.id = camera.id;
  result.intrinsics.width = camera.width;
  result.intrinsics.height = camera.height;
  CameraSolve s;
  for (BoardViewResult* v : views) {
    if (v->found) s.views.push_back(v);
  }
  result.views_found = int(s.views.size());
  const FieldReader r(file.json_path.string());
  auto too_few = [&](int n, const std::string& what) {
    return FailedPreconditionError(
        file.json_path.string(), ": intrinsics_images: camera \"", camera.id, "\": the board was ",
        what, " in ", n, " of its ", views.size(), " photos; calibration needs at least ",
        options.min_views);
  };
  if (int(s.views.size()) < options.min_views) return too_few(int(s.views.size()), "found");

  // Start: Zhang's method (OpenCV) on every found view.
  auto opencv_calibrate = [&](std::vector<cv::Mat>* rvecs, std::vector<cv::Mat>* tvecs) -> Status {
    std::vector<std::vector<cv::Point3f>> object;
    std::vector<std::vector<cv::Point2f>> image;
    for (BoardViewResult* v : s.views) {
      if (!v->used) continue;
      object.emplace_back();
      image.emplace_back();
      for (int k = 0; k < board.CornerCount(); ++k) {
        if (!v->valid[k]) continue;
        const Vec3d p = board.Corner(k);
        object.back().emplace_back(float(p.x()), float(p.y()), float(p.z()));
        image.back().emplace_back(float(v->corners[k].x()), float(v->corners[k].y()));
      }
    }
    cv::Mat K, dist;
    int flags = options.model.IsFree(kK3) ? 0 : cv::CALIB_FIX_K3;
    try {
      cv::calibrateCamera(object, image, cv::Size(camera.width, camera.height), K, dist, *rvecs,
                          *tvecs, flags);
    } catch (const cv::Exception& e) {
      return FailedPreconditionError(file.json_path.string(), ": intrinsics_images: camera \"",
                                     camera.id, "\": OpenCV calibrateCamera failed: ", e.what());
    }
    IntrinsicParams p{};
    p[kFx] = K.at<double>(0, 0);
    p[kFy] = K.at<double>(1, 1);
    p[kCx] = K.at<double>(0, 2);
    p[kCy] = K.at<double>(1, 2);
    for (int i = 0; i < 5 && i < int(dist.total()); ++i) p[kK1 + i] = dist.at<double>(i);
    if (!options.model.IsFree(kK3)) p[kK3] = 0;
    if (options.model.tie_focal) p[kFx] = p[kFy] = 0.5 * (p[kFx] + p[kFy]);
    for (double v : p) {
      if (!std::isfinite(v)) {
        return FailedPreconditionError(file.json_path.string(), ": intrinsics_images: camera \"",
                                       camera.id, "\": calibrateCamera returned a non-finite start");
      }
    }
    s.intr = p;
    return OkStatus();
  };
  for (BoardViewResult* v : s.views) v->used = true;
  std::vector<cv::Mat> rvecs, tvecs;
  REFLCAP_RETURN_IF_ERROR(opencv_calibrate(&rvecs, &tvecs));

  // Wrong detections: PnP with the start intrinsics, then the reprojection RMS of each view.
  {
    const cv::Matx33d K(s.intr[kFx], 0, s.intr[kCx], 0, s.intr[kFy], s.intr[kCy], 0, 0, 1);
    const std::vector<double> dist(s.intr.begin() + kK1, s.intr.end());
    std::vector<double> rms(s.views.size(), 0);
    s.poses.assign(s.views.size(), {});
    for (size_t v = 0; v < s.views.size(); ++v) {
      std::vector<cv::Point3f> object;
      std::vector<cv::Point2f> image;
      for (int k = 0; k < board.CornerCount(); ++k) {
        if (!s.views[v]->valid[k]) continue;
        const Vec3d p = board.Corner(k);
        object.emplace_back(float(p.x()), float(p.y()), float(p.z()));
        image.emplace_back(float(s.views[v]->corners[k].x()), float(s.views[v]->corners[k].y()));
      }
      cv::Mat rvec, tvec;
      bool ok = false;
      try {
        ok = cv::solvePnP(object, image, K, dist, rvec, tvec, false, cv::SOLVEPNP_ITERATIVE);
      } catch (const cv::Exception&) {
        ok = false;
      }
      if (!ok) {
        rms[v] = 1e9;
        continue;
      }
      for (int i = 0; i < 3; ++i) {
        s.poses[v][i] = rvec.at<double>(i);
        s.poses[v][3 + i] = tvec.at<double>(i);
      }
      std::vector<cv::Point2f> projected;
      cv::projectPoints(object, rvec, tvec, K, dist, projected);
      double sum = 0;
      for (size_t k = 0; k < image.size(); ++k) {
        const double dx = projected[k].x - image[k].x, dy = projected[k].y - image[k].y;
        sum += dx * dx + dy * dy;
      }
      rms[v] = std::sqrt(sum / std::max<size_t>(1, image.size()));
    }
    const double limit = std::max(options.view_rms_factor * internal::Median(rms), options.min_rejected_view_rms_px);
    bool rejected = false;
    for (size_t v = 0; v < s.views.size(); ++v) {
      if (rms[v] > limit) {
        s.views[v]->used = false;
        s.views[v]->status = rms[v] >= 1e9 ? "rejected: PnP failed"
                                           : StrCat("rejected: PnP reprojection RMS ", rms[v], " px > ", limit, " px");
        rejected = true;
      }
    }
    const int used = int(std::count_if(s.views.begin(), s.views.end(), [](auto* v) { return v->used; }));
    if (used < options.min_views) return too_few(used, "found and consistent");
    if (rejected) {
      REFLCAP_RETURN_IF_ERROR(opencv_calibrate(&rvecs, &tvecs));
      size_t m = 0;
      for (size_t v = 0; v < s.views.size(); ++v) {
        if (!s.views[v]->used) continue;
        for (int i = 0; i < 3; ++i) {
          s.poses[v][i] = rvecs[m].at<double>(i);
          s.poses[v][3 + i] = tvecs[m].at<double>(i);
        }
        ++m;
      }
    }
  }

  // Adjust, reject, repeat.
  for (int round = 0; round < kMaxRejectionRounds; ++round) {
    result.iterations += Solve(board, options, &s);
    Evaluate(board, &s);
    if (!RejectOutliers(board, options, &s)) break;
    const int used = int(std::count_if(s.views.begin(), s.views.end(), [](auto* v) { return v->used; }));
    if (used < options.min_views) return too_few(used, "found and consistent");
  }

  // Statistics and covariance at the final point.
  std::vector<Vec2d> used_points;
  double sum = 0, mx = 0;
  int corners = 0;
  for (BoardViewResult* v : s.views) {
    if (!v->used) continue;
    v->status = "used";
    for (int k = 0; k < board.CornerCount(); ++k) {
      if (!v->valid[k]) continue;
      sum += v->residuals[k].squaredNorm();
      mx = std::max(mx, v->residuals[k].norm());
      used_points.push_back(v->corners[k]);
      ++corners;
    }
  }
  for (BoardViewResult* v : s.views) {
    if (!v->used) {
      v->corners_used = 0;
    }
  }
  result.views_used = int(std::count_if(s.views.begin(), s.views.end(), [](auto* v) { return v->used; }));
  result.corners_used = corners;
  result.rms_px = std::sqrt(sum / std::max(1, corners));
  result.max_px = mx;
  const int parameters = options.model.TangentSize() + 6 * result.views_used;
  const int dof = 2 * corners - parameters;
  if (dof <= 0) return too_few(result.views_used, "found with enough corners");
  const double variance = sum / dof;
  result.residual_sigma_px = std::sqrt(variance);
  result.coverage_cells = Coverage(used_points, camera.width, camera.height, &result.coverage_hull,
                                   &result.coverage_radius);

  ceres::Problem problem;
  for (size_t v = 0; v < s.views.size(); ++v) {
    if (!s.views[v]->used) continue;
    for (int k = 0; k < board.CornerCount(); ++k) {
      if (!s.views[v]->valid[k]) continue;
      problem.AddResidualBlock(BoardCornerCost::Create(board.Corner(k), s.views[v]->corners[k]), nullptr,
                               s.intr.data(), s.poses[v].data());
    }
  }
  internal::SetIntrinsicsManifold(options.model, s.intr.data(), &problem);
  REFLCAP_ASSIGN_OR_RETURN(Eigen::MatrixXd cov,
                           internal::BlockCovariance(&problem, {s.intr.data()}, {kIntrinsicCount}, variance));
  result.intrinsics.params = s.intr;
  result.intrinsics.covariance = Eigen::Matrix<double, kIntrinsicCount, kIntrinsicCount>(cov);
  for (int i = 0; i < kIntrinsicCount; ++i) result.intrinsics.sigma[i] = std::sqrt(std::max(0.0, cov(i, i)));
  for (double v : s.intr) {
    if (!std::isfinite(v)) {
      return FailedPreconditionError(file.json_path.string(), ": intrinsics_images: camera \"",
                                     camera.id, "\": the adjustment diverged");
    }
  }
  if (file.ground_truth && file.ground_truth->has_intrinsics) {
    const IntrinsicParams truth = ToIntrinsicParams(file.ground_truth->K[cam], file.ground_truth->dist[cam]);
    IntrinsicParams e{};
    for (int i = 0; i < kIntrinsicCount; ++i) e[i] = s.intr[i] - truth[i];
    result.error = e;
  }
  return result;
}

}  // namespace

Status IntrinsicsOptions::Validate() const {
  REFLCAP_RETURN_IF_ERROR(model.Validate());
  if (!model.IsFree(kFx) || !model.IsFree(kFy) || !model.IsFree(kCx) || !model.IsFree(kCy)) {
    return InvalidArgumentError("intrinsics calibration estimates fx, fy, cx and cy (got ", model.ToString(), ")");
  }
  if (!(loss_scale_px > 0)) return InvalidArgumentError("loss scale must be positive (got ", loss_scale_px, ")");
  if (!(outlier_sigmas > 0)) return InvalidArgumentError("outlier sigmas must be positive (got ", outlier_sigmas, ")");
  if (!(view_rms_factor > 1)) return InvalidArgumentError("view RMS factor must exceed 1 (got ", view_rms_factor, ")");
  if (!(min_rejected_view_rms_px >= 0)) return InvalidArgumentError("min_rejected_view_rms_px must not be negative");
  if (min_views < 3) return InvalidArgumentError("min_views must be at least 3 (got ", min_views, ")");
  if (threads < 0) return InvalidArgumentError("threads must not be negative");
  return detect.Validate();
}

StatusOr<std::vector<BoardViewResult>> DetectBoardPhotos(const CalibFile& file, const DetectOptions& detect,
                                                         int threads) {
  REFLCAP_RETURN_IF_ERROR(CheckBoardSession(file));
  REFLCAP_RETURN_IF_ERROR(CheckBoardPhotos(file));
  const size_t n = file.board_images.size();
  std::vector<DetectJob> jobs(n);
  {
    Progress progress("detecting boards", int64_t(n));
    ParallelFor(0, int64_t(n), 1, [&](int64_t begin, int64_t end, int) {
      for (int64_t i = begin; i < end; ++i) {
        const BoardImage& image = file.board_images[i];
        const std::string field = StrCat("intrinsics_images[", i, "].file");
        auto grey = LoadGrey(file.Resolve(image.file));
        if (!grey.ok()) {
          jobs[i].status = grey.status().WithContext(StrCat(file.json_path.string(), ": ", field));
        } else if (grey->width != file.cameras[image.camera].width ||
                   grey->height != file.cameras[image.camera].height) {
          jobs[i].status = InvalidArgumentError(
              file.json_path.string(), ": ", field, ": ", image.file, " is ", grey->width, "x",
              grey->height, " but camera \"", file.cameras[image.camera].id, "\" is ",
              file.cameras[image.camera].width, "x", file.cameras[image.camera].height);
        } else {
          auto found = FindBoards(*grey, {*file.board}, 1, detect, &jobs[i].refused);
          if (!found.empty()) jobs[i].detection = std::move(found.front());
        }
        progress.Advance();
      }
    }, threads);
  }
  for (const DetectJob& job : jobs) REFLCAP_RETURN_IF_ERROR(job.status);
  std::vector<BoardViewResult> views(n);
  for (size_t i = 0; i < n; ++i) {
    BoardViewResult& view = views[i];
    view.file = file.board_images[i].file;
    view.camera = file.board_images[i].camera;
    // Four corners at least: a homography (and a pose) needs them.
    if (jobs[i].detection && jobs[i].detection->ValidCount() >= 4) {
      view.found = true;
      view.corners = jobs[i].detection->corners;
      view.valid = jobs[i].detection->valid;
      view.status = "found";
    } else {
      view.status = jobs[i].refused.empty() ? "board not found"
                                            : StrCat("board not found: ", jobs[i].refused.front());
    }
  }
  return views;
}

StatusOr<IntrinsicsResult> CalibrateIntrinsics(const CalibFile& file, const IntrinsicsOptions& options) {
  REFLCAP_RETURN_IF_ERROR(options.Validate());
  REFLCAP_RETURN_IF_ERROR(CheckBoardSession(file));
  IntrinsicsResult result;
  const auto t0 = std::chrono::steady_clock::now();
  REFLCAP_ASSIGN_OR_RETURN(result.views, DetectBoardPhotos(file, options.detect, options.threads));
  const auto t1 = std::chrono::steady_clock::now();
  result.detect_s = std::chrono::duration<double>(t1 - t0).count();
  for (size_t c = 0; c < file.cameras.size(); ++c) {
    std::vector<BoardViewResult*> views;
    for (BoardViewResult& v : result.views) {
      if (v.camera == int(c)) views.push_back(&v);
    }
    if (views.empty()) continue;
    REFLCAP_ASSIGN_OR_RETURN(IntrinsicsCameraResult cam, CalibrateCamera(file, int(c), views, options));
    result.cameras.push_back(std::move(cam));
  }
  result.solve_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t1).count();
  return result;
}

std::string IntrinsicsToJson(const CalibFile& file, const IntrinsicsResult& result,
                             const IntrinsicsOptions& options) {
  Json root = Json::object();
  root["format"] = "reflcap-intrinsics/1";
  root["source"] = std::filesystem::absolute(file.json_path).lexically_normal().string();
  root["model"] = "pinhole, OpenCV distortion [k1, k2, p1, p2, k3], zero skew";
  root["estimated"] = options.model.ToString();
  Json cameras = Json::array();
  for (const IntrinsicsCameraResult& c : result.cameras) {
    const CameraIntrinsics& in = c.intrinsics;
    Json j = {{"id", in.id}, {"width", in.width}, {"height", in.height}};
    j["K"] = jsonio::MatrixJson(KFromParams(in.params));
    const auto dist = DistFromParams(in.params);
    j["dist"] = Json(std::vector<double>(dist.begin(), dist.end()));
    Json sigma = Json::object();
    for (int i = 0; i < kIntrinsicCount; ++i) sigma[IntrinsicName(i)] = in.sigma[i];
    j["sigma"] = sigma;
    if (in.covariance) j["covariance"] = jsonio::MatrixJson(*in.covariance);
    j["rms_px"] = c.rms_px;
    j["max_px"] = c.max_px;
    j["residual_sigma_px"] = c.residual_sigma_px;
    j["views_found"] = c.views_found;
    j["views_used"] = c.views_used;
    j["corners_used"] = c.corners_used;
    j["coverage"] = {{"cells_8x8", c.coverage_cells}, {"hull_area", c.coverage_hull},
                     {"max_radius", c.coverage_radius}};
    if (c.error) {
      Json e = Json::object();
      for (int i = 0; i < kIntrinsicCount; ++i) e[IntrinsicName(i)] = (*c.error)[i];
      j["error_vs_ground_truth"] = e;
    }
    cameras.push_back(j);
  }
  root["cameras"] = cameras;
  root["covariance_order"] = Json::array({"fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"});
  Json views = Json::array();
  for (const BoardViewResult& v : result.views) {
    Json j = {{"file", v.file}, {"camera", file.cameras[v.camera].id}, {"status", v.status}};
    if (v.used) {
      j["rms_px"] = v.rms_px;
      j["max_px"] = v.max_px;
      j["corners_used"] = v.corners_used;
      j["corners_rejected"] = v.corners_rejected;
      j["cam_from_board"] = jsonio::MatrixJson(v.cam_from_board.ToMatrix());
    }
    views.push_back(j);
  }
  root["views"] = views;
  root["timing_s"] = {{"detect", result.detect_s}, {"solve", result.solve_s}};
  return root.dump(2) + "\n";
}

StatusOr<std::vector<CameraIntrinsics>> ReadIntrinsicsFile(const std::filesystem::path& path) {
  auto text = ReadTextFile(path);
  if (!text.ok()) return NotFoundError(path.string(), ": cannot open intrinsics file");
  const FieldReader r(path.string());
  REFLCAP_ASSIGN_OR_RETURN(Json root, jsonio::ParseJsonObject(*text, path.string()));
  REFLCAP_ASSIGN_OR_RETURN(const Json* format, r.Required(root, "", "format"));
  REFLCAP_ASSIGN_OR_RETURN(std::string f, r.String(*format, "format"));
  if (f != "reflcap-intrinsics/1") {
    return r.Error("format", StrCat("\"", f, "\" (expected \"reflcap-intrinsics/1\")"));
  }
  REFLCAP_ASSIGN_OR_RETURN(const Json* cameras, r.Required(root, "", "cameras"));
  if (!cameras->is_array() || cameras->empty()) return r.Error("cameras", "must be a non-empty array");
  std::vector<CameraIntrinsics> out;
  for (size_t i = 0; i < cameras->size(); ++i) {
    const std::string at = FieldReader::Index("cameras", i);
    const Json& j = (*cameras)[i];
    CameraIntrinsics c;
    REFLCAP_ASSIGN_OR_RETURN(const Json* id, r.Required(j, at, "id"));
    REFLCAP_ASSIGN_OR_RETURN(c.id, r.String(*id, at + ".id"));
    for (const CameraIntrinsics& other : out) {
      if (other.id == c.id) return r.Error(at + ".id", StrCat("duplicate id \"", c.id, "\""));
    }
    REFLCAP_ASSIGN_OR_RETURN(const Json* w, r.Required(j, at, "width"));
    REFLCAP_ASSIGN_OR_RETURN(c.width, r.PositiveInt(*w, at + ".width"));
    REFLCAP_ASSIGN_OR_RETURN(const Json* h, r.Required(j, at, "height"));
    REFLCAP_ASSIGN_OR_RETURN(c.height, r.PositiveInt(*h, at + ".height"));
    REFLCAP_ASSIGN_OR_RETURN(const Json* k, r.Required(j, at, "K"));
    REFLCAP_ASSIGN_OR_RETURN(Mat3d K, r.CameraMatrix(*k, at + ".K"));
    std::array<double, 5> dist{};
    if (const Json* d = FieldReader::Optional(j, "dist")) {
      REFLCAP_ASSIGN_OR_RETURN(dist, r.Distortion(*d, at + ".dist"));
    }
    c.params = ToIntrinsicParams(K, dist);
    if (const Json* sigma = FieldReader::Optional(j, "sigma")) {
      for (int p = 0; p < kIntrinsicCount; ++p) {
        if (const Json* v = FieldReader::Optional(*sigma, IntrinsicName(p))) {
          REFLCAP_ASSIGN_OR_RETURN(c.sigma[p], r.Number(*v, at + ".sigma." + IntrinsicName(p)));
          if (c.sigma[p] < 0) return r.Error(at + ".sigma." + IntrinsicName(p), "must not be negative");
        }
      }
    }
    if (const Json* cov = FieldReader::Optional(j, "covariance")) {
      REFLCAP_ASSIGN_OR_RETURN(Eigen::MatrixXd m, r.Matrix(*cov, kIntrinsicCount, kIntrinsicCount, at + ".covariance"));
      // Written with full double precision: asymmetry beyond 1e-9 relative is a broken file.
      if ((m - m.transpose()).cwiseAbs().maxCoeff() > 1e-9 * std::max(1.0, m.cwiseAbs().maxCoeff())) {
        return r.Error(at + ".covariance", "must be symmetric");
      }
      c.covariance = Eigen::Matrix<double, kIntrinsicCount, kIntrinsicCount>(m);
    }
    out.push_back(std::move(c));
  }
  return out;
}

}  // namespace reflcap::calib
