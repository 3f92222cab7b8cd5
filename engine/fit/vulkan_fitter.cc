// The Vulkan fitter (vulkan_fitter.h): batches of prepared problems, their device buffers, and
// the dispatch loop that runs shaders/fit/lm_fit.comp until every problem's LM has ended.
//
// Data layout (shaders/shared/fit_gpu.h has the word layouts):
//   records  the residuals, on the device only: one RGBA32F uniform texel buffer of residual
//            quads (shared/fit_gpu.h; lm_fit.comp says why): texel t owns QuadBound(samples(t))
//            quads of 5 texels, enough for its problems' quads (none for a texel too large for
//            a batch: its problems are solved on the CPU). The host keeps no copy: a prepared
//            problem's ResidualView keeps its counts, and the few texels whose finishing reads
//            residuals (a Lambert-only fallback, a channel retry) are prepared again then.
//   desc     per problem: first record, channel blocks, stages, masks, loss scale, x0.
//   queue    device problems sorted by residual count, largest first: lanes in lock-step
//            (lavapipe runs 8 invocations as one SIMD subgroup) then take problems of similar
//            size, and the sample loop of a subgroup does not idle lanes on short problems.
//   lanes    per persistent lane, the LM state of its current problem between dispatches.
//   results  per problem: status, free mask, iterations, cost, x, J^T J at x.
#include "engine/fit/vulkan_fitter.h"

#include <algorithm>
#include <atomic>
#include <filesystem>
#include <chrono>
#include <cstring>
#include <future>
#include <map>
#include <vector>

#include "engine/core/log.h"
#include "engine/core/default_init_allocator.h"
#include "engine/core/parallel.h"
#include "engine/fit/fitter_base.h"
#include "engine/fit/problem.h"
#include "engine/fit/vulkan_fit_kernel.h"
#include "engine/gpu/chunking.h"
#include "engine/gpu/device_info.h"
#include "engine/gpu/shader_blobs.h"
#include "engine/gpu/vk_buffer.h"
#include "engine/gpu/vk_commands.h"
#include "engine/gpu/vk_context.h"
#include "shaders/shared/fit_gpu.h"

namespace reflcap::fit {
namespace {

namespace sh = gpu::shared;

// Batch limits (VulkanFitterOptions: 0 = these). 32,768 problems: enough lanes to fill a GPU,
// and two host batches of at most ~100 MB (prepared + solved problems, records).
constexpr uint32_t kDefaultBatchProblems = 1u << 15;
constexpr uint64_t kDefaultBatchResiduals = uint64_t{1} << 21;  // 40 MiB of records
// Persistent lanes: a CPU device runs a few workgroups at a time (one per thread), so a
// thousand lanes keep it busy, and fewer lanes than problems let every lane take several: a
// lane's 8-wide subgroup runs until its slowest problem ends, which one problem per lane leaves
// to chance (lavapipe, 1,024 samples per texel, batches of ~2,000 problems: 4,096 lanes 13.9k
// fits/s, 1,024 lanes 16.3k; 64 samples unchanged). A GPU needs tens of thousands in flight.
constexpr uint32_t kSoftwareLanes = 1024;
constexpr uint32_t kGpuLanes = 65536;
constexpr uint32_t kLocalSize = 64;
// The cluster kernel (lm_fit_cluster.comp): invocations per problem by default — at 64 samples a
// problem has 16 quads, two per invocation, and a 32-wide subgroup holds four problems (8, 16
// and 32 are the choices a GPU's subgroup allows; bench/RESULTS.md has the measured sweep).
constexpr uint32_t kDefaultClusterSize = 8;
// Invocations per dispatch: 262,144 fills a large GPU (an H100 holds 132 SMs x 2,048 resident
// invocations) whatever the cluster size.
constexpr uint32_t kClusterInvocations = 1u << 18;
// Problems per dispatch per resident cluster: clusters take new problems as theirs end, so a few
// per cluster keep the device full while the slowest finish; dispatches of one batch run
// concurrently (disjoint queue ranges and control slots), recorded into one submission.
constexpr uint64_t kProblemsPerCluster = 4;
// Batch limits of the cluster kernel (a GPU holds them easily: 2^25 records are 640 MiB of
// quads), and the fraction of the device's local memory a batch's buffers may take (two batches
// are in flight).
constexpr uint32_t kClusterBatchProblems = 1u << 20;
constexpr uint64_t kClusterBatchResiduals = uint64_t{1} << 25;
constexpr uint64_t kDeviceMemoryFraction = 8;
// Status word of a result before the kernel writes it: a problem still holding it after the
// submission was never solved (a dispatch cut short).
constexpr uint32_t kUnsolved = 0xFFFFFFFFu;
// Loop steps kept back from the device's loop budget for loops a driver compiler might add
// (lm_fit.comp has exactly two: ticks and samples; fit_vulkan_test.cc checks its SPIR-V).
constexpr uint32_t kLoopReserve = 32;
// Residual evaluations per submission at most (lanes x ticks x residuals): ~7 GFLOP, a few
// milliseconds on a GPU, well under a second on lavapipe, so no submission approaches a
// desktop driver's watchdog (~2 s).
constexpr uint64_t kMaxResidualEvaluationsPerSubmit = uint64_t{1} << 26;
// Texels per ParallelFor task in preparation and post-processing.
constexpr int64_t kTexelsPerTask = 64;

// LM ticks (steps of lm_fit.comp's tick loop, of lm_fit_cluster.comp's step loop) one problem
// takes at most — a bound no correct run reaches: every tick of a stage either evaluates (<=
// max_iterations + 1 per stage), rejects a step without evaluating (counted as an iteration), or
// fails a factorisation (< kLmMaxSolveFailures in a row between the others); two stages, and a
// tick to start and to end.
uint64_t ProblemTickBound(const LmSettings& settings) {
  const uint64_t stage_ticks = (uint64_t(settings.max_iterations) + 2) *
                               (uint64_t(sh::kLmMaxSolveFailures) + 1);
  return 2 * stage_ticks + 2;
}

enum Route : uint8_t { kRouteTrivial = 0, kRouteDevice = 1, kRouteCpu = 2 };

gpu::ShaderId LmShader(const ProblemLayout& layout) {
  static constexpr gpu::ShaderId kAniso[] = {gpu::ShaderId::kLmFitAnisoK0, gpu::ShaderId::kLmFitAnisoK1,
                                             gpu::ShaderId::kLmFitAnisoK2, gpu::ShaderId::kLmFitAnisoK3};
  static constexpr gpu::ShaderId kIso[] = {gpu::ShaderId::kLmFitIsoK0, gpu::ShaderId::kLmFitIsoK1,
                                           gpu::ShaderId::kLmFitIsoK2, gpu::ShaderId::kLmFitIsoK3};
  static constexpr gpu::ShaderId kShared[] = {gpu::ShaderId::kLmFitSharedK0, gpu::ShaderId::kLmFitSharedK1,
                                              gpu::ShaderId::kLmFitSharedK2};
  switch (layout.model) {
    case LobeModel::kAniso: return kAniso[layout.lobes];
    case LobeModel::kIso: return kIso[layout.lobes];
    case LobeModel::kShared: return kShared[layout.lobes];
  }
  return gpu::ShaderId::kCount;
}

gpu::ShaderId ClusterShader(const ProblemLayout& layout) {
  static constexpr gpu::ShaderId kAniso[] = {
      gpu::ShaderId::kLmFitClusterAnisoK0, gpu::ShaderId::kLmFitClusterAnisoK1,
      gpu::ShaderId::kLmFitClusterAnisoK2, gpu::ShaderId::kLmFitClusterAnisoK3};
  static constexpr gpu::ShaderId kIso[] = {
      gpu::ShaderId::kLmFitClusterIsoK0, gpu::ShaderId::kLmFitClusterIsoK1,
      gpu::ShaderId::kLmFitClusterIsoK2, gpu::ShaderId::kLmFitClusterIsoK3};
  static constexpr gpu::ShaderId kShared[] = {gpu::ShaderId::kLmFitClusterSharedK0,
                                              gpu::ShaderId::kLmFitClusterSharedK1,
                                              gpu::ShaderId::kLmFitClusterSharedK2};
  switch (layout.model) {
    case LobeModel::kAniso: return kAniso[layout.lobes];
    case LobeModel::kIso: return kIso[layout.lobes];
    case LobeModel::kShared: return kShared[layout.lobes];
  }
  return gpu::ShaderId::kCount;
}

// The cluster kernel needs subgroup shuffles in compute shaders, a subgroup of at least one
// cluster, and a workgroup made of whole subgroups (kLocalSize a multiple of the subgroup size).
bool SupportsClusters(const gpu::DeviceInfo& info) {
  return info.compute_subgroup_shuffle && info.subgroup_size >= 1 &&
         kLocalSize % info.subgroup_size == 0;
}

StatusOr<VulkanFitKernel> ChooseKernel(const gpu::DeviceInfo& info, VulkanFitKernel wanted) {
  switch (wanted) {
    case VulkanFitKernel::kAuto:
      return !info.IsSoftware() && SupportsClusters(info) ? VulkanFitKernel::kClusters
                                                          : VulkanFitKernel::kLanes;
    case VulkanFitKernel::kLanes:
      return VulkanFitKernel::kLanes;
    case VulkanFitKernel::kClusters:
      if (!SupportsClusters(info)) {
        return UnavailableError("Vulkan fitter: the cluster kernel needs subgroup shuffles in "
                                "compute shaders and a subgroup size dividing ", kLocalSize,
                                "; ", info.name, " has subgroup size ", info.subgroup_size,
                                info.compute_subgroup_shuffle ? "" : " and no compute shuffles");
      }
      return VulkanFitKernel::kClusters;
  }
  return VulkanFitKernel::kLanes;
}

StatusOr<uint32_t> ChooseClusterSize(const gpu::DeviceInfo& info, uint32_t wanted) {
  const uint32_t largest = std::min(kMaxVulkanFitClusterSize, info.subgroup_size);
  if (wanted == 0) return std::min(kDefaultClusterSize, largest);
  if ((wanted & (wanted - 1)) != 0 || wanted > largest) {
    return InvalidArgumentError("Vulkan fitter: cluster size ", wanted,
                                " must be a power of two of at most ", largest, " on ", info.name,
                                " (subgroup size ", info.subgroup_size, ")");
  }
  return wanted;
}

uint32_t FloatBits(float v) {
  uint32_t bits;
  std::memcpy(&bits, &v, sizeof bits);
  return bits;
}
float BitsFloat(uint32_t bits) {
  float v;
  std::memcpy(&v, &bits, sizeof v);
  return v;
}

// Device quads (four residuals each, shared/fit_gpu.h) of a problem of `residuals` residuals.
uint64_t QuadsOf(uint64_t residuals) { return (residuals + 3) / 4; }

// Quads that a texel's problems need at most: a problem of c residuals needs ceil(c / 4) <=
// (c + 3) / 4, and the problems' c sum to at most 3 x samples.
uint64_t QuadBound(uint64_t samples, int per_texel) {
  return (3 * samples + 3 * uint64_t(per_texel)) / 4;
}

double Seconds(std::chrono::steady_clock::time_point since) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - since).count();
}

