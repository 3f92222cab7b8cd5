#pragma once
// How closely two renders of the same image agree — the Vulkan renderer's acceptance criterion
// (issue 6): PSNR between a render and the CPU reference's, excluding pixels within 2 px of
// cast-shadow edges and silhouettes, where shadow-map texels and rasteriser coverage decide pixels
// that the reference's exact rays decide differently; the excluded fraction is part of the result.
// Used by tests/render/vulkan and bench/render.
//
// Definitions. Object pixels: reference mask OR other mask. Edge pixels: both pixels of every pair
// of 4-neighbours that differ in the reference mask (silhouettes), or that are both object pixels
// and differ in the reference's aux cast_shadow (shadow edges). Excluded: object pixels within
// `exclusion_px` (Euclidean) of an edge pixel (validate::DilateMask). Compared: the other object
// pixels. PSNR = 10 log10(P² / MSE) over the compared pixels' three channels, P = the largest
// reference value there; capped at validate::kMaxPsnrDb.
#include <cstddef>
#include <string>

#include "engine/image/image.h"
#include "render/reference/reference_renderer.h"

namespace reflcap::render {

// The exclusion band, px.
constexpr double kEdgeExclusionPx = 2;
// The bar for Vulkan vs CPU, dB.
constexpr double kMinAgreementPsnrDb = 50;

struct RenderAgreement {
  double psnr_db = 0;  // over compared pixels (pooled over images after Add)
  size_t object_pixels = 0;
  size_t excluded_pixels = 0;  // object pixels within the band of an edge
  size_t compared_pixels = 0;
  size_t mask_mismatches = 0;    // compared pixels where the two masks differ
  size_t shadow_mismatches = 0;  // compared pixels where aux cast_shadow differs
  double max_abs_error = 0;      // over compared pixels and channels
  double max_aux_cos_error = 0;  // |Δ cos θi|, |Δ cos θo| on compared pixels in both masks
  double sse_over_peak2 = 0;     // Σ (other - reference)² / P² (pools images like validate)
  size_t values = 0;             // compared values (3 per pixel)
  Image excluded;                // 1 = excluded (single-image results only)

  double ExcludedFraction() const {
    return object_pixels ? double(excluded_pixels) / double(object_pixels) : 0;
  }
  // Pools another image's result (PSNR from the pooled Σ e²/P²).
  void Add(const RenderAgreement& other);
  std::string ToString() const;
};

// Compares `other` with `reference` (same size; both rendered with aux buffers).
RenderAgreement CompareRenders(const RenderResult& reference, const RenderResult& other,
                               double exclusion_px = kEdgeExclusionPx);

}  // namespace reflcap::render
