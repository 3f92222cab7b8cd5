#pragma once
// ColorChecker in the rig: detection, pose, reference radiance, and colour calibration.
//
// Detection. OpenCV's mcc module (contrib; Debian's libopencv-contrib-dev) finds the chart's
// outline in a tone-mapped rendition of the merged chart photograph; several renditions (two
// brightnesses, two scales) are tried. Its outline is coarse (several pixels off on a 320 px
// image), so it only seeds our refinement: (1) a homography from the chart plane to the image is
// fitted to the 24 patch centroids (each patch segmented by region growing against the black
// frame), three times; (2) every patch edge is located to a fraction of a pixel by the area under
// its normalised step profile (for a blurred step the integral of (v − frame)/(patch − frame)
// across the edge is the distance to it, whatever the blur, as long as it is symmetric), lines
// are fitted to the edges and intersected into 96 corners; (3) the chart's pose follows by PnP
// (IPPE, then Levenberg–Marquardt) with the camera's intrinsics and distortion. Every cyclic order
// of mcc's four outline points is tried and the one whose patch colours best match the reference
// (after a per-channel gain) wins, so a chart upside down in the image is handled. When mcc finds
// nothing, corners declared in a chart geometry file (`corners_px` of each patch) seed the same
// refinement; without either, DetectChart fails with an error naming the photograph.
//
// Reference radiance. Each patch is Lambertian with the reference albedo ρ (colour.h): its
// radiance is ρ/π · E, E = I cos θ / d² from the photograph's light (point) or I cos θ
// (directional), evaluated per pixel at the chart point the pixel sees (the pose above).
//
// Colour. The camera's channels are c = g · true (per-channel gains g, the white-balance cast);
// g is the weighted least-squares ratio of measured to reference radiance over the neutral patches'
// pixels. A 3×3 matrix M (true = M · camera) is fitted to all 24 patches (relative errors) as an
// option. ΔE00 per patch, before (camera colours) and after correction, compares albedos in CIELAB.
#include <array>
#include <optional>
#include <string>
#include <vector>

#include "acquire/radiometry/colour.h"
#include "acquire/radiometry/merge.h"
#include "engine/camera/camera.h"
#include "engine/capture/capture.h"
#include "engine/core/status.h"
#include "engine/image/image.h"

namespace reflcap::radiometry {

using PatchQuad = std::array<Vec2d, 4>;  // top-left, top-right, bottom-right, bottom-left
using ChartCorners = std::array<PatchQuad, kChartPatches>;

// Physical layout of a ColorChecker Classic (4 × 6 square patches with black gaps). Chart frame:
// origin at the centre of the patch grid, +x along rows (patch 1 -> 6), +y up (row 4 -> row 1),
// +z the normal towards the camera. Defaults: the brackets/1 chart (40 mm patches, 6 mm gaps).
struct ChartLayout {
  double patch_m = 0.040;  // patch side, metres, > 0
  double gap_m = 0.006;    // black gap between patches, metres, > 0
  Status Validate() const;
  // A point of patch i (0-based): (u, v) in [0, 1]² from its top-left corner, u right, v down.
  Vec2d PatchPoint(int patch, double u, double v) const;
  Vec2d PatchCorner(int patch, int corner) const;  // corner 0..3: TL, TR, BR, BL
};

struct ChartDetection {
  std::string method;        // "mcc" or "declared"
  std::string seed;          // which rendition / hypothesis seeded the refinement
  std::vector<Vec2d> mcc_box;  // mcc's outline (empty when declared corners seeded it)
  ChartCorners corners_px{};   // refined corners, pixel coordinates
  Rigid3 cam_from_chart;
  Rigid3 world_from_chart;
  double reprojection_rms_px = 0;  // PnP residual over the 96 corners
  double colour_residual = 0;      // RMS log mismatch of patch colours after per-channel gains
  int edges_refined = 0;           // of 96
};

// camera_hdr: the merged chart photograph (camera RGB, linear). declared: corners from a chart
// geometry file, used only when mcc finds no chart (or when use_mcc is false). NotFound "no
// ColorChecker found" otherwise.
StatusOr<ChartDetection> DetectChart(const Image& camera_hdr, const Camera& camera,
                                     const ChartLayout& layout,
                                     const std::optional<ChartCorners>& declared,
                                     bool use_mcc = true);

// One pixel of a patch's inner region: the chart point it sees receives E_c = intensity_c · geometry.
struct ChartPixel {
  int x = 0, y = 0;
  int patch = 0;
  double geometry = 0;  // cos θ / d² (point light) or cos θ (directional)
};
// Pixels whose centre sees the central `inner` fraction (per side) of a patch.
std::vector<ChartPixel> ChartInnerPixels(const ChartDetection& detection, const Camera& camera,
                                         const ChartLayout& layout, const Light& light,
                                         double inner = 0.5);

struct PatchColour {
  std::string name;
  Vec3d reference_albedo = Vec3d::Zero();
  Vec3d camera_albedo = Vec3d::Zero();     // measured radiance · π / E, camera RGB, before correction
  Vec3d corrected_albedo = Vec3d::Zero();  // after the correction that is applied
  int pixels = 0;            // inner pixels measured in every channel
  int clipped = 0;           // inner pixels with a clipped or dark channel (left out)
  double delta_e_before = 0;
  double delta_e_gains = 0;
  double delta_e_matrix = 0;
};

struct ColourCalibration {
  Vec3d gains = Vec3d::Ones();       // camera = gains · true
  Mat3d matrix = Mat3d::Identity();  // true = matrix · camera (fitted on all patches)
  bool matrix_applied = false;
  std::array<PatchColour, kChartPatches> patches;
  Vec3d neutral_ratio_spread = Vec3d::Zero();  // std of per-patch measured/reference, neutral row
  double mean_delta_e_before = 0, mean_delta_e_gains = 0, mean_delta_e_matrix = 0;
  double max_delta_e_gains = 0;
  // The correction to apply to camera RGB: diag(1/gains), or the matrix.
  Mat3d Correction() const;
};

// Gains (and matrix) from the merged chart. FailedPrecondition when a neutral patch has no
// measured pixel in some channel (the chart photograph is clipped or black there).
StatusOr<ColourCalibration> CalibrateColour(const MergedBracket& chart,
                                            const std::vector<ChartPixel>& pixels,
                                            const Light& light, bool apply_matrix);

}  // namespace reflcap::radiometry
