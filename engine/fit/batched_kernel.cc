// SIMD normal-equation kernel of the batched CPU fitter (batched_kernel.h: why libmvec is called
// by name, and the per-ISA builds). The model and the loss are model.h's and lm.h's templates
// instantiated with a lane pack, so the lanes compute exactly the scalar path's formula.
#include "engine/fit/batched_kernel.h"

#include <cmath>
#include <cstring>

#if defined(__x86_64__)
#include <immintrin.h>
#endif

#include "engine/fit/lm.h"

namespace reflcap::fit {
namespace {

#define REFLCAP_AI __attribute__((always_inline)) inline

// kLanes floats as one value, held as kLanes / W native vectors of W floats (W = 16 on
// AVX-512, 8 on AVX2, 4 on SSE2), with the arithmetic, comparisons and Select that model.h's
// masked-style templates use. Native widths matter: GCC splits wider generic vectors for
// arithmetic but scalarises their comparisons and selects. Everything inlines into the kernel of
// one ISA, so packs stay in vector registers and never cross a call.
template <int W>
struct Pack {
  typedef float F __attribute__((vector_size(W * sizeof(float))));
  static constexpr int kParts = kLanes / W;
  F p[kParts];
  Pack() = default;
  REFLCAP_AI Pack(double d) {  // NOLINT: broadcast, like T(1.0)
    for (int k = 0; k < kParts; ++k) p[k] = F{} + float(d);
  }
};
// A lane condition lhs > rhs, kept as its operands so that Select emits one compare-and-blend
// (a materialised mask vector is what GCC scalarises).
template <int W>
struct PackMask {
  Pack<W> lhs, rhs;
};

#define REFLCAP_PACK_BINARY(OP)                                         \
  template <int W>                                                      \
  REFLCAP_AI Pack<W> operator OP(const Pack<W>& a, const Pack<W>& b) {  \
    Pack<W> r;                                                          \
    for (int k = 0; k < Pack<W>::kParts; ++k) r.p[k] = a.p[k] OP b.p[k]; \
    return r;                                                           \
  }
REFLCAP_PACK_BINARY(+)
REFLCAP_PACK_BINARY(-)
REFLCAP_PACK_BINARY(*)
REFLCAP_PACK_BINARY(/)
#undef REFLCAP_PACK_BINARY

template <int W>
REFLCAP_AI Pack<W> operator-(const Pack<W>& a) { return Pack<W>(0.0) - a; }
template <int W>
REFLCAP_AI Pack<W>& operator+=(Pack<W>& a, const Pack<W>& b) { return a = a + b; }
template <int W>
REFLCAP_AI PackMask<W> operator>(const Pack<W>& a, const Pack<W>& b) { return {a, b}; }
template <int W>
REFLCAP_AI PackMask<W> operator<(const Pack<W>& a, const Pack<W>& b) { return {b, a}; }
template <int W>
REFLCAP_AI Pack<W> Select(const PackMask<W>& c, const Pack<W>& a, const Pack<W>& b) {
  Pack<W> r;
  for (int k = 0; k < Pack<W>::kParts; ++k) r.p[k] = c.lhs.p[k] > c.rhs.p[k] ? a.p[k] : b.p[k];
  return r;
}
// exp and log of a native vector: glibc's libmvec variants, called by their vector-ABI names
// (_ZGV<isa>N<W>v_<fn>, exported by libmvec.so.1 since glibc 2.22) so that no vectoriser
// heuristic decides whether the lobe's two transcendental calls run 16 lanes at a time or one.
// Elsewhere, element loops (scalar libm calls).
#if defined(__x86_64__) && defined(__GLIBC__)
typedef float F16 __attribute__((vector_size(64)));
typedef float F8 __attribute__((vector_size(32)));
typedef float F4 __attribute__((vector_size(16)));
extern "C" {
F16 _ZGVeN16v_expf(F16);
F16 _ZGVeN16v_logf(F16);
F8 _ZGVdN8v_expf(F8);
F8 _ZGVdN8v_logf(F8);
F4 _ZGVbN4v_expf(F4);
F4 _ZGVbN4v_logf(F4);
}
REFLCAP_AI F16 VecExp(F16 v) { return _ZGVeN16v_expf(v); }
REFLCAP_AI F16 VecLog(F16 v) { return _ZGVeN16v_logf(v); }
REFLCAP_AI F8 VecExp(F8 v) { return _ZGVdN8v_expf(v); }
REFLCAP_AI F8 VecLog(F8 v) { return _ZGVdN8v_logf(v); }
REFLCAP_AI F4 VecExp(F4 v) { return _ZGVbN4v_expf(v); }
REFLCAP_AI F4 VecLog(F4 v) { return _ZGVbN4v_logf(v); }
#else
template <typename F>
REFLCAP_AI F VecExp(F v) {
  for (int i = 0; i < int(sizeof(F) / sizeof(float)); ++i) v[i] = std::exp(v[i]);
  return v;
}
template <typename F>
REFLCAP_AI F VecLog(F v) {
  for (int i = 0; i < int(sizeof(F) / sizeof(float)); ++i) v[i] = std::log(v[i]);
  return v;
}
#endif

template <int W>
REFLCAP_AI Pack<W> exp(const Pack<W>& a) {
  Pack<W> r;
  for (int k = 0; k < Pack<W>::kParts; ++k) r.p[k] = VecExp(a.p[k]);
  return r;
}
template <int W>
REFLCAP_AI Pack<W> log(const Pack<W>& a) {
  Pack<W> r;
  for (int k = 0; k < Pack<W>::kParts; ++k) r.p[k] = VecLog(a.p[k]);
  return r;
}
template <int W>
REFLCAP_AI Pack<W> sqrt(const Pack<W>& a) {
  Pack<W> r;
  for (int k = 0; k < Pack<W>::kParts; ++k) {
    for (int i = 0; i < W; ++i) r.p[k][i] = std::sqrt(a.p[k][i]);
  }
  return r;
}

template <int W>
REFLCAP_AI Pack<W> Load(const float* p) {
  Pack<W> r;
  std::memcpy(&r.p, p, sizeof r.p);
  return r;
}
template <int W>
REFLCAP_AI void Store(const Pack<W>& a, float* p) { std::memcpy(p, &a.p, sizeof a.p); }

template <LobeModel M, int K, int W>
REFLCAP_AI void Kernel(LossKind loss, LaneBatch* b) {
  using P4 = Pack<W>;
  constexpr int P = NumParams(M, K);
  constexpr int kPacked = PackedIndex(P, 0);
  P4 x[P];
  for (int j = 0; j < P; ++j) x[j] = Load<W>(b->x[j]);
  const P4 delta = Load<W>(b->loss_scale);
  P4 a[kPacked];
  P4 g[P];
  for (int i = 0; i < kPacked; ++i) a[i] = P4(0.0);
  for (int j = 0; j < P; ++j) g[j] = P4(0.0);
  P4 cost(0.0);
  for (int c = 0; c < ProblemChannels(M); ++c) {
    const int n = b->block_count[c];
    for (int i = 0; i < n; ++i) {
      const size_t o = (size_t(c) * b->capacity + i) * kLanes;
      const P4 sw = Load<W>(b->sw + o);
      P4 grad[P];
      const P4 f = EvalModel<M, K, P4>(x, Load<W>(b->xx + o), Load<W>(b->yy + o), Load<W>(b->zz + o), c, grad);
      const P4 res = sw * (f - Load<W>(b->y + o));
      P4 rho, rho1;
      RobustLoss(loss, res * res, delta, &rho, &rho1);
      cost += P4(0.5) * rho;
      P4 j_sw[P];
      for (int j = 0; j < P; ++j) j_sw[j] = sw * grad[j];
      for (int p = 0; p < P; ++p) {
        g[p] += rho1 * res * j_sw[p];
        const P4 wp = rho1 * j_sw[p];
        for (int q = 0; q <= p; ++q) a[PackedIndex(p, q)] += wp * j_sw[q];
      }
    }
  }
  for (int i = 0; i < kPacked; ++i) Store(a[i], b->a[i]);
  for (int j = 0; j < P; ++j) Store(g[j], b->g[j]);
  Store(cost, b->cost);
}

// EvaluateLobeSum's body: kLanes samples per step, exp(n log b) per lobe as the LM's lanes form
// it (model.h LobeValueAndSlopes), in natural units: saturated at brdf::kMaxLobeValue (the
// exponent argument capped just above log of it, so exp never overflows), cut off at
// kPowBaseMin, and floored at kMinLobeLogArg (1.8e-35: below any value a cost can tell, and
// it keeps the vector expf off its scalar underflow path).
template <int W>
REFLCAP_AI void LobeSum(const float* xx, const float* yy, const float* zz, size_t padded,
                        const float* channel, int lobes, float* out) {
  using P4 = Pack<W>;
  constexpr double kMaxArg = 70.08;  // log(brdf::kMaxLobeValue) = 69.08, + 1: exp stays finite
  static_assert(brdf::kMaxLobeValue == 1e30, "kMaxArg is log(kMaxLobeValue) + 1");
  for (size_t i = 0; i < padded; i += kLanes) {
    const P4 x = Load<W>(xx + i), y = Load<W>(yy + i), z = Load<W>(zz + i);
    P4 sum(0.0);
    for (int k = 0; k < lobes; ++k) {
      const float* lobe = channel + 1 + 4 * k;
      const P4 base = P4(lobe[0]) * x + P4(lobe[1]) * y + P4(lobe[2]) * z;
      const P4 safe_base = Select(base > P4(kPowBaseMin), base, P4(1.0));
      const P4 arg0 = P4(lobe[3]) * log(safe_base);
      P4 arg = Select(arg0 > P4(kMaxArg), P4(kMaxArg), arg0);
      arg = Select(arg < P4(kMinLobeLogArg), P4(kMinLobeLogArg), arg);
      const P4 raw = Select(base > P4(kPowBaseMin), exp(arg), P4(0.0));
      sum += Select(P4(brdf::kMaxLobeValue) > raw, raw, P4(brdf::kMaxLobeValue));
    }
    Store(sum, out + i);
  }
}

using KernelFn = void (*)(LossKind, LaneBatch*);
using LobeSumFn = void (*)(const float*, const float*, const float*, size_t, const float*, int,
                           float*);
struct KernelTable {
  KernelFn aniso[4], iso[4], shared[3];
  LobeSumFn lobe_sum;
  const char* isa;
};

// One set of kernels per ISA, each built for it with its native vector width. `flatten` inlines
// everything they call (model.h's and lm.h's templates included).
#define REFLCAP_KERNEL_SET(ATTR, W, NAME, ISA)                                                  \
  template <LobeModel M, int K>                                                                 \
  ATTR __attribute__((flatten)) void NAME(LossKind loss, LaneBatch* b) {                        \
    Kernel<M, K, W>(loss, b);                                                                   \
  }                                                                                             \
  ATTR __attribute__((flatten)) void NAME##LobeSum(const float* xx, const float* yy,            \
                                                   const float* zz, size_t padded,              \
                                                   const float* channel, int lobes, float* out) { \
    LobeSum<W>(xx, yy, zz, padded, channel, lobes, out);                                        \
  }                                                                                             \
  const KernelTable NAME##Table = {                                                             \
      {NAME<LobeModel::kAniso, 0>, NAME<LobeModel::kAniso, 1>, NAME<LobeModel::kAniso, 2>,      \
       NAME<LobeModel::kAniso, 3>},                                                             \
      {NAME<LobeModel::kIso, 0>, NAME<LobeModel::kIso, 1>, NAME<LobeModel::kIso, 2>,            \
       NAME<LobeModel::kIso, 3>},                                                               \
      {NAME<LobeModel::kShared, 0>, NAME<LobeModel::kShared, 1>, NAME<LobeModel::kShared, 2>}, \
      NAME##LobeSum, ISA};

#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
REFLCAP_KERNEL_SET(__attribute__((target("arch=x86-64-v4"))), 16, KernelV4, "x86-64-v4")
REFLCAP_KERNEL_SET(__attribute__((target("arch=x86-64-v3"))), 8, KernelV3, "x86-64-v3")
REFLCAP_KERNEL_SET(, 4, KernelBase, "x86-64")
// Picks the widest set this CPU runs (once).
const KernelTable& Kernels() {
  static const KernelTable& table = __builtin_cpu_supports("x86-64-v4")   ? KernelV4Table
                                    : __builtin_cpu_supports("x86-64-v3") ? KernelV3Table
                                                                          : KernelBaseTable;
  return table;
}
#else
REFLCAP_KERNEL_SET(, 4, KernelBase, "generic")
const KernelTable& Kernels() { return KernelBaseTable; }
#endif

}  // namespace

void EvaluateLanes(const ProblemLayout& layout, LossKind loss, LaneBatch* batch) {
  const KernelTable& t = Kernels();
  switch (layout.model) {
    case LobeModel::kAniso: return t.aniso[layout.lobes](loss, batch);
    case LobeModel::kIso: return t.iso[layout.lobes](loss, batch);
    case LobeModel::kShared: return t.shared[layout.lobes](loss, batch);
  }
}

void EvaluateLobeSum(const float* xx, const float* yy, const float* zz, size_t padded,
                     const float* channel, int lobes, float* out) {
  REFLCAP_DCHECK(padded % kLanes == 0) << padded;
  REFLCAP_DCHECK(lobes >= 0 && lobes <= brdf::kMaxLobes) << lobes;
  Kernels().lobe_sum(xx, yy, zz, padded, channel, lobes, out);
}

const char* LaneKernelIsa() { return Kernels().isa; }

}  // namespace reflcap::fit
