#pragma once
// Triangulation of decoded structured light: the ray through each decoded camera pixel against the
// projector ray through its decoded (u, v). Both coordinates are used: the depth s along the camera
// ray minimises Σ ((π_p(s) - x) / σ_x)² over x = u, v (Gauss-Newton from the weighted mean of the
// column-plane and row-plane intersections), i.e. the maximum-likelihood point on the camera ray
// under the decoder's per-pixel noise. The remaining residual is the distance of (u, v) from the
// camera pixel's epipolar line: a decoded pair farther than `max_epipolar_px` from it cannot come
// from one surface point and is rejected (Hartley & Zisserman, ch. 9 and 12).
//
// Normals come from the organised point grid (central differences over ±2 then ±1 pixels, no
// depth discontinuity), oriented towards the camera. Each point keeps its depth standard deviation
// and a confidence in (0, 1] (see ViewCloud).
#include <cstdint>
#include <vector>

#include "acquire/scan/decode.h"
#include "engine/camera/camera.h"
#include "engine/core/status.h"
#include "engine/geometry/rigid3.h"
#include "engine/math/types.h"

namespace reflcap::scan {

struct TriangulateOptions {
  // Largest distance (projector px) of the decoded (u, v) from the camera pixel's epipolar line.
  // Default 1.0: 20x the decoder's typical 0.05 px, below a one-pixel decoding slip. > 0.
  double max_epipolar_px = 1.0;
  // Points whose normal makes more than this with the camera or the projector ray are dropped:
  // at grazing incidence a pixel spans a long stretch of surface and the depth is unreliable.
  // Degrees, default 80, in (0, 90).
  double max_incidence_deg = 80.0;
  // A neighbour whose depth differs by more than this factor times the pixel footprint per pixel
  // of offset is across a depth discontinuity (not used for the normal). Default 8 (~83 deg slope).
  double max_slope = 8.0;
  Status Validate() const;
};

// One view's points in the object frame.
struct ViewCloud {
  double turntable_deg = 0;
  std::vector<Vec3f> points;      // object frame, metres
  std::vector<Vec3f> normals;     // unit, object frame, towards the camera
  std::vector<float> sigma_m;     // depth standard deviation along the camera ray, metres
  std::vector<float> confidence;  // (0,1]: min(1, 5th-percentile sigma / sigma) x cos(incidence)
  std::vector<uint32_t> pixel;    // y * width + x in the camera
  Vec3f camera_center;            // camera centre in the object frame
  // Counts: decoded pixels, rejected off the epipolar line, behind a device, without a normal,
  // grazing; kept = points.size().
  int64_t decoded = 0, rejected_epipolar = 0, rejected_behind = 0, rejected_no_normal = 0,
          rejected_grazing = 0;
  double median_epipolar_px = 0;  // over the kept points
  double median_sigma_m = 0;
};

// Triangulates a decoded view. `camera` and `projector` give intrinsics (and distortion);
// proj_from_cam and object_from_cam are the stereo and turntable poses.
StatusOr<ViewCloud> TriangulateView(const DecodedView& view, const Camera& camera,
                                    const Camera& projector, const Rigid3& proj_from_cam,
                                    const Rigid3& object_from_cam,
                                    const TriangulateOptions& options);

}  // namespace reflcap::scan
