#pragma once
// The Vulkan backend of the fitter (Backend::kVulkan): exactly the batched CPU path's algorithm
// with its LM on a Vulkan device (shaders/fit/lm_fit.comp). Vulkan-free: the CLI, the driver and
// the tests use it without Vulkan headers; builds without REFLCAP_ENABLE_VULKAN get stubs that
// say Unavailable.
//
// Division of labour per Fit call (one sample-store chunk):
//   CPU  PrepareTexel for every texel (problem.h: masking, normalisation, classification, start
//        values and stages — the same code every backend runs), on all cores;
//   GPU  the two-stage LM of every problem (lm.h's LmBegin / LmAdvance / Propose, the batched
//        kernel's normal equations, in float);
//   CPU  FinishProblem (rank test on the returned J^T J, standard deviations, status folding,
//        natural units), on all cores. The host keeps no copy of the residuals it laid out for
//        the device: the few texels whose finishing reads them (a Lambert-only fallback, a
//        channel retry) are prepared again.
// The chunk is cut into batches (at most max_batch_problems problems and max_batch_residuals
// residual records, and no binding over the device's maxStorageBufferRange); batch b + 1 is
// prepared and batch b - 1 finished on the CPU while the device runs batch b (two buffer sets).
//
// On the device, each invocation is a persistent lane that takes problems from a queue (sorted
// by residual count, so lanes that run in lock-step see similar sample counts), runs them to the
// end and takes the next. A dispatch runs at most `ticks` LM steps per lane, each one evaluation
// of the normal equations: ticks = (loop budget - 1 - reserve) / (max quads + 2) on
// lavapipe, whose budget of ~65,000 loop steps per invocation would otherwise cut long solves
// off silently (the sample loop takes four residuals, a quad, per pass), and at most kMaxResidualEvaluationsPerSubmit residual evaluations per submit
// everywhere, so no submission runs long. The LM state of unfinished problems stays in device
// buffers between dispatches; the host dispatches until no lane holds a problem.
//
// Problems the device cannot take — more residuals than one invocation's loop budget allows, or
// a texel too large for a batch — are solved on the CPU by the scalar float LM (lm.h, the same
// decisions), so every texel gets the CPU algorithm's answer whatever its size.
#include <cstdint>
#include <memory>
#include <string>

#include "engine/core/status.h"
#include "engine/fit/fitter.h"

namespace reflcap::fit {

// The device's LM kernel.
enum class VulkanFitKernel {
  kAuto,      // kClusters on a GPU whose compute shaders have subgroup shuffles, else kLanes
  kLanes,     // shaders/fit/lm_fit.comp: one problem per persistent invocation, LM state saved
              // between dispatches of a bounded number of steps (lavapipe's loop budget)
  kClusters,  // shaders/fit/lm_fit_cluster.comp: a cluster of invocations per problem, the
              // whole solve on chip in one dispatch (GPUs)
};
const char* VulkanFitKernelName(VulkanFitKernel kernel);
// The largest cluster the cluster kernel takes (lm_fit_cluster.comp kMaxCluster).
constexpr uint32_t kMaxVulkanFitClusterSize = 32;

// Whether the cluster kernel uses the device's exp and log (fit_model.glsl kFitNativeMath).
enum class NativeMath {
  kAuto,  // on a GPU yes, on a CPU device (lavapipe: its built-ins are ~13 % off near 1) no
  kOn,
  kOff,
};

struct VulkanFitterOptions {
  // Device: "" = automatic (a discrete GPU when there is one, else integrated, virtual, CPU),
  // a decimal index or a case-insensitive name substring (gpu::SelectDevice; `--device`).
  std::string device;
  // CPU worker threads for preparation and post-processing (0 = all hardware threads;
  // FitOptions::threads overrides it per call when > 0).
  int threads = 0;
  // Batch limits (0 = automatic: 32,768 problems and 2^21 residual records for kLanes; for
  // kClusters 2^20 problems and 2^25 records, within an eighth of the device's memory — a
  // sample-store chunk is usually one batch; both also kept within maxStorageBufferRange).
  // Small values make tests exercise many batches.
  uint32_t max_batch_problems = 0;
  uint64_t max_batch_residuals = 0;
  // Persistent invocations per dispatch (0 = automatic: kLanes 1,024 on a CPU device, 65,536 on a
  // GPU; kClusters 262,144, enough resident clusters to fill a large GPU; never more than the
  // batch's problems need).
  uint32_t lanes = 0;
  // Problems with more residuals than this are solved on the CPU (0 = as many as one
  // invocation's loop budget allows: ~259,800 on lavapipe, unlimited elsewhere). Tests lower it
  // to exercise the CPU route.
  uint32_t max_device_residuals = 0;
  // Upper bound on LM ticks per dispatch (0 = only the loop budget and the per-submit work cap
  // bound it). Tests use it to force many dispatches.
  uint32_t max_ticks_per_dispatch = 0;
  // false: never write the residual quads straight into mapped device memory, upload them
  // through the staging buffer as on a discrete GPU (tests exercise that path on lavapipe).
  bool map_device_records = true;
  // Bytes per piece of the staging ring that uploads the residual quads when they are not mapped
  // (0 = gpu::kStagingChunkBytes, 32 MiB). Tests lower it to send a small batch in many pieces.
  uint64_t staging_bytes = 0;
  // The LM kernel (`--vulkan-kernel`) and, for kClusters, the invocations per problem (0 =
  // automatic: 8; else a power of two up to 32 and at most the device's subgroup size) and the
  // device's exp/log.
  VulkanFitKernel kernel = VulkanFitKernel::kAuto;
  uint32_t cluster_size = 0;
  NativeMath native_math = NativeMath::kAuto;
  // `reflcap fit`'s chunks in flight (`--vulkan-chunks-in-flight`; fit_driver.h RunFit): 2 runs a
  // second fitter on the same device, so that one chunk's LM runs while the host prepares or
  // finishes the other (a store chunk is one batch: within a chunk nothing overlaps); 1 fits
  // one chunk after another. 0 = automatic: 2 on a GPU, 1 on a CPU device (lavapipe, whose
  // "device" is the host's own cores). Results are the same either way.
  uint32_t chunks_in_flight = 0;

