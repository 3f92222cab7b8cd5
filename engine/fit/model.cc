#include "engine/fit/model.h"

#include <algorithm>
#include <cmath>

namespace reflcap::fit {
namespace {

// s^(1/n) for the map to natural units; 0 for s <= 0 (an absent lobe).
double Root(double s, double n) { return s > 0 ? std::pow(s, 1.0 / n) : 0.0; }

// A finite float for the output maps (non-finite -> 0; beyond float -> clamped).
float ToFiniteFloat(double v) {
  if (!std::isfinite(v)) return 0.0f;
  constexpr double kMax = 3.0e38;  // just below FLT_MAX
  return float(std::clamp(v, -kMax, kMax));
}

}  // namespace

const char* LobeModelName(LobeModel model) {
  switch (model) {
    case LobeModel::kAniso: return "aniso";
    case LobeModel::kIso: return "iso";
    case LobeModel::kShared: return "shared";
  }
  return "?";
}

StatusOr<LobeModel> ParseLobeModel(const std::string& name) {
  if (name == "aniso") return LobeModel::kAniso;
  if (name == "iso") return LobeModel::kIso;
  if (name == "shared") return LobeModel::kShared;
  return InvalidArgumentError("unknown lobe model \"", name, "\" (aniso, iso, shared)");
}

std::vector<std::string> ProblemLayout::ParamNames() const {
  std::vector<std::string> names;
  if (model == LobeModel::kShared) {
    for (const char* c : {"R", "G", "B"}) names.push_back(StrCat("rho.", c));
  } else {
    names.push_back("rho");
  }
  for (int k = 0; k < lobes; ++k) {
    const std::string p = StrCat("lobe", k, ".");
    switch (model) {
      case LobeModel::kAniso:
        for (const char* f : {"Cx", "Cy", "Cz", "n"}) names.push_back(p + f);
        break;
      case LobeModel::kIso:
        for (const char* f : {"Cxy", "Cz", "n"}) names.push_back(p + f);
        break;
      case LobeModel::kShared:
        for (const char* f : {"Cx", "Cy", "n", "s.R", "s.G", "s.B"}) names.push_back(p + f);
        break;
    }
  }
  return names;
}

Status ProblemLayout::Validate() const {
  const int max_lobes = model == LobeModel::kShared ? kMaxSharedLobes : brdf::kMaxLobes;
  if (lobes < 0 || lobes > max_lobes) {
    return InvalidArgumentError("--lobes: must be in [0, ", max_lobes, "] for the ",
                                LobeModelName(model), " lobe model, got ", lobes);
  }
  return OkStatus();
}

uint32_t ProblemLayout::LobeCMask() const {
  uint32_t mask = 0;
  for (int k = 0; k < lobes; ++k) {
    const int o = LobeOffset(model, k);
    switch (model) {
      case LobeModel::kAniso: mask |= 7u << o; break;                  // Cx Cy Cz
      case LobeModel::kIso: mask |= 3u << o; break;                    // Cxy Cz
      case LobeModel::kShared: mask |= (3u << o) | (7u << (o + 3)); break;  // Cx Cy, s_c
    }
  }
  return mask;
}

void ParameterBounds(const ProblemLayout& layout, double* lower, double* upper) {
  const LobeModel m = layout.model;
  for (int c = 0; c < LambertParams(m); ++c) {
    lower[c] = 0;
    upper[c] = kMaxRho;
  }
  for (int k = 0; k < layout.lobes; ++k) {
    const int o = LobeOffset(m, k);
    for (int j = 0; j < ParamsPerLobe(m); ++j) {
      lower[o + j] = -kMaxC;
      upper[o + j] = kMaxC;
    }
    const int e = ExponentIndex(m, k);
    lower[e] = brdf::kMinExponent;
    upper[e] = brdf::kMaxExponent;
    if (m == LobeModel::kShared) {
      for (int c = 0; c < 3; ++c) {
        lower[o + 3 + c] = 0;
        upper[o + 3 + c] = kMaxScale;
      }
    }
  }
}

int OutputSlots(const ProblemLayout& layout, const double* x, double scale, double* out) {
  int n = 0;
  const LobeModel m = layout.model;
  if (m == LobeModel::kShared) {
    for (int c = 0; c < 3; ++c) out[n++] = x[c] * scale;
    for (int k = 0; k < layout.lobes; ++k) {
      const double* l = x + LobeOffset(m, k);
      for (int c = 0; c < 3; ++c) {
        const double root = Root(l[3 + c] * scale, l[2]);
        out[n++] = l[0] * root;
        out[n++] = l[1] * root;
        out[n++] = root;
        out[n++] = l[2];
      }
    }
    return n;
  }
  out[n++] = x[0] * scale;
  for (int k = 0; k < layout.lobes; ++k) {
    const double* l = x + LobeOffset(m, k);
    const double nexp = l[ParamsPerLobe(m) - 1];
    const double root = Root(scale, nexp);
    if (m == LobeModel::kAniso) {
      out[n++] = l[0] * root;
      out[n++] = l[1] * root;
      out[n++] = l[2] * root;
    } else {
      out[n++] = l[0] * root;
      out[n++] = l[0] * root;
      out[n++] = l[1] * root;
    }
    out[n++] = nexp;
  }
  return n;
}

float* OutputSlotRef(const ProblemLayout& layout, int problem, int slot, brdf::BrdfParams* p) {
  auto lobe_field = [](brdf::LobeParams& lobe, int f) -> float* {
    switch (f) {
      case 0: return &lobe.cx;
      case 1: return &lobe.cy;
      case 2: return &lobe.cz;
      default: return &lobe.n;
    }
  };
  if (layout.model == LobeModel::kShared) {
    if (slot < 3) return &p->rho_d[slot];
    const int s = slot - 3;
    const int k = s / 12, c = (s % 12) / 4, f = s % 4;
    return lobe_field(p->lobes[k][c], f);
  }
  if (slot == 0) return &p->rho_d[problem];
  const int s = slot - 1;
  return lobe_field(p->lobes[s / 4][problem], s % 4);
}

int ToBrdfParams(const ProblemLayout& layout, const double* x, double scale, int problem,
                 brdf::BrdfParams* out, double* slots) {
  double own[3 + 12 * brdf::kMaxLobes];
  if (slots == nullptr) slots = own;
  const int n = OutputSlots(layout, x, scale, slots);
  for (int i = 0; i < n; ++i) *OutputSlotRef(layout, problem, i, out) = ToFiniteFloat(slots[i]);
  return n;
}

void FromBrdfParams(const ProblemLayout& layout, const brdf::BrdfParams& params, double scale,
                    int problem, double* x) {
  const LobeModel m = layout.model;
  if (m == LobeModel::kShared) {
    for (int c = 0; c < 3; ++c) x[c] = params.rho_d[c] / scale;
    for (int k = 0; k < layout.lobes; ++k) {
      double* l = x + LobeOffset(m, k);
      const brdf::LobeParams& ref = params.lobes[k][0];
      const double cz = ref.cz != 0 ? ref.cz : 1.0;
      l[0] = ref.cx / cz;
      l[1] = ref.cy / cz;
      l[2] = ref.n;
      for (int c = 0; c < 3; ++c) {
        const brdf::LobeParams& lobe = params.lobes[k][c];
        l[3 + c] = lobe.cz > 0 ? std::pow(double(lobe.cz), double(lobe.n)) / scale : 0.0;
      }
    }
    return;
  }
  x[0] = params.rho_d[problem] / scale;
  for (int k = 0; k < layout.lobes; ++k) {
    double* l = x + LobeOffset(m, k);
    const brdf::LobeParams& lobe = params.lobes[k][problem];
    const double inv_root = std::pow(scale, -1.0 / lobe.n);  // C' = C S^(-1/n)
    if (m == LobeModel::kAniso) {
      l[0] = lobe.cx * inv_root;
      l[1] = lobe.cy * inv_root;
      l[2] = lobe.cz * inv_root;
      l[3] = lobe.n;
    } else {
      l[0] = 0.5 * (lobe.cx + lobe.cy) * inv_root;
      l[1] = lobe.cz * inv_root;
      l[2] = lobe.n;
    }
  }
}

}  // namespace reflcap::fit
