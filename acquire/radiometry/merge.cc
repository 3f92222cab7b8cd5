// HDR merge of one bracket (see merge.h).
#include "acquire/radiometry/merge.h"

#include <array>
#include <cmath>

namespace reflcap::radiometry {

MergedBracket MergeBracket(const BracketImages& images, const std::vector<double>& exposure_s,
                           const InverseResponse& response, bool keep_weights) {
  const int w = images.width, h = images.height;
  const int exposures = int(images.codes.size());
  MergedBracket out;
  out.value = Image(w, h, 3);
  out.variance = Image(w, h, 3);
  out.flags.assign(size_t(w) * size_t(h) * 3, uint8_t(MergeFlag::kMeasured));
  if (keep_weights) out.weight_share = Image(w, h, exposures);
  // Per channel and code: x and 1 / var(x), 0 for censored codes.
  std::array<std::array<double, kCodeCount>, 3> x{}, inv_var{};
  for (int c = 0; c < 3; ++c) {
    for (int z = 0; z < kCodeCount; ++z) {
      x[c][size_t(z)] = response.X(c, z);
      inv_var[c][size_t(z)] = (z > 0 && z < kClipCode) ? 1.0 / response.CodeVariance(c, z) : 0.0;
    }
  }
  const double t_max = exposure_s.back();
  const size_t pixels = size_t(w) * size_t(h);
  for (size_t p = 0; p < pixels; ++p) {
    for (int c = 0; c < 3; ++c) {
      double sum_w = 0, sum_wv = 0;
      bool any_clipped = false;
      for (int e = 0; e < exposures; ++e) {
        const int z = images.codes[size_t(e)][p * 3 + size_t(c)];
        const double t = exposure_s[size_t(e)];
        // Estimate x/t with variance var/t²: weight t²/var.
        const double wt = inv_var[c][size_t(z)] * t * t;
        sum_w += wt;
        sum_wv += wt * x[c][size_t(z)] / t;
        any_clipped = any_clipped || z == kClipCode;
      }
      const size_t i = p * 3 + size_t(c);
      if (sum_w > 0) {
        out.value.data[i] = float(sum_wv / sum_w);
        out.variance.data[i] = float(1.0 / sum_w);
        ++out.measured;
        if (keep_weights && c == 1) {
          for (int e = 0; e < exposures; ++e) {
            const int z = images.codes[size_t(e)][p * 3 + 1];
            const double t = exposure_s[size_t(e)];
            out.weight_share.data[p * size_t(exposures) + size_t(e)] =
                float(inv_var[1][size_t(z)] * t * t / sum_w);
          }
        }
      } else if (any_clipped) {
        // Lower bound: at least the clip level in the shortest exposure.
        out.value.data[i] = float(x[c][kClipCode] / exposure_s.front());
        out.variance.data[i] = 0;
        out.flags[i] = uint8_t(MergeFlag::kClipped);
        ++out.clipped;
      } else {
        // Every code 0: the value lies in [0, edge / t_max]; 0 with that interval's second moment.
        const double edge = response.BlackEdge(c) / t_max;
        out.value.data[i] = 0;
        out.variance.data[i] = float(edge * edge / 3);
        out.flags[i] = uint8_t(MergeFlag::kDark);
        ++out.dark;
      }
    }
  }
  return out;
}

}  // namespace reflcap::radiometry
