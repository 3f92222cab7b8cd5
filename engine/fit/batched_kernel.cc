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

using KernelFn = void (*)(LossKind, LaneBatch*);
struct KernelTable {
  KernelFn aniso[4], iso[4], shared[3];
  const char* isa;
};

// One set of kernels per ISA, each built for it with its native vector width. `flatten` inlines
// everything they call (model.h's and lm.h's templates included).
#define REFLCAP_KERNEL_SET(ATTR, W, NAME, ISA)                                                  \
  template <LobeModel M, int K>                                                                 \
  ATTR __attribute__((flatten)) void NAME(LossKind loss, LaneBatch* b) {                        \
    Kernel<M, K, W>(loss, b);                                                                   \
  }                                                                                             \
  const KernelTable NAME##Table = {                                                             \
      {NAME<LobeModel::kAniso, 0>, NAME<LobeModel::kAniso, 1>, NAME<LobeModel::kAniso, 2>,      \
       NAME<LobeModel::kAniso, 3>},                                                             \
      {NAME<LobeModel::kIso, 0>, NAME<LobeModel::kIso, 1>, NAME<LobeModel::kIso, 2>,            \
       NAME<LobeModel::kIso, 3>},                                                               \
      {NAME<LobeModel::kShared, 0>, NAME<LobeModel::kShared, 1>, NAME<LobeModel::kShared, 2>}, \
      ISA};

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

const char* LaneKernelIsa() { return Kernels().isa; }

}  // namespace reflcap::fit
