#include "engine/gpu/vk_image.h"

#include <cstring>
#include <utility>

#include "engine/gpu/vk_status.h"

namespace reflcap::gpu {
namespace {

bool IsDepthFormat(VkFormat format) { return format == VK_FORMAT_D32_SFLOAT; }

// Every stage that may touch an image before or after a transition, and every access: correct
// for any pair of uses, at the price of a full pipeline drain (reflcap records a few per frame).
constexpr VkPipelineStageFlags kAllStages = VK_PIPELINE_STAGE_ALL_COMMANDS_BIT;
constexpr VkAccessFlags kAllAccess =
    VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_SHADER_WRITE_BIT | VK_ACCESS_COLOR_ATTACHMENT_READ_BIT |
    VK_ACCESS_COLOR_ATTACHMENT_WRITE_BIT | VK_ACCESS_DEPTH_STENCIL_ATTACHMENT_READ_BIT |
    VK_ACCESS_DEPTH_STENCIL_ATTACHMENT_WRITE_BIT | VK_ACCESS_TRANSFER_READ_BIT |
    VK_ACCESS_TRANSFER_WRITE_BIT | VK_ACCESS_HOST_READ_BIT | VK_ACCESS_HOST_WRITE_BIT;

}  // namespace

uint32_t FormatBytes(VkFormat format) {
  switch (format) {
    case VK_FORMAT_R32_SFLOAT:
    case VK_FORMAT_R32_UINT:
    case VK_FORMAT_R32_SINT:
    case VK_FORMAT_D32_SFLOAT:
      return 4;
    case VK_FORMAT_R32G32B32A32_SFLOAT:
    case VK_FORMAT_R32G32B32A32_UINT:
      return 16;
    default:
      return 0;
  }
}

bool FormatSupports(const VkContext& ctx, VkFormat format, VkFormatFeatureFlags features) {
  VkFormatProperties props{};
  vkGetPhysicalDeviceFormatProperties(ctx.physical_device(), format, &props);
  return (props.optimalTilingFeatures & features) == features;
}

StatusOr<DeviceImage> DeviceImage::Create(VkContext& ctx, const ImageOptions& o) {
  if (o.width == 0 || o.height == 0 || o.layers == 0) {
    return InvalidArgumentError("DeviceImage: empty size ", o.width, "x", o.height, "x", o.layers);
  }
  if (FormatBytes(o.format) == 0) {
    return InvalidArgumentError("DeviceImage: unsupported format ", int(o.format));
  }
  if (o.cube_compatible && (o.layers % 6 != 0 || o.width != o.height)) {
    return InvalidArgumentError("DeviceImage: a cube map needs 6n square layers, got ", o.width,
                                "x", o.height, "x", o.layers);
  }
  VkFormatFeatureFlags features = 0;
  if (o.usage & VK_IMAGE_USAGE_SAMPLED_BIT) features |= VK_FORMAT_FEATURE_SAMPLED_IMAGE_BIT;
  if (o.usage & VK_IMAGE_USAGE_STORAGE_BIT) features |= VK_FORMAT_FEATURE_STORAGE_IMAGE_BIT;
  if (o.usage & VK_IMAGE_USAGE_COLOR_ATTACHMENT_BIT) {
    features |= VK_FORMAT_FEATURE_COLOR_ATTACHMENT_BIT;
  }
  if (o.usage & VK_IMAGE_USAGE_DEPTH_STENCIL_ATTACHMENT_BIT) {
    features |= VK_FORMAT_FEATURE_DEPTH_STENCIL_ATTACHMENT_BIT;
  }
  if (!FormatSupports(ctx, o.format, features)) {
    return UnavailableError("Vulkan device ", ctx.info().name, " does not support format ",
                            int(o.format), " with features 0x", std::hex, features);
  }
  const uint64_t bytes = uint64_t(o.width) * o.height * o.layers * FormatBytes(o.format);
  if (bytes > ctx.max_allocation_bytes()) {
    return UnavailableError("a ", o.width, "x", o.height, "x", o.layers, " image (", bytes,
                            " B) exceeds the single-allocation cap of ", ctx.max_allocation_bytes(),
                            " B on ", ctx.info().name);
  }

  DeviceImage img;
  img.device_ = ctx.device();
  img.width_ = o.width;
  img.height_ = o.height;
  img.layers_ = o.layers;
  img.format_ = o.format;
  img.aspect_ = IsDepthFormat(o.format) ? VK_IMAGE_ASPECT_DEPTH_BIT : VK_IMAGE_ASPECT_COLOR_BIT;

  VkImageCreateInfo info{};
  info.sType = VK_STRUCTURE_TYPE_IMAGE_CREATE_INFO;
  info.flags = o.cube_compatible ? VK_IMAGE_CREATE_CUBE_COMPATIBLE_BIT : 0;
  info.imageType = VK_IMAGE_TYPE_2D;
  info.format = o.format;
  info.extent = {o.width, o.height, 1};
  info.mipLevels = 1;
  info.arrayLayers = o.layers;
  info.samples = VK_SAMPLE_COUNT_1_BIT;
  info.tiling = VK_IMAGE_TILING_OPTIMAL;
  info.usage = o.usage | VK_IMAGE_USAGE_TRANSFER_SRC_BIT | VK_IMAGE_USAGE_TRANSFER_DST_BIT;
  info.sharingMode = VK_SHARING_MODE_EXCLUSIVE;
  info.initialLayout = VK_IMAGE_LAYOUT_UNDEFINED;
  VK_RETURN_IF_ERROR(vkCreateImage(img.device_, &info, nullptr, &img.image_));

  VkMemoryRequirements req{};
  vkGetImageMemoryRequirements(img.device_, img.image_, &req);
  StatusOr<uint32_t> type =
      ctx.FindMemoryType(req.memoryTypeBits, VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT);
  if (!type.ok()) type = ctx.FindMemoryType(req.memoryTypeBits, 0);
  if (!type.ok()) return type.status();
  VkMemoryAllocateInfo alloc{};
  alloc.sType = VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO;
  alloc.allocationSize = req.size;
  alloc.memoryTypeIndex = *type;
  VK_RETURN_IF_ERROR(vkAllocateMemory(img.device_, &alloc, nullptr, &img.memory_));
  VK_RETURN_IF_ERROR(vkBindImageMemory(img.device_, img.image_, img.memory_, 0));

  VkImageViewCreateInfo view{};
  view.sType = VK_STRUCTURE_TYPE_IMAGE_VIEW_CREATE_INFO;
  view.image = img.image_;
  view.viewType = VK_IMAGE_VIEW_TYPE_2D_ARRAY;
  view.format = o.format;
  view.subresourceRange = {img.aspect_, 0, 1, 0, o.layers};
  VK_RETURN_IF_ERROR(vkCreateImageView(img.device_, &view, nullptr, &img.array_view_));
  img.layer_views_.assign(o.layers, VK_NULL_HANDLE);
  for (uint32_t l = 0; l < o.layers; ++l) {
    view.viewType = VK_IMAGE_VIEW_TYPE_2D;
    view.subresourceRange = {img.aspect_, 0, 1, l, 1};
    VK_RETURN_IF_ERROR(vkCreateImageView(img.device_, &view, nullptr, &img.layer_views_[l]));
  }
  return img;
}

DeviceImage::~DeviceImage() { Release(); }

DeviceImage::DeviceImage(DeviceImage&& other) noexcept { *this = std::move(other); }

DeviceImage& DeviceImage::operator=(DeviceImage&& other) noexcept {
  if (this != &other) {
    Release();
    device_ = std::exchange(other.device_, VK_NULL_HANDLE);
    image_ = std::exchange(other.image_, VK_NULL_HANDLE);
    memory_ = std::exchange(other.memory_, VK_NULL_HANDLE);
    array_view_ = std::exchange(other.array_view_, VK_NULL_HANDLE);
    layer_views_ = std::move(other.layer_views_);
    other.layer_views_.clear();
    width_ = std::exchange(other.width_, 0);
    height_ = std::exchange(other.height_, 0);
    layers_ = std::exchange(other.layers_, 0);
    format_ = other.format_;
    aspect_ = other.aspect_;
    layout_ = std::exchange(other.layout_, VK_IMAGE_LAYOUT_UNDEFINED);
  }
  return *this;
}

void DeviceImage::Release() {
  if (device_ == VK_NULL_HANDLE) return;
  for (VkImageView v : layer_views_) {
    if (v != VK_NULL_HANDLE) vkDestroyImageView(device_, v, nullptr);
  }
  layer_views_.clear();
  if (array_view_ != VK_NULL_HANDLE) vkDestroyImageView(device_, array_view_, nullptr);
  if (image_ != VK_NULL_HANDLE) vkDestroyImage(device_, image_, nullptr);
  if (memory_ != VK_NULL_HANDLE) vkFreeMemory(device_, memory_, nullptr);
  device_ = VK_NULL_HANDLE;
  image_ = VK_NULL_HANDLE;
  memory_ = VK_NULL_HANDLE;
  array_view_ = VK_NULL_HANDLE;
}

void DeviceImage::TransitionTo(VkCommandBuffer cmd, VkImageLayout layout) {
  if (layout == layout_ && layout != VK_IMAGE_LAYOUT_GENERAL) return;
  VkImageMemoryBarrier barrier{};
  barrier.sType = VK_STRUCTURE_TYPE_IMAGE_MEMORY_BARRIER;
  barrier.srcAccessMask = kAllAccess;
  barrier.dstAccessMask = kAllAccess;
  barrier.oldLayout = layout_;
  barrier.newLayout = layout;
  barrier.srcQueueFamilyIndex = VK_QUEUE_FAMILY_IGNORED;
  barrier.dstQueueFamilyIndex = VK_QUEUE_FAMILY_IGNORED;
  barrier.image = image_;
  barrier.subresourceRange = {aspect_, 0, 1, 0, layers_};
  vkCmdPipelineBarrier(cmd, kAllStages, kAllStages, 0, 0, nullptr, 0, nullptr, 1, &barrier);
  layout_ = layout;
}

Status UploadImageLayer(VkContext& ctx, CommandBuffer& cmd, DeviceImage& image, uint32_t layer,
                        const void* data, uint64_t bytes) {
  if (image.handle() == VK_NULL_HANDLE)
    return InvalidArgumentError("UploadImageLayer: empty image");
  if (layer >= image.layers() || bytes != image.layer_bytes()) {
    return InvalidArgumentError("UploadImageLayer: layer ", layer, " of ", image.layers(), ", ",
                                bytes, " bytes for a ", image.layer_bytes(), "-byte layer");
  }
  REFLCAP_ASSIGN_OR_RETURN(Buffer * staging, ctx.StagingBuffer(bytes));
  std::memcpy(staging->mapped(), data, bytes);
  REFLCAP_RETURN_IF_ERROR(cmd.Begin());
  // Keep the other layers' contents: move from the tracked layout (UNDEFINED only before the
  // first upload, when there is nothing to keep).
  image.TransitionTo(cmd.handle(), VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL);
  VkBufferImageCopy region{};
  region.bufferOffset = 0;
  region.imageSubresource = {image.aspect(), 0, layer, 1};
  region.imageExtent = {image.width(), image.height(), 1};
  vkCmdCopyBufferToImage(cmd.handle(), staging->handle(), image.handle(),
                         VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, 1, &region);
  image.TransitionTo(cmd.handle(), VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL);
  return cmd.SubmitAndWait();
}

Status RecordCopyImageToBuffer(CommandBuffer& cmd, DeviceImage& image, uint32_t layer,
                               const Buffer& dst, uint64_t dst_offset) {
  if (!cmd.recording()) {
    return FailedPreconditionError("RecordCopyImageToBuffer: CommandBuffer is not recording");
  }
  if (layer >= image.layers() || dst_offset > dst.size() ||
      image.layer_bytes() > dst.size() - dst_offset) {
    return InvalidArgumentError("RecordCopyImageToBuffer: layer ", layer, " (", image.layer_bytes(),
                                " bytes) at offset ", dst_offset, " of a ", dst.size(),
                                "-byte buffer");
  }
  image.TransitionTo(cmd.handle(), VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL);
  VkBufferImageCopy region{};
  region.bufferOffset = dst_offset;
  region.imageSubresource = {image.aspect(), 0, layer, 1};
  region.imageExtent = {image.width(), image.height(), 1};
  vkCmdCopyImageToBuffer(cmd.handle(), image.handle(), VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL,
                         dst.handle(), 1, &region);
  return OkStatus();
}

StatusOr<Sampler> Sampler::Create(VkContext& ctx) {
  Sampler s;
  s.device_ = ctx.device();
  VkSamplerCreateInfo info{};
  info.sType = VK_STRUCTURE_TYPE_SAMPLER_CREATE_INFO;
  info.magFilter = VK_FILTER_NEAREST;
  info.minFilter = VK_FILTER_NEAREST;
  info.mipmapMode = VK_SAMPLER_MIPMAP_MODE_NEAREST;
  info.addressModeU = VK_SAMPLER_ADDRESS_MODE_CLAMP_TO_EDGE;
  info.addressModeV = VK_SAMPLER_ADDRESS_MODE_CLAMP_TO_EDGE;
  info.addressModeW = VK_SAMPLER_ADDRESS_MODE_CLAMP_TO_EDGE;
  info.maxLod = 0;
  VK_RETURN_IF_ERROR(vkCreateSampler(s.device_, &info, nullptr, &s.sampler_));
  return s;
}

Sampler::~Sampler() {
  if (device_ != VK_NULL_HANDLE && sampler_ != VK_NULL_HANDLE) {
    vkDestroySampler(device_, sampler_, nullptr);
  }
}

Sampler::Sampler(Sampler&& other) noexcept { *this = std::move(other); }

Sampler& Sampler::operator=(Sampler&& other) noexcept {
  if (this != &other) {
    if (device_ != VK_NULL_HANDLE && sampler_ != VK_NULL_HANDLE) {
      vkDestroySampler(device_, sampler_, nullptr);
    }
    device_ = std::exchange(other.device_, VK_NULL_HANDLE);
    sampler_ = std::exchange(other.sampler_, VK_NULL_HANDLE);
  }
  return *this;
}

}  // namespace reflcap::gpu
