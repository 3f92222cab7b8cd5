// Mesh-to-mesh and point-to-point distances (see compare.h).
#include "acquire/scan/compare.h"

#include <algorithm>
#include <numeric>
#include <random>

#include <open3d/core/Tensor.h>
#include <open3d/geometry/KDTreeFlann.h>
#include <open3d/geometry/PointCloud.h>
#include <open3d/t/geometry/RaycastingScene.h>

#include "engine/core/parallel.h"

namespace reflcap::scan {

std::vector<Vec3f> SampleSurface(const TriangleMesh& mesh, int64_t count, uint64_t seed) {
  std::vector<double> cumulative(mesh.triangles.size());
  double total = 0;
  for (size_t t = 0; t < mesh.triangles.size(); ++t) {
    const auto& tri = mesh.triangles[t];
    const Vec3d a = mesh.positions[tri[0]].cast<double>(), b = mesh.positions[tri[1]].cast<double>(),
                c = mesh.positions[tri[2]].cast<double>();
    total += 0.5 * (b - a).cross(c - a).norm();
    cumulative[t] = total;
  }
  std::vector<Vec3f> out;
  if (!(total > 0) || count <= 0) return out;
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  out.reserve(size_t(count));
  for (int64_t i = 0; i < count; ++i) {
    const double r = uni(rng) * total;
    const size_t t = std::min(cumulative.size() - 1,
                              size_t(std::lower_bound(cumulative.begin(), cumulative.end(), r) - cumulative.begin()));
    double s1 = uni(rng), s2 = uni(rng);
    if (s1 + s2 > 1) {
      s1 = 1 - s1;
      s2 = 1 - s2;
    }
    const auto& tri = mesh.triangles[t];
    out.push_back(mesh.positions[tri[0]] + float(s1) * (mesh.positions[tri[1]] - mesh.positions[tri[0]]) +
                  float(s2) * (mesh.positions[tri[2]] - mesh.positions[tri[0]]));
  }
  return out;
}

StatusOr<std::vector<double>> DistanceToMesh(const TriangleMesh& mesh, const std::vector<Vec3f>& points) {
  if (mesh.triangles.empty()) return InvalidArgumentError("distance to an empty mesh");
  namespace core = open3d::core;
  std::vector<float> verts;
  verts.reserve(mesh.positions.size() * 3);
  for (const auto& p : mesh.positions) verts.insert(verts.end(), {p.x(), p.y(), p.z()});
  std::vector<uint32_t> tris;
  tris.reserve(mesh.triangles.size() * 3);
  for (const auto& t : mesh.triangles) tris.insert(tris.end(), {t[0], t[1], t[2]});
  std::vector<float> queries;
  queries.reserve(points.size() * 3);
  for (const auto& p : points) queries.insert(queries.end(), {p.x(), p.y(), p.z()});
  std::vector<double> out;
  if (points.empty()) return out;
  try {
    open3d::t::geometry::RaycastingScene scene;
    scene.AddTriangles(core::Tensor(std::move(verts), {int64_t(mesh.positions.size()), 3}),
                       core::Tensor(std::move(tris), {int64_t(mesh.triangles.size()), 3}));
    const core::Tensor d = scene.ComputeDistance(
        core::Tensor(std::move(queries), {int64_t(points.size()), 3}), HardwareThreads());
    const std::vector<float> values = d.ToFlatVector<float>();
    out.assign(values.begin(), values.end());
  } catch (const std::exception& e) {
    return InternalError("closest-point query failed: ", e.what());
  }
  return out;
}

std::vector<double> DistanceToPoints(const std::vector<Vec3f>& cloud, const std::vector<Vec3f>& queries) {
  std::vector<double> out(queries.size(), std::numeric_limits<double>::infinity());
  if (cloud.empty()) return out;
  open3d::geometry::PointCloud pcd;
  pcd.points_.reserve(cloud.size());
  for (const auto& p : cloud) pcd.points_.push_back(p.cast<double>());
  open3d::geometry::KDTreeFlann tree(pcd);
  ParallelFor(0, int64_t(queries.size()), 4096, [&](int64_t b, int64_t e, int) {
    std::vector<int> idx(1);
    std::vector<double> d2(1);
    for (int64_t i = b; i < e; ++i) {
      if (tree.SearchKNN(Eigen::Vector3d(queries[i].cast<double>()), 1, idx, d2) == 1) {
        out[i] = std::sqrt(d2[0]);
      }
    }
  });
  return out;
}

DistanceStats Summarise(std::vector<double> d) {
  DistanceStats s;
  d.erase(std::remove_if(d.begin(), d.end(), [](double x) { return !std::isfinite(x); }), d.end());
  s.samples = int64_t(d.size());
  if (d.empty()) return s;
  std::sort(d.begin(), d.end());
  auto q = [&](double p) { return d[std::min(d.size() - 1, size_t(p * (d.size() - 1) + 0.5))]; };
  s.median_m = q(0.5);
  s.p90_m = q(0.9);
  s.p95_m = q(0.95);
  s.p99_m = q(0.99);
  s.max_m = d.back();
  s.mean_m = std::accumulate(d.begin(), d.end(), 0.0) / double(d.size());
  s.fraction_over_1mm = double(d.end() - std::upper_bound(d.begin(), d.end(), 1e-3)) / double(d.size());
  return s;
}

}  // namespace reflcap::scan
