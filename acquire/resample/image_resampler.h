#pragma once
// ImageResampler: one photograph of a capture -> one outcome per texel and a BRDF sample for every
// texel that passes all tests (CPU path; visibility and shadows by Embree through RayScene).
//
// It inverts the reference renderer (render/reference/reference_renderer.h): the photograph's
// pixel is exposure_s * f(wi, wo) * E, so f = pixel / (exposure_s * E) with E = I cos θi / d²
// (point light) or I cos θi (directional), cos θi taken at the texel's shading normal, and wi, wo
// expressed in the texel's tangent frame exactly as the renderer builds it (atlas tangent
// re-orthogonalised against the shading normal; bitangent = normal x tangent).
//
// Per texel, for a mesh capture, the tests run in this order and the first one that fails is the
// outcome (Outcome below): the view is not grazing -> the texel projects inside the image (the
// four bilinear taps around its projection, with lens distortion) -> the segment to the camera is
// free (Embree occlusion ray from the texel, offset by RayScene::SurfaceOffset along the
// geometric normal, to the camera centre, or along the view axis of an orthographic camera); the
// texel is then "seen" -> the light is not grazing -> the segment to the light is free -> every
// tap sees the texel's own, lit surface (the camera ray through the tap's pixel centre hits the
// mesh within a depth tolerance of the texel, and that hit point is lit as the renderer decides
// it: both normals face the light and its shadow ray is free) -> the sample point (SamplePoint:
// by default the tap whose hit lies nearest the texel centre, at that hit's geometry, its own
// normal not grazing, else kEdgeSurface / kEdgeShadow) -> the pixel values are usable: every
// tap read finite (else kInvalid), none clipped, the value not negative beyond the noise (else
// kInvalid) and above the noise floor.
//
// The noise of a sample comes from the photograph's variance image when the capture gives one
// (images[].variance, e.g. from `reflcap hdr`'s merge): the value Σ w_k p_k of independent
// pixels (one pixel of weight 1 under SamplePoint::kPixel, the bilinear weights under kTexel)
// has variance Σ w_k² var_k (MeasuredVariance below), to which the relative
// floor is added as in the noise model; otherwise from the noise model (NoiseModel). Either
// variance, divided by the sample's scale² (the value's own scaling), gives the weight 1 / var,
// and the same noise decides the invalid and dark tests.
//
// The tap tests read a per-image "pixel map" of what the camera ray through each pixel centre
// sees (hit or background, depth, lit), filled lazily: a block casts the pixels its candidates'
// taps need that no block has cast yet (Intersect16 and Occluded16 packets). Neighbouring texels
// share taps, so this costs far fewer rays than four per candidate when texels are smaller than
// pixels, and never more. Visibility and shadow rays of a block go out in 16-wide packets.
//
// Normal-map captures (no mesh) take the texel's own pixel as its projection and every texel is
// visible (an orthographic view sees every pixel of its normal map); no occlusion, shadow or tap
// ray is cast. With a height field (SetHeightField: the normal map integrated into a surface,
// engine/mesh/height_field.h) a texel whose march towards the photograph's light passes below
// that surface is kShadowed, tested where the mesh path casts its shadow ray (after the light's
// grazing test); without one, every texel counts as unshadowed.
#include <array>
#include <cmath>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "acquire/resample/chunk_writer.h"
#include "engine/capture/capture.h"
#include "engine/core/status.h"
#include "engine/image/image.h"
#include "engine/math/types.h"
#include "engine/mesh/height_field.h"
#include "engine/mesh/ray_scene.h"
#include "engine/mesh/texel_atlas.h"

