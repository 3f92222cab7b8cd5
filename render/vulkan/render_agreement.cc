// The Vulkan renderer's acceptance criterion (see render_agreement.h). `cpu` is the reference.
#include "render/vulkan/render_agreement.h"

#include <algorithm>
#include <cmath>

#include "engine/core/check.h"
#include "engine/core/status.h"
#include "render/validate/metrics.h"

namespace reflcap::render {

std::string RenderAgreement::ToString() const {
  return StrCat("PSNR ", psnr_db, " dB over ", compared_pixels, " px; excluded ", excluded_pixels,
                " of ", object_pixels, " object px (", 100 * ExcludedFraction(),
                " %); mask mismatches ", mask_mismatches, ", cast_shadow mismatches ",
                shadow_mismatches, ", max |error| ", max_abs_error, ", max aux cos error ",
                max_aux_cos_error);
}

void RenderAgreement::Add(const RenderAgreement& o) {
  object_pixels += o.object_pixels;
  excluded_pixels += o.excluded_pixels;
  compared_pixels += o.compared_pixels;
  mask_mismatches += o.mask_mismatches;
  shadow_mismatches += o.shadow_mismatches;
  max_abs_error = std::max(max_abs_error, o.max_abs_error);
  max_aux_cos_error = std::max(max_aux_cos_error, o.max_aux_cos_error);
  sse_over_peak2 += o.sse_over_peak2;
  values += o.values;
  psnr_db = values == 0 ? 0
            : sse_over_peak2 == 0
                ? validate::kMaxPsnrDb
                : std::min(validate::kMaxPsnrDb, -10 * std::log10(sse_over_peak2 / double(values)));
}

RenderAgreement CompareRenders(const RenderResult& cpu, const RenderResult& gpu,
                               double exclusion_px) {
  REFLCAP_CHECK(cpu.pixels.width == gpu.pixels.width && cpu.pixels.height == gpu.pixels.height);
  REFLCAP_CHECK(!cpu.aux.empty() && !gpu.aux.empty()) << "CompareRenders needs aux buffers";
  const int w = cpu.pixels.width, h = cpu.pixels.height;
  // Edge pixels: 4-neighbours that differ in the CPU mask (silhouettes) or, both on the object,
  // in the CPU's cast_shadow flag (shadow edges). Both pixels of such a pair are edge pixels.
  Image edges(w, h, 1, 0.0f);
  auto object = [&](int x, int y) { return cpu.mask.at(x, y) > 0.5f; };
  auto shadowed = [&](int x, int y) { return cpu.aux.at(x, y, kAuxCastShadow) > 0.5f; };
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const int nx[2] = {x + 1, x}, ny[2] = {y, y + 1};
      for (int k = 0; k < 2; ++k) {
        if (nx[k] >= w || ny[k] >= h) continue;
        const bool silhouette = object(x, y) != object(nx[k], ny[k]);
        const bool shadow_edge =
            object(x, y) && object(nx[k], ny[k]) && shadowed(x, y) != shadowed(nx[k], ny[k]);
        if (silhouette || shadow_edge) edges.at(x, y) = edges.at(nx[k], ny[k]) = 1;
      }
    }
  }
  RenderAgreement a;
  a.excluded = validate::DilateMask(edges, exclusion_px);
  const Image& excluded = a.excluded;
  double peak = 0;
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const bool obj = cpu.mask.at(x, y) > 0.5f || gpu.mask.at(x, y) > 0.5f;
      if (!obj) continue;
      ++a.object_pixels;
      if (excluded.at(x, y) > 0.5f) {
        ++a.excluded_pixels;
        continue;
      }
      ++a.compared_pixels;
      for (int c = 0; c < 3; ++c) peak = std::max(peak, double(cpu.pixels.at(x, y, c)));
    }
  }
  double sse = 0;
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const bool obj = cpu.mask.at(x, y) > 0.5f || gpu.mask.at(x, y) > 0.5f;
      if (!obj || excluded.at(x, y) > 0.5f) continue;
      if ((cpu.mask.at(x, y) > 0.5f) != (gpu.mask.at(x, y) > 0.5f)) ++a.mask_mismatches;
      if ((cpu.aux.at(x, y, kAuxCastShadow) > 0.5f) != (gpu.aux.at(x, y, kAuxCastShadow) > 0.5f)) {
        ++a.shadow_mismatches;
      }
      for (int c = 0; c < 3; ++c) {
        const double e = double(gpu.pixels.at(x, y, c)) - double(cpu.pixels.at(x, y, c));
        sse += e * e;
        a.max_abs_error = std::max(a.max_abs_error, std::abs(e));
      }
      if (cpu.mask.at(x, y) > 0.5f && gpu.mask.at(x, y) > 0.5f) {
        for (int ch : {int(kAuxCosThetaI), int(kAuxCosThetaO)}) {
          a.max_aux_cos_error = std::max(
              a.max_aux_cos_error, double(std::abs(gpu.aux.at(x, y, ch) - cpu.aux.at(x, y, ch))));
        }
      }
      a.values += 3;
    }
  }
  a.sse_over_peak2 = peak > 0 ? sse / (peak * peak) : (sse > 0 ? 1e300 : 0);
  a.psnr_db =
      a.values == 0 ? 0
      : a.sse_over_peak2 == 0
          ? validate::kMaxPsnrDb
          : std::min(validate::kMaxPsnrDb, -10 * std::log10(a.sse_over_peak2 / double(a.values)));
  return a;
}

}  // namespace reflcap::render
