// Preparation of fitting problems from samples and folding of solved problems into TexelFits
// (see problem.h for the rules).
#include "engine/fit/problem.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "engine/fit/seed.h"

namespace reflcap::fit {
namespace {

// A sample's unit directions, or false when it is unusable: not finite (*nonfinite set), too
// short, or grazing.
bool SampleDirections(const BrdfSample& s, double min_cos, Vec3d* wi, Vec3d* wo, bool* nonfinite) {
  for (int j = 0; j < 3; ++j) {
    if (!std::isfinite(s.wi[j]) || !std::isfinite(s.wo[j])) {
      *nonfinite = true;
      return false;
    }
  }
  *wi = Vec3d(s.wi[0], s.wi[1], s.wi[2]);
  *wo = Vec3d(s.wo[0], s.wo[1], s.wo[2]);
  const double ni = wi->norm(), no = wo->norm();
  if (!(ni >= kMinDirectionNorm) || !(no >= kMinDirectionNorm)) return false;
  *wi /= ni;
  *wo /= no;
  return wi->z() >= min_cos && wo->z() >= min_cos;
}

// Channel c of a sample is usable: finite value and weight (*nonfinite set otherwise), weight > 0.
bool ChannelValid(const BrdfSample& s, int c, bool* nonfinite) {
  if (!std::isfinite(s.value[c]) || !std::isfinite(s.weight[c])) {
    *nonfinite = true;
    return false;
  }
  return s.weight[c] > 0;
}

// The k-th smallest of v[0..n) (0-based), reordering v so that v[0..k) <= it: a quickselect
// with a branch-free partition (x < pivot decided by arithmetic, not a branch), as the values
// around a median are in random order and a branchy partition mispredicts half its compares.
float SelectKth(float* v, int n, int k) {
  int lo = 0, hi = n - 1;
  while (lo < hi) {
    const float a = v[lo], b = v[lo + (hi - lo) / 2], c = v[hi];
    const float pivot = std::max(std::min(a, b), std::min(std::max(a, b), c));  // median of 3
    int i = lo;
    for (int j = lo; j <= hi; ++j) {  // [lo, i) < pivot
      const float x = v[j];
      v[j] = v[i];
      v[i] = x;
      i += x < pivot;
    }
    int e = i;
    for (int j = i; j <= hi; ++j) {  // [i, e) == pivot
      const float x = v[j];
      v[j] = v[e];
      v[e] = x;
      e += !(pivot < x);
    }
    if (k < i) {
      hi = i - 1;
    } else if (k < e) {
      return pivot;
    } else {
      lo = e;
    }
  }
  return v[k];
}

// Median of v[0..n) (the upper one for even n); reorders v so that v[0..n/2) precede it. 0 for
// n = 0.
float Median(float* v, int n) {
  if (n <= 0) return 0;
  return SelectKth(v, n, n / 2);
}

struct ChannelStats {
  double median = 0;  // normalised
  double sigma = 0;   // (median - lower quartile) / 0.6745, normalised
  int brightest = -1; // residual index (within the problem's arrays) of the largest excess among
                      // the samples in the evidence cone; -1 when none is
  double excess = 0;  // its value above rho0 / pi
};

// min_mirror_cos: only samples within the evidence cone (cos of their angle to the mirror
// configuration at least this) can be the brightest (the lobe evidence); all enter the median.
ChannelStats Stats(const ProblemArena& arena, size_t begin, int n, float* scratch,
                   double min_mirror_cos) {
  ChannelStats s;
  if (n == 0) return s;
  for (int i = 0; i < n; ++i) scratch[i] = arena.y[begin + i];
  s.median = Median(scratch, n);
  // The lower half now precedes the median: its median is the lower quartile.
  const int half = n / 2;
  const double q1 = half > 0 ? Median(scratch, half) : s.median;
  s.sigma = (s.median - q1) / kQuartileToSigma;
  s.excess = -1e300;
  // Branch-free: whether a sample lies in the cone is as random as its direction, and a branch
  // on it mispredicted about half the time (a fifth of PrepareTexel's time; BM_PrepareTexel).
  for (int i = 0; i < n; ++i) {
    const size_t r = begin + i;
    // cos of the angle between wo and the mirror of wi, from the direction products.
    const bool in_cone = !(-double(arena.xx[r]) - arena.yy[r] + arena.zz[r] < min_mirror_cos);
    const double e = arena.y[r] - s.median;  // rho0 / pi = median
    const bool better = in_cone & (e > s.excess);
    s.excess = better ? e : s.excess;
    s.brightest = better ? i : s.brightest;
  }
  return s;
}

bool HasEvidence(const ChannelStats& s, double evidence_sigmas) {
  return s.brightest >= 0 &&
         s.excess > evidence_sigmas * s.sigma + kEvidenceFloor * std::max(s.median, 0.0);
}

}  // namespace

void ProblemArena::Reserve(size_t residuals, size_t max_samples) {
  for (auto* v : {&xx, &yy, &zz, &y, &sw}) {
    if (v->size() < residuals) v->resize(residuals);
  }
  if (scratch.size() < 3 * max_samples) scratch.resize(3 * max_samples);
  if (products.size() < 3 * max_samples) products.resize(3 * max_samples);
  if (src.size() < residuals) src.resize(residuals);
}

void PrepareTexel(const FitOptions& options, const ProblemLayout& layout,
                  const BrdfSample* samples, size_t count, int texel, ProblemArena* arena,
                  size_t* cursor, PreparedProblem* out) {
  const LobeModel model = layout.model;
  const int num_params = layout.NumParams();
  bool nonfinite = false;

  // 1. Directions once per sample (products and validity into the scratch), the cone test on
  // the way; then the residuals of each channel, raw values and weights.
  const double cone_cos = std::cos(DegToRad(options.highlight_cone_deg));
  const double evidence_cos =
      std::cos(DegToRad(std::max(kEvidenceConeDeg, options.highlight_cone_deg)));
  bool near_mirror = false;
  float* products = arena->products.data();  // xx, yy, zz per sample; NaN marks unusable ones
  for (size_t i = 0; i < count; ++i) {
    const BrdfSample& s = samples[i];
    Vec3d wi, wo;
    float* p = products + 3 * i;
    if (!SampleDirections(s, options.min_cos_theta, &wi, &wo, &nonfinite)) {
      p[0] = std::numeric_limits<float>::quiet_NaN();
      continue;
    }
    p[0] = float(wi.x() * wo.x());
    p[1] = float(wi.y() * wo.y());
    p[2] = float(wi.z() * wo.z());
    bool any_channel = false;
    for (int c = 0; c < 3; ++c) {
      bool ignored = false;
      any_channel = any_channel || ChannelValid(s, c, &ignored);
    }
    const double mirror_cos = -wi.x() * wo.x() - wi.y() * wo.y() + wi.z() * wo.z();
    near_mirror = near_mirror || (any_channel && mirror_cos >= cone_cos);
  }
  const size_t base = *cursor;
  size_t block_begin[4];
  size_t at = base;
  for (int c = 0; c < 3; ++c) {
    block_begin[c] = at;
    for (size_t i = 0; i < count; ++i) {
      const float* p = products + 3 * i;
      if (std::isnan(p[0])) continue;
      if (!ChannelValid(samples[i], c, &nonfinite)) continue;
      arena->xx[at] = p[0];
      arena->yy[at] = p[1];
      arena->zz[at] = p[2];
      arena->y[at] = samples[i].value[c];
      arena->sw[at] = samples[i].weight[c];
      arena->src[at] = uint32_t(i);
      ++at;
    }
  }
  block_begin[3] = at;
  *cursor = at;

  // 2. Problems: normalisation, classification, start.
  const int problems = ProblemsPerTexel(model);
  for (int p = 0; p < problems; ++p) {
    PreparedProblem& q = out[p];
    q = PreparedProblem{};
    q.layout = layout;
    q.texel = texel;
    q.problem = p;
    q.nonfinite_input = nonfinite;
    const int c_begin = model == LobeModel::kShared ? 0 : p;
    const int c_end = model == LobeModel::kShared ? 3 : p + 1;
    const size_t r0 = block_begin[c_begin], r1 = block_begin[c_end];
    const int n = int(r1 - r0);
    ResidualView& view = q.residuals;
    view.xx = arena->xx.data() + r0;
    view.yy = arena->yy.data() + r0;
    view.zz = arena->zz.data() + r0;
    view.y = arena->y.data() + r0;
    view.sw = arena->sw.data() + r0;
    for (int c = 0; c < 4; ++c) {
      const int cc = std::min(c_begin + c, c_end);
      view.begin[c] = int(block_begin[cc] - r0);
    }
    if (model != LobeModel::kShared) view.begin[1] = view.begin[2] = view.begin[3] = n;
    q.samples = model == LobeModel::kShared ? n / 3 : n;

    double scale = 0;
    for (size_t r = r0; r < r1; ++r) scale = std::max(scale, double(std::abs(arena->y[r])));
    // All-zero values: any scale works; 1 keeps the normalised values equal to the raw ones.
    if (!(scale > 0)) scale = 1;
    // Weights: divided by the mean of w (y / S)^2, so the weighted values have unit RMS and every
    // weighted residual is O(1) whatever the noise model (inverse-variance weights of relative
    // noise span 1e20 across a texel whose values span 1e10).
    double weighted_sq = 0, weight_sum = 0;
    for (size_t r = r0; r < r1; ++r) {
      const double v = arena->y[r] / scale;
      weighted_sq += arena->sw[r] * v * v;
      weight_sum += arena->sw[r];
    }
    double weight_scale = n > 0 ? weighted_sq / n : 1.0;
    if (!(weight_scale > 0)) weight_scale = n > 0 ? weight_sum / n : 1.0;  // all values 0
    q.scale = scale;
    q.weight_scale = weight_scale;
    q.loss_scale = options.loss_scale / (std::sqrt(weight_scale) * scale);
    float* __restrict y = arena->y.data();  // distinct arrays: the loop vectorises
    float* __restrict sw = arena->sw.data();
    for (size_t r = r0; r < r1; ++r) {
      y[r] = float(y[r] / scale);
      // min as a compare-and-select (what std::min gives for the finite, non-negative weights
      // here), which vectorises where std::min's branch did not: the division and square root
      // in this loop were a fifth of PrepareTexel.
      const double w = sw[r] / weight_scale;
      sw[r] = float(std::sqrt(w < kMaxNormalisedWeight ? w : kMaxNormalisedWeight));
    }

    ParameterBounds(layout, q.lower, q.upper);
    double* x = q.x0;
    for (int j = 0; j < kMaxParams; ++j) x[j] = 0;

    ChannelStats stats[3];
    for (int c = c_begin; c < c_end; ++c) {
      stats[c] = Stats(*arena, block_begin[c], int(block_begin[c + 1] - block_begin[c]),
                       arena->scratch.data(), evidence_cos);
      x[model == LobeModel::kShared ? c : 0] = std::max(0.0, kPi * stats[c].median);
    }
    if (n == 0) {
      q.preset = FitStatus::kTooFewSamples;
      q.lambert_only = true;
      q.num_stages = 0;
      for (int j = 0; j < num_params; ++j) x[j] = 0;
      for (int k = 0; k < layout.lobes; ++k) x[ExponentIndex(model, k)] = brdf::kMinExponent;
      continue;
    }

    bool lobe_fit = layout.lobes > 0;
    if (q.samples < std::max(options.min_samples, num_params + 1)) {
      q.preset = FitStatus::kTooFewSamples;
      lobe_fit = false;
    } else if (layout.lobes > 0 && !near_mirror) {
      q.preset = FitStatus::kUnidentifiableLobe;
      lobe_fit = false;
    } else if (layout.lobes > 0) {
      bool evidence = false;
      for (int c = c_begin; c < c_end; ++c) evidence |= HasEvidence(stats[c], options.evidence_sigmas);
      lobe_fit = evidence;
    }

    if (!lobe_fit && layout.lobes > 0) {
      q.lambert_only = true;
      for (int k = 0; k < layout.lobes; ++k) x[ExponentIndex(model, k)] = brdf::kMinExponent;
      q.num_stages = 1;
      q.stage_mask[0] = layout.LambertMask();
      continue;
    }
    if (options.init == InitScheme::kFixed) {
      FixedStart(layout, options.start_exponent, scale, x);
      q.num_stages = 1;
      q.stage_mask[0] = layout.AllMask();
    } else {
      // The seed's start: lobe k from the brightest sample of what the start so far leaves.
      const double n0 = options.start_exponent;
      for (int k = 0; k < layout.lobes; ++k) {
        int best = -1;
        double best_excess = 0;
        const ProblemLayout before{model, k};
        for (int r = 0; r < n; ++r) {
          const int c = model == LobeModel::kShared
                            ? (r < view.begin[1] ? 0 : r < view.begin[2] ? 1 : 2)
                            : 0;
          // Lobe 0's start: the model so far is the albedo alone, rho / pi (EvalModel's
          // arithmetic, without its per-call layout switch).
          const double f =
              k == 0 ? x[model == LobeModel::kShared ? c : 0] * kInvPi
                     : EvalModelDyn<double>(before, x, view.xx[r], view.yy[r], view.zz[r], c,
                                            nullptr);
          const double e = view.y[r] - f;
          const bool take = best < 0 || e > best_excess;  // branch-free, as Stats
          best = take ? r : best;
          best_excess = take ? e : best_excess;
        }
        if (best < 0 || (k > 0 && !(best_excess > 0))) {
          // Nothing left to explain: a weaker, sharper copy of lobe 0.
          const int o0 = LobeOffset(model, 0), ok = LobeOffset(model, k);
          for (int j = 0; j < ParamsPerLobe(model); ++j) x[ok + j] = x[o0 + j];
          const double n = std::min(n0 * std::pow(4.0, k), brdf::kMaxExponent);
          x[ExponentIndex(model, k)] = n;
          if (model == LobeModel::kShared) {
            for (int c = 0; c < 3; ++c) x[ok + 3 + c] *= 0.1;
          } else {
            // Peak c^n of lobe 0 at its start n0 becomes a tenth of it at exponent n.
            const double cz0 = x[o0 + (model == LobeModel::kAniso ? 2 : 1)];
            const double peak = std::pow(std::max(cz0, 1e-3), n0) * 0.1;
            const double ratio = std::pow(peak, 1.0 / n) / std::max(cz0, 1e-3);
            for (int j = 0; j < ParamsPerLobe(model) - 1; ++j) x[ok + j] *= ratio;
          }
          continue;
        }
        const BrdfSample& s = samples[arena->src[r0 + size_t(best)]];
        Vec3d wi, wo;
        bool ignored = false;
        SampleDirections(s, -1.0, &wi, &wo, &ignored);
        double excess[3] = {best_excess, 0, 0};
        if (model == LobeModel::kShared) {
          const ProblemLayout before_c{model, k};
          for (int c = 0; c < 3; ++c) {
            bool nf = false;
            if (!ChannelValid(s, c, &nf)) {
              excess[c] = 0;
              continue;
            }
            const float pxx = float(wi.x() * wo.x()), pyy = float(wi.y() * wo.y()),
                        pzz = float(wi.z() * wo.z());
            const double f = EvalModelDyn<double>(before_c, x, pxx, pyy, pzz, c, nullptr);
            excess[c] = s.value[c] / scale - f;
          }
        }
        SeedLobeStart(layout, k, wi, wo, excess, n0, x);
      }
      q.num_stages = layout.lobes > 0 ? 2 : 1;
      q.stage_mask[0] = layout.lobes > 0 ? layout.LobeCMask() : layout.AllMask();
      q.stage_mask[1] = layout.AllMask();
    }
  }
  for (int p = 0; p < problems; ++p) {
    for (int j = 0; j < out[p].layout.NumParams(); ++j) {
      out[p].x0[j] = std::clamp(out[p].x0[j], out[p].lower[j], out[p].upper[j]);
    }
  }
}

void BeginTexel(int lobes, TexelFit* fit) {
  *fit = TexelFit{};
  fit->params.num_lobes = lobes;
  fit->sigma.num_lobes = lobes;
  fit->sigma.rho_d.fill(-1.0f);
  for (auto& lobe : fit->sigma.lobes) {
    for (auto& l : lobe) l = brdf::LobeParams{-1, -1, -1, -1};
  }
  fit->status = FitStatus::kConverged;
}

namespace {

// The free block of the packed symmetric matrix a (size n, mask free), scaled to unit diagonal
// (D A D with D = diag(1 / sqrt(a_jj))) and factorised as L L^T.
struct FreeBlockFactor {
  int m = 0;                   // free parameters
  int idx[kMaxParams] = {};    // their indices
  double scale[kMaxParams];    // D
  double l[kMaxPacked];        // L, packed lower triangle
};

// False when a pivot of the unit-diagonal form is below kLmSingularPivot (rank deficient).
bool FactorFreeBlock(int n, uint32_t free, const double* a, FreeBlockFactor* f) {
  int m = 0;
  for (int j = 0; j < n; ++j) {
    if ((free >> j) & 1u) f->idx[m++] = j;
  }
  f->m = m;
  for (int i = 0; i < m; ++i) {
    const double d = a[PackedIndex(f->idx[i], f->idx[i])];
    // A parameter without any influence on the residuals: nothing determines it.
    if (!(d > 1e-300)) return false;
    f->scale[i] = 1.0 / std::sqrt(d);
  }
  double* l = f->l;
  for (int i = 0; i < m; ++i) {
    for (int j = 0; j <= i; ++j) {
      const int p = std::max(f->idx[i], f->idx[j]), q = std::min(f->idx[i], f->idx[j]);
      l[PackedIndex(i, j)] = a[PackedIndex(p, q)] * f->scale[i] * f->scale[j];
    }
  }
  for (int j = 0; j < m; ++j) {
    double d = l[PackedIndex(j, j)];
    for (int k = 0; k < j; ++k) d -= l[PackedIndex(j, k)] * l[PackedIndex(j, k)];
    if (!(d >= double(gpu::shared::kLmSingularPivot))) return false;
    const double r = std::sqrt(d);
    l[PackedIndex(j, j)] = r;
    for (int i = j + 1; i < m; ++i) {
      double s = l[PackedIndex(i, j)];
      for (int k = 0; k < j; ++k) s -= l[PackedIndex(i, k)] * l[PackedIndex(j, k)];
      l[PackedIndex(i, j)] = s / r;
    }
  }
  return true;
}

// g^T A_ff^-1 g for the free block A_ff of a factorised as above, g indexed by parameter
// (entries of fixed parameters ignored): A_ff^-1 = D (L L^T)^-1 D, so the form is |L^-1 D g|^2,
// one forward substitution (no explicit inverse: a fifth of the divisions).
double InverseQuadraticForm(const FreeBlockFactor& f, const double* g) {
  double z[kMaxParams];
  double v = 0;
  for (int i = 0; i < f.m; ++i) {
    double s = f.scale[i] * g[f.idx[i]];
    for (int k = 0; k < i; ++k) s -= f.l[PackedIndex(i, k)] * z[k];
    z[i] = s / f.l[PackedIndex(i, i)];
    v += z[i] * z[i];
  }
  return v;
}

}  // namespace

bool LobeExceedsEvidence(const ProblemLayout& layout, const double* x) {
  const int per_problem_channels = ProblemChannels(layout.model);
  for (int k = 0; k < layout.lobes; ++k) {
    const double* lobe = x + LobeOffset(layout.model, k);
    // Supremum of the base over unit wi, wo in the upper hemisphere: max(|Cx|, |Cy|, Cz+).
    double c_max = 0, scale = 1;
    switch (layout.model) {
      case LobeModel::kAniso: c_max = std::max({std::abs(lobe[0]), std::abs(lobe[1]), lobe[2]}); break;
      case LobeModel::kIso: c_max = std::max(std::abs(lobe[0]), lobe[1]); break;
      case LobeModel::kShared:
        c_max = std::max({std::abs(lobe[0]), std::abs(lobe[1]), 1.0});
        scale = 0;
        for (int c = 0; c < per_problem_channels; ++c) scale = std::max(scale, lobe[3 + c]);
        break;
    }
    const double exponent = x[ExponentIndex(layout.model, k)];
    if (c_max <= 0 || scale <= 0) continue;
    if (std::log(scale) + exponent * std::log(c_max) > std::log(kMaxLobeSupremum)) return true;
  }
  return false;
}

namespace {

// 2 cost / (residuals - free parameters) in natural noise units, or -1 for a problem without a
// lobe fit (nothing to compare or retry).
double ReducedCost(const PreparedProblem& q, const SolvedProblem& solved) {
  if (q.num_stages == 0 || q.lambert_only || q.preset != FitStatus::kConverged ||
      q.layout.lobes == 0) {
    return -1;
  }
  int free = 0;
  for (uint32_t m = solved.free_mask; m != 0; m &= m - 1) ++free;
  const int dof = std::max(1, q.residuals.count() - free);  // no redundancy: the cost itself
  return 2 * q.scale * q.scale * q.weight_scale * solved.cost / dof;
}

}  // namespace

int PrepareChannelRetries(const PreparedProblem* q, const SolvedProblem* solved, int per_texel,
                          PreparedProblem* retry, int* channel) {
  if (per_texel < 2 || q[0].layout.model == LobeModel::kShared) return 0;
  int best = -1;
  double best_cost = 0;
  for (int p = 0; p < per_texel; ++p) {
    const double r = ReducedCost(q[p], solved[p]);
    if (r < 0 || solved[p].status != FitStatus::kConverged ||
        LobeExceedsEvidence(q[p].layout, solved[p].x)) {
      continue;
    }
    if (best < 0 || r < best_cost) {
      best = p;
      best_cost = r;
    }
  }
  if (best < 0) return 0;
  const ProblemLayout& layout = q[best].layout;
  int count = 0;
  for (int p = 0; p < per_texel; ++p) {
    const double r = ReducedCost(q[p], solved[p]);
    // max(.., 1): a best channel fitted below the noise level must not make noise-level
    // channels look far worse.
    if (p == best || r < 0 || r <= kChannelRetryCostRatio * std::max(best_cost, 1.0)) continue;
    PreparedProblem& out = retry[count];
    out = q[p];
    for (int k = 0; k < layout.lobes; ++k) {
      const int o = LobeOffset(layout.model, k), e = ExponentIndex(layout.model, k);
      const double n = solved[best].x[e];
      // Natural value S (C . v)^n: the same natural lobe in channel p's normalisation.
      const double c_scale = std::pow(q[best].scale / q[p].scale, 1.0 / n);
      for (int j = o; j < o + ParamsPerLobe(layout.model); ++j) {
        const double v = j == e ? n : solved[best].x[j] * c_scale;
        out.x0[j] = std::clamp(v, q[p].lower[j], q[p].upper[j]);  // starts lie within the bounds
      }
    }
    channel[count++] = p;
  }
  return count;
}

int AdoptChannelRetries(const SolvedProblem* retried, const int* channel, int count,
                        SolvedProblem* solved) {
  int taken = 0;
  for (int i = 0; i < count; ++i) {
    // NaN costs never compare lower: a failed retry is never taken.
    if (retried[i].cost < solved[channel[i]].cost) {
      solved[channel[i]] = retried[i];
      ++taken;
    }
  }
  return taken;
}

double LambertFallback(const PreparedProblem& q, double* x) {
  const ProblemLayout& layout = q.layout;
  const ResidualView& r = q.residuals;
  double cost = 0;
  // Weighted least squares of rho / pi = y per channel block: rho = pi sum(w y) / sum(w).
  for (int c = 0; c < ProblemChannels(layout.model); ++c) {
    double sum_wy = 0, sum_w = 0;
    for (int i = r.begin[c]; i < r.begin[c + 1]; ++i) {
      const double w = double(r.sw[i]) * r.sw[i];
      sum_wy += w * r.y[i];
      sum_w += w;
    }
    const double rho = sum_w > 0 ? std::clamp(kPi * sum_wy / sum_w, q.lower[c], q.upper[c]) : 0.0;
    x[c] = rho;
    for (int i = r.begin[c]; i < r.begin[c + 1]; ++i) {
      const double e = double(r.sw[i]) * (rho * kInvPi - r.y[i]);
      cost += 0.5 * e * e;
    }
  }
  for (int k = 0; k < layout.lobes; ++k) {
    const int o = LobeOffset(layout.model, k), e = ExponentIndex(layout.model, k);
    for (int j = o; j < o + ParamsPerLobe(layout.model); ++j) x[j] = (j == e) ? q.x0[e] : 0.0;
  }
  return cost;
}

bool FinishProblem(const PreparedProblem& q, const SolvedProblem& solved_in, TexelFit* fit) {
  const ProblemLayout& layout = q.layout;
  const int n = layout.NumParams();
  const int residuals = q.residuals.count();
  FitStatus status = q.preset != FitStatus::kConverged ? q.preset : solved_in.status;

  FreeBlockFactor factor;
  int free_count = 0;
  for (int j = 0; j < n; ++j) free_count += (solved_in.free_mask >> j) & 1u;
  bool invertible = free_count > 0 && FactorFreeBlock(n, solved_in.free_mask, solved_in.a, &factor);
  if (!invertible && free_count > 0 && residuals > 0 &&
      (status == FitStatus::kConverged || status == FitStatus::kMaxIterations)) {
    status = FitStatus::kSingular;
  }

  // The solution as it is kept: parameters and cost (LambertFallback may replace both), not a
  // copy of the whole SolvedProblem (its normal equations are only read, from solved_in).
  double x[kMaxParams];
  for (int j = 0; j < kMaxParams; ++j) x[j] = solved_in.x[j];
  double cost = solved_in.cost;
  const uint32_t free_mask = solved_in.free_mask;
  // A lobe the data cannot pin down — the LM ended singular, or the lobe rises far above every
  // sample somewhere on the hemisphere (extrapolation, not measurement) — is replaced by the
  // problem's Lambert-only fit, and the status says why (kSingular, kUnidentifiableLobe).
  bool fell_back = false;
  if (layout.lobes > 0 && !q.lambert_only && residuals > 0 &&
      (status == FitStatus::kSingular || LobeExceedsEvidence(layout, x))) {
    // The fallback refits rho from the residuals: a view without them (the Vulkan fitter keeps
    // only their counts) asks for them, before anything was written.
    if (q.residuals.y == nullptr) return false;
    if (status != FitStatus::kSingular) status = FitStatus::kUnidentifiableLobe;
    cost = LambertFallback(q, x);
    fell_back = true;
    invertible = false;  // sigma unknown: the normal equations belong to the discarded lobe fit
  }
  if (q.nonfinite_input) status = FitStatus::kNonFiniteInput;

  // Parameters in natural units.
  double slots[3 + 12 * brdf::kMaxLobes];
  const int num_slots = ToBrdfParams(layout, x, q.scale, q.problem, &fit->params, slots);

  // Standard deviations: Cov = s^2 (J^T J)^-1 on the free block, s^2 = 2 cost / (m - p),
  // pushed through the map to natural units by a forward-difference Jacobian.
  if (invertible && residuals > free_count) {
    const double variance = 2.0 * cost / double(residuals - free_count);
    // g[i][j]: d slot i / d parameter j. Only the num_slots x n block is used, and only it is
    // zeroed (the whole array is 5 KB).
    double g[3 + 12 * brdf::kMaxLobes][kMaxParams];
    for (int i = 0; i < num_slots; ++i) {
      for (int j = 0; j < n; ++j) g[i][j] = 0;
    }
    bool depends_on_fixed[3 + 12 * brdf::kMaxLobes] = {};
    if (layout.model != LobeModel::kShared) {
      // Analytic: rho = S rho'; C = C' r with r = S^(1/n), dC/dn = -C' r log(S) / n^2.
      const bool iso = layout.model == LobeModel::kIso;
      g[0][0] = q.scale;
      for (int k = 0; k < layout.lobes; ++k) {
        const int o = LobeOffset(layout.model, k), e = ExponentIndex(layout.model, k);
        const double nexp = x[e];
        const double r = std::pow(q.scale, 1.0 / nexp);
        const double dr_dn = -r * std::log(q.scale) / (nexp * nexp);
        const int slot = 1 + 4 * k;
        for (int f = 0; f < 3; ++f) {
          const int param = iso ? o + (f < 2 ? 0 : 1) : o + f;
          g[slot + f][param] = r;
          g[slot + f][e] = x[param] * dr_dn;
        }
        g[slot + 3][e] = 1;
      }
      for (int j = 0; j < n; ++j) {
        if ((free_mask >> j) & 1u) continue;
        for (int i = 0; i < num_slots; ++i) depends_on_fixed[i] |= g[i][j] != 0;
      }
    } else {
      for (int j = 0; j < n; ++j) {
        double xp[kMaxParams];
        for (int i = 0; i < n; ++i) xp[i] = x[i];
        // Step 1e-7 relative: forward-difference error ~1e-7, rounding error ~1e-9 in double.
        double h = 1e-7 * std::max(1.0, std::abs(x[j]));
        if (xp[j] + h > q.upper[j]) h = -h;
        xp[j] += h;
        double moved[3 + 12 * brdf::kMaxLobes];
        OutputSlots(layout, xp, q.scale, moved);
        const bool is_free = (free_mask >> j) & 1u;
        for (int i = 0; i < num_slots; ++i) {
          g[i][j] = (moved[i] - slots[i]) / h;
          if (!is_free && g[i][j] != 0) depends_on_fixed[i] = true;
        }
      }
    }
    for (int i = 0; i < num_slots; ++i) {
      const double v = InverseQuadraticForm(factor, g[i]);
      const double sigma = std::sqrt(std::max(0.0, variance * v));
      const bool known = !depends_on_fixed[i] && std::isfinite(sigma) && sigma < 3.0e38;
      *OutputSlotRef(layout, q.problem, i, &fit->sigma) = known ? float(sigma) : -1.0f;
    }
  }

  fit->status = CombineStatus(fit->status, status);
  const double natural_cost = cost * q.weight_scale * q.scale * q.scale;
  fit->cost += std::isfinite(natural_cost) ? float(std::min(natural_cost, 3.0e38)) : 0.0f;
  fit->iterations = std::max(fit->iterations, solved_in.iterations);
  fit->samples = std::max(fit->samples, q.samples);
  fit->residuals += residuals;
  fit->lambert_only = fit->lambert_only || q.lambert_only || fell_back;
  return true;
}

namespace {

template <typename T>
struct ScalarSolve {
  const PreparedProblem& q;
  const LmSettings& settings;
  LossKind loss;

