#pragma once
// DeviceImage: one 2-D VkImage (optionally an array of layers, optionally cube-compatible) in
// device-local memory with its views, and Sampler — what the rasterisation paths need beyond the
// compute foundation's buffers: render targets (colour and depth attachments), textures read with
// texelFetch, and copies between images and buffers. After uVkCompute's vulkan/image.h.
//
// Layout tracking: a DeviceImage remembers the layout its last recorded transition left it in
// (every layer alike). TransitionTo records a barrier from that layout with conservative stage and
// access masks (all shader, attachment and transfer stages), which is correct for every use here
// and costs nothing measurable at reflcap's few transitions per frame. Code that changes the
// layout another way (a render pass's finalLayout) calls set_layout.
//
// Sizes are texels; formats are the handful reflcap renders into or samples (FormatBytes). Create
// refuses an allocation above VkContext::max_allocation_bytes() with Unavailable (as Buffer does).
#include <vulkan/vulkan.h>

#include <cstdint>
#include <vector>

#include "engine/core/status.h"
#include "engine/gpu/vk_buffer.h"
#include "engine/gpu/vk_commands.h"
#include "engine/gpu/vk_context.h"

namespace reflcap::gpu {

// Bytes per texel of the formats reflcap uses (R32_SFLOAT, R32_UINT, R32_SINT,
// R32G32B32A32_SFLOAT, R32G32B32A32_UINT, D32_SFLOAT); 0 for any other.
uint32_t FormatBytes(VkFormat format);
// Whether optimal-tiling images of `format` support every one of `features` on the device.
bool FormatSupports(const VkContext& ctx, VkFormat format, VkFormatFeatureFlags features);

struct ImageOptions {
  uint32_t width = 0;                     // texels, > 0
  uint32_t height = 0;                    // texels, > 0
  uint32_t layers = 1;                    // array layers, > 0 (6 for a cube map)
  VkFormat format = VK_FORMAT_UNDEFINED;  // one FormatBytes knows
  // What the image is for (sampled, colour or depth attachment, storage); transfer source and
  // destination are always added, so any image can be uploaded and read back.
  VkImageUsageFlags usage = 0;
  // VK_IMAGE_CREATE_CUBE_COMPATIBLE_BIT: layers a multiple of 6 and width == height.
  bool cube_compatible = false;
};

class DeviceImage {
 public:
  // InvalidArgument for a bad size or unknown format; Unavailable when the device cannot make such
  // an image (format features, size limits, memory).
  static StatusOr<DeviceImage> Create(VkContext& ctx, const ImageOptions& options);

  DeviceImage() = default;
  ~DeviceImage();
  DeviceImage(DeviceImage&& other) noexcept;
  DeviceImage& operator=(DeviceImage&& other) noexcept;
  DeviceImage(const DeviceImage&) = delete;
  DeviceImage& operator=(const DeviceImage&) = delete;

  VkImage handle() const { return image_; }
  // A view of every layer: VK_IMAGE_VIEW_TYPE_2D_ARRAY (even for one layer, so shaders declare
  // sampler2DArray-style bindings uniformly) — see view_2d for a plain 2-D view of layer 0.
  VkImageView array_view() const { return array_view_; }
  // VK_IMAGE_VIEW_TYPE_2D of layer `layer` (framebuffer attachments, sampler2D bindings).
  VkImageView layer_view(uint32_t layer) const { return layer_views_[layer]; }
  VkImageView view_2d() const { return layer_views_[0]; }
  uint32_t width() const { return width_; }
  uint32_t height() const { return height_; }
  uint32_t layers() const { return layers_; }
  VkFormat format() const { return format_; }
  VkImageAspectFlags aspect() const { return aspect_; }
  uint64_t layer_bytes() const { return uint64_t(width_) * height_ * FormatBytes(format_); }

  VkImageLayout layout() const { return layout_; }
  void set_layout(VkImageLayout layout) { layout_ = layout; }
  // Records a barrier that moves every layer from layout() to `layout` (no-op when equal, except
  // that a write-to-read barrier is still recorded for GENERAL).
  void TransitionTo(VkCommandBuffer cmd, VkImageLayout layout);

 private:
  void Release();

  VkDevice device_ = VK_NULL_HANDLE;
  VkImage image_ = VK_NULL_HANDLE;
  VkDeviceMemory memory_ = VK_NULL_HANDLE;
  VkImageView array_view_ = VK_NULL_HANDLE;
  std::vector<VkImageView> layer_views_;
  uint32_t width_ = 0, height_ = 0, layers_ = 0;
  VkFormat format_ = VK_FORMAT_UNDEFINED;
  VkImageAspectFlags aspect_ = VK_IMAGE_ASPECT_COLOR_BIT;
  VkImageLayout layout_ = VK_IMAGE_LAYOUT_UNDEFINED;
};

// Copies `bytes` (= image.layer_bytes(), rows tightly packed, row 0 first) from host `data` into
// layer `layer`, through the context's staging buffer in one submission of `cmd` (which must not
// be recording); the image ends in SHADER_READ_ONLY_OPTIMAL.
Status UploadImageLayer(VkContext& ctx, CommandBuffer& cmd, DeviceImage& image, uint32_t layer,
                        const void* data, uint64_t bytes);

// Records (into `cmd`, recording) a copy of layer `layer` into `dst` at `dst_offset`, rows
// tightly packed; the image is moved to TRANSFER_SRC_OPTIMAL first. The copy is visible to the
// host after cmd.SubmitAndWait(). InvalidArgument when it does not fit.
Status RecordCopyImageToBuffer(CommandBuffer& cmd, DeviceImage& image, uint32_t layer,
                               const Buffer& dst, uint64_t dst_offset);

// A nearest-neighbour, clamp-to-edge sampler: reflcap's shaders read textures with texelFetch,
// which ignores the sampler, but combined image-sampler bindings need one.
class Sampler {
 public:
  static StatusOr<Sampler> Create(VkContext& ctx);
  Sampler() = default;
  ~Sampler();
  Sampler(Sampler&& other) noexcept;
  Sampler& operator=(Sampler&& other) noexcept;
  Sampler(const Sampler&) = delete;
  Sampler& operator=(const Sampler&) = delete;
  VkSampler handle() const { return sampler_; }

 private:
  VkDevice device_ = VK_NULL_HANDLE;
  VkSampler sampler_ = VK_NULL_HANDLE;
};

}  // namespace reflcap::gpu