// One batch of consecutive texels of a chunk, on the host.
struct Batch {
  uint32_t begin = 0, end = 0;            // chunk texels [begin, end)
  std::vector<uint64_t> quad;             // first device quad of each texel (batch-local)
  std::vector<PreparedProblem> problems;  // (end - begin) x ProblemsPerTexel
  std::vector<SolvedProblem> solved;      // filled for kRouteTrivial / kRouteCpu problems
  std::vector<uint8_t> route;
  // Not zeroed when it grows (a million-texel batch's quads are 3.84 GB: zeroing them was serial,
  // before Prepare's workers write them in parallel). The device reads the quads of the problems
  // it is given (the other texels' quads, like mapped device memory, hold garbage).
  UninitializedVector<float> rgba;        // the device's quads when device_records is not mapped
  internal::TexelBuffer* device_records = nullptr;  // the batch's device quads
  float* quads = nullptr;                 // where Prepare writes them: device_records' memory, or rgba
  std::vector<uint32_t> desc;
  std::vector<uint32_t> queue;
  std::vector<uint32_t> results;          // downloaded results (OUT_STRIDE words per problem)
  uint32_t max_residuals = 0;             // over the queue
  // What the device run did.
  uint32_t dispatches = 0, ticks = 0, lanes = 0;
  uint64_t evaluations = 0;  // residual evaluations on the device
  double device_seconds = 0;
};

class VulkanFitterImpl final : public VulkanFitter {
 public:
  VulkanFitterImpl(std::unique_ptr<gpu::VkContext> ctx, gpu::CommandBuffer cmd,
                   std::unique_ptr<internal::LmKernels> kernels, const VulkanFitterOptions& options)
      : ctx_(std::move(ctx)), cmd_(std::move(cmd)), kernels_(std::move(kernels)), options_(options) {}

  Backend backend() const override { return Backend::kVulkan; }
  std::string device() const override { return ctx_->info().ToString(); }
  const VulkanFitStats& last_stats() const override { return stats_; }
  const std::string& device_name() const override { return ctx_->info().name; }
  bool software_device() const override { return ctx_->info().IsSoftware(); }

  Status Fit(const TexelSampleChunk& chunk, const FitOptions& options,
             std::vector<TexelFit>* results) override;

