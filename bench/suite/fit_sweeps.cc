// The fit sweeps of `reflcap bench` (sweeps.h): fits/s against samples per texel, speed against
// error, and the seed's two-stage start against the fixed start.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <ctime>
#include <limits>

#include "bench/suite/sweeps.h"
#ifdef REFLCAP_HAVE_DEVICE_PEAK
#include "bench/gpu/device_peak.h"
#endif
#include "engine/fit/vulkan_fitter.h"
#include "engine/core/log.h"
#include "engine/fit/synthetic_samples.h"

namespace reflcap::benchsuite {
namespace {

// Seed of the ground-truth texels and their samples (fit_bench.cc uses the same).
constexpr uint64_t kDataSeed = 31;
// Held-out directions per texel for the BRDF-space holdout PSNR, and their seed.
constexpr int kHoldoutSamples = 32;
constexpr uint64_t kHoldoutSeed = 977;

struct FitData {
  int samples = 0;
  std::vector<brdf::BrdfParams> truth;
  TexelSampleChunk chunk;    // noisy training samples
  TexelSampleChunk holdout;  // noise-free held-out directions
};

FitData MakeFitData(int texels, int samples) {
  FitData d;
  d.samples = samples;
  const auto all = fit::SynthMaterialTexels(texels * 6 / 5 + 6, kDataSeed);
  for (size_t t = 0; t < all.size() && int(d.truth.size()) < texels; ++t) {
    if (t % fit::kSynthMaterialCount != 0) d.truth.push_back(all[t]);  // skip matte: no lobe
  }
  fit::SyntheticSampleOptions so;
  so.samples_per_texel = samples;
  so.near_mirror_samples = std::max(4, samples * 12 / 100);
  so.seed = kDataSeed;
  d.chunk = fit::MakeSyntheticChunk(d.truth, so);
  fit::SyntheticSampleOptions ho;
  ho.samples_per_texel = kHoldoutSamples;
  ho.near_mirror_samples = std::max(2, kHoldoutSamples * 12 / 100);
  ho.noise = 0;
  ho.seed = kHoldoutSeed;
  d.holdout = fit::MakeSyntheticChunk(d.truth, ho);
  return d;
}

double Median(std::vector<double> v) {
  if (v.empty()) return std::numeric_limits<double>::quiet_NaN();
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

Accuracy Evaluate(const FitData& d, const std::vector<fit::TexelFit>& fits) {
  Accuracy a;
  std::vector<double> rho, peak, n;
  double converged = 0, iterations = 0, sum_sq = 0;
  int64_t count = 0;
  for (size_t t = 0; t < fits.size(); ++t) {
    const brdf::BrdfParams& p = fits[t].params;
    a.all_finite = a.all_finite && brdf::IsFinite(p);
    converged += fits[t].status == fit::FitStatus::kConverged;
    iterations += fits[t].iterations;
    for (int c = 0; c < 3; ++c) {
      rho.push_back(std::abs(p.rho_d[c] / d.truth[t].rho_d[c] - 1));
      if (p.num_lobes > 0 && !fits[t].lambert_only) {
        peak.push_back(std::abs(fit::LobePeak(p.lobes[0][c]) / fit::LobePeak(d.truth[t].lobes[0][c]) - 1));
        n.push_back(std::abs(p.lobes[0][c].n / d.truth[t].lobes[0][c].n - 1));
      } else {
        // A Lambert-only fit of a lobed texel: the lobe is entirely missing.
        peak.push_back(1.0);
        n.push_back(1.0);
      }
    }
    // Holdout: this texel's held-out values, scaled by its brightest truth value.
    const BrdfSample* s = d.holdout.SamplesOf(uint32_t(t));
    const uint64_t ns = d.holdout.SampleCount(uint32_t(t));
    double scale = 0;
    for (uint64_t i = 0; i < ns; ++i) {
      for (int c = 0; c < 3; ++c) scale = std::max<double>(scale, s[i].value[c]);
    }
    if (scale <= 0) continue;
    for (uint64_t i = 0; i < ns; ++i) {
      const Vec3f f = brdf::EvalRgb(p, Vec3f(s[i].wi[0], s[i].wi[1], s[i].wi[2]),
                                    Vec3f(s[i].wo[0], s[i].wo[1], s[i].wo[2]));
      for (int c = 0; c < 3; ++c) {
        const double e = (double(f[c]) - s[i].value[c]) / scale;
        sum_sq += e * e;
        ++count;
      }
    }
  }
  const double texels = std::max<size_t>(1, fits.size());
  a.median_rel_error_rho_d = Median(rho);
  a.median_rel_error_n = Median(n);
  a.median_rel_error_peak = Median(peak);
  a.converged_fraction = converged / texels;
  a.mean_iterations = iterations / texels;
  // An exact fit would give infinite PSNR; 1e-20 caps it at 200 dB.
  a.holdout_psnr_db = count > 0 ? -10 * std::log10(std::max(sum_sq / count, 1e-20))
                                : std::numeric_limits<double>::quiet_NaN();
  return a;
}

struct Timed {
  Status status;
  std::vector<fit::TexelFit> fits;
  int repetitions = 0;
  double seconds = 0;      // wall, per repetition
  double cpu_seconds = 0;  // process CPU, per repetition
};

// Fits once (the result that is verified), then repeats until min_seconds have passed.
Timed TimeFits(fit::Fitter& fitter, const FitData& d, const fit::FitOptions& options,
               double min_seconds) {
  Timed r;
  r.status = fitter.Fit(d.chunk, options, &r.fits);
  if (!r.status.ok()) return r;
  std::vector<fit::TexelFit> scratch;
  const auto start = std::chrono::steady_clock::now();
  const std::clock_t cpu_start = std::clock();
  double elapsed = 0;
  do {
    r.status = fitter.Fit(d.chunk, options, &scratch);
    if (!r.status.ok()) return r;
    ++r.repetitions;
    elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  } while (elapsed < min_seconds);
  r.seconds = elapsed / r.repetitions;
  r.cpu_seconds = double(std::clock() - cpu_start) / CLOCKS_PER_SEC / r.repetitions;
  return r;
}

std::string Pct(double v) { return StrCat(std::round(v * 1e4) / 1e2, " %"); }

// The strict bars of the fit sweep; "" when met.
std::string CheckStrict(const Accuracy& a, const VerifyBounds& b) {
  if (!a.all_finite) return "non-finite parameters";
  if (!(a.converged_fraction >= b.min_converged_fraction)) {
    return StrCat("converged fraction ", Pct(a.converged_fraction), " < ",
                  Pct(b.min_converged_fraction));
  }
  if (!(a.median_rel_error_rho_d <= b.max_median_rel_error)) {
    return StrCat("median rel. error of rho_d ", Pct(a.median_rel_error_rho_d), " > ",
                  Pct(b.max_median_rel_error));
  }
  if (!(a.median_rel_error_n <= b.max_median_rel_error)) {
    return StrCat("median rel. error of n ", Pct(a.median_rel_error_n), " > ",
                  Pct(b.max_median_rel_error));
  }
  if (!(a.median_rel_error_peak <= b.max_median_rel_error)) {
    return StrCat("median rel. error of the lobe peak ", Pct(a.median_rel_error_peak), " > ",
                  Pct(b.max_median_rel_error));
  }
  return {};
}

// The sanity bars of the capped / fixed-start sweeps; "" when met.
std::string CheckSanity(const Accuracy& a, const VerifyBounds& b) {
  if (!a.all_finite) return "non-finite parameters";
  if (!(a.median_rel_error_rho_d <= b.max_sanity_rel_error_rho_d)) {
    return StrCat("median rel. error of rho_d ", Pct(a.median_rel_error_rho_d), " > ",
                  Pct(b.max_sanity_rel_error_rho_d));
  }
  if (!std::isfinite(a.median_rel_error_n) || !std::isfinite(a.holdout_psnr_db)) {
    return "non-finite error";
  }
  return {};
}

fit::FitOptions BaseOptions(int threads) {
  fit::FitOptions o;  // seed start + two-stage LM, aniso, one lobe: the defaults of `reflcap fit`
  o.threads = threads;
  return o;
}

}  // namespace

std::vector<FitRecord> RunFitSweep(const FitSweepConfig& config, FitterSet& fitters,
                                   const VerifyBounds& bounds, const PointDone& done) {
  std::vector<FitRecord> records;
  for (int samples : config.samples) {
    const FitData d = MakeFitData(config.texels, samples);
    for (auto& [backend, fitter] : fitters.fitters) {
      if (backend == fit::Backend::kCeres && samples > config.ceres_max_samples) continue;
      FitRecord r;
      r.backend = fit::BackendName(backend);
      r.samples_per_texel = samples;
      r.texels = int(d.truth.size());
      r.fits = 3 * int64_t(d.truth.size());
      const Timed t = TimeFits(*fitter, d, BaseOptions(fitters.threads), config.min_seconds);
      if (!t.status.ok()) {
        r.invalid_reason = StrCat("fit failed: ", t.status.ToString());
      } else {
        r.accuracy = Evaluate(d, t.fits);
        r.repetitions = t.repetitions;
        r.seconds = t.seconds;
        r.fits_per_second = r.fits / std::max(t.seconds, 1e-12);
        r.fits_per_cpu_second = r.fits / std::max(t.cpu_seconds, 1e-12);
#ifdef REFLCAP_HAVE_DEVICE_PEAK
        if (const auto* vk = dynamic_cast<const fit::VulkanFitter*>(fitter.get())) {
          // The last repetition's residual evaluations (every repetition does the same work).
          const fit::ProblemLayout layout{BaseOptions(0).lobe_model, BaseOptions(0).lobes};
          r.gflops = double(vk->last_stats().residual_evaluations) *
                     bench::FitFlopsPerResidualEvaluation(layout.NumParams()) /
                     std::max(t.seconds, 1e-12) * 1e-9;
          if (fitters.peak_gflops > 0) r.peak_fraction = r.gflops / fitters.peak_gflops;
        }
#endif
        r.invalid_reason = CheckStrict(r.accuracy, bounds);
        r.valid = r.invalid_reason.empty();
      }
      REFLCAP_LOG(kInfo) << "bench fit: " << r.backend << ", " << samples << " samples: "
                         << std::lround(r.fits_per_second) << " fits/s, converged "
                         << Pct(r.accuracy.converged_fraction)
                         << (r.valid ? "" : " — INVALID: " + r.invalid_reason);
      records.push_back(std::move(r));
      if (done) done();
    }
  }
  return records;
}

std::vector<SpeedErrorRecord> RunSpeedErrorSweep(const SpeedErrorConfig& config,
                                                 FitterSet& fitters, const VerifyBounds& bounds,
                                                 const PointDone& done) {
  std::vector<SpeedErrorRecord> records;
  const FitData d = MakeFitData(config.texels, config.samples);
  for (auto& [backend, fitter] : fitters.fitters) {
    for (const auto& [max_iterations, tolerance] : config.points) {
      SpeedErrorRecord r;
      r.backend = fit::BackendName(backend);
      r.max_iterations = max_iterations;
      r.tolerance = tolerance;
      r.samples_per_texel = config.samples;
      r.texels = int(d.truth.size());
      fit::FitOptions options = BaseOptions(fitters.threads);
      options.max_iterations = max_iterations;
      options.step_tolerance = tolerance;
      options.cost_tolerance = tolerance;
      const Timed t = TimeFits(*fitter, d, options, config.min_seconds);
      if (!t.status.ok()) {
        r.invalid_reason = StrCat("fit failed: ", t.status.ToString());
      } else {
        r.accuracy = Evaluate(d, t.fits);
        r.seconds = t.seconds;
        r.fits_per_second = 3.0 * d.truth.size() / std::max(t.seconds, 1e-12);
        r.fits_per_cpu_second = 3.0 * d.truth.size() / std::max(t.cpu_seconds, 1e-12);
        r.invalid_reason = CheckSanity(r.accuracy, bounds);
        r.valid = r.invalid_reason.empty();
      }
      REFLCAP_LOG(kInfo) << "bench speed_vs_error: " << r.backend << ", max_iterations "
                         << max_iterations << ", tolerance " << tolerance << ": "
                         << std::lround(r.fits_per_second) << " fits/s, err n "
                         << Pct(r.accuracy.median_rel_error_n)
                         << (r.valid ? "" : " — INVALID: " + r.invalid_reason);
      records.push_back(std::move(r));
      if (done) done();
    }
  }
  MarkParetoFront(&records);
  return records;
}

std::vector<InitRecord> RunInitSweep(const InitConfig& config, FitterSet& fitters,
                                     const VerifyBounds& bounds, const PointDone& done) {
  std::vector<InitRecord> records;
  for (int samples : config.samples) {
    const FitData d = MakeFitData(config.texels, samples);
    for (auto& [backend, fitter] : fitters.fitters) {
      if (backend == fit::Backend::kCeres && samples > config.ceres_max_samples) continue;
      for (fit::InitScheme init : {fit::InitScheme::kSeed, fit::InitScheme::kFixed}) {
        InitRecord r;
        r.backend = fit::BackendName(backend);
        r.init = fit::InitSchemeName(init);
        r.samples_per_texel = samples;
        r.texels = int(d.truth.size());
        fit::FitOptions options = BaseOptions(fitters.threads);
        options.init = init;
        const Timed t = TimeFits(*fitter, d, options, config.min_seconds);
        if (!t.status.ok()) {
          r.invalid_reason = StrCat("fit failed: ", t.status.ToString());
        } else {
          r.accuracy = Evaluate(d, t.fits);
          r.seconds = t.seconds;
          r.fits_per_second = 3.0 * d.truth.size() / std::max(t.seconds, 1e-12);
          r.fits_per_cpu_second = 3.0 * d.truth.size() / std::max(t.cpu_seconds, 1e-12);
          r.invalid_reason = CheckSanity(r.accuracy, bounds);
          r.valid = r.invalid_reason.empty();
        }
        REFLCAP_LOG(kInfo) << "bench init_schemes: " << r.backend << ", " << r.init << ", "
                           << samples << " samples: converged "
                           << Pct(r.accuracy.converged_fraction) << ", err n "
                           << Pct(r.accuracy.median_rel_error_n) << ", "
                           << std::lround(r.fits_per_second) << " fits/s"
                           << (r.valid ? "" : " — INVALID: " + r.invalid_reason);
        records.push_back(std::move(r));
        if (done) done();
      }
    }
  }
  return records;
}

void MarkParetoFront(std::vector<SpeedErrorRecord>* records) {
  auto error = [](const SpeedErrorRecord& r) {
    return std::max(r.accuracy.median_rel_error_rho_d, r.accuracy.median_rel_error_n);
  };
  for (SpeedErrorRecord& a : *records) {
    a.pareto = a.valid;
    if (!a.valid) continue;
    for (const SpeedErrorRecord& b : *records) {
      if (&a == &b || !b.valid || b.backend != a.backend) continue;
      const bool no_worse = b.fits_per_second >= a.fits_per_second && error(b) <= error(a);
      const bool better = b.fits_per_second > a.fits_per_second || error(b) < error(a);
      if (no_worse && better) {
        a.pareto = false;
        break;
      }
    }
  }
}

}  // namespace reflcap::benchsuite