namespace reflcap::resample {

// Where a mesh texel's sample is measured (ResampleOptions::sample_point, `--sample-point`).
enum class SamplePoint : uint8_t {
  // The photograph's pixel that measured the texel: of the four around its projection (all of
  // which passed the footprint tests), the one whose camera ray hits the surface inside the
  // texel (the hit's UV falls in it: TexelAtlas::TexelUnderUv, the renderers' lookup) nearest
  // its centre; when none does, an area-filtered camera (camera.h PixelFilter) takes the pixel
  // whose hit is nearest the texel centre — its footprint straddles texels anyway — while a
  // point-sampling one rejects the pair (Outcome::kEdgeTexel): each of its pixels saw exactly
  // one other texel, whose reflectance may differ. The sample has the geometry of that hit: its
  // position, interpolated shading normal, view and light directions, light distance and
  // cos θi, i.e. the configuration the pixel measured (in the texel's tangent direction
  // re-orthogonalised against the hit's normal, as the renderer shades the hit).
  // Why: on a curved surface the normal turns across a pixel; interpolating neighbouring pixels
  // at the texel centre mixes radiance from other normals into one configuration, which blurs a
  // sharp highlight in angle and fits lobes broader and weaker than they are (synth
  // sharp-highlight material, n = 250: holdout rel. RMSE 0.23 with kTexel, 0.02 with kPixel).
  // And a pixel whose hit lies in the neighbouring texel measured that texel's reflectance:
  // at a material boundary 0.66 % of the noise-free demo's samples were another material's,
  // which cost its holdout 48.77 dB against a 52.72 dB noise bound (52.13 dB without them).
  kPixel = 0,
  // Bilinear interpolation of the four pixels at the texel centre's projection, with the texel
  // centre's geometry (the only choice before 2026-11-27): averages the noise of up to four
  // pixels, blurs highlights.
  kTexel = 1,
};
const char* SamplePointName(SamplePoint point);
// "pixel" or "texel"; InvalidArgument naming --sample-point otherwise.
StatusOr<SamplePoint> ParseSamplePoint(const std::string& name);
// `--pixel-filter`: "capture" (nullopt: each camera's cameras[].pixel_filter), "area" or
// "point" (every camera's pixels taken as such); InvalidArgument naming the option otherwise.
StatusOr<std::optional<PixelFilter>> ParsePixelFilter(const std::string& name);

// What became of one (texel, image) pair, in test order (the first failing test names it).
enum class Outcome : uint8_t {
  kKept = 0,
  kGrazingView,   // n_s·v <= min_cos, or n_g·v <= 0 (geometric back face)
  kEdgeOutside,   // a bilinear tap of non-zero weight lies outside the image, or the texel is
                  // behind a pinhole camera
  kOccluded,      // something lies on the segment from the texel to the camera
  kGrazingLight,  // n_s·l <= min_cos, or n_g·l <= 0
  kShadowed,      // something lies on the segment from the texel to the light
  kEdgeSurface,   // a tap's camera ray misses the object or hits it off the texel's depth
                  // (silhouette or depth discontinuity inside the pixel footprint); under
                  // SamplePoint::kPixel also when the chosen pixel's hit is seen at n_s·v <=
                  // min_cos (a rim inside the footprint)
  kEdgeShadow,    // a tap's surface point is unlit (a shadow boundary inside the footprint);
                  // under SamplePoint::kPixel also when the chosen pixel's hit has n_s·l <=
                  // min_cos (the terminator inside the footprint)
  kInvalid,       // a tap is NaN or Inf, or a channel is negative beyond the noise
  kClipped,       // a tap reaches the image's saturation level in some channel
  kDark,          // every channel at or below the noise floor
  // Tested after the footprint tests and before the pixel tests (numbered last so the older
  // outcomes keep their codes): SamplePoint::kPixel with a point-sampling camera, a texel the view
  // resolves (kMinResolvedTexelPixels), and no tap's hit inside it — every pixel around its
  // projection measured another texel.
  kEdgeTexel,
};
constexpr int kOutcomeCount = 12;
const char* OutcomeName(Outcome outcome);

// The camera sees the texel: the view is not grazing, it projects inside the image and nothing
// occludes it (every outcome from kGrazingLight on, and kKept).
inline bool Seen(Outcome o) { return o == Outcome::kKept || o >= Outcome::kGrazingLight; }
// The photograph shows the texel lit: seen, the light is not grazing and nothing shadows it; only
// the footprint and pixel tests remain (every outcome from kEdgeSurface on, and kKept). The count
// of such observations per texel is what the rig offers; kept samples are what survives.
inline bool Observed(Outcome o) { return o == Outcome::kKept || o >= Outcome::kEdgeSurface; }

// The rejection reasons of resample_report.json: the six plus `invalid`.
enum class Reason { kOccluded, kShadowed, kGrazing, kClipped, kDark, kEdge, kInvalid };
constexpr int kReasonCount = 7;
const char* ReasonName(Reason reason);
// kGrazingView/kGrazingLight -> kGrazing; kEdgeOutside/kEdgeSurface/kEdgeShadow -> kEdge; ...
// Must not be called with kKept.
Reason ReasonOf(Outcome outcome);

// SamplePoint::kPixel with point pixels: a texel none of whose four pixels hit it is rejected
// (kEdgeTexel) only when it spans at least this many pixels in the view (its side on the surface
// times sqrt(cos θo) over the pixel footprint, the square root of its projected area in pixels).
// Why: such a texel is resolved, so its missing pixel means this view saw its neighbours, whose
// values belong to them. A smaller texel is finer than the view resolves; whichever pixel measured
// it measured its neighbourhood, as an area-filtered pixel would, and without those samples
// atlases finer than the photographs starve: on the million preset (1,008,600 texels, 1024 px;
// median 0.88 px per texel) rejecting every such pair cost 32 % of the samples and 0.16 dB of
// holdout PSNR against this threshold, while the demo (median 1.15 px) scores the same at 0 and
// 0.5 (52.13 / 52.12 dB) and loses 2.3 dB at 1.0.
constexpr float kMinResolvedTexelPixels = 0.5f;

// Rejects a sample whose every channel is at or below kDarkSigmas read-noise standard deviations:
// 3 sigma leaves a 0.1 % chance that pure read noise passes as signal. (With read_sigma = 0, a
// noise-free capture, only pixels <= 0 are dark.)
constexpr double kDarkSigmas = 3;
// A channel below -kInvalidSigmas * read_sigma cannot be noise around a non-negative radiance
// (probability < 3e-7): the pixel is corrupt. Within that band a negative channel is kept as
// measured (clamping it would bias dark texels upwards).
constexpr double kInvalidSigmas = 5;
// The smallest relative standard deviation a pixel is credited with, whatever the noise model
// says: half-float storage alone rounds to 2^-11 (4.9e-4) relative, and no photograph's
// radiometric calibration is better than 0.1 %. It keeps weights finite for noise-free captures.
constexpr double kRelativeSigmaFloor = 1e-3;
// Edge test depth tolerance, in pixel footprints (the size of one pixel at the texel's depth),
// applied as kEdgeDepthSlack * footprint * (1 + sqrt(2) tan θo): a plane seen at θo changes depth
// by up to sqrt(2) * footprint * tan θo between the texel's projection and a tap centre (taps lie
// within sqrt(2) pixels); the 1 absorbs curvature and tessellation inside the footprint; the
// factor 2 keeps smooth, slanted surfaces from being rejected. A silhouette or an occluding
// contour puts a tap on the background or on another surface, usually far beyond that.
constexpr double kEdgeDepthSlack = 2;

// Sensor noise of a capture's pixels (one channel, after nothing but the camera):
// var(p) = photon_sigma_at_1² · max(p, 0) + read_sigma² + (kRelativeSigmaFloor · max_c p)².
struct NoiseModel {
  double photon_sigma_at_1 = 0;  // photon (shot) noise std at pixel value 1
  double read_sigma = 0;         // signal-independent std
  std::string source;            // where these numbers came from (for the report)