 private:
  struct Plan {
    ProblemLayout layout;
    int per_texel = 1;
    int num_params = 1;
    LmSettings settings;
    int workers = 1;
    uint32_t max_problems = 0;     // per batch
    uint64_t max_records = 0;      // per batch
    uint64_t max_texels = 0;       // device texels (5 per quad) per batch
    uint32_t max_device_residuals = 0;  // per problem
    uint32_t lane_cap = 0;
    VulkanFitKernel kernel = VulkanFitKernel::kLanes;
    uint32_t cluster_size = 0;
    bool native_math = false;
    bool channel_retry = true;
    LossKind loss = LossKind::kNone;

    // A texel of `samples` samples fits a batch (else it is alone in its batch and its problems
    // are solved on the CPU), and the device quads reserved for it (0 when it does not fit).
    bool FitsABatch(uint64_t samples) const {
      return 3 * samples <= max_records &&
             REFLCAP_FIT_QUAD_TEXELS * QuadBound(samples, per_texel) <= max_texels;
    }
    uint64_t DeviceQuads(uint64_t samples) const {
      return FitsABatch(samples) ? QuadBound(samples, per_texel) : 0;
    }
  };

  // Texel ranges of the chunk's batches.
  std::vector<std::pair<uint32_t, uint32_t>> CutBatches(const TexelSampleChunk& chunk,
                                                        const Plan& plan) const;
  void Prepare(const TexelSampleChunk& chunk, const FitOptions& options, const Plan& plan,
               uint32_t begin, uint32_t end, Batch* b);
  Status RunOnDevice(const Plan& plan, VkPipeline pipeline, Batch* b);
  Status RunLanes(const Plan& plan, VkPipeline pipeline, Batch* b);
  Status RunClusters(const Plan& plan, VkPipeline pipeline, Batch* b);
  // The batch on the device: its buffers sized (each binding within maxStorageBufferRange), the
  // settings, descriptors, queue (and quads when not written in place) uploaded, and the kernels'
  // descriptor set pointed at them; `lane_bytes` and `control_bytes` are the kernel's lane-state
  // and control sizes. *result_bytes gets the results' size.
  Status BindBatch(const Plan& plan, Batch* b, uint64_t lane_bytes, uint64_t control_bytes,
                   uint64_t* result_bytes);
  void Finish(const TexelSampleChunk& chunk, const FitOptions& options, const Plan& plan,
              const Batch& b, std::vector<TexelFit>* results);
  Status Ensure(gpu::Buffer* buffer, uint64_t bytes);

  std::unique_ptr<gpu::VkContext> ctx_;
  gpu::CommandBuffer cmd_;
  std::unique_ptr<internal::LmKernels> kernels_;
  VulkanFitterOptions options_;
  std::vector<ProblemArena> arenas_;
  Batch batches_[2];
  struct {
    gpu::Buffer settings, desc, queue, lanes, results, control;
  } buffers_;
  // The device quads of the two host batches (batches_[k] uses records_[k]), sized in Fit
  // before any batch is prepared.
  internal::TexelBuffer records_[2];
  VulkanFitStats stats_;
};

std::vector<std::pair<uint32_t, uint32_t>> VulkanFitterImpl::CutBatches(
    const TexelSampleChunk& chunk, const Plan& plan) const {
  std::vector<std::pair<uint32_t, uint32_t>> out;
  uint32_t begin = 0;
  uint64_t records = 0, texels = 0;
  for (uint32_t t = 0; t < chunk.texel_count; ++t) {
    const uint64_t slots = 3 * chunk.SampleCount(t);
    const uint64_t quad_texels = REFLCAP_FIT_QUAD_TEXELS * plan.DeviceQuads(chunk.SampleCount(t));
    const uint64_t problems = uint64_t(t - begin + 1) * plan.per_texel;
    if (t > begin && (problems > plan.max_problems || records + slots > plan.max_records ||
                      texels + quad_texels > plan.max_texels)) {
      out.emplace_back(begin, t);
      begin = t;
      records = texels = 0;
    }
    records += slots;
    texels += quad_texels;
  }
  if (chunk.texel_count > begin) out.emplace_back(begin, chunk.texel_count);
  return out;
}

