#include "engine/gpu/vk_pipeline.h"

#include <utility>

#include "engine/gpu/vk_status.h"

namespace reflcap::gpu {
namespace {

constexpr uint32_t kSpirvMagic = 0x07230203;

Status ValidateOptions(const VkContext& ctx, const ComputePipelineOptions& o) {
  const DeviceInfo& d = ctx.info();
  if (o.shader == ShaderId::kCount) return InvalidArgumentError("ComputePipeline: no shader");
  const char* name = ShaderName(o.shader);
  if (o.num_buffers == 0 || o.num_buffers > d.max_per_stage_storage_buffers) {
    return InvalidArgumentError("ComputePipeline ", name, ": num_buffers ", o.num_buffers,
                                " outside [1, ", d.max_per_stage_storage_buffers, "]");
  }
  if (o.push_constant_bytes % 4 != 0 || o.push_constant_bytes > d.max_push_constants_size) {
    return InvalidArgumentError("ComputePipeline ", name, ": push_constant_bytes ",
                                o.push_constant_bytes,
                                " must be a multiple of 4 and <= ", d.max_push_constants_size);
  }
  if (o.local_size_x == 0 || o.local_size_x > d.max_compute_work_group_size[0] ||
      o.local_size_x > d.max_compute_work_group_invocations) {
    return InvalidArgumentError("ComputePipeline ", name, ": local_size_x ", o.local_size_x,
                                " outside [1, ", d.max_compute_work_group_size[0], "]");
  }
  for (const SpecConstant& c : o.spec_constants) {
    if (c.id == kLocalSizeXConstantId) {
      return InvalidArgumentError("ComputePipeline ", name, ": specialization constant ",
                                  kLocalSizeXConstantId, " is local_size_x; set local_size_x");
    }
  }
  return OkStatus();
}

}  // namespace

StatusOr<ComputePipeline> ComputePipeline::Create(VkContext& ctx,
                                                  const ComputePipelineOptions& options) {
  REFLCAP_RETURN_IF_ERROR(ValidateOptions(ctx, options));
  const Span spirv = ShaderBlob(options.shader);
  if (spirv.size < 5 || spirv.data[0] != kSpirvMagic) {
    return InternalError("shader ", ShaderName(options.shader), " is not SPIR-V");
  }

  ComputePipeline p;
  p.device_ = ctx.device();
  p.num_buffers_ = options.num_buffers;
  p.push_constant_bytes_ = options.push_constant_bytes;
  p.local_size_x_ = options.local_size_x;
  p.shader_ = options.shader;

  std::vector<VkDescriptorSetLayoutBinding> bindings(options.num_buffers);
  for (uint32_t i = 0; i < options.num_buffers; ++i) {
    bindings[i].binding = i;
    bindings[i].descriptorType = VK_DESCRIPTOR_TYPE_STORAGE_BUFFER;
    bindings[i].descriptorCount = 1;
    bindings[i].stageFlags = VK_SHADER_STAGE_COMPUTE_BIT;
  }
  VkDescriptorSetLayoutCreateInfo set_info{};
  set_info.sType = VK_STRUCTURE_TYPE_DESCRIPTOR_SET_LAYOUT_CREATE_INFO;
  set_info.bindingCount = options.num_buffers;
  set_info.pBindings = bindings.data();
  VK_RETURN_IF_ERROR(vkCreateDescriptorSetLayout(p.device_, &set_info, nullptr, &p.set_layout_));

  VkPushConstantRange push_range{VK_SHADER_STAGE_COMPUTE_BIT, 0, options.push_constant_bytes};
  VkPipelineLayoutCreateInfo layout_info{};
  layout_info.sType = VK_STRUCTURE_TYPE_PIPELINE_LAYOUT_CREATE_INFO;
  layout_info.setLayoutCount = 1;
  layout_info.pSetLayouts = &p.set_layout_;
  layout_info.pushConstantRangeCount = options.push_constant_bytes > 0 ? 1 : 0;
  layout_info.pPushConstantRanges = &push_range;
  VK_RETURN_IF_ERROR(vkCreatePipelineLayout(p.device_, &layout_info, nullptr, &p.layout_));

  VkShaderModuleCreateInfo module_info{};

  module_info.sType = VK_STRUCTURE_TYPE_SHADER_MODULE_CREATE_INFO;
  module_info.codeSize = spirv.size_bytes();
  module_info.pCode = spirv.data;
  VkShaderModule module = VK_NULL_HANDLE;
  VK_RETURN_IF_ERROR(vkCreateShaderModule(p.device_, &module_info, nullptr, &module));

  std::vector<SpecConstant> constants = options.spec_constants;
  constants.push_back(SpecConstant::Uint(kLocalSizeXConstantId, options.local_size_x));
  std::vector<VkSpecializationMapEntry> entries(constants.size());
  std::vector<uint32_t> data(constants.size());
  for (size_t i = 0; i < constants.size(); ++i) {
    entries[i].constantID = constants[i].id;
    entries[i].offset = static_cast<uint32_t>(i * sizeof(uint32_t));
    entries[i].size = sizeof(uint32_t);
    data[i] = constants[i].bits;
  }
  VkSpecializationInfo spec{};
  spec.mapEntryCount = static_cast<uint32_t>(entries.size());
  spec.pMapEntries = entries.data();
  spec.dataSize = data.size() * sizeof(uint32_t);
  spec.pData = data.data();

  VkComputePipelineCreateInfo info{};

  info.sType = VK_STRUCTURE_TYPE_COMPUTE_PIPELINE_CREATE_INFO;
  info.stage.sType = VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO;
  info.stage.stage = VK_SHADER_STAGE_COMPUTE_BIT;
  info.stage.module = module;
  info.stage.pName = "main";
  info.stage.pSpecializationInfo = &spec;
  info.layout = p.layout_;
  const VkResult r =
      vkCreateComputePipelines(p.device_, VK_NULL_HANDLE, 1, &info, nullptr, &p.pipeline_);
  vkDestroyShaderModule(p.device_, module, nullptr);
  if (r != VK_SUCCESS) {
    return VkResultToStatus(
        r, StrCat("vkCreateComputePipelines(", ShaderName(options.shader), ")").c_str(), __FILE__,
        __LINE__);
  }
  return p;
}

ComputePipeline::~ComputePipeline() { Release(); }

ComputePipeline::ComputePipeline(ComputePipeline&& other) noexcept { *this = std::move(other); }

ComputePipeline& ComputePipeline::operator=(ComputePipeline&& other) noexcept {
  if (this != &other) {
    Release();
    device_ = std::exchange(other.device_, VK_NULL_HANDLE);
    set_layout_ = std::exchange(other.set_layout_, VK_NULL_HANDLE);
    layout_ = std::exchange(other.layout_, VK_NULL_HANDLE);
    pipeline_ = std::exchange(other.pipeline_, VK_NULL_HANDLE);
    num_buffers_ = other.num_buffers_;
    push_constant_bytes_ = other.push_constant_bytes_;
    local_size_x_ = other.local_size_x_;
    shader_ = other.shader_;
  }
  return *this;
}

void ComputePipeline::Release() {
  if (device_ == VK_NULL_HANDLE) return;
  if (pipeline_ != VK_NULL_HANDLE) vkDestroyPipeline(device_, pipeline_, nullptr);
  if (layout_ != VK_NULL_HANDLE) vkDestroyPipelineLayout(device_, layout_, nullptr);
  if (set_layout_ != VK_NULL_HANDLE) vkDestroyDescriptorSetLayout(device_, set_layout_, nullptr);
  device_ = VK_NULL_HANDLE;
  pipeline_ = VK_NULL_HANDLE;
  layout_ = VK_NULL_HANDLE;
  set_layout_ = VK_NULL_HANDLE;
}

}  // namespace reflcap::gpu
