#pragma once
// HeightField: the surface of a normal-map capture recovered from its normals, and the cast-shadow
// test on it. A normal-map capture (capture/1 with a normal_map block, e.g. DiLiGenT imported by
// `reflcap import-diligent`) has no geometry, only a normal per masked pixel of an orthographic
// camera; concave objects still cast shadows on themselves, and this is what predicts them.
//
// Integration. In the camera's frame (OpenCV: +x right = +column, +y down = +row, +z away from
// the viewer) a visible surface is h(u, v), the height towards the camera in pixel units (metres
// = h * pixel_size_m when the camera gives one). Its normal (n_c = cam_from_world * n_world,
// facing the camera: n_c.z < 0) fixes the gradient
//   p = dh/du = n_c.x / n_c.z,   q = dh/dv = n_c.y / n_c.z
// (with n_z = -n_c.z the component towards the camera, p = -n_x/n_z, q = -n_y/n_z). h is the
// least-squares solution over the texels (masked pixels with a usable normal, BuildNormalMapAtlas)
// of one equation per pair of 4-neighbouring texels, h_b - h_a = (g_a + g_b) / 2 with g the
// gradient along that axis (trapezoidal rule): a sparse, symmetric positive semi-definite system
// (the graph Laplacian of the texels) solved by sparse Cholesky (Eigen's SimplicialLDLT), with
// one texel per connected component pinned to remove the free constant. Nothing couples pixels
// across the mask boundary (unlike Frankot–Chellappa's FFT, which wraps around the image), and a
// hole in the mask is simply a gap in the graph. Each component's free constant is then set so
// that the mean height of its boundary texels (a texel with a 4-neighbour that is not one) is 0:
// the silhouette is where the surface turns away, the nearest thing to a common depth that
// disconnected parts have (their true offsets are unknowable from normals alone).
//
// Limits (documented, not hidden): least squares smooths across depth discontinuities (an
// occluding contour inside the mask, e.g. an arm in front of a body): the jump is spread over
// the neighbouring pixels, so a step's shadow starts too close and its height is underestimated.
// IntegrationStats reports the residual that measures it (a perfectly integrable normal map has
// none). Near the silhouette n_z -> 0 and the gradient diverges; it is clamped (kMaxSlope).
//
// Shadow test (MakeHeightFieldMarch, HeightFieldShadowed). Lights are directional, so every pixel
// marches along the same image-plane direction, the light's projection, one pixel column or row
// per step, while the ray rises by a fixed height per step; the point is in cast shadow when the
// height field (bilinear over the texels among the four pixels around the sample) lies more than
// kHeightFieldShadowBiasPx above the ray somewhere along it. The march ends lit when the ray
// rises above the field's highest point or leaves the image (nothing lies outside the mask in an
// orthographic view), after at most kMaxHeightFieldMarchSteps steps. O(steps) per pixel and light.
// HeightFieldShadowed is float arithmetic in a fixed order without fused multiply-add, the C++
// twin of the GLSL function of the same name (shaders/common/height_field.glsl).
#include <cstddef>
#include <string>
#include <vector>

#include "engine/camera/camera.h"
#include "engine/core/status.h"
#include "engine/math/types.h"
#include "engine/mesh/texel_atlas.h"
#include "shaders/shared/height_field.h"

