#include "calib/camera_model.h"

#include <algorithm>

#include <ceres/rotation.h>

namespace reflcap::calib {

const char* IntrinsicName(int index) {
  static const char* const kNames[kIntrinsicCount] = {"fx", "fy", "cx", "cy", "k1",
                                                      "k2", "p1", "p2", "k3"};
  return index >= 0 && index < kIntrinsicCount ? kNames[index] : "?";
}

IntrinsicParams ToIntrinsicParams(const Mat3d& K, const std::array<double, 5>& dist) {
  return {K(0, 0), K(1, 1), K(0, 2), K(1, 2), dist[0], dist[1], dist[2], dist[3], dist[4]};
}

StatusOr<IntrinsicsModel> IntrinsicsModel::Parse(const std::string& list) {
  IntrinsicsModel m;
  m.free.clear();
  size_t pos = 0;
  while (pos <= list.size()) {
    const size_t comma = std::min(list.find(',', pos), list.size());
    const std::string item = list.substr(pos, comma - pos);
    pos = comma + 1;
    if (item == "f") {
      m.tie_focal = true;
      for (int k : {kFx, kFy}) {
        if (!m.IsFree(k)) m.free.push_back(k);
      }
      continue;
    }
    int index = -1;
    for (int k = 0; k < kIntrinsicCount; ++k) {
      if (item == IntrinsicName(k)) index = k;
    }
    if (index < 0) {
      return InvalidArgumentError("unknown intrinsic parameter \"", item,
                                  "\" (expected f, fx, fy, cx, cy, k1, k2, p1, p2, k3)");
    }
    if (m.IsFree(index)) return InvalidArgumentError("intrinsic parameter \"", item, "\" listed twice");
    m.free.push_back(index);
  }
  std::sort(m.free.begin(), m.free.end());
  REFLCAP_RETURN_IF_ERROR(m.Validate());
  return m;
}

std::string IntrinsicsModel::ToString() const {
  std::string out;
  for (int k : free) {
    if (tie_focal && k == kFy) continue;
    if (!out.empty()) out += ",";
    out += tie_focal && k == kFx ? "f" : IntrinsicName(k);
  }
  return out.empty() ? "none" : out;
}

bool IntrinsicsModel::IsFree(int index) const {
  return std::find(free.begin(), free.end(), index) != free.end();
}

Eigen::MatrixXd IntrinsicsModel::Basis() const {
  Eigen::MatrixXd a = Eigen::MatrixXd::Zero(kIntrinsicCount, TangentSize());
  int col = 0;
  for (int k = 0; k < kIntrinsicCount; ++k) {
    if (!IsFree(k)) continue;
    if (tie_focal && k == kFy) {
      a(kFy, 0) = 1;  // fx's column (fx comes first)
      continue;
    }
    a(k, col++) = 1;
  }
  return a;
}

Status IntrinsicsModel::Validate() const {
  for (size_t i = 0; i < free.size(); ++i) {
    if (free[i] < 0 || free[i] >= kIntrinsicCount) return InvalidArgumentError("unknown intrinsic parameter index ", free[i]);
    for (size_t k = 0; k < i; ++k) {
      if (free[k] == free[i]) return InvalidArgumentError("intrinsic parameter ", IntrinsicName(free[i]), " listed twice");
    }
  }
  if (tie_focal && !(IsFree(kFx) && IsFree(kFy))) return InvalidArgumentError("a tied focal length needs fx and fy free");
  return OkStatus();
}

Mat3d KFromParams(const IntrinsicParams& p) {
  Mat3d K = Mat3d::Identity();
  K(0, 0) = p[kFx];
  K(1, 1) = p[kFy];
  K(0, 2) = p[kCx];
  K(1, 2) = p[kCy];
  return K;
}

std::array<double, 5> DistFromParams(const IntrinsicParams& p) {
  return {p[kK1], p[kK2], p[kP1], p[kP2], p[kK3]};
}

Camera MakeCamera(const std::string& id, int width, int height, const IntrinsicParams& p,
                  const Rigid3& cam_from_world) {
  Camera cam;
  cam.id = id;
  cam.width = width;
  cam.height = height;
  cam.K = KFromParams(p);
  cam.dist = DistFromParams(p);
  cam.cam_from_world = cam_from_world;
  return cam;
}

std::array<double, 6> PoseToParams(const Rigid3& t) {
  std::array<double, 6> out{};
  // ceres wants column-major rotation matrices.
  const Eigen::Matrix<double, 3, 3, Eigen::ColMajor> r = t.rotation;
  ceres::RotationMatrixToAngleAxis(r.data(), out.data());
  out[3] = t.translation.x();
  out[4] = t.translation.y();
  out[5] = t.translation.z();
  return out;
}

Rigid3 ParamsToPose(const double* p) {
  Eigen::Matrix<double, 3, 3, Eigen::ColMajor> r;
  ceres::AngleAxisToRotationMatrix(p, r.data());
  return {Mat3d(r), Vec3d(p[3], p[4], p[5])};
}

}  // namespace reflcap::calib