  // Variance of one channel value p of a pixel whose largest channel is max_channel.
  double PixelVariance(double p, double max_channel) const {
    const double floor = kRelativeSigmaFloor * max_channel;
    return photon_sigma_at_1 * photon_sigma_at_1 * (p > 0 ? p : 0) + read_sigma * read_sigma +
           floor * floor;
  }
  double DarkFloor() const { return kDarkSigmas * read_sigma; }
  double InvalidFloor() const { return -kInvalidSigmas * read_sigma; }
};

// ---- Noise from a variance image (images[].variance) --------------------------------------------
// C++ twins of masks.comp's functions of the same names; float, in the GPU's order of operations.

// Variance of the bilinear interpolation Σ_k w_k p_k of `tap_count` taps of independent pixels
// whose variances are in `variance` (3 channels): Σ_k w_k² var_k per channel. Taps of weight 0
// are skipped (they may lie outside the image).
inline Vec3f MeasuredVariance(const Image& variance, const int* x, const int* y, const float* w,
                              int tap_count) {
  Vec3f var = Vec3f::Zero();
  for (int k = 0; k < tap_count; ++k) {
    if (w[k] == 0) continue;
    const float* v = variance.pixel(x[k], y[k]);
    const float w2 = w[k] * w[k];
    var += w2 * Vec3f(v[0], v[1], v[2]);
  }
  return var;
}
// Invalid: some channel below -kInvalidSigmas of its own standard deviation (the noise model's
// InvalidFloor with the measured σ in place of read_sigma).
inline bool MeasuredInvalid(const Vec3f& value, const Vec3f& var) {
  for (int c = 0; c < 3; ++c) {
    if (value[c] < -float(kInvalidSigmas) * std::sqrt(var[c])) return true;
  }
  return false;
}
// Dark: every channel at or below kDarkSigmas of its own standard deviation — no channel is
// measured above the noise (signal-to-noise ratio <= 3; with zero variance only values <= 0).
inline bool MeasuredDark(const Vec3f& value, const Vec3f& var) {
  for (int c = 0; c < 3; ++c) {
    if (!(value[c] <= float(kDarkSigmas) * std::sqrt(var[c]))) return false;
  }
  return true;
}
// Variance credited to one channel of a kept sample (pixel units²): the measured variance plus
// the relative floor NoiseModel::PixelVariance applies (kRelativeSigmaFloor · max channel)².
inline double MeasuredPixelVariance(float var, float max_channel) {
  const double floor = kRelativeSigmaFloor * max_channel;
  return double(var) + floor * floor;
}

// What one photograph gave.
struct ImageOutput {
  std::vector<uint8_t> outcome;   // per texel: Outcome
  std::vector<TexelSample> kept;  // one per kOutcome::kKept texel, ascending texel order
  // Ray counts: camera rays of the pixel map, its shadow rays (hits facing the light),
  // texel->camera occlusion rays, texel->light occlusion rays.
  uint64_t primary_rays = 0, tap_shadow_rays = 0, visibility_rays = 0, shadow_rays = 0;
};

// The checks every resampling path makes of photograph `image_index` before it reads `pixels`:
// an index within the capture's images, and an RGB image of its camera's size. InvalidArgument
// naming the capture file and the image's field otherwise. With `variance` (not null), also
// CheckVarianceImage (engine/capture/capture.h): RGB, the camera's size, finite and >= 0.
Status CheckPhotograph(const Capture& capture, uint32_t image_index, const Image& pixels,
                       const Image* variance = nullptr);

class ImageResampler {
 public:
  // `scene` is the mesh's RayScene for mesh captures and nullptr for normal-map captures; the
  // capture, atlas and scene must outlive the resampler. min_cos in [0, 1). threads: 0 = all.
  // FailedPrecondition (naming capture.json and the field) for what the resampler cannot use: an
  // orthographic camera without pixel_size_m for a mesh, a point light or a turntable angle in a
  // normal-map capture.
  static StatusOr<std::unique_ptr<ImageResampler>> Create(const Capture& capture,
                                                          const TexelAtlas& atlas,
                                                          const RayScene* scene,
                                                          const NoiseModel& noise, double min_cos,
                                                          int threads = 0);

