#pragma once
// The per-texel fitting problems: parameter layouts of the three lobe models, their bounds, and
// the model with its analytic gradient, written once for every variant the fitters need.
//
// A texel's BRDF is Lambert + K Lafortune lobes per RGB channel (engine/brdf/lafortune.h):
//   f_c(wi, wo) = rho_d,c / pi + sum_k max(0, Cx,k,c xx + Cy,k,c yy + Cz,k,c zz)^n_k,c
// with xx = wix wox, yy = wiy woy, zz = wiz woz. The lobe models restrict it:
//
//   kAniso  every channel is its own problem, 1 + 4K unknowns: [rho, (Cx, Cy, Cz, n) per lobe] —
//           exactly the brdf layout (ParamsPerChannel).
//   kIso    every channel is its own problem, 1 + 3K unknowns: [rho, (Cxy, Cz, n) per lobe] with
//           Cx = Cy = Cxy (a lobe symmetric about the normal).
//   kShared one problem couples the three channels, 3 + 6K unknowns:
//           [rho_R, rho_G, rho_B, (Cx, Cy, n, s_R, s_G, s_B) per lobe], and
//             lobe_k,c = s_k,c * max(0, Cx xx + Cy yy + zz)^n
//           i.e. the lobe's shape (C's direction and n) is common to the channels and only its
//           scale s_c >= 0 is per channel (dichromatic). Cz is fixed to 1: (C, s) and
//           (a C, s / a^n) give the same lobe, so one of them must be pinned, and Cz = 1 keeps
//           s_c equal to the lobe's value at normal incidence. In brdf terms channel c has
//           C_c = s_c^(1/n) (Cx, Cy, 1) and n_c = n (exact, as s b^n = (s^(1/n) b)^n for b > 0).
//           K = 1 has 9 unknowns (the "8" counts an isotropic shared lobe); K <= 2 keeps
//           the problem within kMaxParams = 16, so K = 3 is not offered for kShared.
//
// Parameters live in *normalised units* while fitting: every value of a problem is divided by
// the problem's scale S (its brightest valid value, see problem.h), so rho' = rho / S,
// s' = s / S and C' = C S^(-1/n) (because (C' b)^n = C^n b^n / S). The bounds below are in
// those units. Bounds are enforced by projection (clamping each trial point into the box, after
// Gpufit), not by reparameterisation:
//   rho' in [0, kMaxRho]       albedo is non-negative; the cap only keeps it finite
//   C'   in [-kMaxC, kMaxC]    C's kept finite
//   n    in [kMinExponent, kMaxExponent] = [1, 1e4] (brdf), the valid exponent range
//   s'   in [0, kMaxScale]     a lobe adds light
//
// The model is written once as templates over T and a compile-time layout (LobeModel, K), in a
// branch-free "masked" style (Mitsuba's active lanes): every data-dependent choice is a Select,
// so T can be float or double (the scalar fitters), ceres::Jet (autodiff checks and the Ceres
// backend) or a SIMD lane pack (engine/fit/batched_kernel.cc). A lobe is 0 where its base
// b <= kPowBaseMin and saturates at kMaxFitLobeValue (as brdf::LafortuneLobe at kMaxLobeValue); its value is
// exp(n log b), with the exponent argument capped so no Inf ever arises, and its slope
// n b^(n-1) is formed as n * value / b (one exp and one log per lobe).
#include <array>
#include <cmath>
#include <string>
#include <vector>

#include "engine/brdf/lafortune.h"
#include "engine/core/status.h"
#include "engine/math/safe_math.h"
#include "engine/math/types.h"
#include "shaders/shared/fit_status.h"

