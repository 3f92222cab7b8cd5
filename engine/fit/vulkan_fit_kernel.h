#pragma once
// The Vulkan objects of the fitter's LM kernel (shaders/fit/lm_fit.comp) that the compute
// foundation's all-storage-buffer ComputePipeline does not cover: the kernel reads its residuals
// through a uniform texel buffer (why: lm_fit.comp's header), so it has its own descriptor set
// layout (bindings 0-2 and 4-6 storage buffers, 3 a uniform texel buffer), pipelines, and
// texel buffers with views. Used by engine/fit/vulkan_fitter.cc only; includes Vulkan.
#include <vulkan/vulkan.h>

#include <cstdint>
#include <map>
#include <memory>

#include "engine/core/status.h"
#include "engine/gpu/shader_blobs.h"
#include "engine/gpu/vk_buffer.h"
#include "engine/gpu/vk_commands.h"
#include "engine/gpu/vk_context.h"
#include "shaders/shared/fit_gpu.h"

namespace reflcap::fit::internal {

// A VkBuffer of UNIFORM_TEXEL_BUFFER usage with its memory (device-local; mapped when that memory
// is also host-visible, as on lavapipe and integrated GPUs) and one VkBufferView of `format`.
class TexelBuffer {
 public:
  // Room for `elements` (> 0) texels of `element_bytes` bytes each. Unavailable beyond the
  // context's allocation cap or maxTexelBufferElements. The memory is mapped when it is
  // host-visible and coherent, unless `allow_mapping` is false (tests: the staging path a
  // discrete GPU takes).
  static StatusOr<TexelBuffer> Create(gpu::VkContext& ctx, uint64_t elements, VkFormat format,
                                      uint32_t element_bytes, bool allow_mapping = true);
  TexelBuffer() = default;
  ~TexelBuffer();
  TexelBuffer(TexelBuffer&& other) noexcept;
  TexelBuffer& operator=(TexelBuffer&& other) noexcept;
  TexelBuffer(const TexelBuffer&) = delete;
  TexelBuffer& operator=(const TexelBuffer&) = delete;

  // Copies `bytes` bytes to the start of the buffer and waits until they are there: a memcpy when
  // mapped, else through the context's staging ring (gpu::UploadThroughStaging: host copies over
  // several threads overlapping the device's copies) in pieces of `staging_bytes` (> 0).
  Status Upload(gpu::VkContext& ctx, const void* data, uint64_t bytes,
                uint64_t staging_bytes = gpu::kStagingChunkBytes);

  uint64_t elements() const { return elements_; }
  VkBufferView view() const { return view_; }
  // The buffer's memory mapped for the host (write there, then no Upload is needed), or null
  // when the memory is not host-visible and coherent.
  void* mapped() const { return mapped_; }

 private:
  void Release();

  VkDevice device_ = VK_NULL_HANDLE;
  VkBuffer buffer_ = VK_NULL_HANDLE;
  VkDeviceMemory memory_ = VK_NULL_HANDLE;
  VkBufferView view_ = VK_NULL_HANDLE;
  void* mapped_ = nullptr;
  uint64_t elements_ = 0;
  uint64_t bytes_ = 0;
};

// maxTexelBufferElements of the context's device.
uint64_t MaxTexelBufferElements(const gpu::VkContext& ctx);

// What one dispatch of the kernel binds.
struct LmBindings {
  gpu::BufferBinding settings, desc, queue, lanes, results, control;  // bindings 0, 1, 2, 4, 5, 6
  VkBufferView records = VK_NULL_HANDLE;  // binding 3, RGBA32F residual quads (fit_gpu.h)
};

// The kernel's descriptor set layout, pipeline layout, one descriptor set, and one pipeline per
// (shader permutation, loss), compiled on first use.
class LmKernels {
 public:
  static StatusOr<std::unique_ptr<LmKernels>> Create(gpu::VkContext& ctx, uint32_t local_size_x);
  ~LmKernels();
  LmKernels(const LmKernels&) = delete;
  LmKernels& operator=(const LmKernels&) = delete;

  // The pipeline of `shader` specialised for `loss` (kFitLoss*) and, for the cluster kernel, its
  // cluster size and whether it uses the device's exp/log (constants 2 and 3; lm_fit.comp has
  // neither and ignores them).
  StatusOr<VkPipeline> Pipeline(gpu::ShaderId shader, int loss, uint32_t cluster_size = 8,
                                bool native_math = false);
  // Points the descriptor set at `b`. No submission that uses the set may be running.
  void Write(const LmBindings& b);
  // Records binding `pipeline` and the set, the 16 bytes of push constants (FitGpuPush for
  // lm_fit.comp, FitGpuClusterPush for lm_fit_cluster.comp), the dispatch of `groups` workgroups
  // and, when `barrier`, a barrier that makes its writes visible to later commands, into `cmd`
  // (recording). Dispatches over disjoint queue ranges and control slots (the cluster kernel's)
  // may go without one and run concurrently.
  void RecordDispatch(gpu::CommandBuffer& cmd, VkPipeline pipeline, const void* push,
                      uint32_t groups, bool barrier = true) const;

 private:
  LmKernels() = default;

  VkDevice device_ = VK_NULL_HANDLE;
  uint32_t local_size_x_ = 64;
  VkDescriptorSetLayout set_layout_ = VK_NULL_HANDLE;
  VkPipelineLayout layout_ = VK_NULL_HANDLE;
  VkDescriptorPool pool_ = VK_NULL_HANDLE;
  VkDescriptorSet set_ = VK_NULL_HANDLE;
  std::map<uint64_t, VkPipeline> pipelines_;
};

}  // namespace reflcap::fit::internal