void VulkanFitterImpl::Prepare(const TexelSampleChunk& chunk, const FitOptions& options,
                               const Plan& plan, uint32_t begin, uint32_t end, Batch* b) {
  const int per_texel = plan.per_texel;
  const int P = plan.num_params;
  const int desc_stride = REFLCAP_FIT_DESC_STRIDE(P);
  const uint32_t texels = end - begin;
  const size_t problems = size_t(texels) * per_texel;
  b->begin = begin;
  b->end = end;
  b->quad.resize(texels + 1);
  b->quad[0] = 0;
  for (uint32_t t = 0; t < texels; ++t) {
    b->quad[t + 1] = b->quad[t] + plan.DeviceQuads(chunk.SampleCount(begin + t));
  }
  b->problems.resize(problems);
  b->solved.resize(problems);
  b->route.assign(problems, kRouteTrivial);
  // On a device whose memory the host sees (lavapipe, integrated GPUs) the quads go straight into
  // the batch's texel buffer, which the device is not reading (it runs the other batch).
  const uint64_t quad_floats = std::max<uint64_t>(1, b->quad[texels]) * REFLCAP_FIT_QUAD_TEXELS * 4;
  REFLCAP_CHECK(b->device_records != nullptr && b->device_records->elements() * 4 >= quad_floats);
  if (b->device_records->mapped() != nullptr) {
    b->quads = static_cast<float*>(b->device_records->mapped());
  } else {
    b->rgba.resize(quad_floats);
    b->quads = b->rgba.data();
  }
  b->desc.resize(problems * desc_stride);

  // Thread time in PrepareTexel and in the layout below, in nanoseconds (VulkanFitStats).
  std::atomic<int64_t> texel_ns{0}, layout_ns{0};
  ParallelFor(
      0, texels, kTexelsPerTask,
      [&](int64_t t0, int64_t t1, int worker) {
        ProblemArena& arena = arenas_[worker];
        int64_t task_texel_ns = 0, task_layout_ns = 0;
        auto mark = std::chrono::steady_clock::now();
        auto lap = [&mark](int64_t* ns) {
          const auto now = std::chrono::steady_clock::now();
          *ns += std::chrono::duration_cast<std::chrono::nanoseconds>(now - mark).count();
          mark = now;
        };
        for (int64_t t = t0; t < t1; ++t) {
          const uint32_t texel = begin + uint32_t(t);
          size_t cursor = 0;
          PreparedProblem* q = &b->problems[size_t(t) * per_texel];
          PrepareTexel(options, plan.layout, chunk.SamplesOf(texel), chunk.SampleCount(texel),
                       int(texel), &arena, &cursor, q);
          lap(&task_texel_ns);
          // A texel larger than a whole batch (alone in its batch, CutBatches) stays on the CPU.
          const bool fits_a_batch = plan.FitsABatch(chunk.SampleCount(texel));
          uint64_t quad = b->quad[t];  // the texel's next free device quad
          for (int p = 0; p < per_texel; ++p) {
            const size_t i = size_t(t) * per_texel + p;
            PreparedProblem& problem = q[p];
            ResidualView& view = problem.residuals;
            const int count = view.count();
            const float* from[REFLCAP_FIT_RECORD_FLOATS] = {view.xx, view.yy, view.zz, view.y,
                                                            view.sw};
            if (problem.num_stages == 0) {
              // As the batched path: nothing to solve, the start is the answer.
              SolvedProblem& out = b->solved[i];
              out = SolvedProblem{};
              for (int j = 0; j < kMaxParams; ++j) out.x[j] = problem.x0[j];
              out.status = FitStatus::kConverged;
              b->route[i] = kRouteTrivial;
            } else if (!fits_a_batch || count > int(plan.max_device_residuals)) {
              // Too large for one invocation's loop budget (or for a batch): the scalar float
              // LM of lm.h, which takes the same decisions, while the arena holds the residuals.
              b->solved[i] = SolveScalar<float>(problem, plan.settings, options.loss);
              b->route[i] = kRouteCpu;
            } else {
              const uint64_t quads = QuadsOf(count);
              float* texel = &b->quads[quad * REFLCAP_FIT_QUAD_TEXELS * 4];
              for (uint64_t q = 0; q < quads; ++q) {
                for (int k = 0; k < REFLCAP_FIT_QUAD_TEXELS; ++k, texel += 4) {
                  for (int c = 0; c < 4; ++c) {
                    const int r = int(4 * q) + c;
                    texel[c] = r < count ? from[k][r] : 0.0f;  // padding: no weight
                  }
                }
              }
              uint32_t* d = &b->desc[i * desc_stride];
              d[sh::kFitDescBegin] = uint32_t(quad * REFLCAP_FIT_QUAD_TEXELS);
              quad += quads;
              d[sh::kFitDescBlock1] = uint32_t(view.begin[1]);
              d[sh::kFitDescBlock2] = uint32_t(view.begin[2]);
              d[sh::kFitDescCount] = uint32_t(count);
              d[sh::kFitDescStages] = uint32_t(problem.num_stages);
              d[sh::kFitDescMask0] = problem.stage_mask[0];
              d[sh::kFitDescMask1] = problem.stage_mask[1];
              d[sh::kFitDescLossScale] = FloatBits(float(problem.loss_scale));
              for (int j = 0; j < P; ++j) d[sh::kFitDescX0 + j] = FloatBits(float(problem.x0[j]));
              b->route[i] = kRouteDevice;
            }
            // The arena is the next texel's: the view keeps the counts only (Finish prepares
            // the texel again where a fallback or a retry reads residuals).
            view.xx = view.yy = view.zz = view.y = view.sw = nullptr;
          }
          lap(&task_layout_ns);
        }
        texel_ns += task_texel_ns;
        layout_ns += task_layout_ns;
      },
      plan.workers);
  stats_.prepare_texel_thread_seconds += double(texel_ns) * 1e-9;
  stats_.prepare_layout_thread_seconds += double(layout_ns) * 1e-9;

  b->queue.clear();
  for (size_t i = 0; i < problems; ++i) {
    if (b->route[i] == kRouteDevice) b->queue.push_back(uint32_t(i));
  }
  std::stable_sort(b->queue.begin(), b->queue.end(), [&](uint32_t a, uint32_t c) {
    return b->problems[a].residuals.count() > b->problems[c].residuals.count();
  });
  b->max_residuals = b->queue.empty() ? 0 : uint32_t(b->problems[b->queue[0]].residuals.count());
}

Status VulkanFitterImpl::Ensure(gpu::Buffer* buffer, uint64_t bytes) {
  bytes = std::max<uint64_t>(bytes, 16);
  if (buffer->handle() != VK_NULL_HANDLE && buffer->size() >= bytes) return OkStatus();
  // Room to grow by a quarter, so that batches of slightly different sizes reuse the buffer.
  const uint64_t want = std::min<uint64_t>(bytes + bytes / 4, ctx_->max_allocation_bytes());
  REFLCAP_ASSIGN_OR_RETURN(*buffer, gpu::Buffer::Create(*ctx_, std::max(want, bytes),
                                                        gpu::MemoryKind::kDevice));
  return OkStatus();
}

Status VulkanFitterImpl::RunOnDevice(const Plan& plan, VkPipeline pipeline, Batch* b) {
  b->dispatches = b->ticks = b->lanes = 0;
  b->evaluations = 0;
  if (b->queue.empty()) return OkStatus();
  return plan.kernel == VulkanFitKernel::kClusters ? RunClusters(plan, pipeline, b)
                                                   : RunLanes(plan, pipeline, b);
}

