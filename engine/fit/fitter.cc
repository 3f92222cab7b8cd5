#include "engine/fit/fitter.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "engine/core/parallel.h"
#include "engine/fit/fitter_base.h"
#include "engine/fit/vulkan_fitter.h"

namespace reflcap::fit {

const char* BackendName(Backend backend) {
  switch (backend) {
    case Backend::kCpu: return "cpu";
    case Backend::kCeres: return "ceres";
    case Backend::kVulkan: return "vulkan";
  }
  return "?";
}

StatusOr<Backend> ParseBackend(const std::string& name) {
  if (name == "cpu") return Backend::kCpu;
  if (name == "ceres") return Backend::kCeres;
  if (name == "vulkan") return Backend::kVulkan;
  return InvalidArgumentError("--backend: unknown backend \"", name, "\" (cpu, ceres, vulkan)");
}

const char* FitStatusName(FitStatus status) {
  switch (status) {
    case FitStatus::kConverged: return "converged";
    case FitStatus::kMaxIterations: return "max_iterations";
    case FitStatus::kSingular: return "singular";
    case FitStatus::kTooFewSamples: return "too_few_samples";
    case FitStatus::kUnidentifiableLobe: return "unidentifiable_lobe";
    case FitStatus::kNonFiniteInput: return "non_finite_input";
  }
  return "?";
}

FitStatus CombineStatus(FitStatus a, FitStatus b) {
  auto severity = [](FitStatus s) {
    switch (s) {
      case FitStatus::kConverged: return 0;
      case FitStatus::kMaxIterations: return 1;
      case FitStatus::kSingular: return 2;
      case FitStatus::kUnidentifiableLobe: return 3;
      case FitStatus::kTooFewSamples: return 4;
      case FitStatus::kNonFiniteInput: return 5;
    }
    return 5;
  };
  return severity(a) >= severity(b) ? a : b;
}

const char* InitSchemeName(InitScheme init) { return init == InitScheme::kSeed ? "seed" : "fixed"; }

StatusOr<InitScheme> ParseInitScheme(const std::string& name) {
  if (name == "seed") return InitScheme::kSeed;
  if (name == "fixed") return InitScheme::kFixed;
  return InvalidArgumentError("--init: unknown start \"", name, "\" (seed, fixed)");
}

const char* LossKindName(LossKind loss) {
  switch (loss) {
    case LossKind::kNone: return "none";
    case LossKind::kHuber: return "huber";
    case LossKind::kCauchy: return "cauchy";
  }
  return "?";
}

StatusOr<LossKind> ParseLossKind(const std::string& name) {
  if (name == "none") return LossKind::kNone;
  if (name == "huber") return LossKind::kHuber;
  if (name == "cauchy") return LossKind::kCauchy;
  return InvalidArgumentError("--loss: unknown loss \"", name, "\" (none, huber, cauchy)");
}

Status FitOptions::Validate() const {
  REFLCAP_RETURN_IF_ERROR((ProblemLayout{lobe_model, lobes}.Validate()));
  REFLCAP_RETURN_IF_ERROR(lobe_transfer.Validate());
  REFLCAP_RETURN_IF_ERROR(clusters.Validate());
  REFLCAP_RETURN_IF_ERROR(albedo_fill.Validate());
  if (!(loss_scale > 0) || !std::isfinite(loss_scale)) {
    return InvalidArgumentError("--loss-scale: must be positive, got ", loss_scale);
  }
  if (max_iterations < 1 || max_iterations > 10000) {
    return InvalidArgumentError("--max-iterations: must be in [1, 10000], got ", max_iterations);
  }
  if (first_stage_iterations < 1 || first_stage_iterations > 10000) {
    return InvalidArgumentError("first_stage_iterations must be in [1, 10000], got ",
                                first_stage_iterations);
  }
  if (!(start_exponent >= brdf::kMinExponent && start_exponent <= brdf::kMaxExponent)) {
    return InvalidArgumentError("start exponent must be in [", brdf::kMinExponent, ", ",
                                brdf::kMaxExponent, "], got ", start_exponent);
  }
  if (min_samples < 1) return InvalidArgumentError("min_samples must be >= 1, got ", min_samples);
  if (!(min_cos_theta >= 0 && min_cos_theta < 1)) {
    return InvalidArgumentError("min_cos_theta must be in [0, 1), got ", min_cos_theta);
  }
  if (!(highlight_cone_deg > 0 && highlight_cone_deg <= 90)) {
    return InvalidArgumentError("highlight_cone_deg must be in (0, 90], got ", highlight_cone_deg);
  }
  if (!(evidence_sigmas >= 0) || !std::isfinite(evidence_sigmas)) {
    return InvalidArgumentError("evidence_sigmas must be >= 0, got ", evidence_sigmas);
  }
  for (double t : {step_tolerance, cost_tolerance, gradient_tolerance}) {
    if (!(t >= 0 && t < 1)) return InvalidArgumentError("LM tolerances must be in [0, 1), got ", t);
  }
  if (threads < 0) return InvalidArgumentError("--threads: must be >= 0, got ", threads);
  return OkStatus();
}

std::string FitOptions::ToString() const {
  std::ostringstream out;
  out << "FitOptions{lobes=" << lobes << ", lobe_model=" << LobeModelName(lobe_model)
      << ", init=" << InitSchemeName(init) << ", loss=" << LossKindName(loss)
      << ", loss_scale=" << loss_scale << ", max_iterations=" << max_iterations
      << ", first_stage_iterations=" << first_stage_iterations
      << ", start_exponent=" << start_exponent << ", min_samples=" << min_samples
      << ", min_cos_theta=" << min_cos_theta << ", highlight_cone_deg=" << highlight_cone_deg
      << ", evidence_sigmas=" << evidence_sigmas << ", step_tolerance=" << step_tolerance
      << ", cost_tolerance=" << cost_tolerance << ", gradient_tolerance=" << gradient_tolerance
      << ", channel_retry=" << (channel_retry ? "on" : "off") << ", threads=" << threads << "}";
  return out.str();
}

LmSettings MakeLmSettings(const FitOptions& options) {
  LmSettings s;
  s.max_iterations = options.max_iterations;
  s.first_stage_iterations = options.first_stage_iterations;
  s.step_tolerance = options.step_tolerance;
  s.cost_tolerance = options.cost_tolerance;
  s.gradient_tolerance = options.gradient_tolerance;
  return s;
}

LmSettings StageSettings(const LmSettings& settings, int stage, int num_stages) {
  LmSettings s = settings;
  if (num_stages == 2 && stage == 0) s.max_iterations = settings.first_stage_iterations;
  return s;
}

double LobePeak(const brdf::LobeParams& lobe) {
  return lobe.cz > 0 ? std::pow(double(lobe.cz), double(lobe.n)) : 0.0;
}

namespace internal {

int FitterBase::threads() const { return threads_ > 0 ? threads_ : HardwareThreads(); }

Status ValidateChunk(const TexelSampleChunk& chunk) {
  const uint32_t texels = chunk.texel_count;
  if (chunk.offsets.size() != size_t(texels) + 1 || chunk.offsets[0] != 0 ||
      chunk.offsets[texels] != chunk.samples.size()) {
    return InvalidArgumentError("sample chunk at texel ", chunk.first_texel,
                                ": offsets do not describe its ", chunk.samples.size(), " samples");
  }
  for (uint32_t t = 0; t < texels; ++t) {
    if (chunk.offsets[t + 1] < chunk.offsets[t]) {
      return InvalidArgumentError("sample chunk at texel ", chunk.first_texel,
                                  ": offsets decrease at texel ", t);
    }
  }
  return OkStatus();
}

int TexelsPerTask(uint32_t texels, int workers) {
  const uint64_t tasks = uint64_t(std::max(workers, 1)) * kMinTasksPerWorker;
  const uint64_t even = (uint64_t(texels) + tasks - 1) / tasks;
  return int(std::clamp<uint64_t>(even, kMinTexelsPerTask, kTexelsPerTask));
}

Status FitterBase::Fit(const TexelSampleChunk& chunk, const FitOptions& options,
                       std::vector<TexelFit>* results) {
  REFLCAP_RETURN_IF_ERROR(options.Validate());
  REFLCAP_RETURN_IF_ERROR(ValidateChunk(chunk));
  const uint32_t texels = chunk.texel_count;
  const ProblemLayout layout{options.lobe_model, options.lobes};
  const LmSettings settings = MakeLmSettings(options);
  const int workers = options.threads > 0 ? options.threads : threads();
  results->resize(texels);

  const int task_texels = TexelsPerTask(texels, workers);
  // Size every workspace for the largest task before the parallel loop.
  size_t max_task_samples = 0, max_samples = 0;
  for (uint32_t b = 0; b < texels; b += task_texels) {
    const uint32_t e = std::min<uint32_t>(texels, b + task_texels);
    max_task_samples = std::max<size_t>(max_task_samples, chunk.offsets[e] - chunk.offsets[b]);
  }
  for (uint32_t t = 0; t < texels; ++t) max_samples = std::max<size_t>(max_samples, chunk.SampleCount(t));
  const size_t max_problems = size_t(task_texels) * ProblemsPerTexel(layout.model);
  if (workspaces_.size() < size_t(workers)) workspaces_.resize(workers);
  for (Workspace& w : workspaces_) {
    w.arena.Reserve(3 * max_task_samples, max_samples);
    if (w.problems.size() < max_problems) w.problems.resize(max_problems);
    if (w.solved.size() < max_problems) w.solved.resize(max_problems);
    if (w.retry.size() < max_problems) {
      w.retry.resize(max_problems);
      w.retry_solved.resize(max_problems);
      w.retry_problem.resize(max_problems);
    }
    Reserve(&w, layout, max_samples, max_problems);
  }

  ParallelFor(
      0, texels, task_texels,
      [&](int64_t begin, int64_t end, int worker) {
        Workspace& w = workspaces_[worker];
        const int per_texel = ProblemsPerTexel(layout.model);
        size_t cursor = 0;
        int count = 0;
        for (int64_t t = begin; t < end; ++t) {
          PrepareTexel(options, layout, chunk.SamplesOf(uint32_t(t)), chunk.SampleCount(uint32_t(t)),
                       int(t), &w.arena, &cursor, &w.problems[count]);
          count += per_texel;
        }
        Solve(&w, options, settings, w.problems.data(), count, w.solved.data());
        if (options.channel_retry) {
          // Every texel's retries in one Solve call, then each keeps the better solution.
          int retries = 0;
          for (int i = 0; i < count; i += per_texel) {
            const int n = PrepareChannelRetries(&w.problems[i], &w.solved[i], per_texel,
                                                &w.retry[retries], &w.retry_problem[retries]);
            for (int r = retries; r < retries + n; ++r) w.retry_problem[r] += i;
            retries += n;
          }
          if (retries > 0) {
            Solve(&w, options, settings, w.retry.data(), retries, w.retry_solved.data());
            AdoptChannelRetries(w.retry_solved.data(), w.retry_problem.data(), retries,
                                w.solved.data());
          }
        }
        for (int i = 0; i < count; i += per_texel) {
          TexelFit& fit = (*results)[w.problems[i].texel];
          BeginTexel(layout.lobes, &fit);
          for (int p = 0; p < per_texel; ++p) FinishProblem(w.problems[i + p], w.solved[i + p], &fit);
        }
      },
      workers);
  return OkStatus();
}

namespace {

class ScalarFitter : public FitterBase {
 public:
  ScalarFitter(bool use_double, int threads) : FitterBase(threads), double_(use_double) {}
  Backend backend() const override { return Backend::kCpu; }
  std::string device() const override {
    return StrCat("cpu scalar reference (", double_ ? "double" : "float", "), ", threads(), " threads");
  }

