#pragma once
// A UV atlas for a scanned mesh: charts + packing, written here because Debian's Open3D 0.16 is
// built without UVAtlas ("UVAtlas not available in Debian") and CGAL 5.5 parameterises one disc
// at a time without segmentation or packing.
//
// Charts: faces are grown from seeds in breadth-first order over the mesh, cheapest first (normal
// deviation from the seed plus distance), while every face normal stays within
// `max_chart_angle_deg` of the chart's projection axis (Sander et al. 2001 and Lévy et al. 2002 grow
// charts the same way; the planar criterion is D-Charts' (Julius et al. 2005) "planarity"). Each
// chart is projected orthographically on the plane normal to its axis: no triangle flips (every
// n·axis > cos(max angle) > 0), stretch at most 1/cos(max angle). Faces whose projection overlaps
// an earlier face of their chart (an exact separating-axis test: folds and double layers of the
// mesh) become charts of their own. Charts that fill less than half their bounding box (arcs,
// combs) are halved across their long axis; then neighbouring charts are merged, smallest first,
// while the union stays within the cone, fills half its box and does not overlap itself.
// Packing: one scale for all charts (texel density uniform up to the projection's cosine); each
// chart, rotated to its principal axes and tried at 0 and 90 degrees, is rasterised conservatively
// at the atlas resolution, dilated by the gutter, and placed at the first free position in
// scan-line order (bitmap packing as in xatlas); the largest scale that packs is found by
// bisection. The result has no overlapping texels at `resolution` by construction, which
// engine/mesh/texel_atlas.h relies on.
#include <cstdint>

#include "engine/core/status.h"
#include "engine/mesh/mesh.h"

namespace reflcap::scan {

struct UvAtlasOptions {
  // Atlas resolution the packing is made for (texels per side; the texel atlas of `reflcap
  // resample --atlas-res` at this size has `gutter_texels` between charts). Range [64, 16384].
  int resolution = 512;
  // Empty texels kept between charts at `resolution`. Range [0, 8]. With 0 charts still never
  // share a texel (their conservative rasters are disjoint) at `resolution` or any multiple of it,
  // which is all reflcap needs: it looks texels up by the pixel containing a UV (TexelAtlas::
  // PixelOfUv) and never interpolates between them. 1 or more suits bilinear texture lookups in
  // other tools, at ~5 % less atlas use (suzanne: area use 0.74 -> 0.70).
  int gutter_texels = 0;
  // Largest angle between a face normal and its chart's projection axis, degrees; stretch is at
  // most 1/cos of it. Range [10, 80]; default 45 (stretch <= 1.41; measured on suzanne, 35-60
  // degrees give 0.65-0.70 area use with a gutter of 1, 45 the best).
  double max_chart_angle_deg = 45.0;
  Status Validate() const;
};

struct UvAtlasStats {
  int64_t charts = 0;
  int64_t split_charts = 0;       // charts regrown because their projection overlapped itself
  double area_use = 0;            // Σ UV triangle area (the unit square = 1)
  double texel_use = 0;           // texels of the conservative raster at `resolution` / resolution²
  int64_t overlap_pixels = 0;     // pixel centres inside two triangles at kOverlapCheckResolution
  double max_stretch = 0;         // largest 1/cos(face normal, chart axis)
  double scale_texels_per_m = 0;  // texel density at `resolution`
  double seconds = 0;
};

// Overlaps are counted at this resolution (a pixel centre strictly inside two UV triangles).
constexpr int kOverlapCheckResolution = 4096;

// Replaces mesh->corner_uvs with the atlas. FailedPrecondition when the mesh has no triangles or
// packing fails; InvalidArgument for bad options.
Status ComputeUvAtlas(TriangleMesh* mesh, const UvAtlasOptions& options, UvAtlasStats* stats);

// Pixel centres (at resolution x resolution over the unit square) strictly inside two or more
// UV triangles of `mesh` (triangles sharing an edge do not count). 0 = no overlap.
int64_t CountUvOverlaps(const TriangleMesh& mesh, int resolution);

}  // namespace reflcap::scan