Status VulkanFitterImpl::BindBatch(const Plan& plan, Batch* b, uint64_t lane_bytes,
                                   uint64_t control_bytes, uint64_t* result_bytes) {
  const int P = plan.num_params;
  const uint64_t problems = b->problems.size();
  const uint64_t desc_bytes = problems * REFLCAP_FIT_DESC_STRIDE(P) * 4;
  const uint64_t queue_bytes = b->queue.size() * 4;
  *result_bytes = problems * REFLCAP_FIT_OUT_STRIDE(P) * 4;
  const uint64_t range = ctx_->info().max_storage_buffer_range;
  for (uint64_t bytes : {desc_bytes, queue_bytes, *result_bytes, lane_bytes, control_bytes}) {
    if (bytes > range) {
      return InternalError("Vulkan fitter: a batch binding of ", bytes,
                           " bytes exceeds maxStorageBufferRange (", range, ")");
    }
  }
  REFLCAP_RETURN_IF_ERROR(Ensure(&buffers_.settings, sizeof(sh::FitGpuSettings)));
  REFLCAP_RETURN_IF_ERROR(Ensure(&buffers_.desc, desc_bytes));
  REFLCAP_RETURN_IF_ERROR(Ensure(&buffers_.queue, queue_bytes));
  REFLCAP_RETURN_IF_ERROR(Ensure(&buffers_.results, *result_bytes));
  REFLCAP_RETURN_IF_ERROR(Ensure(&buffers_.lanes, lane_bytes));
  REFLCAP_RETURN_IF_ERROR(Ensure(&buffers_.control, control_bytes));

  sh::FitGpuSettings settings{};
  {
    double lo[kMaxParams] = {}, hi[kMaxParams] = {};
    ParameterBounds(plan.layout, lo, hi);
    for (int j = 0; j < kMaxParams; ++j) {
      settings.lower[j] = float(lo[j]);
      settings.upper[j] = float(hi[j]);
    }
  }
  settings.max_iterations = plan.settings.max_iterations;
  settings.first_stage_iterations = plan.settings.first_stage_iterations;
  settings.step_tolerance = float(plan.settings.step_tolerance);
  settings.cost_tolerance = float(plan.settings.cost_tolerance);
  settings.gradient_tolerance = float(plan.settings.gradient_tolerance);
  REFLCAP_RETURN_IF_ERROR(gpu::Upload(*ctx_, &settings, sizeof settings, buffers_.settings));
  REFLCAP_RETURN_IF_ERROR(gpu::Upload(*ctx_, b->desc.data(), desc_bytes, buffers_.desc));
  REFLCAP_RETURN_IF_ERROR(gpu::Upload(*ctx_, b->queue.data(), queue_bytes, buffers_.queue));
  if (b->device_records->mapped() == nullptr) {
    const uint64_t texels = std::max<uint64_t>(1, b->quad.back()) * REFLCAP_FIT_QUAD_TEXELS;
    REFLCAP_RETURN_IF_ERROR(b->device_records->Upload(
        *ctx_, b->rgba.data(), texels * 16,
        options_.staging_bytes > 0 ? options_.staging_bytes : gpu::kStagingChunkBytes));
  }

  internal::LmBindings bindings;
  bindings.settings = gpu::Bind(buffers_.settings, 0, sizeof(sh::FitGpuSettings));
  bindings.desc = gpu::Bind(buffers_.desc, 0, desc_bytes);
  bindings.queue = gpu::Bind(buffers_.queue, 0, queue_bytes);
  bindings.lanes = gpu::Bind(buffers_.lanes, 0, lane_bytes);
  bindings.results = gpu::Bind(buffers_.results, 0, *result_bytes);
  bindings.control = gpu::Bind(buffers_.control, 0, control_bytes);
  bindings.records = b->device_records->view();
  kernels_->Write(bindings);
  return OkStatus();
}

Status VulkanFitterImpl::RunLanes(const Plan& plan, VkPipeline pipeline, Batch* b) {
  const auto start = std::chrono::steady_clock::now();
  const int P = plan.num_params;
  const uint64_t problems = b->problems.size();
  const uint32_t lanes = std::min<uint32_t>(uint32_t(b->queue.size()), plan.lane_cap);
  const uint64_t lane_bytes = uint64_t(lanes) * REFLCAP_FIT_LANE_STRIDE(P) * 4;
  uint64_t result_bytes = 0;
  REFLCAP_RETURN_IF_ERROR(BindBatch(plan, b, lane_bytes, sizeof(sh::FitGpuControl), &result_bytes));

  // Ticks per dispatch: the loop budget (T (Q + 2) + 1 steps for Q quads, see lm_fit.comp) and
  // the submit work cap.
  const uint64_t r = std::max<uint32_t>(1, b->max_residuals);
  uint64_t ticks = std::max<uint64_t>(1, kMaxResidualEvaluationsPerSubmit / (uint64_t(lanes) * r));
  const uint32_t budget = gpu::MaxLoopIterationsPerInvocation(*ctx_);
  if (budget != gpu::kNoLoopIterationLimit) {
    ticks = std::min<uint64_t>(ticks, (budget - 1 - kLoopReserve) / (QuadsOf(b->max_residuals) + 2));
  }
  if (options_.max_ticks_per_dispatch > 0) {
    ticks = std::min<uint64_t>(ticks, options_.max_ticks_per_dispatch);
  }
  REFLCAP_CHECK(ticks >= 1) << "problems above max_device_residuals reached the device";
  const uint64_t problem_ticks = ProblemTickBound(plan.settings);
  const uint64_t max_dispatches = (b->queue.size() * problem_ticks) / (uint64_t(lanes) * ticks) +
                                  problem_ticks / ticks + 3;

  const sh::FitGpuPush push{uint32_t(b->queue.size()), lanes, uint32_t(ticks), 0};
  const uint32_t groups = uint32_t(gpu::GroupCount(lanes, kLocalSize));
  REFLCAP_RETURN_IF_ERROR(cmd_.Begin());
  // Every lane starts idle (problem word = kFitNoProblem), the queue at its head.
  REFLCAP_RETURN_IF_ERROR(cmd_.FillBuffer(buffers_.lanes, 0, lane_bytes, sh::kFitNoProblem));
  REFLCAP_RETURN_IF_ERROR(cmd_.FillBuffer(buffers_.control, 0, sizeof(sh::FitGpuControl), 0));
  for (uint64_t d = 0;; ++d) {
    if (d > 0) REFLCAP_RETURN_IF_ERROR(cmd_.Begin());
    REFLCAP_RETURN_IF_ERROR(  // busy and evaluations
        cmd_.FillBuffer(buffers_.control, offsetof(sh::FitGpuControl, busy), 8, 0));
    kernels_->RecordDispatch(cmd_, pipeline, &push, groups);
    REFLCAP_RETURN_IF_ERROR(cmd_.SubmitAndWait());
    sh::FitGpuControl control{};
    REFLCAP_RETURN_IF_ERROR(gpu::Download(*ctx_, buffers_.control, 0, sizeof control, &control));
    ++b->dispatches;
    b->evaluations += control.evaluations;
    if (control.busy == 0) break;
    if (d + 1 >= max_dispatches) {
      return InternalError("Vulkan fitter: ", control.busy, " lanes still busy after ",
                           d + 1, " dispatches of ", ticks, " ticks (bound ", max_dispatches, ")");
    }
  }
  b->results.resize(problems * REFLCAP_FIT_OUT_STRIDE(P));
  REFLCAP_RETURN_IF_ERROR(gpu::Download(*ctx_, buffers_.results, 0, result_bytes, b->results.data()));
  b->ticks = uint32_t(ticks);
  b->lanes = lanes;
  b->device_seconds = Seconds(start);
  return OkStatus();
}