 protected:
  void Solve(Workspace*, const FitOptions& options, const LmSettings& settings,
             const PreparedProblem* problems, int count, SolvedProblem* solved) override {
    for (int i = 0; i < count; ++i) {
      solved[i] = double_ ? SolveScalar<double>(problems[i], settings, options.loss)
                          : SolveScalar<float>(problems[i], settings, options.loss);
    }
  }

 private:
  bool double_;
};

}  // namespace
}  // namespace internal

std::unique_ptr<Fitter> CreateScalarFitter(bool use_double, int threads) {
  return std::make_unique<internal::ScalarFitter>(use_double, threads);
}

StatusOr<std::unique_ptr<Fitter>> CreateFitter(Backend backend, int threads,
                                               const std::string& device) {
  VulkanFitterOptions vulkan;
  vulkan.device = device;
  return CreateFitter(backend, threads, vulkan);
}

StatusOr<std::unique_ptr<Fitter>> CreateFitter(Backend backend, int threads,
                                               const VulkanFitterOptions& vulkan) {
  switch (backend) {
    case Backend::kCpu: return internal::CreateBatchedFitter(threads);
    case Backend::kCeres: return internal::CreateCeresFitter(threads);
    case Backend::kVulkan: {
      VulkanFitterOptions options = vulkan;
      options.threads = threads;
      REFLCAP_ASSIGN_OR_RETURN(std::unique_ptr<VulkanFitter> fitter, CreateVulkanFitter(options));
      return std::unique_ptr<Fitter>(std::move(fitter));
    }
  }
  return InvalidArgumentError("unknown backend");
}

}  // namespace reflcap::fit
