#pragma once
// Distances between a scanned mesh and a reference mesh, for the scan report and the tests.
// Accuracy: points sampled uniformly (by area) on the scan where a view saw the surface (within
// `seen_distance_m` of a measured point; the pipeline also reports the whole scan), unsigned
// distance to the reference surface. Completeness: points sampled on the reference where a view saw the surface (within
// `seen_distance_m` of a measured point), distance to the scan; a hole in the scan shows up as
// reference points far from it. Exact point-to-triangle distances (Open3D's RaycastingScene,
// Embree's closest-point query), not nearest-vertex approximations.
#include <cstdint>
#include <vector>

#include "engine/core/status.h"
#include "engine/math/types.h"
#include "engine/mesh/mesh.h"

namespace reflcap::scan {

struct DistanceStats {
  int64_t samples = 0;
  double median_m = 0, p90_m = 0, p95_m = 0, p99_m = 0, max_m = 0, mean_m = 0;
  double fraction_over_1mm = 0;  // share of the samples farther than 1 mm
};

// `count` points on `mesh`, uniform by area, deterministic for `seed`.
std::vector<Vec3f> SampleSurface(const TriangleMesh& mesh, int64_t count, uint64_t seed);

// Unsigned distance from each point to the surface of `mesh`. InvalidArgument for an empty mesh.
StatusOr<std::vector<double>> DistanceToMesh(const TriangleMesh& mesh, const std::vector<Vec3f>& points);

// Distance from each query point to the nearest of `cloud` (a KD-tree).
std::vector<double> DistanceToPoints(const std::vector<Vec3f>& cloud, const std::vector<Vec3f>& queries);

DistanceStats Summarise(std::vector<double> distances);

}  // namespace reflcap::scan