namespace reflcap::fit {

enum class LobeModel { kAniso = 0, kIso = 1, kShared = 2 };

constexpr int kMaxParams = gpu::shared::kLmMaxParams;  // 16
constexpr int kMaxPacked = gpu::shared::kLmMaxPacked;  // 16 * 17 / 2
static_assert(kMaxPacked == kMaxParams * (kMaxParams + 1) / 2);
constexpr int kMaxSharedLobes = 2;

// Normalised-unit bounds (see the file comment). kMaxRho: 1e3 x the brightest value of the
// texel times pi, far beyond any albedo. kMaxC: |C'| b <= 1e3 already gives a lobe far above the
// normalised data (<= 1) for any n >= 1. kMaxScale: like kMaxRho.
constexpr double kMaxRho = gpu::shared::kFitMaxRho;
constexpr double kMaxC = gpu::shared::kFitMaxC;
constexpr double kMaxScale = gpu::shared::kFitMaxScale;
// Lobe saturation while fitting (normalised units, where the brightest value is 1): a lobe 1e6
// times brighter than every sample is never a fit, and saturating there (value constant,
// gradient 0, like brdf::kMaxLobeValue in natural units) keeps the LM's float quantities in
// range together with kMaxNormalisedWeight: a weighted residual is at most 1e6 x 1e10.
constexpr double kMaxFitLobeValue = gpu::shared::kFitMaxLobeValue;
// exp() argument cap: log(kMaxFitLobeValue) + 1, so exp never overflows and the capped value is
// still above kMaxFitLobeValue, where the lobe saturates anyway.
constexpr double kMaxLobeLogArg = gpu::shared::kFitMaxLobeLogArg;  // log(1e6) = 13.8155
// exp() argument floor: a lobe below e^-80 = 1.8e-35 of the brightest value is 0 for any fit,
// and keeping exp's argument above float's underflow threshold (-87.3) keeps glibc's vector
// expf on its fast path (it falls back to scalar expf, lane by lane, for underflowing lanes).
// The floor makes a live lobe >= 1.8e-35 instead of ~0 far from its peak: no fit can tell.
constexpr double kMinLobeLogArg = gpu::shared::kFitMinLobeLogArg;
// Normalised weights are clamped to this (sqrt: 1e10): a sample that certain carries the texel
// alone already, and the cap keeps squared weighted residuals, summed, below FLT_MAX.
constexpr double kMaxNormalisedWeight = gpu::shared::kFitMaxNormalisedWeight;

const char* LobeModelName(LobeModel model);  // "aniso", "iso", "shared"
StatusOr<LobeModel> ParseLobeModel(const std::string& name);

// Parameter count of one problem, per lobe, and problems per texel.
constexpr int ParamsPerLobe(LobeModel m) { return m == LobeModel::kAniso ? 4 : m == LobeModel::kIso ? 3 : 6; }
constexpr int LambertParams(LobeModel m) { return m == LobeModel::kShared ? 3 : 1; }
constexpr int NumParams(LobeModel m, int lobes) { return LambertParams(m) + ParamsPerLobe(m) * lobes; }
// Residual channels of one problem (1: one channel's samples; 3: all three) and problems/texel.
constexpr int ProblemChannels(LobeModel m) { return m == LobeModel::kShared ? 3 : 1; }
constexpr int ProblemsPerTexel(LobeModel m) { return m == LobeModel::kShared ? 1 : 3; }
// Index of lobe k's first parameter and of its exponent.
constexpr int LobeOffset(LobeModel m, int k) { return LambertParams(m) + ParamsPerLobe(m) * k; }
constexpr int ExponentIndex(LobeModel m, int k) {
  return LobeOffset(m, k) + (m == LobeModel::kAniso ? 3 : 2);
}

// A problem's shape: lobe model and lobe count (0..kMaxLobes, <= kMaxSharedLobes for kShared).
struct ProblemLayout {
  LobeModel model = LobeModel::kAniso;
  int lobes = 1;