Status VulkanFitterImpl::RunClusters(const Plan& plan, VkPipeline pipeline, Batch* b) {
  const auto start = std::chrono::steady_clock::now();
  const int P = plan.num_params;
  const uint64_t problems = b->problems.size();
  const uint32_t cluster = plan.cluster_size;
  const uint64_t resident = std::max<uint64_t>(1, plan.lane_cap / cluster);
  // Problems per dispatch: a few per resident cluster; on a device with a loop budget
  // (lavapipe, where this kernel runs only when asked for) few enough that one cluster taking
  // them all stays within it: a step is one pass of the step loop and ceil(Q / C) of the sample
  // loop plus its exit test, for Q quads.
  uint64_t per_dispatch = resident * kProblemsPerCluster;
  const uint32_t budget = gpu::MaxLoopIterationsPerInvocation(*ctx_);
  if (budget != gpu::kNoLoopIterationLimit) {
    const uint64_t step = (QuadsOf(b->max_residuals) + cluster - 1) / cluster + 2;
    const uint64_t per_problem = ProblemTickBound(plan.settings) * step + 1;
    REFLCAP_CHECK(per_problem <= budget - kLoopReserve)
        << "problems above max_device_residuals reached the device";
    per_dispatch = std::min<uint64_t>(per_dispatch, (budget - kLoopReserve) / per_problem);
  }
  const uint64_t count = b->queue.size();
  const uint64_t dispatches = (count + per_dispatch - 1) / per_dispatch;
  const uint64_t control_bytes = dispatches * sizeof(sh::FitGpuControl);
  uint64_t result_bytes = 0;
  // Binding 4 (lane state) is unused by this kernel: a minimal buffer stands in.
  REFLCAP_RETURN_IF_ERROR(BindBatch(plan, b, 16, control_bytes, &result_bytes));

  // One submission: reset the counters, mark every result unsolved, then all dispatches (no
  // barrier between them: disjoint queue ranges, control slots and results).
  REFLCAP_RETURN_IF_ERROR(cmd_.Begin());
  REFLCAP_RETURN_IF_ERROR(cmd_.FillBuffer(buffers_.control, 0, control_bytes, 0));
  REFLCAP_RETURN_IF_ERROR(cmd_.FillBuffer(buffers_.results, 0, result_bytes, kUnsolved));
  uint32_t max_invocations = 0;
  for (uint64_t d = 0; d < dispatches; ++d) {
    const uint64_t begin = d * per_dispatch;
    const uint64_t n = std::min(per_dispatch, count - begin);
    const uint64_t invocations = std::min(n, resident) * cluster;
    max_invocations = std::max<uint32_t>(max_invocations, uint32_t(invocations));
    const sh::FitGpuClusterPush push{uint32_t(begin), uint32_t(n), uint32_t(d), 0};
    kernels_->RecordDispatch(cmd_, pipeline, &push,
                             uint32_t(gpu::GroupCount(invocations, kLocalSize)),
                             /*barrier=*/d + 1 == dispatches);
  }
  REFLCAP_RETURN_IF_ERROR(cmd_.SubmitAndWait());
  std::vector<sh::FitGpuControl> control(dispatches);
  REFLCAP_RETURN_IF_ERROR(gpu::Download(*ctx_, buffers_.control, 0, control_bytes, control.data()));
  b->results.resize(problems * REFLCAP_FIT_OUT_STRIDE(P));
  REFLCAP_RETURN_IF_ERROR(gpu::Download(*ctx_, buffers_.results, 0, result_bytes, b->results.data()));
  for (const sh::FitGpuControl& c : control) b->evaluations += c.evaluations;
  for (uint32_t i : b->queue) {
    if (b->results[size_t(i) * REFLCAP_FIT_OUT_STRIDE(P) + sh::kFitOutStatus] == kUnsolved) {
      return InternalError("Vulkan fitter: problem ", i, " of a batch of ", count,
                           " was not solved by the cluster kernel (", dispatches,
                           " dispatches of up to ", per_dispatch, " problems on ",
                           ctx_->info().name, ")");
    }
  }
  b->dispatches = uint32_t(dispatches);
  b->lanes = max_invocations;
  b->device_seconds = Seconds(start);
  return OkStatus();
}

void VulkanFitterImpl::Finish(const TexelSampleChunk& chunk, const FitOptions& options,
                              const Plan& plan, const Batch& b, std::vector<TexelFit>* results) {
  const int per_texel = plan.per_texel;
  const int P = plan.num_params;
  const int stride = REFLCAP_FIT_OUT_STRIDE(P);
  const int packed = PackedIndex(P, 0);
  std::atomic<uint64_t> reprepared{0};
  ParallelFor(
      0, b.end - b.begin, kTexelsPerTask,
      [&](int64_t t0, int64_t t1, int worker) {
        constexpr int kMaxPerTexel = ProblemsPerTexel(LobeModel::kAniso);  // aniso, iso: 3
        static_assert(kMaxPerTexel >= ProblemsPerTexel(LobeModel::kIso) &&
                      kMaxPerTexel >= ProblemsPerTexel(LobeModel::kShared));
        SolvedProblem solved[kMaxPerTexel], retried[kMaxPerTexel];
        PreparedProblem retry[kMaxPerTexel], again[kMaxPerTexel];
        int retry_problem[kMaxPerTexel];
        uint64_t task_reprepared = 0;
        for (int64_t t = t0; t < t1; ++t) {
          const size_t first = size_t(t) * per_texel;
          const uint32_t texel = b.begin + uint32_t(t);
          for (int p = 0; p < per_texel; ++p) {
            const size_t i = first + p;
            if (b.route[i] != kRouteDevice) {
              solved[p] = b.solved[i];
              continue;
            }
            const uint32_t* w = &b.results[i * stride];
            solved[p] = SolvedProblem{};
            solved[p].status = FitStatus(int(w[sh::kFitOutStatus]));
            solved[p].free_mask = w[sh::kFitOutFreeMask];
            solved[p].iterations = int(w[sh::kFitOutIterations]);
            solved[p].cost = BitsFloat(w[sh::kFitOutCost]);
            for (int j = 0; j < P; ++j) solved[p].x[j] = BitsFloat(w[sh::kFitOutX + j]);
            for (int k = 0; k < packed; ++k) solved[p].a[k] = BitsFloat(w[sh::kFitOutX + P + k]);
          }
          // The batch's problems keep their residuals' counts only; a texel whose finishing
          // reads residuals is prepared again into this worker's arena (the same problems: the
          // preparation is deterministic).
          const PreparedProblem* q = &b.problems[first];
          auto with_residuals = [&]() {
            if (q != again) {
              size_t cursor = 0;
              PrepareTexel(options, plan.layout, chunk.SamplesOf(texel), chunk.SampleCount(texel),
                           int(texel), &arenas_[worker], &cursor, again);
              q = again;
              ++task_reprepared;
            }
          };
          if (plan.channel_retry) {
            // The few retried channels run the device's scalar twin here (lm.h in float).
            int n = PrepareChannelRetries(q, solved, per_texel, retry, retry_problem);
            if (n > 0 && q[0].residuals.y == nullptr) {
              with_residuals();
              n = PrepareChannelRetries(q, solved, per_texel, retry, retry_problem);
            }
            for (int r = 0; r < n; ++r) {
              retried[r] = SolveScalar<float>(retry[r], plan.settings, plan.loss);
            }
            AdoptChannelRetries(retried, retry_problem, n, solved);
          }
          TexelFit& fit = (*results)[texel];
          BeginTexel(plan.layout.lobes, &fit);
          for (int p = 0; p < per_texel; ++p) {
            if (FinishProblem(q[p], solved[p], &fit)) continue;
            // A Lambert-only fallback needs the residuals: the texel again, from the start.
            with_residuals();
            BeginTexel(plan.layout.lobes, &fit);
            for (int r = 0; r < per_texel; ++r) REFLCAP_CHECK(FinishProblem(q[r], solved[r], &fit));
            break;
          }
        }
        reprepared += task_reprepared;
      },
      plan.workers);
  stats_.reprepared_texels += reprepared;
}

