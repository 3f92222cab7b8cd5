#include "engine/gpu/vk_graphics_pipeline.h"

#include <utility>

#include "engine/core/check.h"
#include "engine/gpu/vk_status.h"

namespace reflcap::gpu {
namespace {

constexpr uint32_t kSpirvMagic = 0x07230203;

StatusOr<VkShaderModule> CreateModule(VkDevice device, ShaderId id) {
  const Span spirv = ShaderBlob(id);
  if (spirv.size < 5 || spirv.data[0] != kSpirvMagic) {
    return InternalError("shader ", ShaderName(id), " is not SPIR-V");
  }
  VkShaderModuleCreateInfo info{};
  info.sType = VK_STRUCTURE_TYPE_SHADER_MODULE_CREATE_INFO;
  info.codeSize = spirv.size_bytes();
  info.pCode = spirv.data;
  VkShaderModule module = VK_NULL_HANDLE;
  VK_RETURN_IF_ERROR(vkCreateShaderModule(device, &info, nullptr, &module));
  return module;
}

// Specialization data for a list of 32-bit constants; keeps the arrays alive with the info.
struct Specialization {
  std::vector<VkSpecializationMapEntry> entries;
  std::vector<uint32_t> data;
  VkSpecializationInfo info{};

  explicit Specialization(const std::vector<SpecConstant>& constants) {
    entries.resize(constants.size());
    data.resize(constants.size());
    for (size_t i = 0; i < constants.size(); ++i) {
      entries[i] = {constants[i].id, uint32_t(i * sizeof(uint32_t)), sizeof(uint32_t)};
      data[i] = constants[i].bits;
    }
    info.mapEntryCount = uint32_t(entries.size());
    info.pMapEntries = entries.data();
    info.dataSize = data.size() * sizeof(uint32_t);
    info.pData = data.data();
  }
};

StatusOr<VkPipelineLayout> CreateLayout(VkContext& ctx, VkDescriptorSetLayout set_layout,
                                        uint32_t push_bytes, VkShaderStageFlags stages) {
  if (set_layout == VK_NULL_HANDLE) return InvalidArgumentError("Pipeline: no set layout");
  if (push_bytes % 4 != 0 || push_bytes > ctx.info().max_push_constants_size) {
    return InvalidArgumentError(
        "Pipeline: push_constant_bytes ", push_bytes,
        " must be a multiple of 4 and <= ", ctx.info().max_push_constants_size);
  }
  VkPushConstantRange range{stages, 0, push_bytes};
  VkPipelineLayoutCreateInfo info{};
  info.sType = VK_STRUCTURE_TYPE_PIPELINE_LAYOUT_CREATE_INFO;
  info.setLayoutCount = 1;
  info.pSetLayouts = &set_layout;
  info.pushConstantRangeCount = push_bytes > 0 ? 1 : 0;
  info.pPushConstantRanges = &range;
  VkPipelineLayout layout = VK_NULL_HANDLE;
  VK_RETURN_IF_ERROR(vkCreatePipelineLayout(ctx.device(), &info, nullptr, &layout));
  return layout;
}

}  // namespace

// ---- RenderTarget --------------------------------------------------------------------------

StatusOr<RenderTarget> RenderTarget::Create(VkContext& ctx, const std::vector<DeviceImage*>& colors,
                                            DeviceImage* depth, VkImageLayout color_final_layout,
                                            VkImageLayout depth_final_layout, PassWait wait) {
  if (colors.empty() && depth == nullptr) {
    return InvalidArgumentError("RenderTarget: no attachments");
  }
  const DeviceImage* first = colors.empty() ? depth : colors[0];
  std::vector<DeviceImage*> all = colors;
  if (depth != nullptr) all.push_back(depth);
  for (const DeviceImage* img : all) {
    if (img == nullptr || img->handle() == VK_NULL_HANDLE) {
      return InvalidArgumentError("RenderTarget: an attachment is empty");
    }
    if (img->width() != first->width() || img->height() != first->height() ||
        img->layers() != first->layers()) {
      return InvalidArgumentError("RenderTarget: attachments differ in size or layers");
    }
  }

  RenderTarget t;
  t.device_ = ctx.device();
  t.colors_ = colors;
  t.depth_ = depth;
  t.color_final_layout_ = color_final_layout;
  t.depth_final_layout_ = depth_final_layout;
  t.width_ = first->width();
  t.height_ = first->height();

  std::vector<VkAttachmentDescription> attachments;
  std::vector<VkAttachmentReference> color_refs;
  for (const DeviceImage* img : colors) {
    VkAttachmentDescription a{};
    a.format = img->format();
    a.samples = VK_SAMPLE_COUNT_1_BIT;
    a.loadOp = VK_ATTACHMENT_LOAD_OP_CLEAR;
    a.storeOp = VK_ATTACHMENT_STORE_OP_STORE;
    a.stencilLoadOp = VK_ATTACHMENT_LOAD_OP_DONT_CARE;
    a.stencilStoreOp = VK_ATTACHMENT_STORE_OP_DONT_CARE;
    a.initialLayout = VK_IMAGE_LAYOUT_UNDEFINED;
    a.finalLayout = color_final_layout;
    color_refs.push_back({uint32_t(attachments.size()), VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL});
    attachments.push_back(a);
  }
  VkAttachmentReference depth_ref{};
  if (depth != nullptr) {
    VkAttachmentDescription a{};
    a.format = depth->format();
    a.samples = VK_SAMPLE_COUNT_1_BIT;
    a.loadOp = VK_ATTACHMENT_LOAD_OP_CLEAR;
    a.storeOp = VK_ATTACHMENT_STORE_OP_STORE;
    a.stencilLoadOp = VK_ATTACHMENT_LOAD_OP_DONT_CARE;
    a.stencilStoreOp = VK_ATTACHMENT_STORE_OP_DONT_CARE;
    a.initialLayout = VK_IMAGE_LAYOUT_UNDEFINED;
    a.finalLayout = depth_final_layout;
    depth_ref = {uint32_t(attachments.size()), VK_IMAGE_LAYOUT_DEPTH_STENCIL_ATTACHMENT_OPTIMAL};
    attachments.push_back(a);
  }
  VkSubpassDescription subpass{};
  subpass.pipelineBindPoint = VK_PIPELINE_BIND_POINT_GRAPHICS;
  subpass.colorAttachmentCount = uint32_t(color_refs.size());
  subpass.pColorAttachments = color_refs.data();
  subpass.pDepthStencilAttachment = depth != nullptr ? &depth_ref : nullptr;

  constexpr VkPipelineStageFlags kOutside = VK_PIPELINE_STAGE_FRAGMENT_SHADER_BIT |
                                            VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT |
                                            VK_PIPELINE_STAGE_TRANSFER_BIT;
  constexpr VkPipelineStageFlags kAttachmentStages = VK_PIPELINE_STAGE_COLOR_ATTACHMENT_OUTPUT_BIT |
                                                     VK_PIPELINE_STAGE_EARLY_FRAGMENT_TESTS_BIT |
                                                     VK_PIPELINE_STAGE_LATE_FRAGMENT_TESTS_BIT;
  constexpr VkAccessFlags kAttachmentWrites =
      VK_ACCESS_COLOR_ATTACHMENT_WRITE_BIT | VK_ACCESS_DEPTH_STENCIL_ATTACHMENT_WRITE_BIT;
  // What earlier work the pass waits for (PassWait).
  VkPipelineStageFlags earlier = kAttachmentStages;
  VkAccessFlags earlier_writes = kAttachmentWrites;
  if (wait == PassWait::kEverything) {
    earlier |= kOutside;
    earlier_writes |= VK_ACCESS_SHADER_WRITE_BIT | VK_ACCESS_TRANSFER_WRITE_BIT;
  } else if (wait == PassWait::kShaderReads) {
    earlier |= VK_PIPELINE_STAGE_FRAGMENT_SHADER_BIT | VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT;
    earlier_writes |= VK_ACCESS_SHADER_WRITE_BIT;
  }
  VkSubpassDependency deps[2] = {};
  // Earlier reads of (and writes to) the attachments finish before the pass writes them.
  deps[0].srcSubpass = VK_SUBPASS_EXTERNAL;
  deps[0].dstSubpass = 0;
  deps[0].srcStageMask = earlier;
  deps[0].dstStageMask = kAttachmentStages;
  deps[0].srcAccessMask = earlier_writes;
  deps[0].dstAccessMask = kAttachmentWrites | VK_ACCESS_COLOR_ATTACHMENT_READ_BIT |
                          VK_ACCESS_DEPTH_STENCIL_ATTACHMENT_READ_BIT;
  // The pass's writes are visible to later shader reads and transfers.
  deps[1].srcSubpass = 0;
  deps[1].dstSubpass = VK_SUBPASS_EXTERNAL;
  deps[1].srcStageMask = kAttachmentStages;
  deps[1].dstStageMask = kOutside;
  deps[1].srcAccessMask = kAttachmentWrites;
  deps[1].dstAccessMask = VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_TRANSFER_READ_BIT;

  VkRenderPassCreateInfo rp{};
  rp.sType = VK_STRUCTURE_TYPE_RENDER_PASS_CREATE_INFO;
  rp.attachmentCount = uint32_t(attachments.size());
  rp.pAttachments = attachments.data();
  rp.subpassCount = 1;
  rp.pSubpasses = &subpass;
  rp.dependencyCount = 2;
  rp.pDependencies = deps;
  VK_RETURN_IF_ERROR(vkCreateRenderPass(t.device_, &rp, nullptr, &t.render_pass_));

  for (uint32_t layer = 0; layer < first->layers(); ++layer) {
    std::vector<VkImageView> views;
    for (const DeviceImage* img : all) views.push_back(img->layer_view(layer));
    VkFramebufferCreateInfo fb{};
    fb.sType = VK_STRUCTURE_TYPE_FRAMEBUFFER_CREATE_INFO;
    fb.renderPass = t.render_pass_;
    fb.attachmentCount = uint32_t(views.size());
    fb.pAttachments = views.data();
    fb.width = t.width_;
    fb.height = t.height_;
    fb.layers = 1;
    VkFramebuffer framebuffer = VK_NULL_HANDLE;
    VK_RETURN_IF_ERROR(vkCreateFramebuffer(t.device_, &fb, nullptr, &framebuffer));
    t.framebuffers_.push_back(framebuffer);
  }
  return t;
}

RenderTarget::~RenderTarget() { Release(); }

RenderTarget::RenderTarget(RenderTarget&& other) noexcept { *this = std::move(other); }

RenderTarget& RenderTarget::operator=(RenderTarget&& other) noexcept {
  if (this != &other) {
    Release();
    device_ = std::exchange(other.device_, VK_NULL_HANDLE);
    render_pass_ = std::exchange(other.render_pass_, VK_NULL_HANDLE);
    framebuffers_ = std::move(other.framebuffers_);
    other.framebuffers_.clear();
    colors_ = std::move(other.colors_);
    other.colors_.clear();
    depth_ = std::exchange(other.depth_, nullptr);
    color_final_layout_ = other.color_final_layout_;
    depth_final_layout_ = other.depth_final_layout_;
    width_ = other.width_;
    height_ = other.height_;
  }
  return *this;
}

void RenderTarget::Release() {
  if (device_ == VK_NULL_HANDLE) return;
  for (VkFramebuffer fb : framebuffers_) vkDestroyFramebuffer(device_, fb, nullptr);
  framebuffers_.clear();
  if (render_pass_ != VK_NULL_HANDLE) vkDestroyRenderPass(device_, render_pass_, nullptr);
  render_pass_ = VK_NULL_HANDLE;
  device_ = VK_NULL_HANDLE;
}

void RenderTarget::Begin(VkCommandBuffer cmd, uint32_t layer,
                         const std::vector<VkClearColorValue>& color_clear, float depth_clear) {
  std::vector<VkClearValue> clears(colors_.size() + (depth_ != nullptr ? 1 : 0));
  for (size_t i = 0; i < colors_.size(); ++i) {
    clears[i].color = i < color_clear.size() ? color_clear[i] : VkClearColorValue{};
  }
  if (depth_ != nullptr) clears.back().depthStencil = {depth_clear, 0};
  VkRenderPassBeginInfo begin{};
  begin.sType = VK_STRUCTURE_TYPE_RENDER_PASS_BEGIN_INFO;
  begin.renderPass = render_pass_;
  begin.framebuffer = framebuffers_[layer];
  begin.renderArea = {{0, 0}, {width_, height_}};
  begin.clearValueCount = uint32_t(clears.size());
  begin.pClearValues = clears.data();
  vkCmdBeginRenderPass(cmd, &begin, VK_SUBPASS_CONTENTS_INLINE);
  const VkViewport viewport{0, 0, float(width_), float(height_), 0, 1};
  const VkRect2D scissor{{0, 0}, {width_, height_}};
  vkCmdSetViewport(cmd, 0, 1, &viewport);
  vkCmdSetScissor(cmd, 0, 1, &scissor);
}

void RenderTarget::End(VkCommandBuffer cmd) {
  vkCmdEndRenderPass(cmd);
  for (DeviceImage* img : colors_) img->set_layout(color_final_layout_);
  if (depth_ != nullptr) depth_->set_layout(depth_final_layout_);
}

// ---- Pipeline --------------------------------------------------------------------------------

StatusOr<Pipeline> Pipeline::CreateGraphics(VkContext& ctx, const GraphicsPipelineOptions& o,
                                            const RenderTarget& target) {
  if (o.vertex == ShaderId::kCount) {
    return InvalidArgumentError("Pipeline::CreateGraphics: a vertex shader is required");
  }
  const bool has_fragment = o.fragment != ShaderId::kCount;
  Pipeline p;
  p.device_ = ctx.device();
  p.bind_point_ = VK_PIPELINE_BIND_POINT_GRAPHICS;
  p.push_stages_ = VK_SHADER_STAGE_VERTEX_BIT | VK_SHADER_STAGE_FRAGMENT_BIT;
  p.push_constant_bytes_ = o.push_constant_bytes;
  REFLCAP_ASSIGN_OR_RETURN(p.layout_,
                           CreateLayout(ctx, o.set_layout, o.push_constant_bytes, p.push_stages_));

  REFLCAP_ASSIGN_OR_RETURN(VkShaderModule vert, CreateModule(p.device_, o.vertex));
  StatusOr<VkShaderModule> frag = VkShaderModule(VK_NULL_HANDLE);
  if (has_fragment) frag = CreateModule(p.device_, o.fragment);
  if (!frag.ok()) {
    vkDestroyShaderModule(p.device_, vert, nullptr);
    return frag.status();
  }
  const Specialization spec(o.spec_constants);
  VkPipelineShaderStageCreateInfo stages[2] = {};
  stages[0].sType = VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO;
  stages[0].stage = VK_SHADER_STAGE_VERTEX_BIT;
  stages[0].module = vert;
  stages[0].pName = "main";
  stages[0].pSpecializationInfo = &spec.info;
  stages[1] = stages[0];
  stages[1].stage = VK_SHADER_STAGE_FRAGMENT_BIT;
  stages[1].module = *frag;

  VkPipelineVertexInputStateCreateInfo vertex_input{};
  vertex_input.sType = VK_STRUCTURE_TYPE_PIPELINE_VERTEX_INPUT_STATE_CREATE_INFO;
  VkPipelineInputAssemblyStateCreateInfo assembly{};
  assembly.sType = VK_STRUCTURE_TYPE_PIPELINE_INPUT_ASSEMBLY_STATE_CREATE_INFO;
  assembly.topology = VK_PRIMITIVE_TOPOLOGY_TRIANGLE_LIST;
  VkPipelineViewportStateCreateInfo viewport{};
  viewport.sType = VK_STRUCTURE_TYPE_PIPELINE_VIEWPORT_STATE_CREATE_INFO;
  viewport.viewportCount = 1;
  viewport.scissorCount = 1;
  VkPipelineRasterizationStateCreateInfo raster{};
  raster.sType = VK_STRUCTURE_TYPE_PIPELINE_RASTERIZATION_STATE_CREATE_INFO;
  raster.polygonMode = VK_POLYGON_MODE_FILL;
  raster.cullMode = o.cull_mode;
  raster.frontFace = VK_FRONT_FACE_COUNTER_CLOCKWISE;
  raster.lineWidth = 1.0f;
  VkPipelineMultisampleStateCreateInfo multisample{};
  multisample.sType = VK_STRUCTURE_TYPE_PIPELINE_MULTISAMPLE_STATE_CREATE_INFO;
  multisample.rasterizationSamples = VK_SAMPLE_COUNT_1_BIT;
  VkPipelineDepthStencilStateCreateInfo depth{};
  depth.sType = VK_STRUCTURE_TYPE_PIPELINE_DEPTH_STENCIL_STATE_CREATE_INFO;
  depth.depthTestEnable = o.depth_test ? VK_TRUE : VK_FALSE;
  depth.depthWriteEnable = o.depth_test && o.depth_write ? VK_TRUE : VK_FALSE;
  depth.depthCompareOp = o.depth_compare;
  std::vector<VkPipelineColorBlendAttachmentState> blend(target.color_count());
  for (auto& b : blend) {
    b = {};
    b.colorWriteMask = o.color_writes ? VK_COLOR_COMPONENT_R_BIT | VK_COLOR_COMPONENT_G_BIT |
                                            VK_COLOR_COMPONENT_B_BIT | VK_COLOR_COMPONENT_A_BIT
                                      : 0;
  }
  VkPipelineColorBlendStateCreateInfo color_blend{};
  color_blend.sType = VK_STRUCTURE_TYPE_PIPELINE_COLOR_BLEND_STATE_CREATE_INFO;
  color_blend.attachmentCount = uint32_t(blend.size());
  color_blend.pAttachments = blend.data();
  const VkDynamicState dynamic_states[2] = {VK_DYNAMIC_STATE_VIEWPORT, VK_DYNAMIC_STATE_SCISSOR};
  VkPipelineDynamicStateCreateInfo dynamic{};
  dynamic.sType = VK_STRUCTURE_TYPE_PIPELINE_DYNAMIC_STATE_CREATE_INFO;
  dynamic.dynamicStateCount = 2;
  dynamic.pDynamicStates = dynamic_states;

  VkGraphicsPipelineCreateInfo info{};
  info.sType = VK_STRUCTURE_TYPE_GRAPHICS_PIPELINE_CREATE_INFO;
  info.stageCount = has_fragment ? 2 : 1;
  info.pStages = stages;
  info.pVertexInputState = &vertex_input;
  info.pInputAssemblyState = &assembly;
  info.pViewportState = &viewport;
  info.pRasterizationState = &raster;
  info.pMultisampleState = &multisample;
  info.pDepthStencilState = &depth;
  info.pColorBlendState = &color_blend;
  info.pDynamicState = &dynamic;
  info.layout = p.layout_;
  info.renderPass = target.render_pass();
  info.subpass = 0;
  const VkResult r =
      vkCreateGraphicsPipelines(p.device_, VK_NULL_HANDLE, 1, &info, nullptr, &p.pipeline_);
  vkDestroyShaderModule(p.device_, vert, nullptr);
  if (has_fragment) vkDestroyShaderModule(p.device_, *frag, nullptr);
  if (r != VK_SUCCESS) {
    return VkResultToStatus(r,
                            StrCat("vkCreateGraphicsPipelines(", ShaderName(o.vertex), ", ",
                                   has_fragment ? ShaderName(o.fragment) : "no fragment stage", ")")
                                .c_str(),
                            __FILE__, __LINE__);
  }
  return p;
}

StatusOr<Pipeline> Pipeline::CreateCompute(VkContext& ctx, const ComputeLayoutPipelineOptions& o) {
  if (o.shader == ShaderId::kCount)
    return InvalidArgumentError("Pipeline::CreateCompute: no shader");
  Pipeline p;
  p.device_ = ctx.device();
  p.bind_point_ = VK_PIPELINE_BIND_POINT_COMPUTE;
  p.push_stages_ = VK_SHADER_STAGE_COMPUTE_BIT;
  p.push_constant_bytes_ = o.push_constant_bytes;
  REFLCAP_ASSIGN_OR_RETURN(p.layout_,
                           CreateLayout(ctx, o.set_layout, o.push_constant_bytes, p.push_stages_));
  REFLCAP_ASSIGN_OR_RETURN(VkShaderModule module, CreateModule(p.device_, o.shader));
  const Specialization spec(o.spec_constants);
  VkComputePipelineCreateInfo info{};
  info.sType = VK_STRUCTURE_TYPE_COMPUTE_PIPELINE_CREATE_INFO;
  info.stage.sType = VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO;
  info.stage.stage = VK_SHADER_STAGE_COMPUTE_BIT;
  info.stage.module = module;
  info.stage.pName = "main";
  info.stage.pSpecializationInfo = &spec.info;
  info.layout = p.layout_;
  const VkResult r =
      vkCreateComputePipelines(p.device_, VK_NULL_HANDLE, 1, &info, nullptr, &p.pipeline_);
  vkDestroyShaderModule(p.device_, module, nullptr);
  if (r != VK_SUCCESS) {
    return VkResultToStatus(r,
                            StrCat("vkCreateComputePipelines(", ShaderName(o.shader), ")").c_str(),
                            __FILE__, __LINE__);
  }
  return p;
}

Pipeline::~Pipeline() { Release(); }

Pipeline::Pipeline(Pipeline&& other) noexcept { *this = std::move(other); }

Pipeline& Pipeline::operator=(Pipeline&& other) noexcept {
  if (this != &other) {
    Release();
    device_ = std::exchange(other.device_, VK_NULL_HANDLE);
    layout_ = std::exchange(other.layout_, VK_NULL_HANDLE);
    pipeline_ = std::exchange(other.pipeline_, VK_NULL_HANDLE);
    bind_point_ = other.bind_point_;
    push_stages_ = other.push_stages_;
    push_constant_bytes_ = other.push_constant_bytes_;
  }
  return *this;
}

void Pipeline::Release() {
  if (device_ == VK_NULL_HANDLE) return;
  if (pipeline_ != VK_NULL_HANDLE) vkDestroyPipeline(device_, pipeline_, nullptr);
  if (layout_ != VK_NULL_HANDLE) vkDestroyPipelineLayout(device_, layout_, nullptr);
  pipeline_ = VK_NULL_HANDLE;
  layout_ = VK_NULL_HANDLE;
  device_ = VK_NULL_HANDLE;
}

void Pipeline::Bind(VkCommandBuffer cmd, VkDescriptorSet set) const {
  vkCmdBindPipeline(cmd, bind_point_, pipeline_);
  vkCmdBindDescriptorSets(cmd, bind_point_, layout_, 0, 1, &set, 0, nullptr);
}

void Pipeline::Push(VkCommandBuffer cmd, const void* data, uint32_t size) const {
  REFLCAP_CHECK(size == push_constant_bytes_)
      << size << " bytes of push constants for a " << push_constant_bytes_ << "-byte block";
  if (size > 0) vkCmdPushConstants(cmd, layout_, push_stages_, 0, size, data);
}

}  // namespace reflcap::gpu