  template <LobeModel M, int K>
  SolvedProblem operator()() const {
    constexpr int P = NumParams(M, K);
    SolvedProblem out;
    T x[kMaxParams], lower[kMaxParams], upper[kMaxParams];
    for (int j = 0; j < kMaxParams; ++j) {
      x[j] = T(q.x0[j]);
      lower[j] = T(q.lower[j]);
      upper[j] = T(q.upper[j]);
    }
    LmState<T> state;
    NormalEquations<T> neq;
    for (int i = 0; i < kMaxPacked; ++i) state.at_x.a[i] = T(0);
    state.at_x.cost = T(0);
    for (int stage = 0; stage < q.num_stages; ++stage) {
      const LmSettings stage_settings = StageSettings(settings, stage, q.num_stages);
      LmBegin<T>(P, q.stage_mask[stage], x, &state);
      while (state.phase != LmPhase::kDone) {
        EvaluateNormalEquations<M, K, T>(q.residuals, state.x_new, loss, T(q.loss_scale), &neq);
        LmAdvance<T, P>(stage_settings, lower, upper, neq, &state);
      }
      out.iterations += state.iterations;
      for (int j = 0; j < P; ++j) x[j] = state.x[j];
      out.status = state.status;
      out.free_mask = state.free_mask;
      if (state.status == FitStatus::kSingular && stage + 1 < q.num_stages && !std::isfinite(double(state.cost))) break;
    }
    for (int j = 0; j < kMaxParams; ++j) out.x[j] = double(x[j]);
    for (int i = 0; i < PackedIndex(P, 0); ++i) out.a[i] = double(state.at_x.a[i]);
    out.cost = double(state.at_x.cost);
    return out;
  }
};

}  // namespace

template <typename T>
SolvedProblem SolveScalar(const PreparedProblem& problem, const LmSettings& settings,
                          LossKind loss) {
  return DispatchLayout(problem.layout, ScalarSolve<T>{problem, settings, loss});
}

template SolvedProblem SolveScalar<float>(const PreparedProblem&, const LmSettings&, LossKind);
template SolvedProblem SolveScalar<double>(const PreparedProblem&, const LmSettings&, LossKind);

}  // namespace reflcap::fit