Status VulkanFitterImpl::Fit(const TexelSampleChunk& chunk, const FitOptions& options,
                             std::vector<TexelFit>* results) {
  REFLCAP_RETURN_IF_ERROR(options.Validate());
  REFLCAP_RETURN_IF_ERROR(internal::ValidateChunk(chunk));
  stats_ = VulkanFitStats{};
  results->resize(chunk.texel_count);
  if (chunk.texel_count == 0) return OkStatus();

  Plan plan;
  plan.layout = ProblemLayout{options.lobe_model, options.lobes};
  plan.per_texel = ProblemsPerTexel(plan.layout.model);
  plan.num_params = plan.layout.NumParams();
  plan.settings = MakeLmSettings(options);
  plan.channel_retry = options.channel_retry;
  plan.loss = options.loss;
  plan.workers = options.threads > 0 ? options.threads
                 : options_.threads > 0 ? options_.threads
                                        : HardwareThreads();
  const gpu::DeviceInfo& info = ctx_->info();
  const int P = plan.num_params;
  REFLCAP_ASSIGN_OR_RETURN(plan.kernel, ChooseKernel(info, options_.kernel));
  if (plan.kernel == VulkanFitKernel::kClusters) {
    REFLCAP_ASSIGN_OR_RETURN(plan.cluster_size, ChooseClusterSize(info, options_.cluster_size));
    plan.native_math = options_.native_math == NativeMath::kAuto ? !info.IsSoftware()
                                                                 : options_.native_math == NativeMath::kOn;
  }
  const bool clusters = plan.kernel == VulkanFitKernel::kClusters;
  const uint64_t range = info.max_storage_buffer_range;
  const uint64_t widest = std::max<uint64_t>(REFLCAP_FIT_OUT_STRIDE(P), REFLCAP_FIT_DESC_STRIDE(P)) * 4;
  // One batch per chunk on a GPU: measured on an H100 (10^6 texels, 64 samples, chunks of
  // 62,500 texels), cutting a chunk into four batches to overlap the host's preparation with the
  // device raised the device's time from 0.16 to 0.46 s (a quarter-chunk batch cannot fill the
  // device) and lowered the end-to-end rate from 2.2 to 1.9 M fits/s.
  plan.max_problems = std::min<uint64_t>(
      options_.max_batch_problems > 0 ? options_.max_batch_problems
      : clusters                      ? kClusterBatchProblems
                                      : kDefaultBatchProblems,
      range / widest);
  plan.max_problems = std::max<uint32_t>(plan.max_problems, plan.per_texel);
  plan.max_records = options_.max_batch_residuals > 0 ? options_.max_batch_residuals
                     : clusters                       ? kClusterBatchResiduals
                                                      : kDefaultBatchResiduals;
  if (options_.max_batch_residuals == 0 && info.device_local_heap_size > 0) {
    // Two batches in flight, each ~ 20 bytes of quads per record plus descriptors and results.
    plan.max_records = std::max<uint64_t>(
        1, std::min(plan.max_records, info.device_local_heap_size / kDeviceMemoryFraction / 20));
  }
  plan.max_texels = internal::MaxTexelBufferElements(*ctx_);
  const uint32_t budget = gpu::MaxLoopIterationsPerInvocation(info);
  if (budget == gpu::kNoLoopIterationLimit) {
    plan.max_device_residuals = uint32_t(std::min<uint64_t>(plan.max_records, 0x7FFFFFFF));
  } else if (!clusters) {
    plan.max_device_residuals = 4 * (budget - 3 - kLoopReserve);  // one tick: Q + 2 steps, + 1
  } else {
    // One problem, worst case, within the budget: ProblemTickBound steps of ceil(Q / C) + 2.
    const uint64_t steps = (budget - kLoopReserve - 1) / ProblemTickBound(plan.settings);
    plan.max_device_residuals =
        uint32_t(std::max<uint64_t>(steps, 3) - 2) * plan.cluster_size * 4;
  }
  if (options_.max_device_residuals > 0) {
    plan.max_device_residuals = std::min(plan.max_device_residuals, options_.max_device_residuals);
  }
  plan.lane_cap = options_.lanes > 0 ? options_.lanes
                  : clusters          ? kClusterInvocations
                  : info.IsSoftware() ? kSoftwareLanes
                                      : kGpuLanes;
  plan.lane_cap = std::min<uint64_t>(plan.lane_cap, range / (REFLCAP_FIT_LANE_STRIDE(P) * 4));
  stats_.loop_budget = budget;
  stats_.kernel = plan.kernel;
  stats_.cluster_size = plan.cluster_size;
  stats_.native_math = plan.native_math;
  stats_.max_device_residuals = plan.max_device_residuals;
  stats_.min_ticks_per_dispatch = 0;

  REFLCAP_ASSIGN_OR_RETURN(
      VkPipeline pipeline,
      kernels_->Pipeline(clusters ? ClusterShader(plan.layout) : LmShader(plan.layout),
                         int(options.loss), std::max<uint32_t>(plan.cluster_size, 1),
                         plan.native_math));

  // Per-worker arenas for one texel of the chunk's largest sample count.
  uint64_t max_samples = 1;
  for (uint32_t t = 0; t < chunk.texel_count; ++t) {
    max_samples = std::max<uint64_t>(max_samples, chunk.SampleCount(t));
  }
  if (arenas_.size() < size_t(plan.workers)) arenas_.resize(plan.workers);
  for (ProblemArena& a : arenas_) a.Reserve(3 * max_samples, max_samples);

  const std::vector<std::pair<uint32_t, uint32_t>> cuts = CutBatches(chunk, plan);
  // Device quads of the largest batch (as Prepare lays them out).
  uint64_t max_texels = 1;
  for (const auto& [first, last] : cuts) {
    uint64_t quads = 0;
    for (uint32_t t = first; t < last; ++t) quads += plan.DeviceQuads(chunk.SampleCount(t));
    max_texels = std::max<uint64_t>(max_texels, quads * REFLCAP_FIT_QUAD_TEXELS);
  }
  for (size_t k = 0; k < std::min<size_t>(2, cuts.size()); ++k) {
    if (records_[k].elements() < max_texels) {
      // Room to grow by a quarter, as Ensure, so that chunks of slightly different sizes reuse it.
      const uint64_t want = std::min<uint64_t>(max_texels + max_texels / 4, plan.max_texels);
      records_[k] = internal::TexelBuffer{};  // free the old one first
      REFLCAP_ASSIGN_OR_RETURN(records_[k], internal::TexelBuffer::Create(
                                                *ctx_, std::max(want, max_texels),
                                                VK_FORMAT_R32G32B32A32_SFLOAT, 16,
                                                options_.map_device_records));
    }
    batches_[k].device_records = &records_[k];
    stats_.records_mapped = records_[k].mapped() != nullptr;
  }
  // Batch k runs on the device while batch k - 1 is finished and batch k + 1 prepared on the CPU
  // (two host batches: k + 1 reuses k - 1's once it is finished).
  auto timed_prepare = [&](uint32_t first, uint32_t last, Batch* b) {
    const auto t0 = std::chrono::steady_clock::now();
    Prepare(chunk, options, plan, first, last, b);
    stats_.prepare_seconds += Seconds(t0);
  };
  auto timed_finish = [&](const Batch& b) {
    const auto t0 = std::chrono::steady_clock::now();
    Finish(chunk, options, plan, b, results);
    stats_.finish_seconds += Seconds(t0);
  };
  timed_prepare(cuts[0].first, cuts[0].second, &batches_[0]);
  for (size_t k = 0; k < cuts.size(); ++k) {
    Batch& current = batches_[k % 2];
    Batch& other = batches_[(k + 1) % 2];
    std::future<Status> device = std::async(std::launch::async, [&] {
      return RunOnDevice(plan, pipeline, &current);
    });
    if (k > 0) timed_finish(other);
    if (k + 1 < cuts.size()) timed_prepare(cuts[k + 1].first, cuts[k + 1].second, &other);
    REFLCAP_RETURN_IF_ERROR(device.get());
    ++stats_.batches;
    stats_.dispatches += current.dispatches;
    stats_.max_dispatches_per_batch = std::max(stats_.max_dispatches_per_batch, current.dispatches);
    if (current.ticks > 0) {
      stats_.min_ticks_per_dispatch = stats_.min_ticks_per_dispatch == 0
                                          ? current.ticks
                                          : std::min(stats_.min_ticks_per_dispatch, current.ticks);
    }
    stats_.max_residuals = std::max(stats_.max_residuals, current.max_residuals);
    stats_.lanes = std::max(stats_.lanes, current.lanes);
    stats_.device_seconds += current.device_seconds;
    stats_.residual_evaluations += current.evaluations;
    for (uint8_t route : current.route) {
      stats_.gpu_problems += route == kRouteDevice;
      stats_.cpu_problems += route == kRouteCpu;
      stats_.trivial_problems += route == kRouteTrivial;
    }
  }
  timed_finish(batches_[(cuts.size() - 1) % 2]);
  return OkStatus();
}

}  // namespace

