#pragma once
// VkContext: one headless Vulkan 1.2 instance, one physical device, one logical device with a
// single compute queue (graphics + compute with ContextOptions::require_graphics, for the Vulkan
// renderer) and a command pool — what every reflcap GPU path (the GPU fitter, visibility masks,
// the Vulkan renderer) creates once and shares. No surface, no swapchain.
// After uVkCompute's vulkan/driver.h + device.h, folded into one object.
//
// Device choice: ContextOptions::device (see SelectDevice in engine/gpu/device_info.h): a discrete
// GPU when there is one, else an integrated or virtual GPU, else a CPU device (lavapipe); or an
// explicit name substring or index (the CLI's --device NAME|INDEX). Every optional feature the
// device supports from a fixed list (shaderFloat64, shaderInt64, shaderInt16, 16-bit storage,
// shaderFloat16, hostQueryReset, scalarBlockLayout) is enabled; DeviceInfo says which.
//
// Validation: in Debug builds (or when asked) VK_LAYER_KHRONOS_validation is enabled if it is
// installed, and its messages go to REFLCAP_LOG through a VK_EXT_debug_utils messenger.
//
// Errors: Create returns Unavailable with a message saying what is missing when there is no
// Vulkan driver (ICD), no device, or no usable one, so that `--backend auto` can fall back to the
// CPU. A VkContext is used by one thread at a time; objects created from it (Buffer,
// ComputePipeline, CommandBuffer, TimestampQueryPool) must be destroyed before it.
//
// This header includes <vulkan/vulkan.h>: include it only from GPU code. Code that only reports
// devices uses engine/gpu/device_info.h and ListDevices below.
#include <vulkan/vulkan.h>

#include <memory>
#include <string>
#include <vector>

#include "engine/core/status.h"
#include "engine/gpu/device_info.h"

namespace reflcap::gpu {

struct ContextOptions {
  // "" = automatic; a decimal index; or a case-insensitive substring of the device name, driver
  // name or driver info ("lavapipe" matches llvmpipe). See SelectDevice.
  std::string device;
  // Enable VK_LAYER_KHRONOS_validation when it is installed (logs a note when it is not).
  // Default: on in Debug builds (NDEBUG undefined), off otherwise.
#ifdef NDEBUG
  bool validation = false;
#else
  bool validation = true;
#endif
  // How long CommandBuffer::SubmitAndWait waits for one submission before returning Unavailable,
  // seconds (> 0). Real GPUs should finish each submit in well under a second; lavapipe runs on
  // the CPU and may take far longer for the same work.
  double submit_timeout_s = 60.0;
  // Use a queue family that supports graphics as well as compute (the Vulkan renderer's
  // rasterisation passes). Off: the compute-only family is preferred where there is one. On a
  // device without such a family Create returns Unavailable.
  bool require_graphics = false;

  Status Validate() const;
};

// Largest single allocation reflcap makes: lavapipe crashes (instead of failing) on an
// allocation above 2 GiB, and allocations near a heap's size fail or thrash on many drivers.
// Buffer::Create refuses larger requests with Unavailable; the effective cap is
// VkContext::max_allocation_bytes() (also <= maxMemoryAllocationSize and the device-local heap).
inline constexpr uint64_t kMaxAllocationBytes = uint64_t{1} << 30;  // 1 GiB

// Every physical device the Vulkan loader reports, with its limits and whether it is usable.
// Unavailable when there is no Vulkan driver (no ICD) or no device at all.
StatusOr<std::vector<DeviceInfo>> ListDevices();

class Buffer;  // engine/gpu/vk_buffer.h

class VkContext {
 public:
  static StatusOr<std::unique_ptr<VkContext>> Create(const ContextOptions& options = {});
  ~VkContext();
  VkContext(const VkContext&) = delete;
  VkContext& operator=(const VkContext&) = delete;

  // The device in use, its limits and enabled features (timestamp_valid_bits is the queue's).
  const DeviceInfo& info() const { return info_; }
  const ContextOptions& options() const { return options_; }
  bool validation_enabled() const { return validation_enabled_; }

  VkInstance instance() const { return instance_; }
  VkPhysicalDevice physical_device() const { return physical_device_; }
  VkDevice device() const { return device_; }
  VkQueue queue() const { return queue_; }
  uint32_t queue_family() const { return queue_family_; }
  VkCommandPool command_pool() const { return command_pool_; }

  // Effective per-allocation cap: min(kMaxAllocationBytes, maxMemoryAllocationSize,
  // device-local heap size).
  uint64_t max_allocation_bytes() const;

  // Index of a memory type allowed by `type_bits` (VkMemoryRequirements::memoryTypeBits) with
  // all `required` flags, preferring one that also has all `preferred` flags. NotFound if none.
  StatusOr<uint32_t> FindMemoryType(uint32_t type_bits, VkMemoryPropertyFlags required,
                                    VkMemoryPropertyFlags preferred = 0) const;
  // Flags of memory type `index`.
  VkMemoryPropertyFlags MemoryTypeFlags(uint32_t index) const;

  // vkDeviceWaitIdle.
  Status WaitIdle();

  // A host-visible, coherent buffer of at least `bytes` bytes (> 0) that UploadStaged and
  // DownloadStaged reuse across calls instead of allocating one each time; it grows on demand and
  // its contents belong to whoever called last.
  StatusOr<Buffer*> StagingBuffer(uint64_t bytes);

 private:
  VkContext() = default;

  ContextOptions options_;
  DeviceInfo info_;
  bool validation_enabled_ = false;
  VkInstance instance_ = VK_NULL_HANDLE;
  VkDebugUtilsMessengerEXT messenger_ = VK_NULL_HANDLE;
  VkPhysicalDevice physical_device_ = VK_NULL_HANDLE;
  VkPhysicalDeviceMemoryProperties memory_properties_{};
  VkDevice device_ = VK_NULL_HANDLE;
  VkQueue queue_ = VK_NULL_HANDLE;
  uint32_t queue_family_ = 0;
  VkCommandPool command_pool_ = VK_NULL_HANDLE;
  std::unique_ptr<Buffer> staging_;
};

// MaxLoopIterationsPerInvocation(ctx.info()): see engine/gpu/device_info.h.
inline uint32_t MaxLoopIterationsPerInvocation(const VkContext& ctx) {
  return MaxLoopIterationsPerInvocation(ctx.info());
}

}  // namespace reflcap::gpu
