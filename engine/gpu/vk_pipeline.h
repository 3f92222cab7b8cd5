#pragma once
// ComputePipeline: a compute shader from ShaderBlob with its pipeline layout — one descriptor set
// (set 0) of `num_buffers` storage buffers at bindings 0..num_buffers-1, an optional push-constant
// block and specialization constants. CommandBuffer::Dispatch binds buffers to it.
// After uVkCompute's vulkan/pipeline.h.
//
// Conventions of reflcap's shaders (shaders/*/*.comp): specialization constant 0 is local_size_x
// (`layout(local_size_x = 64, local_size_x_id = 0) in;`), so ComputePipelineOptions::local_size_x
// overrides the shader's default; constant ids >= 1 are the shader's own (iteration caps, ...);
// push constants carry per-dispatch values (chunk offset and count).
#include <vulkan/vulkan.h>

#include <cstdint>
#include <cstring>
#include <vector>

#include "engine/core/status.h"
#include "engine/gpu/shader_blobs.h"
#include "engine/gpu/vk_context.h"

namespace reflcap::gpu {

// One 32-bit specialization constant (uint, int, float or bool as its bit pattern).
struct SpecConstant {
  uint32_t id = 0;
  uint32_t bits = 0;

  static SpecConstant Uint(uint32_t id, uint32_t value) { return {id, value}; }
  static SpecConstant Int(uint32_t id, int32_t value) { return {id, static_cast<uint32_t>(value)}; }
  static SpecConstant Float(uint32_t id, float value) {
    uint32_t bits;
    std::memcpy(&bits, &value, sizeof(bits));
    return {id, bits};
  }
};

// Specialization constant id of local_size_x in reflcap's shaders.
inline constexpr uint32_t kLocalSizeXConstantId = 0;

struct ComputePipelineOptions {
  ShaderId shader = ShaderId::kCount;  // required
  // Storage-buffer bindings 0..num_buffers-1 of set 0 (1..maxPerStageDescriptorStorageBuffers).
  uint32_t num_buffers = 1;
  // Size of the shader's push_constant block in bytes (a multiple of 4, <= maxPushConstantsSize;
  // 0 = none). Dispatch checks that every push matches it.
  uint32_t push_constant_bytes = 0;
  // Workgroup size along x (> 0, <= maxComputeWorkGroupSize[0] and
  // maxComputeWorkGroupInvocations), set through specialization constant kLocalSizeXConstantId,
  // which every reflcap shader declares (local_size_y = local_size_z = 1).
  uint32_t local_size_x = 64;
  std::vector<SpecConstant> spec_constants;  // ids other than kLocalSizeXConstantId
};

class ComputePipeline {
 public:
  static StatusOr<ComputePipeline> Create(VkContext& ctx, const ComputePipelineOptions& options);

  ComputePipeline() = default;
  ~ComputePipeline();
  ComputePipeline(ComputePipeline&& other) noexcept;
  ComputePipeline& operator=(ComputePipeline&& other) noexcept;
  ComputePipeline(const ComputePipeline&) = delete;
  ComputePipeline& operator=(const ComputePipeline&) = delete;

  VkPipeline pipeline() const { return pipeline_; }
  VkPipelineLayout layout() const { return layout_; }
  VkDescriptorSetLayout set_layout() const { return set_layout_; }
  uint32_t num_buffers() const { return num_buffers_; }
  uint32_t push_constant_bytes() const { return push_constant_bytes_; }
  uint32_t local_size_x() const { return local_size_x_; }
  ShaderId shader() const { return shader_; }

 private:
  void Release();

  VkDevice device_ = VK_NULL_HANDLE;
  VkDescriptorSetLayout set_layout_ = VK_NULL_HANDLE;
  VkPipelineLayout layout_ = VK_NULL_HANDLE;
  VkPipeline pipeline_ = VK_NULL_HANDLE;
  uint32_t num_buffers_ = 0;
  uint32_t push_constant_bytes_ = 0;
  uint32_t local_size_x_ = 0;
  ShaderId shader_ = ShaderId::kCount;
};

}  // namespace reflcap::gpu