StatusOr<std::unique_ptr<VulkanFitter>> CreateVulkanFitter(const VulkanFitterOptions& options) {
  REFLCAP_RETURN_IF_ERROR(options.Validate());
  gpu::ContextOptions context_options;
  context_options.device = options.device;
  StatusOr<std::unique_ptr<gpu::VkContext>> ctx = gpu::VkContext::Create(context_options);
  if (!ctx.ok()) {
    return Status(ctx.status().code(),
                  StrCat("--backend vulkan: ", ctx.status().message()));
  }
  REFLCAP_ASSIGN_OR_RETURN(gpu::CommandBuffer cmd, gpu::CommandBuffer::Create(**ctx));
  REFLCAP_ASSIGN_OR_RETURN(std::unique_ptr<internal::LmKernels> kernels,
                           internal::LmKernels::Create(**ctx, kLocalSize));
  return std::unique_ptr<VulkanFitter>(new VulkanFitterImpl(std::move(ctx).value(), std::move(cmd),
                                                            std::move(kernels), options));
}

namespace {

// Whether the machine has a GPU's device node: DRM render or card nodes (Mesa's and AMD's
// drivers), NVIDIA's, or WSL's. A hardware Vulkan device needs one; without any, the probe below
// would only load every installed driver (Debian's mesa-vulkan-drivers: four, 25-50 ms per
// process, paid by each shard of a batch fit) to find at most lavapipe, which `auto` does not
// choose.
bool GpuDeviceNodePresent() {
  std::error_code ec;
  for (const char* node : {"/dev/nvidiactl", "/dev/nvidia0", "/dev/dxg"}) {
    if (std::filesystem::exists(node, ec)) return true;
  }
  for (const auto& entry : std::filesystem::directory_iterator("/dev/dri", ec)) {
    const std::string name = entry.path().filename().string();
    if (name.rfind("renderD", 0) == 0 || name.rfind("card", 0) == 0) return true;
  }
  return false;
}

}  // namespace

StatusOr<AutoBackendChoice> ChooseAutoBackend(const std::string& device) {
  AutoBackendChoice choice;
  if (device.empty() && !GpuDeviceNodePresent()) {
    choice.backend = Backend::kCpu;
    choice.reason = "no GPU on this machine (no /dev/dri render or card node, no /dev/nvidia*): "
                    "fitting on the CPU";
    return choice;
  }
  StatusOr<std::vector<gpu::DeviceInfo>> devices = gpu::ListDevices();
  if (!devices.ok()) {
    if (!device.empty()) {
      return Status(devices.status().code(), StrCat("--device ", device, ": ", devices.status().message()));
    }
    choice.backend = Backend::kCpu;
    choice.fell_back = true;
    choice.reason = StrCat("no Vulkan device (", devices.status().message(),
                           "): fitting on the CPU");
    return choice;
  }
  StatusOr<size_t> selected = gpu::SelectDevice(*devices, device);
  if (!selected.ok()) {
    if (!device.empty()) return selected.status();
    choice.backend = Backend::kCpu;
    choice.fell_back = true;
    choice.reason = StrCat("no usable Vulkan device (", selected.status().message(),
                           "): fitting on the CPU");
    return choice;
  }
  const gpu::DeviceInfo& d = (*devices)[*selected];
  choice.device = d.name;
  if (!d.IsSoftware()) {
    choice.backend = Backend::kVulkan;
    choice.reason = StrCat("Vulkan ", gpu::DeviceTypeName(d.type), " ", d.name);
  } else if (!device.empty()) {
    choice.backend = Backend::kVulkan;
    choice.reason = StrCat("Vulkan CPU device ", d.name, " (chosen by --device)");
  } else {
    choice.backend = Backend::kCpu;
    choice.reason = StrCat("the only Vulkan device is the CPU device ", d.name,
                           ": the batched CPU path is faster on the same cores");
  }
  return choice;
}

}  // namespace reflcap::fit
