#include "calib/turntable.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <map>
#include <numeric>
#include <set>

#include <ceres/ceres.h>
#include <ceres/rotation.h>
#include <opencv2/calib3d.hpp>

#include "calib/board_cost.h"
#include "calib/solver_util.h"
#include "engine/core/log.h"
#include "engine/core/parallel.h"
#include "engine/core/progress.h"

namespace reflcap::calib {
namespace {

using internal::BoardCornerCost;
using internal::ProjectBoardCorner;

constexpr int kMaxRejectionRounds = 8;
// Weights are re-estimated until no weight moves by more than this fraction (a 5 % change in a
// weight changes the estimates far below their sigmas).
constexpr double kWeightTolerance = 0.05;
// How many corners' worth of belief a view's noise starts with at the median view's: a view of
// ~30 corners then sits about halfway between its own residuals and the median.
constexpr double kWeightPriorCorners = 20;
// No corner closer than this to its projection is an outlier, whatever the robust sigma: with
// near-perfect data (synthetic, noise-free) sigma -> 0 would reject good corners by rounding.
constexpr double kMinOutlierPx = 0.05;
constexpr int kMaxIterations = 200;
// Pose pairs used for the baseline's axis: their relative rotation must exceed 10 degrees (below,
// the rotation axis of a small noisy rotation is poorly defined) and stay below 170 (near 180 the
// sign of the axis cannot be told).
constexpr double kMinPairAngleDeg = 10;
constexpr double kMaxPairAngleDeg = 170;
// Metres that weigh like one degree when two poses are compared for the symmetric-board numbering
// (a wrong numbering moves a pose by tens of degrees or centimetres; noise by < 0.1 of either).
constexpr double kMetresPerDegree = 0.01;
// Two candidate poses of a photo's cuboid closer than this (pose distance above) support each other.
constexpr double kSupportDistance = 2.0;

double WrapDeg180(double deg) {
  double w = std::fmod(deg, 360.0);
  if (w > 180) w -= 360;
  if (w <= -180) w += 360;
  return w;
}

Mat3d ProjectToRotation(const Mat3d& m) {
  Eigen::JacobiSVD<Mat3d> svd(m, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Mat3d r = svd.matrixU() * svd.matrixV().transpose();
  if (r.determinant() < 0) {
    Mat3d u = svd.matrixU();
    u.col(2) *= -1;
    r = u * svd.matrixV().transpose();
  }
  return r;
}

// Chordal mean of rigid transforms (rotations) and arithmetic mean (translations).
Rigid3 MeanPose(const std::vector<Rigid3>& poses) {
  Mat3d sum = Mat3d::Zero();
  Vec3d t = Vec3d::Zero();
  for (const Rigid3& p : poses) {
    sum += p.rotation;
    t += p.translation;
  }
  return {ProjectToRotation(sum), t / double(poses.size())};
}

double PoseDistance(const Rigid3& a, const Rigid3& b) {
  return RotationAngleDeg(a.rotation * b.rotation.transpose()) +
         (a.translation - b.translation).norm() / kMetresPerDegree;
}

Vec2d ProjectCam(const IntrinsicParams& intr, const Vec3d& p_cam) {
  double pixel[2];
  const double p[3] = {p_cam.x(), p_cam.y(), p_cam.z()};
  ProjectToPixel(intr.data(), p, pixel);
  return {pixel[0], pixel[1]};
}

// ---- Per-photo detection ---------------------------------------------------------------------

struct FaceDet {
  int face = 0;
  std::string found_by;
  std::vector<Vec2d> corners;
  std::vector<uint8_t> valid;
  std::vector<std::vector<int>> alternatives;  // other numberings (BoardDetection)
};

// One interpretation of a photo: a numbering of every face found and the cuboid's pose.
struct Hypothesis {
  std::vector<FaceDet> faces;
  Rigid3 cam_from_box;
  double pnp_rms = 0;
};

struct PhotoDetection {
  Status status;
  std::vector<Hypothesis> hypotheses;  // 0: nothing found; 1: resolved; more: to resolve
  std::vector<std::string> refused;
};

FaceDet Renumbered(const FaceDet& d, int numbering) {
  if (numbering < 0) {
    FaceDet out = d;
    out.alternatives.clear();
    return out;
  }
  FaceDet out;
  out.face = d.face;
  out.found_by = d.found_by;
  const std::vector<int>& alt = d.alternatives[numbering];
  for (size_t k = 0; k < alt.size(); ++k) {
    out.corners.push_back(d.corners[alt[k]]);
    out.valid.push_back(d.valid[alt[k]]);
  }
  return out;
}

// PnP for the cuboid from face detections (valid corners only); false when it fails.
bool SolvePose(const std::vector<BoardSpec>& faces, const std::vector<FaceDet>& dets,
               const IntrinsicParams& intr, Rigid3* cam_from_box, double* rms) {
  std::vector<cv::Point3d> object;
  std::vector<cv::Point2d> image;
  for (const FaceDet& d : dets) {
    const BoardSpec& f = faces[d.face];
    for (int k = 0; k < f.CornerCount(); ++k) {
      if (!d.valid[k]) continue;
      const Vec3d p = f.Corner(k);
      object.emplace_back(p.x(), p.y(), p.z());
      image.emplace_back(d.corners[k].x(), d.corners[k].y());
    }
  }
  if (object.size() < 6) return false;
  const cv::Matx33d K(intr[kFx], 0, intr[kCx], 0, intr[kFy], intr[kCy], 0, 0, 1);
  const std::vector<double> dist(intr.begin() + kK1, intr.end());
  cv::Mat rvec, tvec;
  try {
    // One face is a plane: IPPE is exact for planes; several faces: SQPnP, then LM polishing.
    const int method = dets.size() == 1 ? cv::SOLVEPNP_IPPE : cv::SOLVEPNP_SQPNP;
    if (!cv::solvePnP(object, image, K, dist, rvec, tvec, false, method)) return false;
    cv::solvePnPRefineLM(object, image, K, dist, rvec, tvec);
  } catch (const cv::Exception&) {
    return false;
  }
  std::array<double, 6> p{};
  for (int i = 0; i < 3; ++i) {
    p[i] = rvec.at<double>(i);
    p[3 + i] = tvec.at<double>(i);
  }
  *cam_from_box = ParamsToPose(p.data());
  double sum = 0;
  for (size_t k = 0; k < object.size(); ++k) {
    const Vec3d q = *cam_from_box * Vec3d(object[k].x, object[k].y, object[k].z);
    if (!(q.z() > 0)) return false;
    sum += (ProjectCam(intr, q) - Vec2d(image[k].x, image[k].y)).squaredNorm();
  }
  *rms = std::sqrt(sum / object.size());
  return std::isfinite(*rms);
}

double FaceCos(const BoardSpec& f, const Rigid3& cam_from_box) {
  const Vec3d centre = cam_from_box * f.Point(0.5 * (f.corners_x - 1), 0.5 * (f.corners_y - 1));
  const Vec3d normal = cam_from_box.rotation * f.normal;
  return -normal.dot(centre.normalized());
}

// Reprojection RMS of one face detection under a pose.
double FaceRms(const BoardSpec& f, const FaceDet& d, const IntrinsicParams& intr, const Rigid3& pose) {
  double sum = 0;
  int n = 0;
  for (int k = 0; k < f.CornerCount(); ++k) {
    if (!d.valid[k]) continue;
    const Vec3d q = pose * f.Corner(k);
    if (!(q.z() > 0)) return 1e30;
    sum += (ProjectCam(intr, q) - d.corners[k]).squaredNorm();
    ++n;
  }
  return n > 0 ? std::sqrt(sum / n) : 1e30;
}

// Hypotheses from the boards of a full-image search: the unambiguous ones fix the pose and the
// numbering of the others; without any, each numbering of the first board is one hypothesis.
std::vector<Hypothesis> BuildHypotheses(const std::vector<BoardSpec>& faces,
                                        const std::vector<FaceDet>& dets, const IntrinsicParams& intr) {
  std::vector<FaceDet> fixed;
  for (const FaceDet& d : dets) {
    if (d.alternatives.empty()) fixed.push_back(d);
  }
  std::vector<std::vector<FaceDet>> seeds;
  if (!fixed.empty()) {
    seeds.push_back(fixed);
  } else {
    for (int n = -1; n < int(dets.front().alternatives.size()); ++n) seeds.push_back({Renumbered(dets.front(), n)});
  }
  std::vector<Hypothesis> out;
  for (auto& seed : seeds) {
    Hypothesis h;
    if (!SolvePose(faces, seed, intr, &h.cam_from_box, &h.pnp_rms)) continue;
    h.faces = seed;
    // Every other ambiguous board: the numbering that fits this pose best.
    for (const FaceDet& d : dets) {
      const bool taken = std::any_of(h.faces.begin(), h.faces.end(), [&](const FaceDet& e) { return e.face == d.face; });
      if (taken) continue;
      double best = 1e30;
      int best_n = -1;
      for (int n = -1; n < int(d.alternatives.size()); ++n) {
        const double rms = FaceRms(faces[d.face], Renumbered(d, n), intr, h.cam_from_box);
        if (rms < best) {
          best = rms;
          best_n = n;
        }
      }
      h.faces.push_back(Renumbered(d, best_n));
    }
    out.push_back(std::move(h));
  }
  return out;
}

// Searches one face inside its outline as `cam_from_box` predicts it (the board plus half its
// margin); nullopt with `why` when not found or too few corners survive refinement.
std::optional<BoardDetection> SearchFace(const Image& grey, const CalibFile& file, int f,
                                         const Rigid3& cam_from_box, const IntrinsicParams& intr,
                                         const TurntableOptions& options, std::string* why) {
  const BoardSpec& face = file.faces[f];
  std::vector<Vec2d> region, predicted;
  for (const Vec2d& q : BoardOutline(face, 0.5)) {
    const Vec3d p = cam_from_box * face.Point(q.x(), q.y());
    if (!(p.z() > 0)) {
      *why = "behind the camera";
      return std::nullopt;
    }
    region.push_back(ProjectCam(intr, p));
  }
  for (int k = 0; k < face.CornerCount(); ++k) predicted.push_back(ProjectCam(intr, cam_from_box * face.Corner(k)));
  auto found = FindBoardInRegion(grey, file.faces, f, region, &predicted, options.detect, why);
  if (found && found->ValidCount() < 4) {
    *why = "too few corners survived refinement";
    return std::nullopt;
  }
  return found;
}

PhotoDetection DetectPhoto(const CalibFile& file, int index, const IntrinsicParams& intr,
                           const TurntableOptions& options) {
  PhotoDetection out;
  const CuboidImage& image = file.images[index];
  const CalibCamera& cam = file.cameras[image.camera];
  const std::string field = StrCat("images[", index, "].file");
  auto grey = LoadGrey(file.Resolve(image.file));
  if (!grey.ok()) {
    out.status = grey.status().WithContext(StrCat(file.json_path.string(), ": ", field));
    return out;
  }
  if (grey->width != cam.width || grey->height != cam.height) {
    out.status = InvalidArgumentError(file.json_path.string(), ": ", field, ": ", image.file, " is ",
                                      grey->width, "x", grey->height, " but camera \"", cam.id,
                                      "\" is ", cam.width, "x", cam.height);
    return out;
  }
  // The full-image search without the slow exhaustive retry: a photo where the fast search finds
  // nothing is searched again where the start rig predicts each face (SearchPredictedFaces).
  DetectOptions fast = options.detect;
  fast.exhaustive_retry = false;
  std::vector<FaceDet> dets;
  for (BoardDetection& b : FindBoards(*grey, file.faces, 1, fast, &out.refused)) {
    if (b.ValidCount() < 4) continue;
    dets.push_back({b.board, "full-image search", std::move(b.corners), std::move(b.valid), std::move(b.alternatives)});
  }
  if (dets.empty()) return out;
  std::vector<Hypothesis> hyps = BuildHypotheses(file.faces, dets, intr);
  // Every face the pose shows well enough, searched where the pose puts it.
  std::vector<int> extra_found(hyps.size(), 0);
  for (size_t h = 0; h < hyps.size(); ++h) {
    Hypothesis& hyp = hyps[h];
    for (size_t f = 0; f < file.faces.size(); ++f) {
      const bool have = std::any_of(hyp.faces.begin(), hyp.faces.end(), [&](const FaceDet& d) { return d.face == int(f); });
      if (have) continue;
      const BoardSpec& face = file.faces[f];
      if (FaceCos(face, hyp.cam_from_box) < options.min_cos) continue;
      std::string why;
      auto found = SearchFace(*grey, file, int(f), hyp.cam_from_box, intr, options, &why);
      if (!found) {
        if (hyps.size() == 1) out.refused.push_back(StrCat("face ", face.name, " (predicted in view): ", why));
        continue;
      }
      hyp.faces.push_back({int(f), "predicted outline", std::move(found->corners), std::move(found->valid), {}});
      ++extra_found[h];
    }
    // Final pose from every face of this interpretation.
    Rigid3 pose;
    double rms = 0;
    if (hyp.faces.size() > 1 && SolvePose(file.faces, hyp.faces, intr, &pose, &rms)) {
      hyp.cam_from_box = pose;
      hyp.pnp_rms = rms;
    }
  }
  // Of several interpretations, the one under which more faces were found where predicted.
  if (hyps.size() > 1) {
    const int best = *std::max_element(extra_found.begin(), extra_found.end());
    std::vector<Hypothesis> kept;
    for (size_t h = 0; h < hyps.size(); ++h) {
      if (extra_found[h] == best) kept.push_back(std::move(hyps[h]));
    }
    hyps = std::move(kept);
  }
  out.hypotheses = std::move(hyps);
  return out;
}

// ---- The seed's baseline -----------------------------------------------------------------------

struct PoseAtAngle {
  double angle_deg = 0;
  Rigid3 cam_from_box;
};

// Axis (unit) and a point of it in the camera frame from the cuboid's poses at several angles.
bool AxisFromPoses(const std::vector<PoseAtAngle>& poses, Vec3d* axis, Vec3d* point) {
  Vec3d sum = Vec3d::Zero();
  std::vector<std::pair<Mat3d, Vec3d>> motions;
  for (size_t k = 0; k < poses.size(); ++k) {
    for (size_t l = k + 1; l < poses.size(); ++l) {
      const double delta = WrapDeg180(poses[l].angle_deg - poses[k].angle_deg);
      const Mat3d r = poses[l].cam_from_box.rotation * poses[k].cam_from_box.rotation.transpose();
      const Eigen::AngleAxisd aa(r);
      const double angle = RadToDeg(aa.angle());
      if (angle < kMinPairAngleDeg || angle > kMaxPairAngleDeg) continue;
      sum += (delta >= 0 ? 1.0 : -1.0) * aa.axis();
      const Vec3d t = poses[l].cam_from_box.translation - r * poses[k].cam_from_box.translation;
      motions.emplace_back(r, t);
    }
  }
  // Axes that cancel out (a sum of unit vectors near zero) define no direction.
  if (motions.empty() || sum.norm() < 1e-9) return false;
  *axis = sum.normalized();
  // (I - R) p = t for every pair; p is defined up to a shift along the axis, which the extra row
  // axis . p = 0 removes.
  Eigen::MatrixXd a(3 * motions.size() + 1, 3);
  Eigen::VectorXd b(3 * motions.size() + 1);
  for (size_t m = 0; m < motions.size(); ++m) {
    a.block<3, 3>(3 * m, 0) = Mat3d::Identity() - motions[m].first;
    b.segment<3>(3 * m) = motions[m].second;
  }
  a.row(3 * motions.size()) = axis->transpose();
  b(3 * motions.size()) = 0;
  *point = a.colPivHouseholderQr().solve(b);
  return point->allFinite() && axis->allFinite();
}

// Where the line (point, axis) meets the plane through `origin` with `normal`.
Vec3d LinePlane(const Vec3d& point, const Vec3d& axis, const Vec3d& origin, const Vec3d& normal) {
  const double denom = axis.dot(normal);
  // An axis parallel to the cuboid's bottom cannot happen with a cuboid standing on the plate; keep
  // the point rather than divide by ~0.
  if (std::abs(denom) < 1e-9) return point;
  return point + axis * ((origin - point).dot(normal) / denom);
}

// A frame with z = axis, origin = point, x = `toward` made perpendicular to z; as cam_from_frame.
Rigid3 FrameFromAxis(const Vec3d& axis, const Vec3d& point, const Vec3d& toward) {
  Vec3d x = toward - toward.dot(axis) * axis;
  // `toward` along the axis (a camera right above the turntable): any perpendicular will do.
  if (x.norm() < 1e-9) x = axis.unitOrthogonal();
  x.normalize();
  const Vec3d y = axis.cross(x);
  Mat3d r;
  r.col(0) = x;
  r.col(1) = y;
  r.col(2) = axis;
  return {r, point};
}

// The cuboid at angle 0 in the camera frame implied by its pose at `angle_deg` and the axis.
Rigid3 BoxAtZero(const PoseAtAngle& p, const Vec3d& axis, const Vec3d& point) {
  const Mat3d r = AxisAngleRotation(axis, -DegToRad(p.angle_deg));
  const Rigid3 undo{r, point - r * point};
  return undo * p.cam_from_box;
}

// ---- Bundle adjustment ---------------------------------------------------------------------------

// Fixed quantities of the axis parametrisation: a = normalize(a0 + alpha u0 + beta v0),
// p = p0 + s u0 + t v0.
struct AxisBasis {
  Vec3d a0, u0, v0, p0;
};

struct TurntableCornerCost {
  TurntableCornerCost(const Vec3d& p_box, const Vec2d& obs, double angle_rad, const AxisBasis& basis,
                      double weight)
      : p_(p_box), obs_(obs), angle_(angle_rad), b_(basis), weight_(weight) {}

  template <typename T>
  bool operator()(const T* intr, const T* cam, const T* axis_ab, const T* point_st, const T* box,
                  const T* offset, T* residual) const {
    T a[3], p[3];
    for (int i = 0; i < 3; ++i) {
      a[i] = T(b_.a0[i]) + axis_ab[0] * T(b_.u0[i]) + axis_ab[1] * T(b_.v0[i]);
      p[i] = T(b_.p0[i]) + point_st[0] * T(b_.u0[i]) + point_st[1] * T(b_.v0[i]);
    }
    const T norm = sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
    for (int i = 0; i < 3; ++i) a[i] /= norm;
    const T x_box[3] = {T(p_.x()), T(p_.y()), T(p_.z())};
    T x0[3];
    ceres::AngleAxisRotatePoint(box, x_box, x0);
    T v[3];
    for (int i = 0; i < 3; ++i) v[i] = x0[i] + box[3 + i] - p[i];
    T w[3];
    RotateAboutAxis(a, T(angle_) + offset[0], v, w);
    T d[3];
    for (int i = 0; i < 3; ++i) d[i] = w[i] + p[i] - cam[3 + i];
    T q[3];
    ceres::AngleAxisRotatePoint(cam, d, q);
    if (!(q[2] > T(0))) return false;
    T pixel[2];
    ProjectToPixel(intr, q, pixel);
    residual[0] = T(weight_) * (pixel[0] - T(obs_.x()));
    residual[1] = T(weight_) * (pixel[1] - T(obs_.y()));
    return true;
  }

  static ceres::CostFunction* Create(const Vec3d& p_box, const Vec2d& obs, double angle_rad,
                                     const AxisBasis& basis, double weight) {
    return new ceres::AutoDiffCostFunction<TurntableCornerCost, 2, kIntrinsicCount, 6, 2, 2, 6, 1>(
        new TurntableCornerCost(p_box, obs, angle_rad, basis, weight));
  }

  Vec3d p_;
  Vec2d obs_;
  double angle_;
  AxisBasis b_;
  double weight_;  // reference noise / this view's noise
};

// The adjustment's parameter blocks.
struct Params {
  AxisBasis basis;
  std::vector<IntrinsicParams> intr;
  std::vector<std::array<double, 6>> cam;  // angle-axis cam_from_world, centre (world)
  std::array<double, 2> axis_ab{};
  std::array<double, 2> point_st{};
  std::array<double, 6> box{};             // angle-axis world_from_box0, translation
  std::vector<std::array<double, 1>> offset;  // radians, per angle
  std::vector<std::array<double, 6>> board_pose;  // per board photo: angle-axis cam_from_board, translation

  static Params FromModel(const RigModel& m) {
    Params p;
    p.basis.a0 = m.axis.normalized();
    p.basis.u0 = p.basis.a0.unitOrthogonal();
    p.basis.v0 = p.basis.a0.cross(p.basis.u0);
    p.basis.p0 = m.point;
    p.intr = m.intrinsics;
    for (const Rigid3& c : m.cam_from_world) {
      std::array<double, 6> q = PoseToParams(c);
      const Vec3d centre = c.Inverse().translation;
      for (int i = 0; i < 3; ++i) q[3 + i] = centre[i];
      p.cam.push_back(q);
    }
    p.box = PoseToParams(m.world_from_box0);
    for (double d : m.angle_offset_deg) p.offset.push_back({DegToRad(d)});
    return p;
  }

  RigModel ToModel() const {
    RigModel m;
    m.intrinsics = intr;
    for (const auto& q : cam) {
      Rigid3 r = ParamsToPose(q.data());
      r.translation = -(r.rotation * Vec3d(q[3], q[4], q[5]));
      m.cam_from_world.push_back(r);
    }
    m.axis = (basis.a0 + axis_ab[0] * basis.u0 + axis_ab[1] * basis.v0).normalized();
    m.point = basis.p0 + point_st[0] * basis.u0 + point_st[1] * basis.v0;
    m.world_from_box0 = ParamsToPose(box.data());
    for (const auto& o : offset) m.angle_offset_deg.push_back(RadToDeg(o[0]));
    return m;
  }
};

Vec2d ViewResidual(const RigModel& m, const CalibFile& file, const FaceView& v, int k, bool* ok) {
  const CuboidImage& image = file.images[v.image];
  Vec2d pixel;
  *ok = m.Project(image.camera, image.turntable_deg, image.angle, file.faces[v.face].Corner(k), &pixel);
  return pixel - v.corners[k];
}

// Residuals, RMS and max of every used view under a model.
void EvaluateViews(const RigModel& m, const CalibFile& file, std::vector<FaceView>* views, bool baseline) {
  for (FaceView& v : *views) {
    const int n = file.faces[v.face].CornerCount();
    std::vector<Vec2d>& res = baseline ? v.baseline_residuals : v.residuals;
    res.assign(n, Vec2d::Zero());
    double sum = 0, mx = 0;
    int count = 0;
    for (int k = 0; k < n; ++k) {
      if (!v.valid[k]) continue;
      bool ok = false;
      const Vec2d r = ViewResidual(m, file, v, k, &ok);
      res[k] = ok ? r : Vec2d(1e6, 1e6);
      sum += res[k].squaredNorm();
      mx = std::max(mx, res[k].norm());
      ++count;
    }
    const double rms = count > 0 ? std::sqrt(sum / count) : 0;
    if (baseline) {
      v.baseline_rms_px = rms;
    } else {
      v.rms_px = rms;
      v.max_px = mx;
      v.corners_used = count;
    }
  }
}

// Adds the residual blocks of every used view; returns their count.
int BuildProblem(const CalibFile& file, std::vector<FaceView>& views, std::vector<BoardViewResult>* boards,
                 const TurntableOptions& options,
                 int reference_angle, const std::vector<uint8_t>& camera_seen,
                 const std::vector<uint8_t>& angle_seen, Params* p, ceres::Problem* problem,
                 bool robust) {
  int blocks = 0;
  for (FaceView& v : views) {
    if (!v.used) continue;
    const CuboidImage& image = file.images[v.image];
    const BoardSpec& face = file.faces[v.face];
    for (int k = 0; k < face.CornerCount(); ++k) {
      if (!v.valid[k]) continue;
      problem->AddResidualBlock(
          TurntableCornerCost::Create(face.Corner(k), v.corners[k], DegToRad(image.turntable_deg), p->basis,
                                      v.weight),
          robust ? new ceres::HuberLoss(options.loss_scale_px) : nullptr, p->intr[image.camera].data(),
          p->cam[image.camera].data(), p->axis_ab.data(), p->point_st.data(), p->box.data(),
          p->offset[image.angle].data());
      ++blocks;
    }
  }
  if (blocks == 0) return 0;
  problem->SetParameterBlockConstant(p->cam[0].data());
  for (BoardViewResult& v : *boards) {
    if (!v.used) continue;
    for (size_t k = 0; k < v.valid.size(); ++k) {
      if (!v.valid[k]) continue;
      problem->AddResidualBlock(BoardCornerCost::Create(file.board->Corner(int(k)), v.corners[k], v.weight),
                                robust ? new ceres::HuberLoss(options.loss_scale_px) : nullptr,
                                p->intr[v.camera].data(), p->board_pose[&v - boards->data()].data());
    }
  }
  for (size_t c = 0; c < p->intr.size(); ++c) {
    if (!camera_seen[c]) continue;
    if (!options.refine_intrinsics) {
      problem->SetParameterBlockConstant(p->intr[c].data());
    } else {
      internal::SetIntrinsicsManifold(options.intrinsics_model, p->intr[c].data(), problem);
    }
  }
  for (size_t a = 0; a < p->offset.size(); ++a) {
    if (!angle_seen[a]) continue;
    if (!options.angle_offsets || int(a) == reference_angle) problem->SetParameterBlockConstant(p->offset[a].data());
  }
  return blocks;
}

// Per-view noise weights (TurntableOptions::weight_views): each view's noise per axis from its own
// residuals, shrunk towards the median view's by kWeightPriorCorners corners of evidence; weight =
// median noise / view noise. Returns the largest relative change of a weight.
double UpdateWeights(std::vector<FaceView>* views, std::vector<BoardViewResult>* boards) {
  std::vector<double> variances;
  for (const FaceView& v : *views) {
    if (v.used && v.corners_used > 0) variances.push_back(0.5 * v.rms_px * v.rms_px);
  }
  for (const BoardViewResult& v : *boards) {
    if (v.used && v.corners_used > 0) variances.push_back(0.5 * v.rms_px * v.rms_px);
  }
  const double median = internal::Median(variances);
  if (!(median > 0)) return 0;
  double change = 0;
  auto update = [&](double rms, int n, double* weight) {
    const double var = (n * 0.5 * rms * rms + kWeightPriorCorners * median) / (n + kWeightPriorCorners);
    const double w = std::sqrt(median / var);
    change = std::max(change, std::abs(w - *weight) / *weight);
    *weight = w;
  };
  for (FaceView& v : *views) {
    if (v.used) update(v.rms_px, v.corners_used, &v.weight);
  }
  for (BoardViewResult& v : *boards) {
    if (v.used) update(v.rms_px, v.corners_used, &v.weight);
  }
  return change;
}

// Rejects outlier corners and views (face views of the cuboid, or board photos: each set with
// its own robust sigma and median); true when anything changed. `why` ends a rejected view's
// status.
template <typename View>
bool RejectOutliers(const TurntableOptions& options, const std::string& why, std::vector<View>* views) {
  std::vector<double> components, view_rms;
  for (const View& v : *views) {
    if (!v.used) continue;
    view_rms.push_back(v.rms_px);
    for (size_t k = 0; k < v.valid.size(); ++k) {
      if (!v.valid[k]) continue;
      components.push_back(v.residuals[k].x());
      components.push_back(v.residuals[k].y());
    }
  }
  if (view_rms.empty()) return false;
  const double limit = std::max(options.outlier_sigmas * internal::RobustSigma(components), kMinOutlierPx);
  const double view_limit = std::max(options.view_rms_factor * internal::Median(view_rms),
                                     options.min_rejected_view_rms_px);
  // Outlier corners first; a view is judged on the corners it keeps, in a later round.
  bool changed = false;
  for (View& v : *views) {
    if (!v.used) continue;
    for (size_t k = 0; k < v.valid.size(); ++k) {
      if (v.valid[k] && v.residuals[k].norm() > limit) {
        v.valid[k] = 0;
        ++v.corners_rejected;
        changed = true;
      }
    }
  }
  if (changed) return true;
  for (View& v : *views) {
    if (v.used && v.rms_px > view_limit) {
      v.used = false;
      v.status = StrCat("rejected: reprojection RMS ", v.rms_px, " px > ", view_limit, " px", why);
      changed = true;
    }
  }
  return changed;
}

// Start pose of a board photo by PnP with the start intrinsics; false when PnP fails.
bool InitBoardPose(const BoardSpec& board, const BoardViewResult& v, const IntrinsicParams& intr,
                   std::array<double, 6>* pose) {
  std::vector<cv::Point3d> object;
  std::vector<cv::Point2d> image;
  for (size_t k = 0; k < v.valid.size(); ++k) {
    if (!v.valid[k]) continue;
    const Vec3d q = board.Corner(int(k));
    object.emplace_back(q.x(), q.y(), q.z());
    image.emplace_back(v.corners[k].x(), v.corners[k].y());
  }
  const cv::Matx33d K(intr[kFx], 0, intr[kCx], 0, intr[kFy], intr[kCy], 0, 0, 1);
  const std::vector<double> dist(intr.begin() + kK1, intr.end());
  cv::Mat rvec, tvec;
  try {
    if (!cv::solvePnP(object, image, K, dist, rvec, tvec, false, cv::SOLVEPNP_IPPE)) return false;
    cv::solvePnPRefineLM(object, image, K, dist, rvec, tvec);
  } catch (const cv::Exception&) {
    return false;
  }
  for (int i = 0; i < 3; ++i) {
    (*pose)[i] = rvec.at<double>(i);
    (*pose)[3 + i] = tvec.at<double>(i);
  }
  return std::all_of(pose->begin(), pose->end(), [](double x) { return std::isfinite(x); });
}

void EvaluateBoards(const CalibFile& file, const Params& p, std::vector<BoardViewResult>* boards) {
  for (size_t b = 0; b < boards->size(); ++b) {
    BoardViewResult& v = (*boards)[b];
    if (!v.used) continue;
    v.residuals.assign(v.valid.size(), Vec2d::Zero());
    v.cam_from_board = ParamsToPose(p.board_pose[b].data());
    double sum = 0, mx = 0;
    int n = 0;
    for (size_t k = 0; k < v.valid.size(); ++k) {
      if (!v.valid[k]) continue;
      v.residuals[k] = ProjectBoardCorner(p.intr[v.camera], p.board_pose[b].data(), file.board->Corner(int(k))) - v.corners[k];
      sum += v.residuals[k].squaredNorm();
      mx = std::max(mx, v.residuals[k].norm());
      ++n;
    }
    v.corners_used = n;
    v.rms_px = n > 0 ? std::sqrt(sum / n) : 0;
    v.max_px = mx;
  }
}

// Rotation sigma (degrees, about the rotated frame's axes) of an angle-axis block from its
// covariance, through the numerical Jacobian of the rotation's left perturbation.
Vec3d RotationSigmaDeg(const double* aa, const Eigen::Matrix3d& cov) {
  Eigen::Matrix3d j;
  const Rigid3 base = ParamsToPose(std::array<double, 6>{aa[0], aa[1], aa[2], 0, 0, 0}.data());
  // Step small against 1 rad, large against double rounding of the rotation (1e-16).
  constexpr double h = 1e-7;
  for (int c = 0; c < 3; ++c) {
    std::array<double, 6> q{aa[0], aa[1], aa[2], 0, 0, 0};
    q[c] += h;
    const Mat3d delta = ParamsToPose(q.data()).rotation * base.rotation.transpose();
    const Eigen::AngleAxisd d(delta);
    j.col(c) = d.axis() * d.angle() / h;
  }
  const Mat3d s = j * cov * j.transpose();
  return Vec3d(std::sqrt(std::max(0.0, s(0, 0))), std::sqrt(std::max(0.0, s(1, 1))),
               std::sqrt(std::max(0.0, s(2, 2)))) * (180.0 / kPi);
}

RmsStat Stat(const std::vector<const Vec2d*>& residuals) {
  RmsStat s;
  double sum = 0;
  for (const Vec2d* r : residuals) {
    sum += r->squaredNorm();
    s.max_px = std::max(s.max_px, r->norm());
  }
  s.corners = int(residuals.size());
  s.rms_px = s.corners > 0 ? std::sqrt(sum / s.corners) : 0;
  return s;
}

// Angle between two directions, degrees; atan2 keeps small angles exact where acos of a dot
// product near 1 does not (a vector 1e-7 off unit length reads as 0.02 degrees).
double AngleDeg(const Vec3d& a, const Vec3d& b) {
  return RadToDeg(std::atan2(a.cross(b).norm(), a.dot(b)));
}

Rigid3 Orthonormalised(Rigid3 t) {
  t.rotation = ProjectToRotation(t.rotation);
  return t;
}

TruthComparison Compare(const CalibFile& file, const RigModel& m) {
  CalibGroundTruth gt = *file.ground_truth;
  // Ground-truth rotations written in single precision are orthonormal only to ~1e-7.
  for (Rigid3& t : gt.cam_from_world) t = Orthonormalised(t);
  for (auto& [key, t] : gt.cam_from_box) t = Orthonormalised(t);
  if (gt.world_from_box_at_0) gt.world_from_box_at_0 = Orthonormalised(*gt.world_from_box_at_0);
  TruthComparison c;
  const Rigid3& est0 = m.cam_from_world[0];
  const Rigid3& gt0 = gt.cam_from_world[0];
  const Vec3d axis_est = (est0.rotation * m.axis).normalized();
  const Vec3d axis_gt = (gt0.rotation * gt.axis).normalized();
  c.axis_deg = AngleDeg(axis_est, axis_gt);
  const Vec3d point_gt = gt0 * gt.point;
  const Vec3d at_plate = LinePlane(est0 * m.point, axis_est, point_gt, axis_gt);
  c.point_mm = 1000 * (at_plate - point_gt).norm();
  for (size_t i = 0; i < m.cam_from_world.size(); ++i) {
    const Rigid3& est_i = m.cam_from_world[i];
    const Rigid3& gt_i = gt.cam_from_world[i];
    const Vec3d a_est = (est_i.rotation * m.axis).normalized(), a_gt = (gt_i.rotation * gt.axis).normalized();
    const Vec3d p_gt = gt_i * gt.point;
    c.axis_deg_per_camera.push_back(AngleDeg(a_est, a_gt));
    c.point_mm_per_camera.push_back(1000 * (LinePlane(est_i * m.point, a_est, p_gt, a_gt) - p_gt).norm());
    c.max_axis_deg = std::max(c.max_axis_deg, c.axis_deg_per_camera.back());
    c.max_point_mm = std::max(c.max_point_mm, c.point_mm_per_camera.back());
  }
  for (size_t i = 0; i < m.cam_from_world.size(); ++i) {
    const Rigid3 est = m.cam_from_world[i] * est0.Inverse();
    const Rigid3 truth = gt.cam_from_world[i] * gt0.Inverse();
    const double rot = RotationAngleDeg(est.rotation * truth.rotation.transpose());
    const double centre = 1000 * (est.Inverse().translation - truth.Inverse().translation).norm();
    c.camera_rotation_deg.push_back(rot);
    c.camera_centre_mm.push_back(centre);
    c.max_camera_rotation_deg = std::max(c.max_camera_rotation_deg, rot);
    c.max_camera_centre_mm = std::max(c.max_camera_centre_mm, centre);
  }
  std::vector<double> rot, trans;
  for (const CuboidImage& image : file.images) {
    std::optional<Rigid3> truth;
    if (auto it = gt.cam_from_box.find(image.file); it != gt.cam_from_box.end()) {
      truth = it->second;
    } else if (gt.world_from_box_at_0) {
      const Turntable t{gt.axis, gt.point};
      truth = gt.cam_from_world[image.camera] * t.WorldFromObject(image.turntable_deg) * *gt.world_from_box_at_0;
    }
    if (!truth) continue;
    const Rigid3 est = m.CamFromBox(image.camera, image.turntable_deg, image.angle);
    rot.push_back(RotationAngleDeg(est.rotation * truth->rotation.transpose()));
    trans.push_back(1000 * (est.translation - truth->translation).norm());
  }
  if (!rot.empty()) {
    c.box_rotation_median_deg = internal::Median(rot);
    c.box_rotation_max_deg = *std::max_element(rot.begin(), rot.end());
    c.box_translation_median_mm = internal::Median(trans);
    c.box_translation_max_mm = *std::max_element(trans.begin(), trans.end());
  }
  if (gt.has_intrinsics) {
    for (size_t i = 0; i < m.intrinsics.size(); ++i) {
      const IntrinsicParams truth = ToIntrinsicParams(gt.K[i], gt.dist[i]);
      IntrinsicParams e{};
      for (int k = 0; k < kIntrinsicCount; ++k) e[k] = m.intrinsics[i][k] - truth[k];
      c.intrinsics_error.push_back(e);
    }
  }
  return c;
}

// The output gauge (header comment) as new_from_old for a model in any gauge.
Rigid3 TurntableGauge(const RigModel& m) {
  const Vec3d centre0 = m.cam_from_world[0].Inverse().translation;
  const Rigid3 world_from_t = FrameFromAxis(m.axis, m.point, centre0 - m.point);
  return world_from_t.Inverse();
}

// The seed's baseline (header comment): a turntable frame per camera from its own numbered
// photos (anchors: cameras with two or more), the cuboid's pose in that frame averaged over the
// anchors, and the other cameras from their photos' implied poses.
struct BaselineFit {
  std::vector<std::optional<Rigid3>> cam_from_t;
  Rigid3 box_in_t;

  Rigid3 TFromBox(double angle_deg) const {
    const Mat3d rz = AxisAngleRotation(Vec3d::UnitZ(), DegToRad(angle_deg));
    return Rigid3{rz, Vec3d::Zero()} * box_in_t;
  }
  // The model in the turntable frame (cameras without a pose get the identity; callers check).
  RigModel Model(const CalibFile& file, const std::vector<IntrinsicParams>& intrinsics) const {
    RigModel m;
    m.intrinsics = intrinsics;
    for (const auto& c : cam_from_t) m.cam_from_world.push_back(c.value_or(Rigid3()));
    m.axis = Vec3d::UnitZ();
    m.point = Vec3d::Zero();
    m.world_from_box0 = box_in_t;
    m.angle_offset_deg.assign(file.angles_deg.size(), 0.0);
    return m;
  }
};

StatusOr<BaselineFit> FitBaseline(const CalibFile& file, const std::vector<std::vector<int>>& photos_of,
                                  const std::vector<PhotoDetection>& photos) {
  const size_t n_cam = file.cameras.size();
  BaselineFit fit;
  fit.cam_from_t.assign(n_cam, std::nullopt);
  std::vector<Rigid3> box_in_t_samples;
  for (size_t c = 0; c < n_cam; ++c) {
    std::vector<PoseAtAngle> poses;
    for (int i : photos_of[c]) {
      if (photos[i].hypotheses.size() == 1) poses.push_back({file.images[i].turntable_deg, photos[i].hypotheses[0].cam_from_box});
    }
    Vec3d axis, point;
    if (poses.size() < 2 || !AxisFromPoses(poses, &axis, &point)) continue;
    std::vector<Rigid3> at_zero;
    for (const PoseAtAngle& p : poses) at_zero.push_back(BoxAtZero(p, axis, point));
    const Rigid3 box0 = MeanPose(at_zero);
    const Vec3d origin = LinePlane(point, axis, box0.translation, box0.rotation.col(2));
    const Rigid3 frame = FrameFromAxis(axis, origin, box0.rotation.col(0));
    fit.cam_from_t[c] = frame;
    box_in_t_samples.push_back(frame.Inverse() * box0);
  }
  if (box_in_t_samples.empty()) {
    return FailedPreconditionError(
        file.json_path.string(), ": images: no camera found the cuboid, with its boards numbered "
        "unambiguously, at two turntable angles between ", kMinPairAngleDeg, " and ", kMaxPairAngleDeg,
        " degrees apart: the axis cannot be started");
  }
  fit.box_in_t = MeanPose(box_in_t_samples);
  for (size_t c = 0; c < n_cam; ++c) {
    if (fit.cam_from_t[c]) continue;
    std::vector<Rigid3> implied;
    for (int i : photos_of[c]) {
      if (photos[i].hypotheses.size() == 1) {
        implied.push_back(photos[i].hypotheses[0].cam_from_box * fit.TFromBox(file.images[i].turntable_deg).Inverse());
      }
    }
    if (!implied.empty()) fit.cam_from_t[c] = MeanPose(implied);
  }
  return fit;
}

// Numbers the photos that showed only symmetric boards: per camera, the interpretation whose
// implied camera pose agrees with the camera's pose (or, for a camera without one, with the
// largest group of agreeing interpretations among its photos).
Status ResolveNumbering(const CalibFile& file, const std::vector<std::vector<int>>& photos_of,
                        const BaselineFit& fit, std::vector<PhotoDetection>* photos) {
  for (size_t c = 0; c < file.cameras.size(); ++c) {
    std::vector<std::pair<int, Rigid3>> candidates;  // (photo, implied cam_from_t)
    for (int i : photos_of[c]) {
      for (const Hypothesis& h : (*photos)[i].hypotheses) {
        candidates.emplace_back(i, h.cam_from_box * fit.TFromBox(file.images[i].turntable_deg).Inverse());
      }
    }
    if (candidates.empty()) continue;
    Rigid3 reference;
    if (fit.cam_from_t[c]) {
      reference = *fit.cam_from_t[c];
    } else {
      size_t best = 0;
      std::vector<int> support(candidates.size(), 0);
      for (size_t a = 0; a < candidates.size(); ++a) {
        std::set<int> photos_agreeing;
        for (const auto& [photo, pose] : candidates) {
          if (PoseDistance(pose, candidates[a].second) < kSupportDistance) photos_agreeing.insert(photo);
        }
        support[a] = int(photos_agreeing.size());
        if (support[a] > support[best]) best = a;
      }
      // Two different poses with the same support: every interpretation is as consistent as the
      // other (a symmetric board centred on the turntable axis), and the camera could be on either.
      for (size_t a = 0; a < candidates.size(); ++a) {
        if (support[a] == support[best] && PoseDistance(candidates[a].second, candidates[best].second) >= kSupportDistance) {
          return FailedPreconditionError(
              file.json_path.string(), ": images: camera \"", file.cameras[c].id,
              "\" saw only boards that look the same turned by 180 degrees, and its photos agree with "
              "either numbering: its pose cannot be told (a face with one odd and one even square count "
              "in view would)");
        }
      }
      reference = candidates[best].second;
    }
    for (int i : photos_of[c]) {
      auto& hyps = (*photos)[i].hypotheses;
      if (hyps.size() <= 1) continue;
      size_t best = 0;
      double best_d = 1e30;
      for (size_t h = 0; h < hyps.size(); ++h) {
        const double d = PoseDistance(hyps[h].cam_from_box * fit.TFromBox(file.images[i].turntable_deg).Inverse(), reference);
        if (d < best_d) {
          best_d = d;
          best = h;
        }
      }
      Hypothesis keep = std::move(hyps[best]);
      hyps.clear();
      hyps.push_back(std::move(keep));
    }
  }
  return OkStatus();
}

// Second detection pass for one photo: faces the rig shows at cos >= min_cos that are missing.
void SearchPredictedFaces(const CalibFile& file, int index, const RigModel& rig, const IntrinsicParams& intr,
                          const TurntableOptions& options, PhotoDetection* photo) {
  const CuboidImage& image = file.images[index];
  const Rigid3 pose = rig.CamFromBox(image.camera, image.turntable_deg, image.angle);
  std::vector<int> missing;
  for (size_t f = 0; f < file.faces.size(); ++f) {
    if (!photo->hypotheses.empty()) {
      const auto& faces = photo->hypotheses[0].faces;
      if (std::any_of(faces.begin(), faces.end(), [&](const FaceDet& d) { return d.face == int(f); })) continue;
    }
    if (FaceCos(file.faces[f], pose) >= options.min_cos) missing.push_back(int(f));
  }
  if (missing.empty()) return;
  auto grey = LoadGrey(file.Resolve(image.file));
  if (!grey.ok()) {
    photo->status = grey.status().WithContext(StrCat(file.json_path.string(), ": images[", index, "].file"));
    return;
  }
  if (photo->hypotheses.empty()) photo->hypotheses.emplace_back();
  Hypothesis& h = photo->hypotheses[0];
  bool added = false;
  for (int f : missing) {
    std::string why;
    auto found = SearchFace(*grey, file, f, pose, intr, options, &why);
    if (!found) {
      photo->refused.push_back(StrCat("face ", file.faces[f].name, " (rig predicts it in view): ", why));
      continue;
    }
    h.faces.push_back({f, "predicted by the start rig", std::move(found->corners), std::move(found->valid), {}});
    added = true;
  }
  if (!added) {
    if (h.faces.empty()) photo->hypotheses.clear();
    return;
  }
  Rigid3 solved;
  double rms = 0;
  if (SolvePose(file.faces, h.faces, intr, &solved, &rms)) {
    h.cam_from_box = solved;
    h.pnp_rms = rms;
  } else if (h.faces.size() == 1 && h.faces[0].found_by == "predicted by the start rig") {
    photo->hypotheses.clear();
  }
}

}  // namespace

// ---- RigModel ----------------------------------------------------------------------------------

Rigid3 RigModel::WorldFromBox(double angle_deg, int angle) const {
  const double offset = angle >= 0 && angle < int(angle_offset_deg.size()) ? angle_offset_deg[angle] : 0.0;
  const Turntable t{axis, point};
  return t.WorldFromObject(angle_deg + offset) * world_from_box0;
}

Rigid3 RigModel::CamFromBox(int camera, double angle_deg, int angle) const {
  return cam_from_world[camera] * WorldFromBox(angle_deg, angle);
}

bool RigModel::Project(int camera, double angle_deg, int angle, const Vec3d& p_box, Vec2d* pixel) const {
  const Vec3d q = CamFromBox(camera, angle_deg, angle) * p_box;
  if (!(q.z() > 0)) return false;
  *pixel = ProjectCam(intrinsics[camera], q);
  return true;
}

RigModel RigModel::Transformed(const Rigid3& new_from_old) const {
  RigModel m = *this;
  const Rigid3 old_from_new = new_from_old.Inverse();
  for (Rigid3& c : m.cam_from_world) c = c * old_from_new;
  m.axis = new_from_old.rotation * axis;
  m.point = new_from_old * point;
  m.world_from_box0 = new_from_old * world_from_box0;
  return m;
}

double RotationAngleDeg(const Mat3d& r) {
  const double c = std::clamp(0.5 * (r.trace() - 1), -1.0, 1.0);
  // acos loses precision near 0; the sine from the skew part keeps small angles exact.
  const double s = 0.5 * Vec3d(r(2, 1) - r(1, 2), r(0, 2) - r(2, 0), r(1, 0) - r(0, 1)).norm();
  return RadToDeg(std::atan2(s, c));
}

Status TurntableOptions::Validate() const {
  if (!(min_cos > 0 && min_cos < 1)) return InvalidArgumentError("min-cos must be in (0, 1) (got ", min_cos, ")");
  if (!(loss_scale_px > 0)) return InvalidArgumentError("loss scale must be positive (got ", loss_scale_px, ")");
  if (!(outlier_sigmas > 0)) return InvalidArgumentError("outlier sigmas must be positive (got ", outlier_sigmas, ")");
  if (!(view_rms_factor > 1)) return InvalidArgumentError("view RMS factor must exceed 1 (got ", view_rms_factor, ")");
  if (!(min_rejected_view_rms_px >= 0)) return InvalidArgumentError("min_rejected_view_rms_px must not be negative");
  REFLCAP_RETURN_IF_ERROR(intrinsics_model.Validate());
  if (threads < 0) return InvalidArgumentError("threads must not be negative");
  return detect.Validate();
}

namespace {

// Steps 2-6 of the calibration on detected (or given) boards; with `photos_on_disk` the start rig
// also guides a second search of the photos, and the board photos can join the adjustment.
StatusOr<TurntableResult> Adjust(const CalibFile& file, const std::vector<IntrinsicParams>& start,
                                 std::vector<PhotoDetection> photos, const TurntableOptions& options,
                                 bool photos_on_disk, TurntableResult result) {
  const std::string name = file.json_path.string();
  const size_t n_cam = file.cameras.size(), n_img = file.images.size();
  const auto t1 = std::chrono::steady_clock::now();
  // 2. Baseline from the numbered photos; it numbers the photos that showed only symmetric boards.
  std::vector<std::vector<int>> photos_of(n_cam);
  for (size_t i = 0; i < n_img; ++i) photos_of[file.images[i].camera].push_back(int(i));
  REFLCAP_ASSIGN_OR_RETURN(BaselineFit first, FitBaseline(file, photos_of, photos));
  REFLCAP_RETURN_IF_ERROR(ResolveNumbering(file, photos_of, first, &photos));
  // 3. Every face the start rig shows at cos >= min_cos and the first pass missed, searched where
  // the rig puts it (also in photos where the full-image search found nothing).
  if (photos_on_disk) {
    REFLCAP_ASSIGN_OR_RETURN(first, FitBaseline(file, photos_of, photos));
    const RigModel guide = first.Model(file, start);
    Progress progress("searching faces where the start rig predicts them", int64_t(n_img));
    ParallelFor(0, int64_t(n_img), 1, [&](int64_t begin, int64_t end, int) {
      for (int64_t i = begin; i < end; ++i) {
        SearchPredictedFaces(file, int(i), guide, start[file.images[i].camera], options, &photos[i]);
        progress.Advance();
      }
    }, options.threads);
  }
  for (const PhotoDetection& p : photos) REFLCAP_RETURN_IF_ERROR(p.status);
  REFLCAP_ASSIGN_OR_RETURN(BaselineFit fit, FitBaseline(file, photos_of, photos));
  for (size_t c = 0; c < n_cam; ++c) {
    if (!fit.cam_from_t[c]) {
      return FailedPreconditionError(name, ": images: camera \"", file.cameras[c].id,
                                     "\": the cuboid was found in none of its ", photos_of[c].size(),
                                     " photos, so its pose is unknown");
    }
  }
  // The baseline in camera 0's frame (the adjustment's gauge).
  const RigModel baseline_t = fit.Model(file, start);
  const RigModel baseline = baseline_t.Transformed(baseline_t.cam_from_world[0]);

  // 4. Face views: the numbered faces of every photo.
  std::set<int> angles_with_views;
  for (size_t i = 0; i < n_img; ++i) {
    ImageResult ir;
    ir.file = file.images[i].file;
    ir.camera = file.images[i].camera;
    ir.angle = file.images[i].angle;
    ir.refused = photos[i].refused;
    if (photos[i].hypotheses.empty()) {
      ir.status = "no board found";
    } else {
      const Hypothesis& h = photos[i].hypotheses[0];
      for (const FaceDet& d : h.faces) {
        FaceView v;
        v.image = int(i);
        v.face = d.face;
        v.found_by = d.found_by;
        v.corners = d.corners;
        v.valid = d.valid;
        v.cos_view = FaceCos(file.faces[d.face], baseline.CamFromBox(ir.camera, file.images[i].turntable_deg, ir.angle));
        if (v.cos_view < options.min_cos) {
          v.status = StrCat("oblique: cos ", v.cos_view, " < ", options.min_cos);
        } else {
          v.used = true;
          v.status = "used";
          angles_with_views.insert(ir.angle);
        }
        result.views.push_back(std::move(v));
      }
      ir.status = StrCat(h.faces.size(), " face", h.faces.size() == 1 ? "" : "s", " found");
    }
    result.images.push_back(std::move(ir));
  }
  if (angles_with_views.size() < 2) {
    return FailedPreconditionError(name, ": images: the cuboid was seen well enough (cos >= ",
                                   options.min_cos, ") at ", angles_with_views.size(),
                                   " turntable angle(s); the axis needs two or more");
  }

  // 5. Bundle adjustment in camera 0's gauge.
  Params p = Params::FromModel(baseline);
  std::vector<uint8_t> camera_seen(n_cam, 0), angle_seen(file.angles_deg.size(), 0);
  for (const FaceView& v : result.views) {
    if (!v.used) continue;
    camera_seen[file.images[v.image].camera] = 1;
    angle_seen[file.images[v.image].angle] = 1;
  }
  const int reference_angle = *angles_with_views.begin();
  if (options.refine_intrinsics && options.intrinsics_model.tie_focal) {
    for (IntrinsicParams& in : p.intr) in[kFx] = in[kFy] = 0.5 * (in[kFx] + in[kFy]);
  }
  if (photos_on_disk && options.refine_intrinsics && options.board_photos && file.board &&
      !file.board_images.empty()) {
    REFLCAP_ASSIGN_OR_RETURN(result.board_views, DetectBoardPhotos(file, options.detect, options.threads));
    p.board_pose.assign(result.board_views.size(), {});
    for (size_t b = 0; b < result.board_views.size(); ++b) {
      BoardViewResult& v = result.board_views[b];
      if (!v.found) continue;
      v.used = InitBoardPose(*file.board, v, p.intr[v.camera], &p.board_pose[b]);
      v.status = v.used ? "used" : "rejected: PnP failed";
    }
  }
  for (int round = 0; round < kMaxRejectionRounds; ++round) {
    ceres::Problem problem;
    if (BuildProblem(file, result.views, &result.board_views, options, reference_angle, camera_seen,
                     angle_seen, &p, &problem, true) == 0) {
      return FailedPreconditionError(name, ": images: no usable face view left after outlier rejection");
    }
    ceres::Solver::Summary summary;
    ceres::Solve(internal::SolverOptions(options.threads, kMaxIterations, false), &problem, &summary);
    result.iterations += int(summary.iterations.size());
    result.rejection_rounds = round + 1;
    EvaluateViews(p.ToModel(), file, &result.views, false);
    EvaluateBoards(file, p, &result.board_views);
    const bool faces_changed = RejectOutliers(
        options, StrCat(" (", options.view_rms_factor, "x the median face view)"), &result.views);
    const bool boards_changed = RejectOutliers(options, "", &result.board_views);
    const bool weights_changed =
        options.weight_views && UpdateWeights(&result.views, &result.board_views) > kWeightTolerance;
    if (!faces_changed && !boards_changed && !weights_changed) break;
  }
  for (size_t c = 0; c < n_cam; ++c) {
    if (!camera_seen[c]) {
      return FailedPreconditionError(name, ": images: camera \"", file.cameras[c].id,
                                     "\": no face view seen at cos >= ", options.min_cos);
    }
  }

  // 6. Statistics, covariance, gauges.
  RigModel model = p.ToModel();
  // Nothing non-finite may leave: a diverged adjustment is an error, not a rig.
  bool finite = std::all_of(p.box.begin(), p.box.end(), [](double v) { return std::isfinite(v); }) &&
                std::isfinite(p.axis_ab[0] + p.axis_ab[1] + p.point_st[0] + p.point_st[1]);
  for (const auto& c : p.cam) finite &= std::all_of(c.begin(), c.end(), [](double v) { return std::isfinite(v); });
  for (const auto& in : p.intr) finite &= std::all_of(in.begin(), in.end(), [](double v) { return std::isfinite(v); });
  for (const auto& o : p.offset) finite &= std::isfinite(o[0]);
  if (!finite) return FailedPreconditionError(name, ": the bundle adjustment diverged (non-finite parameters)");
  EvaluateViews(model, file, &result.views, false);
  EvaluateViews(baseline, file, &result.views, true);
  std::vector<const Vec2d*> all, all_base;
  std::vector<std::vector<const Vec2d*>> per_cam(n_cam), per_angle(file.angles_deg.size()),
      per_face(file.faces.size()), per_cam_base(n_cam);
  for (FaceView& v : result.views) {
    if (!v.used) {
      v.corners_used = 0;
      continue;
    }
    const CuboidImage& image = file.images[v.image];
    for (size_t k = 0; k < v.valid.size(); ++k) {
      if (!v.valid[k]) continue;
      all.push_back(&v.residuals[k]);
      all_base.push_back(&v.baseline_residuals[k]);
      per_cam[image.camera].push_back(&v.residuals[k]);
      per_cam_base[image.camera].push_back(&v.baseline_residuals[k]);
      per_angle[image.angle].push_back(&v.residuals[k]);
      per_face[v.face].push_back(&v.residuals[k]);
    }
  }
  result.total = Stat(all);
  result.baseline_total = Stat(all_base);
  for (auto& r : per_cam) result.per_camera.push_back(Stat(r));
  for (auto& r : per_cam_base) result.baseline_per_camera.push_back(Stat(r));
  for (auto& r : per_angle) result.per_angle.push_back(Stat(r));
  for (auto& r : per_face) result.per_face.push_back(Stat(r));

  int free_params = 6 * int(n_cam - 1) + 4 + 6;
  if (options.angle_offsets) free_params += int(angles_with_views.size()) - 1;
  if (options.refine_intrinsics) free_params += int(n_cam) * options.intrinsics_model.TangentSize();
  std::vector<const Vec2d*> board_residuals;
  for (const BoardViewResult& v : result.board_views) {
    if (!v.used) continue;
    free_params += 6;
    for (size_t k = 0; k < v.valid.size(); ++k) {
      if (v.valid[k]) board_residuals.push_back(&v.residuals[k]);
    }
  }
  result.board_total = Stat(board_residuals);
  result.parameters = free_params;
  const int dof = 2 * (result.total.corners + result.board_total.corners) - free_params;
  if (dof <= 0) {
    return FailedPreconditionError(name, ": images: ", result.total.corners, " corners cannot determine ",
                                   free_params, " parameters");
  }
  // The residual variance in reference units (weighted residuals) scales the covariance.
  double sum = 0;
  for (const FaceView& v : result.views) {
    for (size_t k = 0; v.used && k < v.valid.size(); ++k) {
      if (v.valid[k]) sum += v.weight * v.weight * v.residuals[k].squaredNorm();
    }
  }
  for (const BoardViewResult& v : result.board_views) {
    for (size_t k = 0; v.used && k < v.valid.size(); ++k) {
      if (v.valid[k]) sum += v.weight * v.weight * v.residuals[k].squaredNorm();
    }
  }
  const double variance = sum / dof;
  result.residual_sigma_px = std::sqrt(variance);

  {
    ceres::Problem problem;
    BuildProblem(file, result.views, &result.board_views, options, reference_angle, camera_seen, angle_seen,
                 &p, &problem, false);
    std::vector<double*> blocks;
    std::vector<int> sizes;
    for (size_t c = 0; c < n_cam; ++c) {
      blocks.push_back(p.cam[c].data());
      sizes.push_back(6);
    }
    blocks.push_back(p.axis_ab.data());
    sizes.push_back(2);
    blocks.push_back(p.point_st.data());
    sizes.push_back(2);
    blocks.push_back(p.box.data());
    sizes.push_back(6);
    for (size_t a = 0; a < p.offset.size(); ++a) {
      if (!angle_seen[a]) continue;
      blocks.push_back(p.offset[a].data());
      sizes.push_back(1);
    }
    for (size_t c = 0; c < n_cam; ++c) {
      blocks.push_back(p.intr[c].data());
      sizes.push_back(kIntrinsicCount);
    }
    auto cov = internal::BlockCovariance(&problem, blocks, sizes, variance);
    if (!cov.ok()) {
      return FailedPreconditionError(name, ": the geometry does not determine the rig (",
                                     cov.status().message(), "): more turntable angles, cameras or faces are needed");
    }
    const Eigen::MatrixXd& m = *cov;
    int o = 0;
    RigSigmas& s = result.sigma;
    for (size_t c = 0; c < n_cam; ++c, o += 6) {
      s.camera_rotation_deg.push_back(RotationSigmaDeg(p.cam[c].data(), m.block<3, 3>(o, o)));
      s.camera_centre_mm.push_back(1000 * m.block<3, 3>(o + 3, o + 3).diagonal().cwiseMax(0).cwiseSqrt());
    }
    s.axis_components_deg = RadToDeg(1) * m.block<2, 2>(o, o).diagonal().cwiseMax(0).cwiseSqrt();
    s.axis_deg = s.axis_components_deg.norm();
    o += 2;
    s.point_mm = 1000 * std::sqrt(std::max(0.0, m(o, o) + m(o + 1, o + 1)));
    o += 2;
    s.box_rotation_deg = RotationSigmaDeg(p.box.data(), m.block<3, 3>(o, o));
    s.box_translation_mm = 1000 * m.block<3, 3>(o + 3, o + 3).diagonal().cwiseMax(0).cwiseSqrt();
    o += 6;
    s.angle_offset_deg.assign(p.offset.size(), 0.0);
    for (size_t a = 0; a < p.offset.size(); ++a) {
      if (!angle_seen[a]) continue;
      s.angle_offset_deg[a] = RadToDeg(std::sqrt(std::max(0.0, m(o, o))));
      ++o;
    }
    for (size_t c = 0; c < n_cam; ++c, o += kIntrinsicCount) {
      IntrinsicParams sig{};
      for (int k = 0; k < kIntrinsicCount; ++k) sig[k] = std::sqrt(std::max(0.0, m(o + k, o + k)));
      s.intrinsics.push_back(sig);
    }
  }

  result.rig_cam0 = model;
  result.baseline_cam0 = baseline;
  result.rig = model.Transformed(TurntableGauge(model));
  result.baseline = baseline.Transformed(TurntableGauge(baseline));
  if (file.ground_truth && file.ground_truth->has_extrinsics) {
    result.truth = Compare(file, model);
    result.baseline_truth = Compare(file, baseline);
  }
  result.solve_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t1).count();
  return result;
}

}  // namespace

StatusOr<TurntableResult> CalibrateTurntable(const CalibFile& file, const std::vector<IntrinsicParams>& start,
                                             const TurntableOptions& options) {
  REFLCAP_RETURN_IF_ERROR(options.Validate());
  REFLCAP_RETURN_IF_ERROR(CheckCuboidSession(file));
  REFLCAP_CHECK(start.size() == file.cameras.size());
  REFLCAP_RETURN_IF_ERROR(CheckCuboidPhotos(file));
  if (options.refine_intrinsics && options.board_photos && file.board) {
    REFLCAP_RETURN_IF_ERROR(CheckBoardPhotos(file));
  }
  const size_t n_img = file.images.size();
  TurntableResult result;
  const auto t0 = std::chrono::steady_clock::now();
  // 1. Detection, in parallel over photos.
  std::vector<PhotoDetection> photos(n_img);
  {
    Progress progress("detecting the cuboid's boards", int64_t(n_img));
    ParallelFor(0, int64_t(n_img), 1, [&](int64_t begin, int64_t end, int) {
      for (int64_t i = begin; i < end; ++i) {
        photos[i] = DetectPhoto(file, int(i), start[file.images[i].camera], options);
        progress.Advance();
      }
    }, options.threads);
  }
  for (const PhotoDetection& p : photos) REFLCAP_RETURN_IF_ERROR(p.status);
  result.detect_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return Adjust(file, start, std::move(photos), options, true, std::move(result));
}

StatusOr<TurntableResult> CalibrateTurntableFromCorners(const CalibFile& file,
                                                        const std::vector<IntrinsicParams>& start,
                                                        const std::vector<std::vector<FaceCorners>>& corners,
                                                        const TurntableOptions& options) {
  REFLCAP_RETURN_IF_ERROR(options.Validate());
  REFLCAP_RETURN_IF_ERROR(CheckCuboidSession(file));
  REFLCAP_CHECK(start.size() == file.cameras.size());
  REFLCAP_CHECK(corners.size() == file.images.size());
  std::vector<PhotoDetection> photos(file.images.size());
  for (size_t i = 0; i < corners.size(); ++i) {
    if (corners[i].empty()) continue;
    Hypothesis h;
    for (const FaceCorners& fc : corners[i]) {
      REFLCAP_CHECK(fc.face >= 0 && fc.face < int(file.faces.size()));
      REFLCAP_CHECK(int(fc.corners.size()) == file.faces[fc.face].CornerCount());
      FaceDet d;
      d.face = fc.face;
      d.found_by = "given";
      d.corners = fc.corners;
      d.valid = fc.valid.empty() ? std::vector<uint8_t>(fc.corners.size(), 1) : fc.valid;
      h.faces.push_back(std::move(d));
    }
    if (SolvePose(file.faces, h.faces, start[file.images[i].camera], &h.cam_from_box, &h.pnp_rms)) {
      photos[i].hypotheses.push_back(std::move(h));
    }
  }
  return Adjust(file, start, std::move(photos), options, false, TurntableResult());
}

}  // namespace reflcap::calib
