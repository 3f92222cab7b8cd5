// Camera-projector triangulation with both projector coordinates (see triangulate.h).
#include "acquire/scan/triangulate.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "engine/core/parallel.h"

namespace reflcap::scan {

namespace {

constexpr int kGaussNewtonSteps = 4;  // the 1-D problem is nearly linear: 2 steps reach 1e-12
// Smallest |d(projector coordinate)/d(depth)| (normalised units per metre) that still constrains
// the depth; below it the axis is parallel to the epipolar line and carries no depth.
constexpr double kMinSensitivity = 1e-9;

// Normalised (undistorted) image coordinates of a pixel of a pinhole device.
Vec2d Normalised(const Camera& c, double x, double y) {
  const double yn = (y - c.K(1, 2)) / c.K(1, 1);
  const double xn = (x - c.K(0, 2) - c.K(0, 1) * yn) / c.K(0, 0);
  return c.HasDistortion() ? c.Undistort(Vec2d(xn, yn)) : Vec2d(xn, yn);
}

double Median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

}  // namespace

Status TriangulateOptions::Validate() const {
  if (!(max_epipolar_px > 0 && max_epipolar_px < 1e6)) {
    return InvalidArgumentError("max_epipolar_px must be positive, got ", max_epipolar_px);
  }
  if (!(max_incidence_deg > 0 && max_incidence_deg < 90)) {
    return InvalidArgumentError("max_incidence_deg must be in (0, 90), got ", max_incidence_deg);
  }
  if (!(max_slope > 0 && max_slope < 1e6)) {
    return InvalidArgumentError("max_slope must be positive, got ", max_slope);
  }
  return OkStatus();
}

StatusOr<ViewCloud> TriangulateView(const DecodedView& view, const Camera& camera,
                                    const Camera& projector, const Rigid3& proj_from_cam,
                                    const Rigid3& object_from_cam,
                                    const TriangulateOptions& options) {
  REFLCAP_RETURN_IF_ERROR(options.Validate());
  if (view.width != camera.width || view.height != camera.height) {
    return InvalidArgumentError("decoded view is ", view.width, "x", view.height, ", camera is ",
                                camera.width, "x", camera.height);
  }
  const int w = view.width, h = view.height;
  const size_t n = size_t(w) * h;
  const Mat3d& R = proj_from_cam.rotation;
  const Vec3d& t = proj_from_cam.translation;
  const double fu = projector.K(0, 0), fv = projector.K(1, 1);
  constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

  std::vector<Vec3d> grid(n, Vec3d::Constant(kNaN));
  std::vector<double> sigma(n, kNaN), epipolar(n, kNaN);
  std::vector<uint8_t> status(n, 0);  // 0 none, 1 ok, 2 epipolar, 3 behind
  ParallelFor(0, h, 8, [&](int64_t y0, int64_t y1, int) {
    for (int64_t y = y0; y < y1; ++y) {
      for (int x = 0; x < w; ++x) {
        const size_t i = size_t(y) * w + x;
        if (view.outcome[i] != uint8_t(PixelOutcome::kDecoded)) continue;
        const Vec2d cn = Normalised(camera, x, double(y));
        const Vec3d d(cn.x(), cn.y(), 1.0);  // camera ray, parameter s = depth z
        const Vec3d p = R * d;
        const Vec2d pn = Normalised(projector, view.u[i], view.v[i]);
        const double sa = std::max(double(view.sigma_u[i]), 1e-6) / fu;  // 1e-6 px: no zero weight
        const double sb = std::max(double(view.sigma_v[i]), 1e-6) / fv;
        auto proj = [&](double s, double* a, double* b, double* da, double* db) {
          const double zx = s * p.x() + t.x(), zy = s * p.y() + t.y(), zz = s * p.z() + t.z();
          *a = zx / zz;
          *b = zy / zz;
          *da = (p.x() * t.z() - p.z() * t.x()) / (zz * zz);
          *db = (p.y() * t.z() - p.z() * t.y()) / (zz * zz);
          return zz;
        };
        // Initial depth: the column- and row-plane intersections, weighted by their variances.
        const double den_u = p.x() - pn.x() * p.z(), den_v = p.y() - pn.y() * p.z();
        double s_num = 0, s_den = 0;
        for (int axis = 0; axis < 2; ++axis) {
          const double den = axis == 0 ? den_u : den_v;
          if (std::abs(den) < kMinSensitivity) continue;
          const double s_axis = axis == 0 ? (pn.x() * t.z() - t.x()) / den_u
                                          : (pn.y() * t.z() - t.y()) / den_v;
          double a, b, da, db;
          proj(s_axis, &a, &b, &da, &db);
          const double deriv = axis == 0 ? da : db;
          const double sig = axis == 0 ? sa : sb;
          const double weight = deriv * deriv / (sig * sig);
          if (!std::isfinite(s_axis) || !std::isfinite(weight)) continue;
          s_num += weight * s_axis;
          s_den += weight;
        }
        if (!(s_den > 0)) {
          status[i] = 3;
          continue;
        }
        double s = s_num / s_den;
        double a = 0, b = 0, da = 0, db = 0, jtj = 0;
        for (int it = 0; it < kGaussNewtonSteps; ++it) {
          proj(s, &a, &b, &da, &db);
          const double ja = da / sa, jb = db / sb;
          const double ra = (a - pn.x()) / sa, rb = (b - pn.y()) / sb;
          jtj = ja * ja + jb * jb;
          if (!(jtj > 0)) break;
          s -= (ja * ra + jb * rb) / jtj;
        }
        const double zz = proj(s, &a, &b, &da, &db);
        if (!(s > 0) || !(zz > 0) || !std::isfinite(s)) {
          status[i] = 3;
          continue;
        }
        const double res_px = std::hypot((a - pn.x()) * fu, (b - pn.y()) * fv);
        epipolar[i] = res_px;
        if (res_px > options.max_epipolar_px) {
          status[i] = 2;
          continue;
        }
        const double ja = da / sa, jb = db / sb;
        sigma[i] = 1.0 / std::sqrt(ja * ja + jb * jb);
        grid[i] = s * d;
        status[i] = 1;
      }
    }
  });

  ViewCloud cloud;
  const Vec3d cam_center_obj = object_from_cam.translation;
  cloud.camera_center = cam_center_obj.cast<float>();
  const Vec3d proj_center_cam = -(R.transpose() * t);
  const double cos_max = std::cos(DegToRad(options.max_incidence_deg));
  const double fx = camera.K(0, 0);
  std::vector<double> kept_sigma, kept_epipolar;
  std::vector<Vec3d> normals(n, Vec3d::Zero());
  for (size_t i = 0; i < n; ++i) {
    if (view.outcome[i] != uint8_t(PixelOutcome::kDecoded)) continue;
    ++cloud.decoded;
    if (status[i] == 2) ++cloud.rejected_epipolar;
    if (status[i] == 3) ++cloud.rejected_behind;
  }
  // Normals from the organised grid.
  auto valid = [&](int x, int y) {
    return x >= 0 && y >= 0 && x < w && y < h && status[size_t(y) * w + x] == 1;
  };
  auto tangent = [&](int x, int y, int dx, int dy, Vec3d* out) {
    const Vec3d& c = grid[size_t(y) * w + x];
    const double limit_per_px = options.max_slope * c.z() / fx;
    for (int r : {2, 1}) {
      const bool plus = valid(x + dx * r, y + dy * r), minus = valid(x - dx * r, y - dy * r);
      const Vec3d* pp = plus ? &grid[size_t(y + dy * r) * w + x + dx * r] : nullptr;
      const Vec3d* pm = minus ? &grid[size_t(y - dy * r) * w + x - dx * r] : nullptr;
      const bool ok_p = pp && std::abs(pp->z() - c.z()) <= limit_per_px * r;
      const bool ok_m = pm && std::abs(pm->z() - c.z()) <= limit_per_px * r;
      if (ok_p && ok_m) {
        *out = *pp - *pm;
        return true;
      }
      if (ok_p) {
        *out = *pp - c;
        return true;
      }
      if (ok_m) {
        *out = c - *pm;
        return true;
      }
    }
    return false;
  };
  std::vector<size_t> kept;
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const size_t i = size_t(y) * w + x;
      if (status[i] != 1) continue;
      Vec3d tx, ty;
      if (!tangent(x, y, 1, 0, &tx) || !tangent(x, y, 0, 1, &ty)) {
        ++cloud.rejected_no_normal;
        continue;
      }
      Vec3d nrm = ty.cross(tx);
      if (!(nrm.norm() > 0)) {
        ++cloud.rejected_no_normal;
        continue;
      }
      nrm.normalize();
      const Vec3d& pt = grid[i];
      if (nrm.dot(pt) > 0) nrm = -nrm;
      const double cos_cam = -nrm.dot(pt.normalized());
      const double cos_proj = nrm.dot((proj_center_cam - pt).normalized());
      if (cos_cam < cos_max || cos_proj < cos_max) {
        ++cloud.rejected_grazing;
        continue;
      }
      normals[i] = nrm;
      kept.push_back(i);
    }
  }
  for (size_t i : kept) kept_sigma.push_back(sigma[i]);
  std::vector<double> sorted_sigma = kept_sigma;
  std::sort(sorted_sigma.begin(), sorted_sigma.end());
  const double sigma_ref = sorted_sigma.empty() ? 1.0 : sorted_sigma[sorted_sigma.size() / 20];
  for (size_t i : kept) {
    const Vec3d& pt = grid[i];
    const double cos_cam = -normals[i].dot(pt.normalized());
    cloud.points.push_back((object_from_cam * pt).cast<float>());
    cloud.normals.push_back((object_from_cam.rotation * normals[i]).cast<float>());
    cloud.sigma_m.push_back(float(sigma[i]));
    cloud.confidence.push_back(float(std::clamp(std::min(1.0, sigma_ref / sigma[i]) * cos_cam, 1e-6, 1.0)));
    cloud.pixel.push_back(uint32_t(i));
    kept_epipolar.push_back(epipolar[i]);
  }
  cloud.median_epipolar_px = Median(kept_epipolar);
  cloud.median_sigma_m = Median(kept_sigma);
  return cloud;
}

}  // namespace reflcap::scan
