#pragma once
// Merging the per-angle point clouds into one surface.
//
// Registration: the clouds are already in the object frame through the calibrated turntable pose.
// Each view's residual against the others (point-to-plane distance to the nearest point of another
// view, within 2 mm) is measured; with `icp`, each view is refined by point-to-plane ICP (Chen &
// Medioni 1992) against the union of the others and the corrections are reported.
//
// Surface: screened Poisson reconstruction (Kazhdan & Hoppe 2013, Open3D 0.16's implementation of
// PoissonRecon) of all oriented points gives a watertight implicit surface; it is trimmed where no
// view saw the surface (vertices farther than `trim_distance_m` from every measured point, then
// specks below 200 triangles), simplified by quadric error decimation (Garland & Heckbert
// 1997) to `target_triangles`, and its vertices are projected onto the measured points (a weighted
// moving-least-squares plane per vertex, Alexa et al. 2003) so the mesh lies on the data rather
// than on Poisson's smoothed level set. Open3D stays inside merge.cc.
#include <string>
#include <vector>

#include "acquire/scan/triangulate.h"
#include "engine/core/status.h"
#include "engine/mesh/mesh.h"

namespace reflcap::scan {

// Automatic shading-normal radius: this fraction of the points' bounding-box diagonal (5.4 mm on
// suzanne). Measured with `reflcap run` on the suzanne capture (holdout PSNR / rel. RMSE; true
// mesh 36.96 dB / 0.5505): vertex normals 35.70 / 0.5936, 3 mm 36.19 / 0.5742, 5 mm 36.57 /
// 0.5556. The capture's photographs are rendered with normals interpolated over the true mesh's
// ~3.5 mm facets, which the measured positions do not carry; a real object whose shading follows
// its shape wants a smaller radius (--normal-radius-mm; 0 = plain vertex normals).
constexpr double kAutoNormalRadiusFraction = 0.02;

struct MergeOptions {
  // Poisson octree depth; 0 = automatic: the depth whose voxel is closest to the point spacing.
  // Range 0 or [5, 12].
  int poisson_depth = 0;
  // Trim vertices farther than this from every measured point (metres); 0 = automatic: the larger
  // of 4 point spacings and 5 % of the points' bounding-box diagonal (gaps narrower than ~10 % of
  // the object are closed by the watertight surface, larger unseen regions are cut; merge.cc
  // kTrimDiagonalFraction has the measurement). >= 0.
  double trim_distance_m = 0;
  // Decimation target (triangles); 0 = keep Poisson's resolution. >= 0 (and >= 100 if set).
  int target_triangles = 60000;
  // Refine each view's turntable pose by point-to-plane ICP against the other views.
  bool icp = false;
  // ICP correspondence distance, metres (default 2 mm: several times the registration error of a
  // calibrated turntable, far below the object's features). > 0.
  double icp_max_distance_m = 0.002;
  // Vertex projection onto the points: radius (metres; 0 = automatic, 2.5x the point spacing)
  // and passes (0 = off). Ranges >= 0 and [0, 5].
  double refine_radius_m = 0;
  int refine_passes = 2;
  // Shading normals (the mesh's corner normals) averaged over this radius (metres; 0 = the plain
  // vertex normals; negative = automatic, kAutoNormalRadiusFraction of the diagonal).
  double normal_radius_m = -1;
  Status Validate() const;
};

struct ViewRegistration {
  double turntable_deg = 0;
  int64_t residual_points = 0;      // points with a neighbour of another view within 2 mm
  double residual_median_m = 0;     // |point-to-plane| distance to the other views
  double residual_p90_m = 0;
  bool icp_applied = false;
  double icp_rotation_deg = 0;      // the correction ICP applied (0 without --icp)
  double icp_translation_m = 0;
  double residual_median_after_m = 0;  // after ICP (= before without it)
};

// Measures the residuals and, with options.icp, refines the clouds in place.
StatusOr<std::vector<ViewRegistration>> RegisterViews(std::vector<ViewCloud>* clouds,
                                                      const MergeOptions& options);

struct SurfaceStats {
  double point_spacing_m = 0;
  int poisson_depth = 0;
  double trim_distance_m = 0;
  int64_t input_points = 0;
  int64_t poisson_triangles = 0;
  int64_t trimmed_triangles = 0;       // removed as unseen
  int64_t removed_components = 0;      // small pieces left by trimming
  int64_t final_triangles = 0, final_vertices = 0;
  int64_t boundary_edges = 0;          // edges with one triangle (the trim's rim)
  int64_t non_manifold_edges = 0;
  double refine_median_shift_m = 0;    // median vertex move of the projection
  double normal_radius_m = 0;          // shading-normal radius used (0 = vertex normals)
  double poisson_s = 0, trim_s = 0, simplify_s = 0, refine_s = 0;
};

// Poisson + trim + decimate + project: a TriangleMesh (object frame) with corner normals, no UVs.
StatusOr<TriangleMesh> ReconstructSurface(const std::vector<ViewCloud>& clouds,
                                          const MergeOptions& options, SurfaceStats* stats);

}  // namespace reflcap::scan