  int NumParams() const { return fit::NumParams(model, lobes); }
  int Channels() const { return ProblemChannels(model); }
  // Parameter names, e.g. {"rho", "lobe0.Cx", "lobe0.Cy", "lobe0.Cz", "lobe0.n"} (aniso).
  std::vector<std::string> ParamNames() const;
  // Status of the combination: InvalidArgument when lobes is out of range for the model.
  Status Validate() const;
  // Free-parameter masks (bit p = parameter p): every parameter; the Lambert term only (rho's);
  // the lobes' C's only (the seed's first stage: C's of aniso/iso; Cx, Cy and the scales s of
  // shared, which carry the lobe's magnitude that C carries in the other models).
  uint32_t AllMask() const { return (1u << NumParams()) - 1u; }
  uint32_t LambertMask() const { return (1u << LambertParams(model)) - 1u; }
  uint32_t LobeCMask() const;
};

// Lower and upper normalised-unit bounds of every parameter of `layout`.
void ParameterBounds(const ProblemLayout& layout, double* lower, double* upper);

// The model's templates are always inlined: batched_kernel.cc instantiates them with lane packs
// inside functions built for several ISAs (target attributes), and an out-of-line copy built for
// the baseline ISA would be called with another by-value vector ABI.
#if defined(__GNUC__)
#define REFLCAP_FIT_INLINE inline __attribute__((always_inline))
#else
#define REFLCAP_FIT_INLINE inline
#endif

// ---- Masked-style helpers: overloads for scalars here; SIMD packs bring their own ------------
template <typename M, typename T>
REFLCAP_FIT_INLINE T Select(const M& condition, const T& a, const T& b) {
  return condition ? a : b;
}

template <typename T>
REFLCAP_FIT_INLINE T Max(const T& a, const T& b) {
  return Select(a > b, a, b);
}
template <typename T>
REFLCAP_FIT_INLINE T Min(const T& a, const T& b) {
  return Select(b > a, a, b);
}

// One lobe: value max(0, b)^n (capped), d value / d b, d value / d n. Masked, no branches on data.
template <typename T>
REFLCAP_FIT_INLINE T LobeValueAndSlopes(const T& base, const T& n, T* dvalue_dbase, T* dvalue_dn) {
  using std::exp;
  using std::log;
  // Each comparison feeds its Select directly: a comparison kept in a variable is a mask GCC
  // materialises lane by lane for wide SIMD packs, so the conditions are re-stated instead.
  const T safe_base = Select(base > T(kPowBaseMin), base, T(1));  // log(1) = 0: a stand-in
  const T log_base = log(safe_base);
  const T arg0 = n * log_base;
  T arg = Select(arg0 > T(kMaxLobeLogArg), T(kMaxLobeLogArg), arg0);
  arg = Select(arg < T(kMinLobeLogArg), T(kMinLobeLogArg), arg);
  const T raw = Select(base > T(kPowBaseMin), exp(arg), T(0));
  const T value = Select(T(kMaxFitLobeValue) > raw, raw, T(kMaxFitLobeValue));
  // Slopes, 0 where cut off (value = 0), floored or saturated (the value is a constant there).
  // The 0/1 factors are clamps of a steep ramp, not selects with a 0 arm: GCC turns `c ? 0 : x`
  // on wide lane packs into a bit mask it builds lane by lane. kRamp: a ramp that reaches 1 within
  // 1e-30 of the threshold (far below float resolution of these quantities) and stays finite
  // (|threshold - x| <= 1e6 here, so |ramp| <= 1e36 < FLT_MAX).
  const T kRamp = T(1e30);
  const T floor_live = Min(Max((arg0 - T(kMinLobeLogArg)) * kRamp, T(0)), T(1));
  const T saturation_live = Min(Max((T(kMaxFitLobeValue) - raw) * kRamp, T(0)), T(1));
  const T live = floor_live * saturation_live;
  *dvalue_dbase = live * n * value / safe_base;
  *dvalue_dn = live * value * log_base;
  return value;
}

// f of residual channel `channel` (0..2; only kShared uses it) at parameters x (normalised
// units), and when grad != nullptr its gradient with respect to all NumParams(M, K) parameters.
template <LobeModel M, int K, typename T>
REFLCAP_FIT_INLINE T EvalModel(const T* x, const T& xx, const T& yy, const T& zz, int channel, T* grad) {
  const T kInvPiT = T(kInvPi);
  T f;
  if constexpr (M == LobeModel::kShared) {
    f = x[channel] * kInvPiT;
    if (grad) {
      for (int c = 0; c < 3; ++c) grad[c] = T(c == channel ? kInvPi : 0.0);
    }
  } else {
    f = x[0] * kInvPiT;
    if (grad) grad[0] = kInvPiT;
  }
  for (int k = 0; k < K; ++k) {
    const T* lobe = x + LobeOffset(M, k);
    T* lobe_grad = grad ? grad + LobeOffset(M, k) : nullptr;
    T dvdb, dvdn;
    if constexpr (M == LobeModel::kAniso) {
      const T base = lobe[0] * xx + lobe[1] * yy + lobe[2] * zz;
      f += LobeValueAndSlopes(base, lobe[3], &dvdb, &dvdn);
      if (lobe_grad) {
        lobe_grad[0] = dvdb * xx;
        lobe_grad[1] = dvdb * yy;
        lobe_grad[2] = dvdb * zz;
        lobe_grad[3] = dvdn;
      }
    } else if constexpr (M == LobeModel::kIso) {
      const T xy = xx + yy;
      const T base = lobe[0] * xy + lobe[1] * zz;
      f += LobeValueAndSlopes(base, lobe[2], &dvdb, &dvdn);
      if (lobe_grad) {
        lobe_grad[0] = dvdb * xy;
        lobe_grad[1] = dvdb * zz;
        lobe_grad[2] = dvdn;
      }
    } else {
      const T base = lobe[0] * xx + lobe[1] * yy + zz;
      const T shape = LobeValueAndSlopes(base, lobe[2], &dvdb, &dvdn);
      const T scale = lobe[3 + channel];
      f += scale * shape;
      if (lobe_grad) {
        lobe_grad[0] = scale * dvdb * xx;
        lobe_grad[1] = scale * dvdb * yy;
        lobe_grad[2] = scale * dvdn;
        for (int c = 0; c < 3; ++c) lobe_grad[3 + c] = c == channel ? shape : T(0);
      }
    }
  }
  return f;
}

// Calls fn.template operator()<M, K>() for the layout's compile-time instantiation.
template <typename Fn>
inline auto DispatchLayout(const ProblemLayout& layout, Fn&& fn) {
  switch (layout.model) {
    case LobeModel::kAniso:
      switch (layout.lobes) {
        case 0: return fn.template operator()<LobeModel::kAniso, 0>();
        case 1: return fn.template operator()<LobeModel::kAniso, 1>();
        case 2: return fn.template operator()<LobeModel::kAniso, 2>();
        default: return fn.template operator()<LobeModel::kAniso, 3>();
      }
    case LobeModel::kIso:
      switch (layout.lobes) {
        case 0: return fn.template operator()<LobeModel::kIso, 0>();
        case 1: return fn.template operator()<LobeModel::kIso, 1>();
        case 2: return fn.template operator()<LobeModel::kIso, 2>();
        default: return fn.template operator()<LobeModel::kIso, 3>();
      }
    default:
      switch (layout.lobes) {
        case 0: return fn.template operator()<LobeModel::kShared, 0>();
        case 1: return fn.template operator()<LobeModel::kShared, 1>();
        default: return fn.template operator()<LobeModel::kShared, 2>();
      }
  }
}

namespace internal {
template <typename T>
struct EvalModelCall {
  const T* x; const T& xx; const T& yy; const T& zz; int channel; T* grad;
  template <LobeModel M, int K>
  T operator()() const { return EvalModel<M, K, T>(x, xx, yy, zz, channel, grad); }
};
}  // namespace internal

// Runtime-layout form of EvalModel (a switch per call: for tests and the scalar fitters).
template <typename T>
inline T EvalModelDyn(const ProblemLayout& layout, const T* x, const T& xx, const T& yy,
                      const T& zz, int channel, T* grad) {
  return DispatchLayout(layout, internal::EvalModelCall<T>{x, xx, yy, zz, channel, grad});
}

// ---- Mapping between a problem's normalised parameters and brdf::BrdfParams ------------------
// Writes the natural-unit BRDF parameters of problem `problem` (a channel for aniso/iso, ignored
// for shared) into *out (num_lobes must already equal layout.lobes). `scale` is the problem's
// normalisation S. Non-finite results are impossible for in-bound x; they are still mapped to 0.
// Returns the number of output slots; with `slots` given, also their values (OutputSlots).
int ToBrdfParams(const ProblemLayout& layout, const double* x, double scale, int problem,
                 brdf::BrdfParams* out, double* slots = nullptr);
// The natural-unit output slots of one problem in BrdfMaps channel order restricted to the
// problem (aniso/iso: rho, then per lobe Cx Cy Cz n of its channel; shared: all channels) —
// used to propagate covariances. Returns the number of slots written to `out` (<= 39).
int OutputSlots(const ProblemLayout& layout, const double* x, double scale, double* out);
// Where OutputSlots' entry i lands in a BrdfParams for problem `problem`.
float* OutputSlotRef(const ProblemLayout& layout, int problem, int slot, brdf::BrdfParams* p);
// Normalised parameters of `problem` that reproduce `params` (the inverse of ToBrdfParams where
// the model can represent them; for iso Cxy = (Cx + Cy) / 2; for shared, channel 0's lobe
// shape with Cz normalised to 1, scales per channel from each channel's Cz^n). For tests and for
// starting values given in natural units.
void FromBrdfParams(const ProblemLayout& layout, const brdf::BrdfParams& params, double scale,
                    int problem, double* x);

}  // namespace reflcap::fit