  Status Validate() const;
};

// What the last Fit call did on the device (for tests and benchmarks).
struct VulkanFitStats {
  uint32_t batches = 0;
  uint64_t gpu_problems = 0;         // problems solved on the device
  uint64_t cpu_problems = 0;         // problems the device could not take (solved on the CPU)
  uint64_t trivial_problems = 0;     // problems without an LM stage (nothing to solve)
  uint32_t dispatches = 0;           // over all batches
  uint32_t max_dispatches_per_batch = 0;
  uint32_t min_ticks_per_dispatch = 0;  // the smallest tick count any batch ran with
  uint32_t max_residuals = 0;        // the largest residual count of a device problem
  uint32_t loop_budget = 0;          // MaxLoopIterationsPerInvocation of the device
  uint32_t max_device_residuals = 0; // residual count above which a problem stays on the CPU
  uint32_t lanes = 0;                // lanes (invocations) of the largest batch
  VulkanFitKernel kernel = VulkanFitKernel::kLanes;  // the kernel that ran
  uint32_t cluster_size = 0;         // invocations per problem (kClusters), else 0
  bool native_math = false;          // kClusters with the device's exp/log
  // The residual quads went straight into mapped device memory (host-visible device-local
  // memory: lavapipe, integrated GPUs, a discrete GPU's resizable BAR), not through staging.
  bool records_mapped = false;
  uint64_t residual_evaluations = 0; // model + normal-equation updates of one residual, on the
                                     // device (the LM's unit of work)
  double device_seconds = 0;         // wall-clock time of the device's batches (upload, LM,
                                     // download), overlapped with CPU preparation
  double prepare_seconds = 0;        // wall-clock time of the host's PrepareTexel passes
  // Of those passes, summed over the worker threads: PrepareTexel itself, and laying its
  // residuals out for the device and for FinishProblem (the device quads, into mapped device
  // memory when records_mapped; and the CPU route's solves). Which of the two sets
  // prepare_seconds on a GPU.
  double prepare_texel_thread_seconds = 0;
  double prepare_layout_thread_seconds = 0;
  double finish_seconds = 0;         // wall-clock time of the host's FinishProblem passes
  // Texels prepared a second time while finishing, for their residuals (which the host does not
  // keep): a Lambert-only fallback or a channel retry reads them.
  uint64_t reprepared_texels = 0;
};

class VulkanFitter : public Fitter {
 public:
  virtual const VulkanFitStats& last_stats() const = 0;
  // The device's name (DeviceInfo::name), e.g. "llvmpipe (LLVM 15.0.6, 256 bits)".
  virtual const std::string& device_name() const = 0;
  // True when the device is a CPU implementation (lavapipe): its time is CPU time.
  virtual bool software_device() const = 0;
};

// CreateFitter (fitter.h) with the Vulkan fitter's options for kVulkan (`vulkan.threads` is
// replaced by `threads`; the other backends ignore `vulkan`).
StatusOr<std::unique_ptr<Fitter>> CreateFitter(Backend backend, int threads,
                                               const VulkanFitterOptions& vulkan);

// A Vulkan fitter on the chosen device. Unavailable with a message saying what is missing when
// this build has no Vulkan, there is no Vulkan driver or device, or the device cannot be used;
// NotFound / FailedPrecondition when `device` names nothing usable (gpu::SelectDevice).
StatusOr<std::unique_ptr<VulkanFitter>> CreateVulkanFitter(const VulkanFitterOptions& options = {});

// `--backend auto`: which backend to use on this machine.
struct AutoBackendChoice {
  Backend backend = Backend::kCpu;
  std::string device;   // the Vulkan device considered (empty when there is none)
  std::string reason;   // one line for the log
  bool fell_back = false;  // no usable Vulkan device (or no Vulkan in this build): warn
};
// The rule: a GPU (discrete, integrated or virtual) → kVulkan; only a CPU Vulkan device
// (lavapipe) → kCpu, because the batched CPU kernel runs on the same cores with wider vectors
// and no driver in between (bench/RESULTS.md, "Fitting (Vulkan)"), unless `device` names that
// device explicitly, which asks for it; no Vulkan driver or device → kCpu, fell_back. Errors:
// NotFound / FailedPrecondition when `device` is given but matches no usable device.
StatusOr<AutoBackendChoice> ChooseAutoBackend(const std::string& device = "");

}  // namespace reflcap::fit
