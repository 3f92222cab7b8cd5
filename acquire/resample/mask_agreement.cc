// Agreement of the Vulkan masks with the Embree rays (see mask_agreement.h).
#include "acquire/resample/mask_agreement.h"

#include <algorithm>
#include <cmath>

#include "acquire/resample/image_resampler.h"

namespace reflcap::resample {
static_assert(kOutcomeCount * kOutcomeCount == 144, "MaskAgreement::confusion is 12 x 12");
namespace {

double RelDiff(double a, double b) {
  const double m = std::max(std::abs(a), std::abs(b));
  return m > 0 ? std::abs(a - b) / m : 0.0;
}

bool FootprintEdge(Outcome o) {
  return o == Outcome::kEdgeSurface || o == Outcome::kEdgeShadow || o == Outcome::kEdgeTexel;
}
// Decided before the visibility mask by the same float/double geometry on both paths.
bool BeforeVisibility(Outcome o) { return o == Outcome::kGrazingView || o == Outcome::kEdgeOutside; }

}  // namespace

bool CameraMapView::Locate(const Vec3f& p_in_object, Vec2d* texel) const {
  const Vec3d q = cam_from_object * p_in_object.cast<double>();
  if (!pinhole) {
    *texel = {q.x() / pixel_size_m + 0.5 * (width - 1), q.y() / pixel_size_m + 0.5 * (height - 1)};
    return true;
  }
  if (!(q.z() > 0)) return false;
  const double x = q.x() / q.z(), y = q.y() / q.z();
  *texel = {fx * x + skew * y + cx, fy * y + cy};
  return true;
}

bool CameraMapView::NearEdge(const Vec2d& texel, int radius) const {
  if (!(std::abs(texel.x()) < 1e8 && std::abs(texel.y()) < 1e8)) return true;
  const int cx0 = int(std::lround(texel.x())), cy0 = int(std::lround(texel.y()));
  for (int y = cy0 - radius; y <= cy0 + radius; ++y) {
    for (int x = cx0 - radius; x <= cx0 + radius; ++x) {
      if (x < 0 || y < 0 || x >= width || y >= height) return true;  // the map's border
      const size_t i = size_t(y) * width + x;
      // Compare with the right and lower neighbours inside the window.
      for (int d = 0; d < 2; ++d) {
        const int nx = x + (d == 0), ny = y + (d == 1);
        if (nx > cx0 + radius || ny > cy0 + radius || nx >= width || ny >= height) continue;
        const size_t j = size_t(ny) * width + nx;
        if (hit[i] != hit[j]) return true;
        if (!hit[i]) continue;
        if (lit[i] != lit[j]) return true;
        const double depth = std::max(distance[i], distance[j]);
        const double footprint = pinhole ? depth * footprint_scale : footprint_scale;
        if (std::abs(double(distance[i]) - double(distance[j])) > kDepthJumpFootprints * footprint) {
          return true;
        }
      }
    }
  }
  return false;
}

void MaskAgreement::Add(const std::vector<Vec3f>& positions, const std::vector<uint8_t>& embree,
                        const std::vector<uint8_t>& vulkan,
                        const std::vector<TexelSample>& embree_kept,
                        const std::vector<TexelSample>& vulkan_kept, const CameraMapView& map) {
  const size_t n = std::min(embree.size(), vulkan.size());
  pairs += n;
  for (size_t t = 0; t < n; ++t) {
    const Outcome a = Outcome(embree[t]), b = Outcome(vulkan[t]);
    if (embree[t] < kOutcomeCount && vulkan[t] < kOutcomeCount) {
      ++confusion[size_t(embree[t]) * kOutcomeCount + vulkan[t]];
    }
    if (a == b) {
      ++agreeing;
      continue;
    }
    if (BeforeVisibility(a) || BeforeVisibility(b)) {
      ++other;
    } else if (Seen(a) != Seen(b)) {
      ++(Seen(b) ? visible_only_vulkan : visible_only_embree);
    } else if (a == Outcome::kGrazingLight || b == Outcome::kGrazingLight) {
      ++other;  // both see it; the light-grazing test (same geometry) decided differently
    } else if ((a == Outcome::kShadowed) != (b == Outcome::kShadowed)) {
      ++(b == Outcome::kShadowed ? lit_only_embree : lit_only_vulkan);
    } else if (FootprintEdge(a) != FootprintEdge(b)) {
      ++(FootprintEdge(b) ? footprint_only_embree : footprint_only_vulkan);
    } else {
      ++other;
    }
    Vec2d texel;
    if (!map.Locate(positions[t], &texel) || map.NearEdge(texel, kNearEdgePixels)) ++near_edge;
  }
  // Values of the samples both keep (both lists ascend by texel).
  size_t i = 0, j = 0;
  while (i < embree_kept.size() && j < vulkan_kept.size()) {
    if (embree_kept[i].texel < vulkan_kept[j].texel) {
      ++i;
    } else if (vulkan_kept[j].texel < embree_kept[i].texel) {
      ++j;
    } else {
      const BrdfSample& a = embree_kept[i].sample;
      const BrdfSample& b = vulkan_kept[j].sample;
      ++kept_both;
      double wo_diff = 0;
      for (int c = 0; c < 3; ++c) wo_diff = std::max(wo_diff, double(std::abs(a.wo[c] - b.wo[c])));
      const double pixel_angle = map.pinhole ? 1.0 / std::max(map.fx, map.fy) : 0.0;
      if (map.pinhole && wo_diff > kSamePixelFraction * pixel_angle) {
        ++other_pixel;
        ++i;
        ++j;
        continue;
      }
      for (int c = 0; c < 3; ++c) {
        max_value_rel_diff = std::max(max_value_rel_diff, RelDiff(a.value[c], b.value[c]));
        max_weight_rel_diff = std::max(max_weight_rel_diff, RelDiff(a.weight[c], b.weight[c]));
        max_direction_diff = std::max({max_direction_diff, double(std::abs(a.wi[c] - b.wi[c])),
                                       double(std::abs(a.wo[c] - b.wo[c]))});
      }
      ++i;
      ++j;
    }
  }
}

}  // namespace reflcap::resample
