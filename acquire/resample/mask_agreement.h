#pragma once
// Agreement of the Vulkan masks (vulkan_masks.h) with the Embree rays of the CPU path
// (image_resampler.h), per (texel, image) pair: what `reflcap resample --backend vulkan
// --cross-check` writes as `mask_agreement` into resample_report.json, and what the tests hold to
// the acceptance tolerance.
//
// A pair agrees when both paths give it the same Outcome. A disagreement is classified by the
// first mask on which the two differ, in test order:
//   visible   one path has the texel seen by the camera (Seen) and the other occluded;
//   lit       both see it, one has it in cast shadow (kShadowed) and the other not;
//   footprint both see it lit, one rejects it at a footprint edge (kEdgeSurface / kEdgeShadow /
//             kEdgeTexel, a hit on the texel border rounded to either side)
//             and the other not;
//   other     anything else: the view-grazing, projection or light-grazing test decided
//             differently by float rounding (the CPU projects in double), kEdgeSurface against
//             kEdgeShadow, or pixel tests after differently rounded taps.
// Each disagreement is also checked against the camera map of its image: it is "near an edge"
// when a depth discontinuity (a hit next to background, or neighbouring distances differing by
// more than kDepthJumpFootprints pixel footprints) or a shadow edge (lit next to unlit) lies
// within kNearEdgePixels camera-map texels of the texel's projection.
#include <array>
#include <cstdint>
#include <vector>

#include "acquire/resample/chunk_writer.h"
#include "engine/geometry/rigid3.h"
#include "engine/math/types.h"

namespace reflcap::resample {

// "Near an edge": within this many camera-map texels (≈ photograph pixels) of the texel's
// projection — the reach of the bilinear taps (1 px) plus the half-texel rounding of each map.
constexpr int kNearEdgePixels = 2;
// A depth discontinuity: neighbouring map texels whose distances differ by more than this many
// pixel footprints. The edge test accepts surfaces up to 81.4° from the view (min_cos 0.15),
// whose depth changes by tan 81.4° = 6.6 footprints per pixel; anything steeper is an edge.
constexpr double kDepthJumpFootprints = 8;
// Two samples of one texel and photograph measured through the same pixel have view directions
// within rounding of each other (the rasteriser's sub-pixel snapping: ~0.04 of a pixel's angle
// measured on lavapipe); neighbouring pixels' rays lie one pixel's angle (1 / focal length in
// pixels) apart: a quarter of it tells them apart. Orthographic views share one direction: there
// the test cannot tell, and a different pixel's sample counts in the maxima.
constexpr double kSamePixelFraction = 0.25;

// What the camera map of one photograph holds (copied back from the GPU), and where an
// object-frame point lands in it.
struct CameraMapView {
  int width = 0, height = 0;     // texels
  std::vector<float> distance;   // per texel (row-major): distance along its ray; 0 = background
  std::vector<uint8_t> hit;      // 1 where the texel's ray hits the object
  std::vector<uint8_t> lit;      // 1 where that hit point is lit (normals face the light, no
                                 // occluder in the light map)
  bool pinhole = true;
  Rigid3 cam_from_object;
  double fx = 1, fy = 1, skew = 0, cx = 0, cy = 0;  // pinhole map intrinsics
  double pixel_size_m = 0;                          // orthographic
  double footprint_scale = 0;  // pixel footprint per metre of depth (pinhole) or metres (ortho)

  // Map texel coordinates (centres at integers) of p; false when p is behind a pinhole camera.
  bool Locate(const Vec3f& p_in_object, Vec2d* texel) const;
  // Whether a depth discontinuity or shadow edge lies within `radius` texels of `texel`.
  bool NearEdge(const Vec2d& texel, int radius) const;
};

struct MaskAgreement {
  uint64_t pairs = 0;     // (texel, image) pairs compared
  uint64_t agreeing = 0;  // same Outcome on both paths
  uint64_t visible_only_vulkan = 0, visible_only_embree = 0;
  uint64_t lit_only_vulkan = 0, lit_only_embree = 0;
  uint64_t footprint_only_vulkan = 0, footprint_only_embree = 0;
  uint64_t other = 0;
  uint64_t near_edge = 0;  // disagreements near a depth discontinuity or shadow edge
  // Samples kept by both paths, and the largest relative difference of their values and
  // weights (|a - b| / max(|a|, |b|), over channels; 0 when equal).
  uint64_t kept_both = 0;
  double max_value_rel_diff = 0;
  double max_weight_rel_diff = 0;
  double max_direction_diff = 0;  // largest |wi - wi'| or |wo - wo'| component
  // SamplePoint::kPixel: samples both keep whose view directions differ by more than
  // kSamePixelFraction of a pixel's angle (pinhole maps): the two paths chose different taps,
  // because two taps' hits lay at almost the same distance from the texel centre (rounding
  // decides). Their values are different pixels', so they are counted here and left out of the
  // three maxima above.
  uint64_t other_pixel = 0;
  // confusion[embree * kOutcomeCount + vulkan]: pairs per (Embree outcome, Vulkan outcome).
  std::array<uint64_t, 144> confusion{};

  uint64_t disagreeing() const { return pairs - agreeing; }
  double AgreeingFraction() const { return pairs ? double(agreeing) / double(pairs) : 1.0; }

  // Adds one photograph: `embree` and `vulkan` are the outcome bytes per texel of the two paths,
  // `embree_kept` and `vulkan_kept` their kept samples (ascending texels); `map` the Vulkan
  // camera map of that photograph.
  void Add(const std::vector<Vec3f>& positions, const std::vector<uint8_t>& embree,
           const std::vector<uint8_t>& vulkan, const std::vector<TexelSample>& embree_kept,
           const std::vector<TexelSample>& vulkan_kept, const CameraMapView& map);
};

}  // namespace reflcap::resample
