#pragma once
// Shared driver of the CPU-side fitters (batched, scalar, Ceres): splits a chunk into tasks of
// consecutive texels over ParallelFor, prepares each texel's problems (problem.h), lets the
// backend solve them, and folds the results into TexelFits. Per-worker workspaces are sized
// before the parallel loop, so the per-texel work allocates nothing (backends keep to that).
#include <memory>
#include <vector>

#include "engine/fit/fitter.h"
#include "engine/fit/lm.h"
#include "engine/fit/problem.h"

namespace reflcap::fit::internal {

// Texels per ParallelFor task: enough problems to keep 16 lanes refilled (3 x 256 = 768), few
// enough that 2 workers balance on small chunks.
constexpr int kTexelsPerTask = 256;
// A chunk too small to give every worker kMinTasksPerWorker tasks of kTexelsPerTask is cut finer,
// down to kMinTexelsPerTask (48 problems: three refills of 16 lanes). The k-fold refits of the
// material clusters fit a few hundred texels per call, one call per store chunk and fold: at 256
// texels a task, 3 of 16 workers had work.
constexpr int kMinTasksPerWorker = 4;
constexpr int kMinTexelsPerTask = 16;
// Texels per task for a chunk of `texels` on `workers` workers (kTexelsPerTask at most).
int TexelsPerTask(uint32_t texels, int workers);

// InvalidArgument unless chunk.offsets describe chunk.samples (texel_count + 1 non-decreasing
// entries from 0 to samples.size()); every backend checks this before fitting.
Status ValidateChunk(const TexelSampleChunk& chunk);

class FitterBase : public Fitter {
 public:
  explicit FitterBase(int threads) : threads_(threads) {}
  Status Fit(const TexelSampleChunk& chunk, const FitOptions& options,
             std::vector<TexelFit>* results) final;

 protected:
  struct Workspace {
    ProblemArena arena;
    std::vector<PreparedProblem> problems;
    std::vector<SolvedProblem> solved;
    // Channel retries (problem.h PrepareChannelRetries): the problems, their solutions, and the
    // index in `problems` each one retries.
    std::vector<PreparedProblem> retry;
    std::vector<SolvedProblem> retry_solved;
    std::vector<int> retry_problem;
    std::shared_ptr<void> backend;  // the backend's own per-worker state
  };
  // Grows the backend's per-worker state for problems of up to `max_samples` samples and
  // `max_problems` problems per task (called before the parallel loop).
  virtual void Reserve(Workspace* w, const ProblemLayout& layout, size_t max_samples,
                       size_t max_problems) {}
  // Solves problems[0..count) into solved[0..count).
  virtual void Solve(Workspace* w, const FitOptions& options, const LmSettings& settings,
                     const PreparedProblem* problems, int count, SolvedProblem* solved) = 0;
  int threads() const;

 private:
  int threads_;
  std::vector<Workspace> workspaces_;
};

std::unique_ptr<Fitter> CreateBatchedFitter(int threads);
std::unique_ptr<Fitter> CreateCeresFitter(int threads);

}  // namespace reflcap::fit::internal