  // Resamples capture.images[image_index] whose pixels are `pixels` (3 channels, the camera's
  // size; else InvalidArgument naming images[i].file). Samples carry image = image_index.
  // `variance`: the photograph's variance image (ReadVarianceImage), whose values replace the
  // noise model for this photograph; nullptr = the noise model. Checked as CheckPhotograph says.
  Status Process(uint32_t image_index, const Image& pixels, ImageOutput* out,
                 const Image* variance = nullptr) const;

  // True when a normal-map capture: no ray is cast.
  bool normal_map() const { return scene_ == nullptr; }

  // Mesh captures: where each texel's sample is measured (SamplePoint; default kPixel).
  // Normal-map captures ignore it: a texel is its own pixel there.
  void SetSamplePoint(SamplePoint point) { sample_point_ = point; }
  SamplePoint sample_point() const { return sample_point_; }
  // What every camera's pixel measures, replacing the capture's cameras[].pixel_filter
  // (SamplePoint::kPixel's choice when no tap's hit lies in the texel); nullopt (the default):
  // each camera's own.
  void SetPixelFilter(std::optional<PixelFilter> filter) { pixel_filter_ = filter; }

  // Normal-map captures: reject texels in cast shadow on `field` (IntegrateNormalMap of the
  // capture's normal map; it must outlive the resampler and have the atlas's size, else
  // InvalidArgument). nullptr (the default) = no shadow test. FailedPrecondition for a mesh
  // capture, whose shadows come from its rays.
  Status SetHeightField(const HeightField* field);
  const HeightField* height_field() const { return height_field_; }

 private:
  ImageResampler() = default;
  struct Frame;
  void ProcessMeshBlock(const Frame& frame, const Image& pixels, const Image* variance,
                        uint32_t image_index, int64_t begin, int64_t end, ImageOutput* out,
                        std::vector<TexelSample>* kept, uint64_t* rays) const;
  // Casts the camera ray (and, for a hit facing the light, the shadow ray) of every listed pixel
  // (y * width + x) and publishes the results in the frame's pixel map.
  void CastPixels(const Frame& frame, const std::vector<uint32_t>& pixels, uint64_t* rays) const;
  void ProcessNormalMapBlock(const Frame& frame, const Image& pixels, const Image* variance,
                             uint32_t image_index, int64_t begin, int64_t end, ImageOutput* out,
                             std::vector<TexelSample>* kept) const;

  const Capture* capture_ = nullptr;
  const TexelAtlas* atlas_ = nullptr;
  const RayScene* scene_ = nullptr;
  const HeightField* height_field_ = nullptr;  // normal-map captures: cast shadows (or none)
  NoiseModel noise_;
  SamplePoint sample_point_ = SamplePoint::kPixel;
  std::optional<PixelFilter> pixel_filter_;
  float min_cos_ = 0;
  int threads_ = 0;
  std::vector<Vec3f> triangle_normals_;  // unit geometric normal per mesh triangle
  std::vector<float> texel_sides_m_;     // TexelSidesM: per texel, its side on the surface
};

}  // namespace reflcap::resample