namespace reflcap {

using HeightFieldMarch = gpu::shared::HeightFieldMarch;
using gpu::shared::kHeightFieldInsideAbove;
using gpu::shared::kHeightFieldMinTapWeight;
using gpu::shared::kHeightFieldOutside;
using gpu::shared::kHeightFieldShadowBiasPx;
using gpu::shared::kMaxHeightFieldMarchSteps;

// Largest height-field slope |(p, q)| the integration uses (pixels of height per pixel), i.e.
// normals up to atan(10) = 84.3 deg from the viewing axis. Beyond it the gradient is dominated by
// normal error, not shape: the slope is tan(theta), whose derivative 1/cos^2(theta) is 101 at
// 84.3 deg, so a 1 deg normal error already moves it by 1.8 px/px, and an exact silhouette normal
// (theta = 90 deg) would be infinite. A steeper gradient keeps its direction and gets this length.
constexpr double kMaxHeightFieldSlope = 10;

// How the gradients are integrated.
//  - kLeastSquares: min Σ_e (h_b − h_a − g_e)², one sparse solve. At a depth discontinuity the
//    normals say nothing of the step, and the squares spread it over the pixels around it: a
//    ridge that should cast a long shadow casts a short one.
//  - kL1: min Σ_e ρ(h_b − h_a − g_e) with ρ the smoothed absolute value √(r² + ε²) (Charbonnier;
//    ε = l1_epsilon_px), by iteratively reweighted least squares (weights ε / √(r² + ε²), from
//    the least-squares start) until no weight changes by more than reweight_tolerance or
//    max_reweights solves. The absolute value lets a few equations carry a whole step, so
//    discontinuities stay sharp (Durou, Aujol, Courteille, "Integrating the normal field of a
//    surface in the presence of discontinuities", EMMCVPR 2009; Quéau, Durou, Aujol, "Normal
//    integration: a survey", JMIV 2018). The objective is convex: the result does not depend on
//    an iteration count once converged.
enum class HeightFieldIntegration { kLeastSquares, kL1 };
const char* HeightFieldIntegrationName(HeightFieldIntegration integration);  // "ls", "l1"

struct HeightFieldOptions {
  // Gradient clamp, > 0 (pixels per pixel); see kMaxHeightFieldSlope.
  double max_slope = kMaxHeightFieldSlope;
  HeightFieldIntegration integration = HeightFieldIntegration::kLeastSquares;
  // kL1's smoothing scale (px): residuals below it are treated quadratically, which keeps the
  // objective smooth for the solver; steps of a pixel or more are far above it. On DiLiGenT
  // 0.05 and 0.1 px gave shadows within 0.5 dB of holdout PSNR-L of 0.02 px's (bear 27.45 and
  // 27.14 against 27.63 dB; the others within 0.15 dB either way), 0.02 px the best on four of
  // five objects.
  double l1_epsilon_px = 0.02;
  // kL1 stops when no equation's weight changes by more than this between solves (weights are
  // in (0, 1]) or after max_reweights solves: DiLiGenT reaches 0.01 in 48 solves on bear, ~0.02
  // after 60 on pot1, and its shadows at 30 and at 60 solves score within 0.06 dB.
  double reweight_tolerance = 0.01;
  int max_reweights = 30;
  Status Validate() const;
};

// What the integration found, for reports and logs.
struct HeightFieldStats {
  size_t texels = 0;        // unknowns: the atlas's texels
  size_t equations = 0;     // 4-neighbour texel pairs
  size_t components = 0;    // connected components of texels (each with its own constant)
  size_t clamped = 0;       // texels whose gradient was clamped to max_slope
  // Texels whose normal faces away from the camera (n_z <= 0 in the camera frame) — impossible
  // for a visible surface, so an error in the normal map; counted, and their gradient is taken
  // as max_slope along the normal's image-plane direction (the surface turning away, as at a
  // silhouette), or 0 when the normal has no image-plane part.
  size_t backfacing = 0;
  // Root-mean-square and largest |h_b - h_a - (g_a + g_b)/2| over the equations (px): 0 for an
  // integrable field; large values mark depth discontinuities and inconsistent normals.
  double rms_residual_px = 0, max_residual_px = 0;
  double min_height_px = 0, max_height_px = 0;
  HeightFieldIntegration integration = HeightFieldIntegration::kLeastSquares;
  int reweights = 0;               // kL1: reweighted solves after the least-squares start
  double weight_change = 0;        // kL1: the largest weight change of the last reweighting
  size_t discontinuities = 0;      // kL1: equations whose final weight is below 0.1 (|r| > 10 ε)
  double seconds = 0;
  std::string ToString() const;
};

struct HeightField {
  int width = 0;   // the camera's (= the atlas's) size
  int height = 0;
  // Row-major width * height: height towards the camera in pixel units, kHeightFieldOutside on
  // pixels that are not texels.
  std::vector<float> heights_px;
  Mat3d cam_from_world = Mat3d::Identity();  // rotation of the camera the field is seen by
  double pixel_size_m = 0;  // metres per pixel (and per unit of height); 0 = not given
  HeightFieldStats stats;

  bool Inside(int x, int y) const {
    return heights_px[size_t(y) * size_t(width) + size_t(x)] > kHeightFieldInsideAbove;
  }
  float At(int x, int y) const { return heights_px[size_t(y) * size_t(width) + size_t(x)]; }
};

// Integrates the normals of a normal-map atlas (BuildNormalMapAtlas: texel = masked pixel,
// unit normals in the world frame) seen by `camera` into a height field. FailedPrecondition
// unless the camera is orthographic (a pinhole view's normal map integrates along rays, which
// this does not do); InvalidArgument when the atlas and the camera differ in size or the options
// are bad; Internal if the sparse factorisation fails. Back-facing normals are counted, not
// errors (HeightFieldStats::backfacing).
StatusOr<HeightField> IntegrateNormalMap(const TexelAtlas& atlas, const Camera& camera,
                                         const HeightFieldOptions& options = {});

// The march of a directional light (unit direction towards it, world frame) over `field`.
// steps = 0 when no point can be shadowed: the light lies along the viewing axis (its image-plane
// part below 1e-6: a ray to it never leaves the pixel, which the camera sees unobstructed).
HeightFieldMarch MakeHeightFieldMarch(const HeightField& field, const Vec3d& light_direction);

// True when the point on pixel (x, y) of the field (a texel: Inside(x, y)) is in cast shadow under
// the light of `march`. `heights` is HeightField::heights_px. float arithmetic as in the GLSL twin.
bool HeightFieldShadowed(const float* heights, const HeightFieldMarch& march, int x, int y);

}  // namespace reflcap
