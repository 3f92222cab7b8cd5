// Inverse camera response estimation (see response.h for the model and the method).
#include "acquire/radiometry/response.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <functional>
#include <limits>
#include <map>

#include <Eigen/Dense>

#include "engine/core/log.h"
#include "engine/core/parallel.h"

namespace reflcap::radiometry {
namespace {

using Eigen::MatrixXd;
using Eigen::VectorXd;

// Value bins of the sampler: 64 per exposure (4 codes each) of the pixel's longest unclipped
// exposure, so bins are ordered by brightness within each exposure list.
constexpr int kBinsPerExposure = 64;
constexpr int kBinCount = kBinsPerExposure * kMaxExposuresPerPhoto;
// A code within this many noise σ of a censoring threshold (black/clip) is not a clean
// measurement: noise moves a pixel across the threshold and the code's conditional mean shifts.
constexpr double kCensorSigmas = 3;
// Codes whose signal-to-noise ratio (x / sensor σ) is below this are noise-floor codes and stay
// out of the estimation: there the noise and the dark-heavy distribution of pixel values pull a
// code's mean radiance below the code's own value (on the shared brackets by 4 % at code 2), a
// bias no response curve should fit. 20 (5 % noise) keeps codes from 7 up at read σ = 0.001 for
// the shared brackets' camera (from 38 for sRGB). Measured, max |log error| over codes 20–235 at
// floors 5 / 10 / 20 / 40: shared brackets 0.0014 / 0.0011 / 0.0009 / 0.0005; an sRGB camera
// 0.012 / 0.008 / 0.005 / 0.003 (its low codes become extrapolation); a free-form curve 0.050 /
// 0.017 / 0.005 / — (at 40 too little range is left to anchor it).
constexpr double kMinEstimationSnr = 20;
// A parametric family explains the data when its χ² is within this fraction of the free-form
// curve's. Free values also fit some aliasing between the rounding bins of exposures an exact
// power of 4 apart — structure no smooth curve has — so even the true curve's χ² exceeds the
// free-form one: measured +2.7 % for a gamma-2.2 camera (smoothness 1; +6.7 % at 1e-3), +0.5 % on
// the shared log-logistic brackets; a curve with a 2 % ripple that the best family (a degree-5
// polynomial) misses by 0.028 in ln x costs +9.2 %.
constexpr double kFamilyChi2Tolerance = 0.05;
// Families whose χ² is within this fraction of the best family's explain the data equally well
// (a wrong family costs tens of percent; the true one against a flexible one drifting along the
// ambiguity: < 0.1 %).
constexpr double kSimplestFamilyTolerance = 0.01;
// Fewest codes a channel's estimation weights may keep (a response needs a range to be fitted).
constexpr long kMinWeightedCodes = 16;
// Monotonicity: adjacent codes must differ by at least this in ln x. The smallest true step of an
// 8-bit response is ~1/255 of the log range per code (> 5e-3); 1e-4 only forbids flat or falling.
constexpr double kMinLogStep = 1e-4;
// Weight of the gauge and of active monotonicity constraints, relative to the mean data weight
// per code: large enough to hold them to 1e-6 relative, small enough for double precision LDLT.
constexpr double kConstraintWeight = 1e3;
// Gauss–Newton on the parametric families: steps and relative stopping tolerance.
constexpr int kMaxGaussNewtonSteps = 200;
// Relative cost decrease below which Gauss–Newton stops: χ² differences that small (1e-9 of
// ~10⁶) are far below what the model choice looks at (percent).
constexpr double kGaussNewtonTolerance = 1e-9;
// Starts of a family's grid that are refined (the others only evaluated).
constexpr int kFamilyStartsRefined = 3;
// Central-difference step for the families' Jacobians (parameters are O(1)).
constexpr double kJacobianStep = 1e-6;
// Clip normalisation: codes this close to 255 (and 255 itself) inform the clip threshold, when
// their predicted ln x lies within this log window of it; both outcomes need this many pixels.
constexpr int kClipWindowCodes = 12;
constexpr double kClipWindowLog = 0.15;
constexpr size_t kMinClipPairs = 20;
// Mitsunaga–Nayar polynomial degrees tried.
constexpr int kMinPolynomialDegree = 2;
constexpr int kMaxPolynomialDegree = 6;
// Log–log polynomial degrees tried (1 would be the gamma family).
constexpr int kMinLogPolynomialDegree = 2;
constexpr int kMaxLogPolynomialDegree = 4;

uint64_t SplitMix64(uint64_t* state) {
  uint64_t z = (*state += 0x9E3779B97F4A7C15ull);
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

bool IsMeasuredCode(int z) { return z >= 1 && z < kClipCode; }

// The objective's data term for one channel: J(g) = gᵀ A g − 2 bᵀ g + c.
struct NormalEquations {
  MatrixXd A = MatrixXd::Zero(kCodeCount, kCodeCount);
  VectorXd b = VectorXd::Zero(kCodeCount);
  double c = 0;
  size_t observations = 0;
  size_t samples = 0;

  double Evaluate(const VectorXd& g) const { return g.dot(A * g) - 2 * b.dot(g) + c; }
  void Add(const NormalEquations& o) {
    A += o.A;
    b += o.b;
    c += o.c;
    observations += o.observations;
    samples += o.samples;
  }
};

struct Observation {
  int code;
  double log_t;
  double w;
};

// The sample's usable observations under `weight` (zero weight = not a measurement).
int Gather(const ResponseSample& s, const std::vector<std::vector<double>>& lists,
           const std::array<double, kCodeCount>& weight, Observation* out) {
  int n = 0;
  const std::vector<double>& log_t = lists[s.list];
  for (int j = 0; j < s.count; ++j) {
    const int z = s.codes[j];
    if (weight[z] > 0) out[n++] = {z, log_t[size_t(j)], weight[z]};
  }
  return n;
}

NormalEquations Accumulate(const std::vector<ResponseSample>& samples,
                           const std::vector<std::vector<double>>& lists,
                           const std::array<double, kCodeCount>& weight) {
  const int workers = std::max(1, HardwareThreads());
  std::vector<NormalEquations> partial(static_cast<size_t>(workers));
  const int64_t n = int64_t(samples.size());
  const int64_t chunk = std::max<int64_t>(4096, n / (workers * 4) + 1);
  ParallelFor(0, n, chunk, [&](int64_t begin, int64_t end, int worker) {
    NormalEquations& eq = partial[size_t(worker)];
    Observation obs[kMaxExposuresPerPhoto];
    for (int64_t i = begin; i < end; ++i) {
      const int m = Gather(samples[size_t(i)], lists, weight, obs);
      if (m < 2) continue;
      double W = 0, wt = 0;
      for (int j = 0; j < m; ++j) {
        W += obs[j].w;
        wt += obs[j].w * obs[j].log_t;
      }
      // P = diag(w) − w wᵀ / W;  J_i = (g − τ)ᵀ P (g − τ).
      double tPt = 0;
      for (int j = 0; j < m; ++j) {
        const int zj = obs[j].code;
        const double wj = obs[j].w;
        eq.A(zj, zj) += wj;
        for (int k = 0; k < m; ++k) eq.A(zj, obs[k].code) -= wj * obs[k].w / W;
        const double Ptau = wj * obs[j].log_t - wj * wt / W;
        eq.b(zj) += Ptau;
        tPt += obs[j].log_t * Ptau;
      }
      eq.c += tPt;
      eq.observations += size_t(m);
      eq.samples += 1;
    }
  }, workers);
  NormalEquations total;
  for (const NormalEquations& p : partial) total.Add(p);
  return total;
}

// The anchored samples as one group with a single unknown constant: for observations with known
// τ = log_radiance + ln t, J = Σ w (g(z) − a − τ)², minimised over a; h(z) = Σ w over observations
// of code z gives A += diag(h) − h hᵀ / W.
void AccumulateAnchored(const std::vector<AnchoredSample>& anchored,
                        const std::vector<std::vector<double>>& lists,
                        const std::array<double, kCodeCount>& weight, NormalEquations* eq) {
  VectorXd h = VectorXd::Zero(kCodeCount), ht = VectorXd::Zero(kCodeCount);
  double W = 0, wt = 0, wtt = 0;
  size_t n = 0;
  Observation obs[kMaxExposuresPerPhoto];
  for (const AnchoredSample& s : anchored) {
    const int m = Gather(s.codes, lists, weight, obs);
    for (int j = 0; j < m; ++j) {
      const double tau = s.log_radiance + obs[j].log_t;
      h(obs[j].code) += obs[j].w;
      ht(obs[j].code) += obs[j].w * tau;
      W += obs[j].w;
      wt += obs[j].w * tau;
      wtt += obs[j].w * tau * tau;
      ++n;
    }
  }
  if (!(W > 0)) return;
  eq->A += MatrixXd(h.asDiagonal()) - h * h.transpose() / W;
  eq->b += ht - h * (wt / W);
  eq->c += wtt - wt * wt / W;
  eq->observations += n;
  eq->samples += 1;
}

// Debevec–Malik solve of one channel: data + λ·(mean data weight)·Σ g''² + gauge, then the
// monotonicity active set over [first, last]. The second derivative is taken with respect to
// u = ln(code / 255) (log_space) or to the code: in log–log coordinates a gamma curve is a
// straight line, so the prior bends no gamma-like response. Returns g with g(255) = 0.
VectorXd SolveDebevec(const NormalEquations& eq, double smoothness, bool log_space, int first,
                      int last) {
  double diag_sum = 0;
  int diag_n = 0;
  int z_ref = first;
  for (int z = 0; z < kCodeCount; ++z) {
    if (eq.A(z, z) > 0) {
      diag_sum += eq.A(z, z);
      ++diag_n;
      if (eq.A(z, z) > eq.A(z_ref, z_ref)) z_ref = z;
    }
  }
  const double scale = diag_n > 0 ? diag_sum / diag_n : 1.0;
  MatrixXd M = eq.A;
  VectorXd rhs = eq.b;
  const double lambda = smoothness * scale;
  // Code 0 has no finite log coordinate; the log-space prior starts at code 1.
  for (int z = log_space ? 2 : 1; z + 1 < kCodeCount; ++z) {
    const int idx[3] = {z - 1, z, z + 1};
    double coef[3] = {1, -2, 1};
    if (log_space) {
      // Non-uniform second difference in u, scaled to the code-space one at u's mean spacing.
      const double h1 = std::log(double(z) / (z - 1)), h2 = std::log(double(z + 1) / z);
      const double mean_h = std::log(255.0) / 254.0;
      const double k = 2 * mean_h * mean_h / (h1 + h2);
      coef[0] = k / h1;
      coef[1] = -k * (1 / h1 + 1 / h2);
      coef[2] = k / h2;
    }
    for (int a = 0; a < 3; ++a) {
      for (int b = 0; b < 3; ++b) M(idx[a], idx[b]) += lambda * coef[a] * coef[b];
    }
  }
  M(z_ref, z_ref) += kConstraintWeight * scale;
  const double mu = kConstraintWeight * scale;
  std::vector<bool> active(kCodeCount, false);
  VectorXd g;
  for (int round = 0; round < kCodeCount; ++round) {
    g = M.ldlt().solve(rhs);
    bool added = false;
    for (int z = first; z < last; ++z) {
      if (!active[size_t(z)] && g(z + 1) - g(z) < kMinLogStep) {
        active[size_t(z)] = true;
        added = true;
        // μ (g(z+1) − g(z) − ε)².
        M(z, z) += mu;
        M(z + 1, z + 1) += mu;
        M(z, z + 1) -= mu;
        M(z + 1, z) -= mu;
        rhs(z + 1) += mu * kMinLogStep;
        rhs(z) -= mu * kMinLogStep;
      }
    }
    if (!added) break;
  }
  if (log_space) g(0) = g(1);  // placeholder; FixCodeZero sets it
  return g.array() - g(kCodeCount - 1);
}

// ---- Parametric families: x(y), y = code / 255 in (0, 1], x(1) = 1. ----------------------------

struct Family {
  std::string name;
  int parameters;
  // ln x at y for parameters p; NaN where undefined.
  std::function<double(const std::vector<double>& p, double y)> log_x;
};

Family Gamma() {
  return {"gamma", 1, [](const std::vector<double>& p, double y) { return p[0] * std::log(y); }};
}

// Parameters (ln a, ln k): the log keeps a, k positive.
Family LogLogistic() {
  return {"loglogistic", 2, [](const std::vector<double>& p, double y) {
            const double a = std::exp(p[0]), k = std::exp(p[1]);
            const double s = 1.0 / (1.0 + std::pow(k, a));
            const double u = y * s;
            if (!(u < 1)) return std::numeric_limits<double>::quiet_NaN();
            return std::log(k) + std::log(u / (1 - u)) / a;
          }};
}

// Coefficients c_1..c_{N-1}; c_N = 1 − Σ.
Family Polynomial(int degree) {
  return {StrCat("polynomial", degree), degree - 1, [degree](const std::vector<double>& p, double y) {
            double x = 0, sum = 0, yn = 1;
            for (int n = 1; n < degree; ++n) {
              yn *= y;
              x += p[size_t(n - 1)] * yn;
              sum += p[size_t(n - 1)];
            }
            yn *= y;
            x += (1 - sum) * yn;
            return x > 0 ? std::log(x) : std::numeric_limits<double>::quiet_NaN();
          }};
}

// x = ((y + α)/(1 + α))^γ: a power law with an offset — the form of sRGB (α = 0.055, γ = 2.4) and
// Rec.709 (α = 0.099, γ = 1/0.45) above their linear toes, which lie below code 21. x(0) > 0
// (a black offset) is harmless: code 0 is censored. Parameters (ln α, ln γ).
Family OffsetGamma() {
  return {"offsetgamma", 2, [](const std::vector<double>& p, double y) {
            const double alpha = std::exp(p[0]), gamma = std::exp(p[1]);
            return gamma * std::log((y + alpha) / (1 + alpha));
          }};
}

// ln x = Σ_{k=1..N} c_k (ln y)^k: a polynomial in log–log coordinates (N = 1 is a gamma curve).
Family LogPolynomial(int degree) {
  return {StrCat("logpolynomial", degree), degree, [degree](const std::vector<double>& p, double y) {
            const double u = std::log(y);
            double v = 0, un = 1;
            for (int k = 1; k <= degree; ++k) {
              un *= u;
              v += p[size_t(k - 1)] * un;
            }
            return v;
          }};
}

// g over codes 1..255 from a family; code 0 gets ln(x(½)/2) (see InverseResponse).
bool FamilyCurve(const Family& f, const std::vector<double>& p, VectorXd* g) {
  g->resize(kCodeCount);
  for (int z = 1; z < kCodeCount; ++z) {
    (*g)(z) = f.log_x(p, z / 255.0);
    if (!std::isfinite((*g)(z))) return false;
  }
  const double edge = f.log_x(p, 0.5 / 255.0);
  (*g)(0) = std::isfinite(edge) ? edge - std::log(2.0) : (*g)(1) - std::log(4.0);
  return true;
}

struct FamilyResult {
  std::vector<double> p;
  double cost = std::numeric_limits<double>::infinity();
  VectorXd g;
};

// Gauss–Newton / Levenberg–Marquardt on J(g(θ)) from a start θ0.
FamilyResult FitFamily(const Family& f, const NormalEquations& eq, std::vector<double> p) {
  FamilyResult best;
  VectorXd g;
  if (!FamilyCurve(f, p, &g)) return best;
  double cost = eq.Evaluate(g);
  double damping = 1e-3;
  const int np = f.parameters;
  for (int step = 0; step < kMaxGaussNewtonSteps; ++step) {
    MatrixXd J(kCodeCount, np);
    bool ok = true;
    for (int k = 0; k < np && ok; ++k) {
      std::vector<double> lo = p, hi = p;
      lo[size_t(k)] -= kJacobianStep;
      hi[size_t(k)] += kJacobianStep;
      VectorXd glo, ghi;
      ok = FamilyCurve(f, lo, &glo) && FamilyCurve(f, hi, &ghi);
      if (ok) J.col(k) = (ghi - glo) / (2 * kJacobianStep);
    }
    if (!ok) break;
    const VectorXd grad = 2 * J.transpose() * (eq.A * g - eq.b);
    const MatrixXd H = 2 * J.transpose() * eq.A * J;
    bool improved = false;
    for (int tries = 0; tries < 20 && !improved; ++tries) {
      MatrixXd Hd = H;
      for (int k = 0; k < np; ++k) Hd(k, k) += damping * std::max(H(k, k), 1e-30);
      const VectorXd delta = Hd.ldlt().solve(-grad);
      std::vector<double> trial = p;
      for (int k = 0; k < np; ++k) trial[size_t(k)] += delta(k);
      VectorXd gt;
      if (delta.allFinite() && FamilyCurve(f, trial, &gt)) {
        const double c = eq.Evaluate(gt);
        if (c < cost) {
          const double gain = cost - c;
          p = trial;
          g = gt;
          cost = c;
          damping = std::max(damping / 3, 1e-12);
          improved = true;
          if (gain <= kGaussNewtonTolerance * std::max(1.0, std::abs(cost))) step = kMaxGaussNewtonSteps;
        } else {
          damping *= 4;
        }
      } else {
        damping *= 4;
      }
    }
    if (!improved) break;
  }
  best.p = p;
  best.cost = cost;
  best.g = g;
  return best;
}

// Start values from the Debevec curve.
std::vector<std::vector<double>> FamilyStarts(const Family& f, const VectorXd& g_debevec, int first,
                                              int last) {
  std::vector<std::vector<double>> starts;
  if (f.name == "gamma") {
    double num = 0, den = 0;
    for (int z = first; z <= last; ++z) {
      const double ly = std::log(z / 255.0);
      num += ly * g_debevec(z);
      den += ly * ly;
    }
    starts.push_back({den > 0 ? num / den : 1.0});
  } else if (f.name == "offsetgamma") {
    for (double alpha : {0.01, 0.05, 0.2, 1.0}) {
      for (double gamma : {1.0, 1.8, 2.4, 3.5}) starts.push_back({std::log(alpha), std::log(gamma)});
    }
  } else if (f.name.rfind("logpolynomial", 0) == 0) {
    // Linear least squares of g = Σ c_k uᵏ on the Debevec curve.
    const int degree = f.parameters;
    MatrixXd U(last - first + 1, degree);
    VectorXd v(last - first + 1);
    for (int z = first; z <= last; ++z) {
      const double u = std::log(z / 255.0);
      double un = 1;
      for (int k = 0; k < degree; ++k) U(z - first, k) = (un *= u);
      v(z - first) = g_debevec(z);
    }
    const VectorXd c = U.colPivHouseholderQr().solve(v);
    starts.push_back(std::vector<double>(c.data(), c.data() + c.size()));
  } else if (f.name == "loglogistic") {
    for (double a : {0.6, 1.0, 1.5, 2.5, 4.0}) {
      for (double k : {0.05, 0.15, 0.4, 1.0, 3.0}) starts.push_back({std::log(a), std::log(k)});
    }
  } else {
    // Linear least squares of x = Σ c_n yⁿ (Σ c = 1) on the Debevec curve, relative weights.
    const int degree = f.parameters + 1;
    MatrixXd X(last - first + 1, f.parameters);
    VectorXd y(last - first + 1);
    for (int z = first; z <= last; ++z) {
      const double yy = z / 255.0, x = std::exp(g_debevec(z)), w = 1 / x;
      const double yN = std::pow(yy, degree);
      for (int n = 1; n < degree; ++n) X(z - first, n - 1) = w * (std::pow(yy, n) - yN);
      y(z - first) = w * (x - yN);
    }
    const VectorXd c = X.colPivHouseholderQr().solve(y);
    starts.push_back(std::vector<double>(c.data(), c.data() + c.size()));
  }
  return starts;
}

bool IsMonotone(const VectorXd& g) {
  for (int z = 1; z + 1 < kCodeCount; ++z) {
    if (!(g(z + 1) > g(z))) return false;
  }
  return true;
}

// ---- Normalisation at the clip ------------------------------------------------------------------

// Where code 255 begins, measured: for every pixel with a near-clip or clipped code at exposure j
// and measured codes in shorter exposures, the shorter ones predict ln x̂_j; P(code 255 | x̂) =
// Φ((ln x̂ − ln θ) / σ) with σ² the prediction's variance plus the read noise (relative). The
// maximum-likelihood ln θ — each pixel weighted by the population it stands for, since the
// sampler's bins select clipped and unclipped pixels at different rates — (the log-likelihood is concave in it: bisection on its derivative) is
// the curve's value at code 254.5, in the curve's own units. NaN when too few pixels inform it.
double ClipThreshold(const std::vector<ResponseSample>& samples,
                     const std::vector<std::vector<double>>& lists, const InverseResponse& r, int c,
                     const std::array<double, kCodeCount>& weight, size_t* pairs_used) {
  struct Pair {
    double log_x, sigma, weight;
    bool clipped;
  };
  std::vector<Pair> pairs;
  const double guess = 0.5 * (r.log_x[size_t(c)][kClipCode - 1] + r.log_x[size_t(c)][kClipCode]);
  const SensorNoise& noise = r.noise[size_t(c)];
  const double read_rel = noise.read_sigma / std::exp(guess);
  for (const ResponseSample& s : samples) {
    const std::vector<double>& log_t = lists[s.list];
    double S = 0, W = 0;
    for (int j = 0; j < s.count; ++j) {
      const int z = s.codes[j];
      if (W > 0 && z >= kClipCode - kClipWindowCodes) {
        const double lx = S / W + log_t[size_t(j)];
        if (std::abs(lx - guess) < kClipWindowLog) {
          pairs.push_back({lx, std::sqrt(1 / W + read_rel * read_rel), s.population_weight, z == kClipCode});
        }
      }
      if (weight[size_t(z)] > 0) {
        S += weight[size_t(z)] * (r.log_x[size_t(c)][size_t(z)] - log_t[size_t(j)]);
        W += weight[size_t(z)];
      }
    }
  }
  *pairs_used = pairs.size();
  size_t clipped = 0;
  for (const Pair& p : pairs) clipped += p.clipped;
  if (clipped < kMinClipPairs || pairs.size() - clipped < kMinClipPairs) {
    return std::numeric_limits<double>::quiet_NaN();
  }
  // d loglik / d ln θ, decreasing in ln θ.
  auto score = [&](double lt) {
    double d = 0;
    for (const Pair& p : pairs) {
      const double u = (p.log_x - lt) / p.sigma;
      const double pdf = std::exp(-0.5 * u * u) / std::sqrt(2 * kPi);
      // Tails: Φ underflows; the ratios φ/Φ tend to |u| there.
      const double cdf = std::max(0.5 * std::erfc(-u / std::sqrt(2.0)), 1e-300);
      const double ccdf = std::max(0.5 * std::erfc(u / std::sqrt(2.0)), 1e-300);
      d += p.weight * (p.clipped ? -pdf / cdf : pdf / ccdf) / p.sigma;
    }
    return d;
  };
  double lo = guess - kClipWindowLog, hi = guess + kClipWindowLog;
  if (!(score(lo) > 0) || !(score(hi) < 0)) return std::numeric_limits<double>::quiet_NaN();
  // Bisection to 1e-7 in ln θ (22 halvings of the window), far below the threshold's precision.
  while (hi - lo > 1e-7) {
    const double mid = 0.5 * (lo + hi);
    (score(mid) > 0 ? lo : hi) = mid;
  }
  return 0.5 * (lo + hi);
}

// Sets the curve's scale so that x(255) = 1 sits half a code step above the measured start of
// code 255 (or, without enough near-clip pixels, where the model extrapolates it).
void NormaliseAtClip(const std::vector<ResponseSample>& samples,
                     const std::vector<std::vector<double>>& lists,
                     const std::array<double, kCodeCount>& weight, int c, InverseResponse* r,
                     double* log_threshold) {
  size_t pairs = 0;
  const double lt = ClipThreshold(samples, lists, *r, c, weight, &pairs);
  auto& g = r->log_x[size_t(c)];
  double top = g[kClipCode];
  if (std::isfinite(lt)) top = lt + 0.5 * (g[kClipCode - 1] - g[kClipCode - 2]);
  for (double& v : g) v -= top;
  if (log_threshold) *log_threshold = std::isfinite(lt) ? lt - top : std::numeric_limits<double>::quiet_NaN();
}

// ---- Noise ------------------------------------------------------------------------------------

// Noise from pairs of consecutive measured exposures of a pixel: with R = t_long / t_short,
// d = x(z_long) − R x(z_short) has variance v(z_long) + R² v(z_short), v(z) = read² + photon x +
// q(z) (q: quantisation). So E[d² − q_long − R² q_short] = read² (1 + R²) + photon (x_long + R² x_short):
// linear least squares for (read², photon) with no circular dependence on the weights.
SensorNoise EstimateNoise(const std::vector<ResponseSample>& samples,
                          const std::vector<std::vector<double>>& lists, const InverseResponse& r,
                          int c, const std::array<double, kCodeCount>& weight) {
  struct Pair {
    double a, b, quantisation, target;
  };
  std::vector<Pair> pairs;
  pairs.reserve(samples.size());
  std::array<double, kCodeCount> q{};
  for (int z = 1; z < kClipCode; ++z) q[size_t(z)] = r.BinWidth(c, z) * r.BinWidth(c, z) / 12;
  for (const ResponseSample& s : samples) {
    const std::vector<double>& log_t = lists[s.list];
    int previous = -1;
    for (int j = 0; j < s.count; ++j) {
      const int z = s.codes[j];
      if (!(weight[size_t(z)] > 0)) continue;
      if (previous >= 0) {
        const int zs = s.codes[previous];
        const double R = std::exp(log_t[size_t(j)] - log_t[size_t(previous)]);
        const double xs = r.X(c, zs), xl = r.X(c, z);
        const double d = xl - R * xs;
        const double quantisation = q[size_t(z)] + R * R * q[size_t(zs)];
        pairs.push_back({1 + R * R, xl + R * R * xs, quantisation, d * d - quantisation});
      }
      previous = j;
    }
  }
  double read2 = 0, photon = 0;
  if (pairs.size() >= 2) {
    for (int round = 0; round < 3; ++round) {
      Eigen::Matrix2d N = Eigen::Matrix2d::Zero();
      Eigen::Vector2d v = Eigen::Vector2d::Zero();
      for (const Pair& p : pairs) {
        // var(d²) = 2 var(d)²: weight by its inverse under the current estimate.
        const double var_d = p.quantisation + read2 * p.a + photon * p.b;
        const double w = 1.0 / (var_d * var_d);
        const Eigen::Vector2d row(p.a, p.b);
        N += w * row * row.transpose();
        v += w * row * p.target;
      }
      Eigen::Vector2d sol = N.ldlt().solve(v);
      if (sol(1) < 0) {  // no shot noise visible: the read term alone
        sol(1) = 0;
        sol(0) = v(0) / N(0, 0);
      }
      if (sol(0) < 0) {  // no read noise visible: the shot term alone
        sol(0) = 0;
        sol(1) = std::max(0.0, v(1) / N(1, 1));
      }
      read2 = sol(0);
      photon = sol(1);
    }
  }
  SensorNoise noise;
  noise.read_sigma = std::sqrt(std::max(read2, 0.0));
  noise.photon_gain = std::max(photon, 0.0);
  return noise;
}

// Estimation weights: 1/var(ln x) for codes clear of the censoring thresholds, else 0.
std::array<double, kCodeCount> NoiseWeights(const InverseResponse& r, int c) {
  std::array<double, kCodeCount> w{};
  const double low = r.BlackEdge(c);
  const double high = r.X(c, kClipCode - 1) + 0.5 * (r.X(c, kClipCode - 1) - r.X(c, kClipCode - 2));
  for (int z = 1; z < kClipCode; ++z) {
    const double x = r.X(c, z);
    const SensorNoise& n = r.noise[c];
    const double sigma = std::sqrt(n.read_sigma * n.read_sigma + n.photon_gain * x);
    if (x - low < kCensorSigmas * sigma || high - x < kCensorSigmas * sigma) continue;
    if (x < kMinEstimationSnr * sigma) continue;
    w[size_t(z)] = x * x / r.CodeVariance(c, z);
  }
  return w;
}

std::array<double, kCodeCount> HatWeights() {
  std::array<double, kCodeCount> w{};
  for (int z = 1; z < kClipCode; ++z) w[size_t(z)] = std::min(z, kClipCode - z);
  return w;
}

void StoreCurve(const VectorXd& g, int c, InverseResponse* r) {
  for (int z = 0; z < kCodeCount; ++z) r->log_x[c][size_t(z)] = g(z);
}

// Debevec stores extrapolated values at 0; replace them by ln(x(½)/2) (see InverseResponse).
void FixCodeZero(InverseResponse* r, int c) {
  r->log_x[c][0] = std::log(std::max(r->BlackEdge(c), 1e-300) / 2);
}

}  // namespace

// ---- InverseResponse --------------------------------------------------------------------------

double InverseResponse::X(int c, int code) const { return std::exp(log_x[size_t(c)][size_t(code)]); }

double InverseResponse::BinWidth(int c, int code) const {
  if (code <= 0) return BlackEdge(c);
  if (code == 1) return X(c, 2) - X(c, 1);
  if (code >= kClipCode) return X(c, kClipCode) - X(c, kClipCode - 1);
  return 0.5 * (X(c, code + 1) - X(c, code - 1));
}

double InverseResponse::BlackEdge(int c) const {
  // Half a step below code 1, never below a quarter of x(1) (a falling extrapolation would).
  return std::max(X(c, 1) - 0.5 * (X(c, 2) - X(c, 1)), 0.25 * X(c, 1));
}

Status ResponseOptions::Validate() const {
  static const char* kModels[] = {"auto", "debevec", "gamma", "offsetgamma", "loglogistic", "logpolynomial", "polynomial"};
  if (std::find(std::begin(kModels), std::end(kModels), model) == std::end(kModels)) {
    return InvalidArgumentError("--response: unknown model \"", model,
                                "\" (expected auto, debevec, gamma, offsetgamma, loglogistic, logpolynomial or polynomial)");
  }
  if (!(smoothness > 0) || !std::isfinite(smoothness)) {
    return InvalidArgumentError("--smoothness: must be a positive number, got ", smoothness);
  }
  if (samples_per_bin < 16 || samples_per_bin > 1000000) {
    return InvalidArgumentError("--samples-per-bin: must be in [16, 1000000], got ", samples_per_bin);
  }
  if (iterations < 1 || iterations > 20) {
    return InvalidArgumentError("response iterations must be in [1, 20], got ", iterations);
  }
  return OkStatus();
}

// ---- Sampler ------------------------------------------------------------------------------------

ResponseSampler::ResponseSampler(const ResponseOptions& options,
                                 const std::vector<std::vector<double>>& exposure_lists)
    : options_(options) {
  std::map<std::vector<double>, uint16_t> index;
  for (const std::vector<double>& list : exposure_lists) {
    std::vector<double> log_t;
    for (double t : list) log_t.push_back(std::log(t));
    auto [it, inserted] = index.emplace(log_t, uint16_t(lists_.size()));
    if (inserted) lists_.push_back(log_t);
    list_of_photo_.push_back(it->second);
  }
  const size_t photos = std::max<size_t>(1, exposure_lists.size());
  // Twice the global cap spread over the photos, so the final draw still chooses.
  per_photo_cap_ = int(std::max<size_t>(16, (2 * size_t(options.samples_per_bin) + photos - 1) / photos));
  photo_bins_.resize(exposure_lists.size());
  for (auto& c : candidates_) c.assign(exposure_lists.size(), 0);
}

void ResponseSampler::AddPhoto(size_t photo, const BracketImages& images) {
  ++photos_added_;
  auto& bins = photo_bins_[photo];
  for (auto& b : bins) b.assign(kBinCount, Reservoir{});
  uint64_t rng = options_.seed * 0x100000001B3ull + photo * 0x9E3779B97F4A7C15ull + 1;
  const size_t pixels = size_t(images.width) * size_t(images.height);
  const int exposures = int(images.codes.size());
  for (size_t p = 0; p < pixels; ++p) {
    for (int c = 0; c < 3; ++c) {
      ResponseSample s;
      s.list = list_of_photo_[photo];
      s.count = uint8_t(exposures);
      int measured = 0, longest = -1;
      for (int e = 0; e < exposures; ++e) {
        const uint8_t z = images.codes[size_t(e)][p * 3 + size_t(c)];
        s.codes[e] = z;
        measured += IsMeasuredCode(z);
        if (z < kClipCode) longest = e;
      }
      if (measured < 2 || longest < 0) continue;
      ++candidates_[size_t(c)][photo];
      const int bin = longest * kBinsPerExposure + s.codes[longest] / (256 / kBinsPerExposure);
      Reservoir& r = bins[size_t(c)][size_t(bin)];
      ++r.seen;
      if (r.kept.size() < size_t(per_photo_cap_)) {
        r.kept.push_back(s);
      } else {
        const uint64_t k = SplitMix64(&rng) % r.seen;
        if (k < uint64_t(per_photo_cap_)) r.kept[size_t(k)] = s;
      }
    }
  }
}

SampleSet ResponseSampler::Finish() {
  SampleSet set;
  set.log_exposures = lists_;
  set.list_of_photo = list_of_photo_;
  set.photos = photos_added_;
  uint64_t rng = options_.seed * 0xD1B54A32D192ED03ull + 7;
  for (int c = 0; c < 3; ++c) {
    for (size_t n : candidates_[size_t(c)]) set.candidates[size_t(c)] += n;
    for (int bin = 0; bin < kBinCount; ++bin) {
      std::vector<ResponseSample> pool;
      for (auto& photo : photo_bins_) {
        if (photo[size_t(c)].empty()) continue;
        const Reservoir& r = photo[size_t(c)][size_t(bin)];
        const size_t first = pool.size();
        pool.insert(pool.end(), r.kept.begin(), r.kept.end());
        for (size_t i = first; i < pool.size(); ++i) {
          pool[i].population_weight = float(double(r.seen) / double(r.kept.size()));
        }
      }
      // Partial Fisher–Yates: a uniform subset of the pool.
      const size_t take = std::min(pool.size(), size_t(options_.samples_per_bin));
      const double thinning = take > 0 ? double(pool.size()) / double(take) : 1.0;
      for (size_t i = 0; i < take; ++i) {
        const size_t j = i + size_t(SplitMix64(&rng) % (pool.size() - i));
        std::swap(pool[i], pool[j]);
        pool[i].population_weight = float(pool[i].population_weight * thinning);
        set.samples[size_t(c)].push_back(pool[i]);
      }
    }
  }
  photo_bins_.clear();
  return set;
}

// ---- Estimation ---------------------------------------------------------------------------------

namespace {

std::vector<Family> FamiliesFor(const std::string& model) {
  std::vector<Family> families;
  const bool all = model == "auto";
  if (all || model == "gamma") families.push_back(Gamma());
  if (all || model == "offsetgamma") families.push_back(OffsetGamma());
  if (all || model == "loglogistic") families.push_back(LogLogistic());
  if (all || model == "logpolynomial") {
    for (int n = kMinLogPolynomialDegree; n <= kMaxLogPolynomialDegree; ++n) {
      families.push_back(LogPolynomial(n));
    }
  }
  if (all || model == "polynomial") {
    for (int n = kMinPolynomialDegree; n <= kMaxPolynomialDegree; ++n) families.push_back(Polynomial(n));
  }
  return families;
}

bool Requested(const std::string& option, const std::string& model) {
  if (option == "auto" || option == model) return true;
  return (option == "polynomial" || option == "logpolynomial") && model.rfind(option, 0) == 0 &&
         model.find_first_not_of("0123456789", option.size()) == std::string::npos;
}

VectorXd Curve(const InverseResponse& r, int c) {
  VectorXd g(kCodeCount);
  for (int z = 0; z < kCodeCount; ++z) g(z) = r.log_x[size_t(c)][size_t(z)];
  return g;
}

// Every candidate on the current normal equations; the debevec one first.
std::vector<ModelFit> FitCandidates(const std::array<NormalEquations, 3>& eq,
                                    const std::array<int, 3>& first, const std::array<int, 3>& last,
                                    const ResponseOptions& options, double log_n) {
  std::vector<ModelFit> out;
  ModelFit d;
  d.model = "debevec";
  d.response.model = d.model;
  int free = 0;
  for (int c = 0; c < 3; ++c) {
    const VectorXd g = SolveDebevec(eq[size_t(c)], options.smoothness, options.log_smoothness,
                                    first[size_t(c)], last[size_t(c)]);
    StoreCurve(g, c, &d.response);
    FixCodeZero(&d.response, c);
    d.response.first_code[size_t(c)] = first[size_t(c)];
    d.response.last_code[size_t(c)] = last[size_t(c)];
    d.chi2 += eq[size_t(c)].Evaluate(Curve(d.response, c));
    free += last[size_t(c)] - first[size_t(c)];
  }
  d.parameters = free / 3;
  d.bic = d.chi2 + double(free) * log_n;
  out.push_back(d);
  if (options.model == "debevec") return out;
  // Families and channels are independent fits: one task each, on every core.
  const std::vector<Family> families = FamiliesFor(options.model);
  std::vector<std::array<FamilyResult, 3>> results(families.size());
  ParallelFor(0, int64_t(families.size()) * 3, 1, [&](int64_t b, int64_t e, int) {
    for (int64_t task = b; task < e; ++task) {
      const Family& family = families[size_t(task / 3)];
      const int c = int(task % 3);
      // Gauss–Newton from the kFamilyStartsRefined starts of lowest cost.
      std::vector<std::pair<double, std::vector<double>>> starts;
      for (auto& p0 : FamilyStarts(family, Curve(d.response, c), first[size_t(c)], last[size_t(c)])) {
        VectorXd g0;
        if (FamilyCurve(family, p0, &g0)) starts.push_back({eq[size_t(c)].Evaluate(g0), std::move(p0)});
      }
      std::sort(starts.begin(), starts.end(),
                [](const auto& a, const auto& b) { return a.first < b.first; });
      if (starts.size() > size_t(kFamilyStartsRefined)) starts.resize(size_t(kFamilyStartsRefined));
      FamilyResult& best = results[size_t(task / 3)][size_t(c)];
      for (const auto& start : starts) {
        FamilyResult r = FitFamily(family, eq[size_t(c)], start.second);
        if (r.cost < best.cost) best = r;
      }
    }
  });
  for (size_t f = 0; f < families.size(); ++f) {
    const Family& family = families[f];
    ModelFit m;
    m.model = family.name;
    m.parameters = family.parameters;
    m.response = d.response;
    m.response.model = family.name;
    bool ok = true;
    for (int c = 0; c < 3 && ok; ++c) {
      const FamilyResult& best = results[f][size_t(c)];
      if (!std::isfinite(best.cost)) {
        ok = false;
        break;
      }
      m.params[size_t(c)] = best.p;
      if (family.name == "loglogistic" || family.name == "offsetgamma") {
        m.params[size_t(c)] = {std::exp(best.p[0]), std::exp(best.p[1])};
      }
      m.monotone = m.monotone && IsMonotone(best.g);
      StoreCurve(best.g, c, &m.response);
      m.chi2 += best.cost;
    }
    if (!ok) continue;
    m.bic = m.chi2 + 3.0 * m.parameters * log_n;
    out.push_back(m);
  }
  return out;
}

// The model to use. Families first: among those whose χ² is within kSimplestFamilyTolerance of
// the best family's, the one with the fewest parameters (then the lower χ²) — Occam, because where
// brackets leave the curve ambiguous a flexible family drifts along the ambiguity at no cost in χ².
// That family is used when its χ² is also within kFamilyChi2Tolerance of the free-form curve's;
// otherwise the free-form curve is, if the brackets identify it (anchors, or exposure ratios
// that are not all powers of one), else the family still. `option` restricts the candidates.
const ModelFit* Choose(const std::vector<ModelFit>& candidates, const std::string& option,
                       bool debevec_identified) {
  const ModelFit& debevec = candidates.front();
  if (option == "debevec") return &debevec;
  const ModelFit* best = nullptr;
  for (const ModelFit& m : candidates) {
    if (&m == &debevec || !m.monotone || !Requested(option, m.model)) continue;
    if (best == nullptr || m.chi2 < best->chi2) best = &m;
  }
  if (best == nullptr) return &debevec;
  const ModelFit* simplest = best;
  for (const ModelFit& m : candidates) {
    if (&m == &debevec || !m.monotone || !Requested(option, m.model)) continue;
    if (m.chi2 > (1 + kSimplestFamilyTolerance) * best->chi2) continue;
    if (m.parameters < simplest->parameters ||
        (m.parameters == simplest->parameters && m.chi2 < simplest->chi2)) {
      simplest = &m;
    }
  }
  if (option != "auto") return simplest;
  if (!debevec_identified || simplest->chi2 <= (1 + kFamilyChi2Tolerance) * debevec.chi2) return simplest;
  return &debevec;
}

// True when every exposure ratio of every bracket is a whole power of the smallest one (within
// 2 %): then any ripple of ln x periodic with that ratio's log fits the brackets as well as the
// truth does (Grossberg & Nayar, PAMI 2003), and only anchors or a parametric family can decide.
bool EqualRatioAmbiguity(const std::vector<std::vector<double>>& lists) {
  constexpr double kCommensurateTolerance = 0.02;
  double smallest = std::numeric_limits<double>::infinity();
  for (const auto& list : lists) {
    for (size_t j = 1; j < list.size(); ++j) smallest = std::min(smallest, list[j] - list[j - 1]);
  }
  if (!std::isfinite(smallest) || !(smallest > 0)) return false;
  for (const auto& list : lists) {
    for (size_t j = 1; j < list.size(); ++j) {
      const double k = (list[j] - list[j - 1]) / smallest;
      if (std::abs(k - std::round(k)) > kCommensurateTolerance) return false;
    }
  }
  return true;
}

}  // namespace

StatusOr<ResponseFit> EstimateResponse(const SampleSet& set, const ResponseOptions& options) {
  REFLCAP_RETURN_IF_ERROR(options.Validate());
  const auto start = std::chrono::steady_clock::now();
  ResponseFit fit;
  std::array<std::array<double, kCodeCount>, 3> weight;
  for (auto& w : weight) w = HatWeights();
  std::array<NormalEquations, 3> eq;
  std::vector<ModelFit> candidates;
  std::array<SensorNoise, 3> noise{};  // quantisation alone until the first estimate
  bool anchored = false;
  for (const auto& a : set.anchored) anchored = anchored || !a.empty();
  const bool identified = anchored || !EqualRatioAmbiguity(set.log_exposures);
  for (int it = 0; it < options.iterations; ++it) {
    std::array<int, 3> first{}, last{};
    size_t total_obs = 0;
    for (int c = 0; c < 3; ++c) {
      eq[size_t(c)] = Accumulate(set.samples[size_t(c)], set.log_exposures, weight[size_t(c)]);
      const size_t before = eq[size_t(c)].observations;
      AccumulateAnchored(set.anchored[size_t(c)], set.log_exposures, weight[size_t(c)], &eq[size_t(c)]);
      fit.anchored_observations[size_t(c)] = eq[size_t(c)].observations - before;
      first[size_t(c)] = last[size_t(c)] = -1;
      for (int z = 0; z < kCodeCount; ++z) {
        if (eq[size_t(c)].A(z, z) > 0) {
          if (first[size_t(c)] < 0) first[size_t(c)] = z;
          last[size_t(c)] = z;
        }
      }
      if (first[size_t(c)] < 0 || last[size_t(c)] - first[size_t(c)] < 2) {
        return FailedPreconditionError(
            "channel ", "RGB"[c], ": no pixel is measured in two exposures between black (code 0) "
            "and clipped (code 255): every bracket is clipped or dark, or too few exposures overlap");
      }
      total_obs += eq[size_t(c)].observations;
    }
    const double log_n = std::log(double(std::max<size_t>(total_obs, 2)));
    candidates = FitCandidates(eq, first, last, options, log_n);
    // χ² does not depend on the scale, so the choice comes first; the clip normalisation (costly:
    // a probit fit over the near-clip pixels) is needed now for the free-form and the chosen
    // curves (noise, weights), for every candidate only for the final report.
    const ModelFit* chosen = Choose(candidates, options.model, identified);
    const bool final_round = it + 1 == options.iterations;
    for (ModelFit& m : candidates) {
      m.response.noise = noise;
      if (!final_round && &m != chosen && &m != &candidates.front()) continue;
      for (int c = 0; c < 3; ++c) {
        NormaliseAtClip(set.samples[size_t(c)], set.log_exposures, weight[size_t(c)], c, &m.response,
                        &m.clip_log_threshold[size_t(c)]);
      }
    }
    InverseResponse next = chosen->response;
    // Noise from the free-form curve's residuals (it fits the exposures' mutual consistency best,
    // even where brackets leave it ambiguous: every curve of the ambiguity fits them alike), then
    // the weights the chosen curve implies. A weights update that would leave a channel almost
    // without codes (a poor early noise estimate) is not taken.
    for (int c = 0; c < 3; ++c) {
      next.noise[size_t(c)] = EstimateNoise(set.samples[size_t(c)], set.log_exposures,
                                            candidates.front().response, c, weight[size_t(c)]);
      const auto updated = NoiseWeights(next, c);
      const long codes = std::count_if(updated.begin(), updated.end(), [](double w) { return w > 0; });
      if (codes >= kMinWeightedCodes) weight[size_t(c)] = updated;
    }
    noise = next.noise;
    for (ModelFit& m : candidates) m.response.noise = noise;
    fit.iterations = it + 1;
  }
  fit.candidates = candidates;
  const ModelFit* chosen = Choose(fit.candidates, options.model, identified);
  fit.debevec_identified = identified;
  fit.response = chosen->response;
  for (int c = 0; c < 3; ++c) {
    fit.samples[size_t(c)] = set.samples[size_t(c)].size();
    fit.observations[size_t(c)] = eq[size_t(c)].observations;
    const double dof = double(eq[size_t(c)].observations) - double(eq[size_t(c)].samples) -
                       double(chosen->parameters);
    fit.reduced_chi2[size_t(c)] = dof > 0 ? eq[size_t(c)].Evaluate(Curve(fit.response, c)) / dof : 0;
  }
  fit.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return fit;
}

ResponseError CompareResponse(const InverseResponse& response, const std::vector<double>& x_of_code,
                              int first, int last) {
  ResponseError e;
  std::vector<double> all;
  for (int c = 0; c < 3; ++c) {
    std::vector<double> d;
    for (int z = first; z <= last; ++z) {
      if (!(x_of_code[size_t(z)] > 0)) continue;
      d.push_back(response.log_x[size_t(c)][size_t(z)] - std::log(x_of_code[size_t(z)]));
    }
    if (d.empty()) continue;
    std::vector<double> sorted = d;
    std::nth_element(sorted.begin(), sorted.begin() + long(sorted.size() / 2), sorted.end());
    const double offset = sorted[sorted.size() / 2];
    std::vector<double> shape, absolute;
    for (double v : d) {
      shape.push_back(std::abs(v - offset));
      absolute.push_back(std::abs(v));
    }
    auto median = [](std::vector<double> v) {
      std::nth_element(v.begin(), v.begin() + long(v.size() / 2), v.end());
      return v[v.size() / 2];
    };
    e.scale[size_t(c)] = std::exp(offset);
    e.max_abs_log[size_t(c)] = *std::max_element(shape.begin(), shape.end());
    e.median_abs_log[size_t(c)] = median(shape);
    e.max_abs_log_absolute[size_t(c)] = *std::max_element(absolute.begin(), absolute.end());
    e.median_abs_log_absolute[size_t(c)] = median(absolute);
    all.insert(all.end(), shape.begin(), shape.end());
    e.max_over_channels = std::max(e.max_over_channels, e.max_abs_log[size_t(c)]);
  }
  if (!all.empty()) {
    std::nth_element(all.begin(), all.begin() + long(all.size() / 2), all.end());
    e.median_over_channels = all[all.size() / 2];
  }
  return e;
}

}  // namespace reflcap::radiometry
