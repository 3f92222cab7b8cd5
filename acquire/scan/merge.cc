// Registration residuals / ICP and Poisson surface reconstruction (see merge.h). Open3D 0.16
// (Debian libopen3d-dev) provides the KD-tree, point-to-plane ICP, screened Poisson and quadric
// decimation; everything it returns is checked and converted to reflcap types here.
#include "acquire/scan/merge.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <map>
#include <memory>

#include <open3d/geometry/KDTreeFlann.h>
#include <open3d/geometry/PointCloud.h>
#include <open3d/geometry/TriangleMesh.h>
#include <open3d/pipelines/registration/Registration.h>
#include <open3d/pipelines/registration/TransformationEstimation.h>
#include <open3d/utility/Logging.h>

#include "engine/core/log.h"
#include "engine/core/parallel.h"
#include "engine/core/progress.h"

namespace reflcap::scan {

namespace {

// Neighbours of another view farther than this do not count as overlap for the residuals.
constexpr double kResidualMaxDistanceM = 0.002;
// Automatic trim distance: the larger of a few point spacings (gaps of missing pixels) and 5 % of
// the points' bounding-box diagonal. Measured on suzanne: trimming at 4 spacings (1.8 mm) leaves
// holes in places the capture's cameras see but the scanner did not (the brow, behind the ears),
// through which re-renders show the inside: holdout PSNR 34.9 dB in the grazing pixels 37.7 dB;
// at 15 mm (5.5 % of the diagonal) the gaps close and grazing pixels reach 43.9 dB (true mesh
// 44.4 dB). Regions wider than ~10 % of the object that no view saw (the base) are still cut.
constexpr double kTrimSpacings = 4.0;
constexpr double kTrimDiagonalFraction = 0.05;
// Points per view used for residuals and spacing: enough for percentiles to ~1 %.
constexpr size_t kResidualSamples = 20000;
// Components with fewer triangles than this after trimming are debris (Poisson's specks along the
// trimmed rim). At Poisson's resolution (triangles about half a voxel, the voxel ~ the point
// spacing) 200 triangles are a patch of ~10 x 10 spacings; a seen patch of the surface that
// trimming separated from the rest (under suzanne's chin: ~700 triangles) is kept.
constexpr size_t kMinComponentTriangles = 200;
// Poisson's bounding cube is the points' box scaled by this (Open3D's default 1.1: a margin so the
// implicit function can close the surface beyond the outermost samples).
constexpr float kPoissonScale = 1.1f;
// Poisson runs on one thread: Open3D's threaded solver sums in a thread-dependent order, so the
// same points gave meshes whose p95 distance to the sphere of the scan tests varied by 6 % from
// run to run; one thread makes the mesh reproducible. Cost on suzanne's 324k points at depth 9:
// 10.3 s instead of 8.8 s on 2 cores (decimation, single-threaded anyway, takes 12.5 s).
constexpr int kPoissonThreads = 1;

double Seconds(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

double Percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  const size_t k = std::min(v.size() - 1, size_t(q * (v.size() - 1) + 0.5));
  std::nth_element(v.begin(), v.begin() + k, v.end());
  return v[k];
}

open3d::geometry::PointCloud ToOpen3d(const ViewCloud& c) {
  open3d::geometry::PointCloud pcd;
  pcd.points_.reserve(c.points.size());
  pcd.normals_.reserve(c.points.size());
  for (size_t i = 0; i < c.points.size(); ++i) {
    pcd.points_.push_back(c.points[i].cast<double>());
    pcd.normals_.push_back(c.normals[i].cast<double>());
  }
  return pcd;
}

// Point-to-plane residuals of `source`'s samples against the nearest point of `targets`.
std::vector<double> Residuals(const ViewCloud& source,
                              const std::vector<const open3d::geometry::PointCloud*>& targets,
                              const std::vector<const open3d::geometry::KDTreeFlann*>& trees) {
  const size_t step = std::max<size_t>(1, source.points.size() / kResidualSamples);
  std::vector<double> out;
  std::vector<int> idx(1);
  std::vector<double> d2(1);
  for (size_t i = 0; i < source.points.size(); i += step) {
    const Eigen::Vector3d p = source.points[i].cast<double>();
    double best = kResidualMaxDistanceM * kResidualMaxDistanceM;
    double best_plane = -1;
    for (size_t t = 0; t < trees.size(); ++t) {
      if (trees[t]->SearchKNN(p, 1, idx, d2) < 1 || d2[0] >= best) continue;
      const Eigen::Vector3d& q = targets[t]->points_[idx[0]];
      const Eigen::Vector3d& n = targets[t]->normals_[idx[0]];
      // Only surfaces facing the same way overlap (not the two sides of a thin part).
      if (n.dot(source.normals[i].cast<double>()) < 0.5) continue;
      best = d2[0];
      best_plane = std::abs(n.dot(p - q));
    }
    if (best_plane >= 0) out.push_back(best_plane);
  }
  return out;
}

// Median distance from each point of a view (sampled) to its nearest neighbour in the same view.
double PointSpacing(const std::vector<ViewCloud>& clouds) {
  std::vector<double> spacing;
  for (const ViewCloud& c : clouds) {
    if (c.points.size() < 2) continue;
    const open3d::geometry::PointCloud pcd = ToOpen3d(c);
    open3d::geometry::KDTreeFlann tree(pcd);
    const size_t step = std::max<size_t>(1, c.points.size() / 2000);
    std::vector<int> idx(2);
    std::vector<double> d2(2);
    for (size_t i = 0; i < c.points.size(); i += step) {
      if (tree.SearchKNN(pcd.points_[i], 2, idx, d2) == 2) spacing.push_back(std::sqrt(d2[1]));
    }
  }
  return Percentile(spacing, 0.5);
}

}  // namespace

Status MergeOptions::Validate() const {
  if (poisson_depth != 0 && (poisson_depth < 5 || poisson_depth > 12)) {
    return InvalidArgumentError("poisson depth must be 0 (automatic) or in [5, 12], got ", poisson_depth);
  }
  if (!(trim_distance_m >= 0 && trim_distance_m < 1e3)) {
    return InvalidArgumentError("trim distance must be >= 0 metres, got ", trim_distance_m);
  }
  if (target_triangles < 0 || (target_triangles > 0 && target_triangles < 100)) {
    return InvalidArgumentError("target triangles must be 0 (keep all) or >= 100, got ", target_triangles);
  }
  if (!(icp_max_distance_m > 0 && icp_max_distance_m < 1e3)) {
    return InvalidArgumentError("ICP distance must be positive metres, got ", icp_max_distance_m);
  }
  if (!(refine_radius_m >= 0 && refine_radius_m < 1e3)) {
    return InvalidArgumentError("refine radius must be >= 0 metres, got ", refine_radius_m);
  }
  if (!(normal_radius_m < 1) || std::isnan(normal_radius_m)) {
    return InvalidArgumentError("normal radius must be below 1 metre, got ", normal_radius_m);
  }
  if (refine_passes < 0 || refine_passes > 5) {
    return InvalidArgumentError("refine passes must be in [0, 5], got ", refine_passes);
  }
  return OkStatus();
}

StatusOr<std::vector<ViewRegistration>> RegisterViews(std::vector<ViewCloud>* clouds,
                                                      const MergeOptions& options) {
  REFLCAP_RETURN_IF_ERROR(options.Validate());
  open3d::utility::SetVerbosityLevel(open3d::utility::VerbosityLevel::Error);
  const size_t n = clouds->size();
  std::vector<ViewRegistration> out(n);
  auto measure = [&](bool after) {
    std::vector<open3d::geometry::PointCloud> pcds;
    for (const ViewCloud& c : *clouds) pcds.push_back(ToOpen3d(c));
    std::vector<std::unique_ptr<open3d::geometry::KDTreeFlann>> trees;
    for (const auto& p : pcds) trees.push_back(std::make_unique<open3d::geometry::KDTreeFlann>(p));
    ParallelFor(0, int64_t(n), 1, [&](int64_t b, int64_t e, int) {
      for (int64_t i = b; i < e; ++i) {
        std::vector<const open3d::geometry::PointCloud*> targets;
        std::vector<const open3d::geometry::KDTreeFlann*> tree_ptrs;
        for (size_t j = 0; j < n; ++j) {
          if (j == size_t(i) || pcds[j].points_.empty()) continue;
          targets.push_back(&pcds[j]);
          tree_ptrs.push_back(trees[j].get());
        }
        const std::vector<double> r = Residuals((*clouds)[i], targets, tree_ptrs);
        ViewRegistration& reg = out[i];
        if (after) {
          reg.residual_median_after_m = Percentile(r, 0.5);
        } else {
          reg.turntable_deg = (*clouds)[i].turntable_deg;
          reg.residual_points = int64_t(r.size());
          reg.residual_median_m = Percentile(r, 0.5);
          reg.residual_p90_m = Percentile(r, 0.9);
          reg.residual_median_after_m = reg.residual_median_m;
        }
      }
    });
  };
  measure(false);
  if (!options.icp || n < 2) return out;

  Progress progress("scan: ICP", int64_t(n));
  std::vector<Eigen::Matrix4d> corrections(n, Eigen::Matrix4d::Identity());
  for (size_t i = 0; i < n; ++i) {
    open3d::geometry::PointCloud source = ToOpen3d((*clouds)[i]);
    open3d::geometry::PointCloud target;
    for (size_t j = 0; j < n; ++j) {
      if (j != i) target += ToOpen3d((*clouds)[j]);
    }
    if (source.points_.size() < 100 || target.points_.size() < 100) {
      progress.Advance();
      continue;
    }
    const auto result = open3d::pipelines::registration::RegistrationICP(
        source, target, options.icp_max_distance_m, Eigen::Matrix4d::Identity(),
        open3d::pipelines::registration::TransformationEstimationPointToPlane());
    const Eigen::Matrix4d& T = result.transformation_;
    if (T.allFinite()) corrections[i] = T;
    progress.Advance();
  }
  progress.Finish();
  for (size_t i = 0; i < n; ++i) {
    const Mat3d R = corrections[i].topLeftCorner<3, 3>();
    const Vec3d t = corrections[i].topRightCorner<3, 1>();
    ViewCloud& c = (*clouds)[i];
    for (size_t k = 0; k < c.points.size(); ++k) {
      c.points[k] = (R * c.points[k].cast<double>() + t).cast<float>();
      c.normals[k] = (R * c.normals[k].cast<double>()).cast<float>();
    }
    c.camera_center = (R * c.camera_center.cast<double>() + t).cast<float>();
    out[i].icp_applied = true;
    out[i].icp_rotation_deg = RadToDeg(Eigen::AngleAxisd(R).angle());
    out[i].icp_translation_m = t.norm();
  }
  measure(true);
  return out;
}

StatusOr<TriangleMesh> ReconstructSurface(const std::vector<ViewCloud>& clouds,
                                          const MergeOptions& options, SurfaceStats* stats) {
  REFLCAP_RETURN_IF_ERROR(options.Validate());
  open3d::utility::SetVerbosityLevel(open3d::utility::VerbosityLevel::Error);
  SurfaceStats local;
  SurfaceStats& st = stats ? *stats : local;
  open3d::geometry::PointCloud all;
  std::vector<float> weight;
  for (const ViewCloud& c : clouds) {
    all += ToOpen3d(c);
    weight.insert(weight.end(), c.confidence.begin(), c.confidence.end());
  }
  st.input_points = int64_t(all.points_.size());
  if (all.points_.size() < 100) {
    return FailedPreconditionError("only ", all.points_.size(),
                                   " points were triangulated (at least 100 are needed for a surface)");
  }
  st.point_spacing_m = PointSpacing(clouds);
  if (!(st.point_spacing_m > 0)) return FailedPreconditionError("the points have no measurable spacing");
  const Eigen::Vector3d extent = all.GetMaxBound() - all.GetMinBound();
  st.poisson_depth = options.poisson_depth;
  if (st.poisson_depth == 0) {
    const double cube = extent.maxCoeff() * kPoissonScale;
    st.poisson_depth = std::clamp(int(std::round(std::log2(cube / st.point_spacing_m))), 5, 11);
  }
  st.trim_distance_m = options.trim_distance_m > 0
                           ? options.trim_distance_m
                           : std::max(kTrimSpacings * st.point_spacing_m, kTrimDiagonalFraction * extent.norm());

  // Poisson.
  auto start = std::chrono::steady_clock::now();
  REFLCAP_LOG(kInfo) << "scan: Poisson reconstruction of " << all.points_.size()
                     << " points at depth " << st.poisson_depth << " (one step, no progress)";
  std::shared_ptr<open3d::geometry::TriangleMesh> mesh;
  try {
    auto [m, densities] = open3d::geometry::TriangleMesh::CreateFromPointCloudPoisson(
        all, size_t(st.poisson_depth), 0.0f, kPoissonScale, false, kPoissonThreads);
    mesh = m;
  } catch (const std::exception& e) {
    return InternalError("Poisson reconstruction failed: ", e.what());
  }
  if (!mesh || mesh->triangles_.empty()) return InternalError("Poisson reconstruction returned no surface");
  st.poisson_triangles = int64_t(mesh->triangles_.size());
  st.poisson_s = Seconds(start);

  // Trim where no view saw the surface.
  start = std::chrono::steady_clock::now();
  open3d::geometry::KDTreeFlann tree(all);
  {
    std::vector<bool> remove(mesh->vertices_.size(), false);
    const double limit2 = st.trim_distance_m * st.trim_distance_m;
    ParallelFor(0, int64_t(mesh->vertices_.size()), 4096, [&](int64_t b, int64_t e, int) {
      std::vector<int> idx(1);
      std::vector<double> d2(1);
      for (int64_t v = b; v < e; ++v) {
        const bool found = tree.SearchKNN(mesh->vertices_[v], 1, idx, d2) == 1;
        remove[v] = !found || d2[0] > limit2;
      }
    });
    const size_t before = mesh->triangles_.size();
    mesh->RemoveVerticesByMask(remove);
    st.trimmed_triangles = int64_t(before - mesh->triangles_.size());
    auto [cluster, cluster_size, cluster_area] = mesh->ClusterConnectedTriangles();
    std::vector<bool> drop(mesh->triangles_.size(), false);
    std::vector<bool> small(cluster_size.size(), false);
    for (size_t c = 0; c < cluster_size.size(); ++c) {
      small[c] = cluster_size[c] < kMinComponentTriangles;
      st.removed_components += small[c] ? 1 : 0;
      REFLCAP_LOG(kDebug) << "scan: component " << c << ": " << cluster_size[c] << " triangles, "
                          << cluster_area[c] * 1e6 << " mm^2" << (small[c] ? " (removed)" : "");
    }
    for (size_t t = 0; t < drop.size(); ++t) drop[t] = small[cluster[t]];
    mesh->RemoveTrianglesByMask(drop);
    mesh->RemoveUnreferencedVertices();
  }
  if (mesh->triangles_.empty()) {
    return FailedPreconditionError("nothing of the Poisson surface lies within ", st.trim_distance_m,
                                   " m of the measured points");
  }
  st.trim_s = Seconds(start);

  // Decimate.
  start = std::chrono::steady_clock::now();
  if (options.target_triangles > 0 && int64_t(mesh->triangles_.size()) > options.target_triangles) {
    REFLCAP_LOG(kInfo) << "scan: decimating " << mesh->triangles_.size() << " -> "
                       << options.target_triangles << " triangles (one step, no progress)";
    mesh = mesh->SimplifyQuadricDecimation(options.target_triangles,
                                           std::numeric_limits<double>::infinity(), 1.0);
  }
  mesh->RemoveDuplicatedVertices();
  mesh->RemoveDegenerateTriangles();
  mesh->RemoveUnreferencedVertices();
  st.simplify_s = Seconds(start);

  // Project vertices onto the measured points.
  start = std::chrono::steady_clock::now();
  const double radius = options.refine_radius_m > 0 ? options.refine_radius_m : 2.5 * st.point_spacing_m;
  std::vector<double> shifts;
  if (options.refine_passes > 0) {
    Progress progress("scan: projecting vertices", int64_t(options.refine_passes) *
                                                     int64_t(mesh->vertices_.size()));
    for (int pass = 0; pass < options.refine_passes; ++pass) {
      mesh->ComputeVertexNormals();
      std::vector<Eigen::Vector3d> moved = mesh->vertices_;
      std::vector<double> shift(mesh->vertices_.size(), 0.0);
      ParallelFor(0, int64_t(mesh->vertices_.size()), 1024, [&](int64_t b, int64_t e, int) {
        std::vector<int> idx;
        std::vector<double> d2;
        for (int64_t v = b; v < e; ++v) {
          const Eigen::Vector3d& x = mesh->vertices_[v];
          const Eigen::Vector3d& nv = mesh->vertex_normals_[v];
          if (tree.SearchRadius(x, radius, idx, d2) < 3) continue;
          // Weighted plane through the neighbours that face the vertex's way: Gaussian in distance
          // (sigma = radius/2) times the point's confidence.
          double wsum = 0;
          Eigen::Vector3d c = Eigen::Vector3d::Zero(), nsum = Eigen::Vector3d::Zero();
          for (size_t k = 0; k < idx.size(); ++k) {
            const Eigen::Vector3d& pn = all.normals_[idx[k]];
            if (pn.dot(nv) < 0.5) continue;  // the other side of a thin part (> 60 deg apart)
            const double w = std::exp(-2.0 * d2[k] / (radius * radius)) * weight[idx[k]];
            c += w * all.points_[idx[k]];
            nsum += w * pn;
            wsum += w;
          }
          if (!(wsum > 0) || !(nsum.norm() > 0)) continue;
          c /= wsum;
          const Eigen::Vector3d n = nsum.normalized();
          const double offset = n.dot(x - c);
          // Moves beyond the search radius would be extrapolation: keep the vertex.
          if (!std::isfinite(offset) || std::abs(offset) > radius) continue;
          moved[v] = x - offset * n;
          shift[v] = std::abs(offset);
        }
        progress.Advance(e - b);
      });
      mesh->vertices_ = moved;
      if (pass == 0) shifts = shift;
    }
    progress.Finish();
  }
  st.refine_median_shift_m = Percentile(shifts, 0.5);
  st.refine_s = Seconds(start);
  mesh->ComputeVertexNormals();
  st.normal_radius_m = options.normal_radius_m >= 0 ? options.normal_radius_m
                                                    : kAutoNormalRadiusFraction * extent.norm();
  if (st.normal_radius_m > 0) {
    // Shading normals: per vertex, the area-weighted face normals within the radius, Gaussian in
    // distance (sigma = radius / 2), only faces turned less than 90 degrees from the vertex's own
    // normal (the other side of a thin part does not count).
    mesh->ComputeTriangleNormals();
    std::vector<Eigen::Vector3d> centroid(mesh->triangles_.size()), weighted(mesh->triangles_.size());
    open3d::geometry::PointCloud centres;
    for (size_t t = 0; t < mesh->triangles_.size(); ++t) {
      const auto& tri = mesh->triangles_[t];
      const Eigen::Vector3d& a = mesh->vertices_[tri[0]];
      const Eigen::Vector3d& b = mesh->vertices_[tri[1]];
      const Eigen::Vector3d& c = mesh->vertices_[tri[2]];
      centroid[t] = (a + b + c) / 3;
      weighted[t] = 0.5 * (b - a).cross(c - a);  // area-weighted normal
    }
    centres.points_ = centroid;
    open3d::geometry::KDTreeFlann face_tree(centres);
    const double r = st.normal_radius_m;
    std::vector<Eigen::Vector3d> smooth(mesh->vertices_.size());
    ParallelFor(0, int64_t(mesh->vertices_.size()), 1024, [&](int64_t b, int64_t e, int) {
      std::vector<int> idx;
      std::vector<double> d2;
      for (int64_t v = b; v < e; ++v) {
        const Eigen::Vector3d& own = mesh->vertex_normals_[v];
        Eigen::Vector3d acc = Eigen::Vector3d::Zero();
        face_tree.SearchRadius(mesh->vertices_[v], r, idx, d2);
        for (size_t k = 0; k < idx.size(); ++k) {
          if (weighted[idx[k]].dot(own) <= 0) continue;
          acc += std::exp(-2.0 * d2[k] / (r * r)) * weighted[idx[k]];
        }
        smooth[v] = acc.norm() > 0 ? Eigen::Vector3d(acc.normalized()) : own;
      }
    });
    mesh->vertex_normals_ = smooth;
  }

  // Edge statistics.
  std::map<std::pair<int, int>, int> edges;
  for (const auto& t : mesh->triangles_) {
    for (int k = 0; k < 3; ++k) {
      int a = t[k], b = t[(k + 1) % 3];
      if (a > b) std::swap(a, b);
      ++edges[{a, b}];
    }
  }
  for (const auto& [e, count] : edges) {
    if (count == 1) ++st.boundary_edges;
    if (count > 2) ++st.non_manifold_edges;
  }

  TriangleMesh out;
  out.positions.reserve(mesh->vertices_.size());
  for (const auto& v : mesh->vertices_) out.positions.push_back(v.cast<float>());
  for (const auto& t : mesh->triangles_) {
    const std::array<uint32_t, 3> tri = {uint32_t(t[0]), uint32_t(t[1]), uint32_t(t[2])};
    const Vec3f e1 = out.positions[tri[1]] - out.positions[tri[0]];
    const Vec3f e2 = out.positions[tri[2]] - out.positions[tri[0]];
    if (!(e1.cross(e2).norm() > 0)) continue;  // zero area after float rounding
    out.triangles.push_back(tri);
    std::array<Vec3f, 3> cn;
    for (int k = 0; k < 3; ++k) {
      Vec3f nn = mesh->vertex_normals_[t[k]].cast<float>();
      cn[k] = nn.norm() > 0 ? nn.normalized() : e1.cross(e2).normalized();
    }
    out.corner_normals.push_back(cn);
  }
  st.final_triangles = int64_t(out.triangles.size());
  st.final_vertices = int64_t(out.positions.size());
  return out;
}

}  // namespace reflcap::scan
