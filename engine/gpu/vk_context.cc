#include "engine/gpu/vk_context.h"

#include <algorithm>
#include <cstring>

#include "engine/core/log.h"
#include "engine/gpu/vk_buffer.h"
#include "engine/gpu/vk_status.h"

namespace reflcap::gpu {
namespace {

constexpr const char* kValidationLayer = "VK_LAYER_KHRONOS_validation";
constexpr uint32_t kRequiredApiVersion = VK_API_VERSION_1_2;

std::string VersionString(uint32_t v) {
  return StrCat(VK_API_VERSION_MAJOR(v), ".", VK_API_VERSION_MINOR(v), ".",
                VK_API_VERSION_PATCH(v));
}

DeviceType ToDeviceType(VkPhysicalDeviceType type) {
  switch (type) {
    case VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU:
      return DeviceType::kDiscreteGpu;
    case VK_PHYSICAL_DEVICE_TYPE_INTEGRATED_GPU:
      return DeviceType::kIntegratedGpu;
    case VK_PHYSICAL_DEVICE_TYPE_VIRTUAL_GPU:
      return DeviceType::kVirtualGpu;
    case VK_PHYSICAL_DEVICE_TYPE_CPU:
      return DeviceType::kCpu;
    default:
      return DeviceType::kOther;
  }
}

VKAPI_ATTR VkBool32 VKAPI_CALL DebugMessengerCallback(
    VkDebugUtilsMessageSeverityFlagBitsEXT severity, VkDebugUtilsMessageTypeFlagsEXT /*types*/,
    const VkDebugUtilsMessengerCallbackDataEXT* data, void* /*user*/) {
  const char* message = (data != nullptr && data->pMessage != nullptr) ? data->pMessage : "";
  if (severity & VK_DEBUG_UTILS_MESSAGE_SEVERITY_ERROR_BIT_EXT) {
    REFLCAP_LOG(kError) << "Vulkan: " << message;
  } else if (severity & VK_DEBUG_UTILS_MESSAGE_SEVERITY_WARNING_BIT_EXT) {
    REFLCAP_LOG(kWarning) << "Vulkan: " << message;
  } else {
    REFLCAP_LOG(kDebug) << "Vulkan: " << message;
  }
  return VK_FALSE;  // never abort the call that triggered the message
}

bool HasLayer(const char* name) {
  uint32_t count = 0;
  if (vkEnumerateInstanceLayerProperties(&count, nullptr) != VK_SUCCESS) return false;
  std::vector<VkLayerProperties> layers(count);
  if (vkEnumerateInstanceLayerProperties(&count, layers.data()) != VK_SUCCESS) return false;
  for (const VkLayerProperties& layer : layers) {
    if (std::strcmp(layer.layerName, name) == 0) return true;
  }
  return false;
}

bool HasInstanceExtension(const char* name) {
  uint32_t count = 0;
  if (vkEnumerateInstanceExtensionProperties(nullptr, &count, nullptr) != VK_SUCCESS) return false;
  std::vector<VkExtensionProperties> extensions(count);
  if (vkEnumerateInstanceExtensionProperties(nullptr, &count, extensions.data()) != VK_SUCCESS) {
    return false;
  }
  for (const VkExtensionProperties& e : extensions) {
    if (std::strcmp(e.extensionName, name) == 0) return true;
  }
  return false;
}

struct InstanceResult {
  VkInstance instance = VK_NULL_HANDLE;
  bool validation = false;
  bool debug_utils = false;
};

StatusOr<InstanceResult> CreateInstance(bool want_validation) {
  uint32_t loader_version = VK_API_VERSION_1_0;
  // vkEnumerateInstanceVersion exists from loader 1.1 on; a 1.0 loader has no such entry point.
  auto enumerate_version = reinterpret_cast<PFN_vkEnumerateInstanceVersion>(
      vkGetInstanceProcAddr(VK_NULL_HANDLE, "vkEnumerateInstanceVersion"));
  if (enumerate_version != nullptr) VK_RETURN_IF_ERROR(enumerate_version(&loader_version));
  if (loader_version < kRequiredApiVersion) {
    return UnavailableError("the Vulkan loader supports Vulkan ", VersionString(loader_version),
                            "; reflcap needs 1.2");
  }

  InstanceResult result;
  std::vector<const char*> layers;
  std::vector<const char*> extensions;
  if (want_validation) {
    if (HasLayer(kValidationLayer)) {
      layers.push_back(kValidationLayer);
      result.validation = true;
    } else {
      REFLCAP_LOG(kDebug) << "Vulkan validation requested but " << kValidationLayer
                          << " is not installed; running without it";
    }
  }
  if (result.validation && HasInstanceExtension(VK_EXT_DEBUG_UTILS_EXTENSION_NAME)) {
    extensions.push_back(VK_EXT_DEBUG_UTILS_EXTENSION_NAME);
    result.debug_utils = true;
  }
  VkInstanceCreateFlags flags = 0;
  // Lists drivers that only implement a portable subset (MoltenVK); harmless elsewhere.
  if (HasInstanceExtension(VK_KHR_PORTABILITY_ENUMERATION_EXTENSION_NAME)) {
    extensions.push_back(VK_KHR_PORTABILITY_ENUMERATION_EXTENSION_NAME);
    flags |= VK_INSTANCE_CREATE_ENUMERATE_PORTABILITY_BIT_KHR;
  }

  VkApplicationInfo app{};

  app.sType = VK_STRUCTURE_TYPE_APPLICATION_INFO;
  app.pApplicationName = "reflcap";
  app.applicationVersion = VK_MAKE_API_VERSION(0, 0, 1, 0);
  app.pEngineName = "reflcap";
  app.engineVersion = VK_MAKE_API_VERSION(0, 0, 1, 0);
  app.apiVersion = kRequiredApiVersion;
  VkInstanceCreateInfo info{};
  info.sType = VK_STRUCTURE_TYPE_INSTANCE_CREATE_INFO;
  info.flags = flags;
  info.pApplicationInfo = &app;
  info.enabledLayerCount = static_cast<uint32_t>(layers.size());
  info.ppEnabledLayerNames = layers.data();
  info.enabledExtensionCount = static_cast<uint32_t>(extensions.size());
  info.ppEnabledExtensionNames = extensions.data();
  const VkResult r = vkCreateInstance(&info, nullptr, &result.instance);
  if (r == VK_ERROR_INCOMPATIBLE_DRIVER) {
    return UnavailableError(
        "no Vulkan driver found (vkCreateInstance: VK_ERROR_INCOMPATIBLE_DRIVER): no ICD is "
        "installed or none supports Vulkan 1.2; install a GPU driver, or mesa-vulkan-drivers for "
        "the CPU device lavapipe");
  }
  VK_RETURN_IF_ERROR(r);
  return result;
}

// The queue family reflcap uses: compute-capable, preferring a compute-only family (asynchronous
// compute on discrete GPUs) that has timestamps, then any compute family with timestamps, then
// any compute family. With `require_graphics`, only families that also support graphics count.
// -1 when there is none.
int ChooseQueueFamily(const std::vector<VkQueueFamilyProperties>& families,
                      bool require_graphics = false) {
  int best = -1;
  int best_score = -1;
  for (size_t i = 0; i < families.size(); ++i) {
    const VkQueueFamilyProperties& f = families[i];
    if (!(f.queueFlags & VK_QUEUE_COMPUTE_BIT) || f.queueCount == 0) continue;
    if (require_graphics && !(f.queueFlags & VK_QUEUE_GRAPHICS_BIT)) continue;
    const int score =
        (f.timestampValidBits > 0 ? 2 : 0) + ((f.queueFlags & VK_QUEUE_GRAPHICS_BIT) ? 0 : 1);
    if (score > best_score) {
      best = static_cast<int>(i);
      best_score = score;
    }
  }
  return best;
}

std::vector<VkQueueFamilyProperties> QueueFamilies(VkPhysicalDevice device) {
  uint32_t count = 0;
  vkGetPhysicalDeviceQueueFamilyProperties(device, &count, nullptr);
  std::vector<VkQueueFamilyProperties> families(count);
  vkGetPhysicalDeviceQueueFamilyProperties(device, &count, families.data());
  return families;
}

DeviceInfo DescribeDevice(VkPhysicalDevice device, uint32_t index) {
  DeviceInfo info;
  info.index = index;
  VkPhysicalDeviceProperties props{};
  vkGetPhysicalDeviceProperties(device, &props);
  info.name = props.deviceName;
  info.type = ToDeviceType(props.deviceType);
  info.vendor_id = props.vendorID;
  info.device_id = props.deviceID;
  info.api_version = props.apiVersion;
  info.driver_version = props.driverVersion;
  const VkPhysicalDeviceLimits& l = props.limits;
  info.max_storage_buffer_range = l.maxStorageBufferRange;
  info.min_storage_buffer_offset_alignment = l.minStorageBufferOffsetAlignment;
  info.non_coherent_atom_size = l.nonCoherentAtomSize;
  info.max_push_constants_size = l.maxPushConstantsSize;
  info.max_per_stage_storage_buffers = l.maxPerStageDescriptorStorageBuffers;
  info.max_compute_work_group_invocations = l.maxComputeWorkGroupInvocations;
  for (int i = 0; i < 3; ++i) {
    info.max_compute_work_group_size[i] = l.maxComputeWorkGroupSize[i];
    info.max_compute_work_group_count[i] = l.maxComputeWorkGroupCount[i];
  }
  info.max_compute_shared_memory_size = l.maxComputeSharedMemorySize;
  info.timestamp_period_ns = l.timestampPeriod;

  VkPhysicalDeviceMemoryProperties memory{};
  vkGetPhysicalDeviceMemoryProperties(device, &memory);
  for (uint32_t h = 0; h < memory.memoryHeapCount; ++h) {
    if (memory.memoryHeaps[h].flags & VK_MEMORY_HEAP_DEVICE_LOCAL_BIT) {
      info.device_local_heap_size =
          std::max(info.device_local_heap_size, memory.memoryHeaps[h].size);
    }
  }
  constexpr VkMemoryPropertyFlags kUnified = VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT |
                                             VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT |
                                             VK_MEMORY_PROPERTY_HOST_COHERENT_BIT;
  for (uint32_t t = 0; t < memory.memoryTypeCount; ++t) {
    if ((memory.memoryTypes[t].propertyFlags & kUnified) == kUnified) info.unified_memory = true;
  }

  const std::vector<VkQueueFamilyProperties> families = QueueFamilies(device);
  const int family = ChooseQueueFamily(families);
  if (family >= 0) info.timestamp_valid_bits = families[family].timestampValidBits;

  if (props.apiVersion < kRequiredApiVersion) {
    info.unusable_reason =
        StrCat("supports Vulkan ", VersionString(props.apiVersion), "; reflcap needs 1.2");
    return info;
  }
  VkPhysicalDeviceVulkan11Properties props11{};
  props11.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_1_PROPERTIES;
  VkPhysicalDeviceVulkan12Properties props12{};
  props12.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_2_PROPERTIES;
  props11.pNext = &props12;
  VkPhysicalDeviceProperties2 props2{};
  props2.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2;
  props2.pNext = &props11;
  vkGetPhysicalDeviceProperties2(device, &props2);
  info.max_memory_allocation_size = props11.maxMemoryAllocationSize;
  info.subgroup_size = props11.subgroupSize;
  constexpr VkSubgroupFeatureFlags kShuffleOps =
      VK_SUBGROUP_FEATURE_BASIC_BIT | VK_SUBGROUP_FEATURE_VOTE_BIT | VK_SUBGROUP_FEATURE_SHUFFLE_BIT;
  info.compute_subgroup_shuffle =
      (props11.subgroupSupportedStages & VK_SHADER_STAGE_COMPUTE_BIT) != 0 &&
      (props11.subgroupSupportedOperations & kShuffleOps) == kShuffleOps;
  info.driver_id = static_cast<uint32_t>(props12.driverID);
  info.driver_name = props12.driverName;
  info.driver_info = props12.driverInfo;

  VkPhysicalDeviceVulkan11Features features11{};

  features11.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_1_FEATURES;
  VkPhysicalDeviceVulkan12Features features12{};
  features12.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_2_FEATURES;
  features11.pNext = &features12;
  VkPhysicalDeviceFeatures2 features2{};
  features2.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_FEATURES_2;
  features2.pNext = &features11;
  vkGetPhysicalDeviceFeatures2(device, &features2);
  info.shader_float64 = features2.features.shaderFloat64;
  info.shader_int64 = features2.features.shaderInt64;
  info.shader_int16 = features2.features.shaderInt16;
  info.storage_buffer_16bit_access = features11.storageBuffer16BitAccess;
  info.shader_float16 = features12.shaderFloat16;
  info.host_query_reset = features12.hostQueryReset;
  info.scalar_block_layout = features12.scalarBlockLayout;

  if (family < 0) {
    info.unusable_reason = "has no compute queue";
    return info;
  }
  info.usable = true;
  return info;
}

StatusOr<std::vector<VkPhysicalDevice>> PhysicalDevices(VkInstance instance) {
  uint32_t count = 0;
  VK_RETURN_IF_ERROR(vkEnumeratePhysicalDevices(instance, &count, nullptr));
  std::vector<VkPhysicalDevice> devices(count);
  if (count > 0) VK_RETURN_IF_ERROR(vkEnumeratePhysicalDevices(instance, &count, devices.data()));
  devices.resize(count);
  if (devices.empty()) {
    return UnavailableError("a Vulkan driver is installed but reports no device");
  }
  return devices;
}

}  // namespace

Status ContextOptions::Validate() const {
  if (!(submit_timeout_s > 0)) {
    return InvalidArgumentError("ContextOptions::submit_timeout_s must be positive (got ",
                                submit_timeout_s, ")");
  }
  return OkStatus();
}

StatusOr<std::vector<DeviceInfo>> ListDevices() {
  REFLCAP_ASSIGN_OR_RETURN(InstanceResult instance, CreateInstance(/*want_validation=*/false));
  StatusOr<std::vector<VkPhysicalDevice>> devices = PhysicalDevices(instance.instance);
  std::vector<DeviceInfo> infos;
  if (devices.ok()) {
    for (size_t i = 0; i < devices->size(); ++i) {
      infos.push_back(DescribeDevice((*devices)[i], static_cast<uint32_t>(i)));
    }
  }
  vkDestroyInstance(instance.instance, nullptr);
  if (!devices.ok()) return devices.status();
  return infos;
}

StatusOr<std::unique_ptr<VkContext>> VkContext::Create(const ContextOptions& options) {
  REFLCAP_RETURN_IF_ERROR(options.Validate());
  std::unique_ptr<VkContext> ctx(new VkContext());
  ctx->options_ = options;

  REFLCAP_ASSIGN_OR_RETURN(InstanceResult instance, CreateInstance(options.validation));
  ctx->instance_ = instance.instance;
  ctx->validation_enabled_ = instance.validation;
  if (instance.debug_utils) {
    auto create_messenger = reinterpret_cast<PFN_vkCreateDebugUtilsMessengerEXT>(
        vkGetInstanceProcAddr(ctx->instance_, "vkCreateDebugUtilsMessengerEXT"));
    if (create_messenger != nullptr) {
      VkDebugUtilsMessengerCreateInfoEXT info{};
      info.sType = VK_STRUCTURE_TYPE_DEBUG_UTILS_MESSENGER_CREATE_INFO_EXT;
      info.messageSeverity = VK_DEBUG_UTILS_MESSAGE_SEVERITY_INFO_BIT_EXT |
                             VK_DEBUG_UTILS_MESSAGE_SEVERITY_WARNING_BIT_EXT |
                             VK_DEBUG_UTILS_MESSAGE_SEVERITY_ERROR_BIT_EXT;
      info.messageType = VK_DEBUG_UTILS_MESSAGE_TYPE_GENERAL_BIT_EXT |
                         VK_DEBUG_UTILS_MESSAGE_TYPE_VALIDATION_BIT_EXT |
                         VK_DEBUG_UTILS_MESSAGE_TYPE_PERFORMANCE_BIT_EXT;
      info.pfnUserCallback = &DebugMessengerCallback;
      VK_RETURN_IF_ERROR(create_messenger(ctx->instance_, &info, nullptr, &ctx->messenger_));
    }
  }

  REFLCAP_ASSIGN_OR_RETURN(std::vector<VkPhysicalDevice> devices, PhysicalDevices(ctx->instance_));
  std::vector<DeviceInfo> infos;
  for (size_t i = 0; i < devices.size(); ++i) {
    infos.push_back(DescribeDevice(devices[i], static_cast<uint32_t>(i)));
  }
  REFLCAP_ASSIGN_OR_RETURN(size_t chosen, SelectDevice(infos, options.device));
  ctx->physical_device_ = devices[chosen];
  ctx->info_ = infos[chosen];
  vkGetPhysicalDeviceMemoryProperties(ctx->physical_device_, &ctx->memory_properties_);

  const std::vector<VkQueueFamilyProperties> families = QueueFamilies(ctx->physical_device_);
  const int family = ChooseQueueFamily(families, options.require_graphics);
  if (family < 0 && options.require_graphics) {
    return UnavailableError("Vulkan device ", ctx->info_.name,
                            " has no queue family with both graphics and compute");
  }
  REFLCAP_CHECK(family >= 0) << "a usable device has a compute queue";
  ctx->queue_family_ = static_cast<uint32_t>(family);
  ctx->info_.timestamp_valid_bits = families[family].timestampValidBits;

  // Enable every optional feature the device has (DescribeDevice read them).
  const DeviceInfo& d = ctx->info_;
  VkPhysicalDeviceVulkan12Features features12{};
  features12.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_2_FEATURES;
  features12.shaderFloat16 = d.shader_float16;
  features12.hostQueryReset = d.host_query_reset;
  features12.scalarBlockLayout = d.scalar_block_layout;
  VkPhysicalDeviceVulkan11Features features11{};
  features11.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_1_FEATURES;
  features11.storageBuffer16BitAccess = d.storage_buffer_16bit_access;
  features11.pNext = &features12;
  VkPhysicalDeviceFeatures2 features2{};
  features2.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_FEATURES_2;
  features2.features.shaderFloat64 = d.shader_float64;
  features2.features.shaderInt64 = d.shader_int64;
  features2.features.shaderInt16 = d.shader_int16;
  features2.pNext = &features11;

  const float priority = 1.0f;
  VkDeviceQueueCreateInfo queue_info{};
  queue_info.sType = VK_STRUCTURE_TYPE_DEVICE_QUEUE_CREATE_INFO;
  queue_info.queueFamilyIndex = ctx->queue_family_;
  queue_info.queueCount = 1;
  queue_info.pQueuePriorities = &priority;
  VkDeviceCreateInfo device_info{};
  device_info.sType = VK_STRUCTURE_TYPE_DEVICE_CREATE_INFO;
  device_info.pNext = &features2;
  device_info.queueCreateInfoCount = 1;
  device_info.pQueueCreateInfos = &queue_info;
  VK_RETURN_IF_ERROR(vkCreateDevice(ctx->physical_device_, &device_info, nullptr, &ctx->device_));
  vkGetDeviceQueue(ctx->device_, ctx->queue_family_, 0, &ctx->queue_);

  VkCommandPoolCreateInfo pool_info{};

  pool_info.sType = VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO;
  pool_info.flags = VK_COMMAND_POOL_CREATE_RESET_COMMAND_BUFFER_BIT;
  pool_info.queueFamilyIndex = ctx->queue_family_;
  VK_RETURN_IF_ERROR(vkCreateCommandPool(ctx->device_, &pool_info, nullptr, &ctx->command_pool_));

  REFLCAP_LOG(kDebug) << "Vulkan device " << ctx->info_.index << ": " << ctx->info_.ToString()
                      << (ctx->validation_enabled_ ? " (validation on)" : "");
  return ctx;
}

VkContext::~VkContext() {
  if (device_ != VK_NULL_HANDLE) vkDeviceWaitIdle(device_);
  staging_.reset();
  if (device_ != VK_NULL_HANDLE) {
    vkDeviceWaitIdle(device_);
    if (command_pool_ != VK_NULL_HANDLE) vkDestroyCommandPool(device_, command_pool_, nullptr);
    vkDestroyDevice(device_, nullptr);
  }
  if (messenger_ != VK_NULL_HANDLE) {
    auto destroy_messenger = reinterpret_cast<PFN_vkDestroyDebugUtilsMessengerEXT>(
        vkGetInstanceProcAddr(instance_, "vkDestroyDebugUtilsMessengerEXT"));
    if (destroy_messenger != nullptr) destroy_messenger(instance_, messenger_, nullptr);
  }
  if (instance_ != VK_NULL_HANDLE) vkDestroyInstance(instance_, nullptr);
}

uint64_t VkContext::max_allocation_bytes() const {
  uint64_t cap = kMaxAllocationBytes;
  if (info_.max_memory_allocation_size > 0) cap = std::min(cap, info_.max_memory_allocation_size);
  if (info_.device_local_heap_size > 0) cap = std::min(cap, info_.device_local_heap_size);
  return cap;
}

StatusOr<uint32_t> VkContext::FindMemoryType(uint32_t type_bits, VkMemoryPropertyFlags required,
                                             VkMemoryPropertyFlags preferred) const {
  int fallback = -1;
  for (uint32_t i = 0; i < memory_properties_.memoryTypeCount; ++i) {
    if (!(type_bits & (1u << i))) continue;
    const VkMemoryPropertyFlags flags = memory_properties_.memoryTypes[i].propertyFlags;
    if ((flags & required) != required) continue;
    if ((flags & preferred) == preferred) return i;
    if (fallback < 0) fallback = static_cast<int>(i);
  }
  if (fallback >= 0) return static_cast<uint32_t>(fallback);
  return NotFoundError("no Vulkan memory type with flags 0x", std::hex, required, " among 0x",
                       type_bits, " on ", info_.name);
}

VkMemoryPropertyFlags VkContext::MemoryTypeFlags(uint32_t index) const {
  REFLCAP_CHECK(index < memory_properties_.memoryTypeCount) << "memory type " << index;
  return memory_properties_.memoryTypes[index].propertyFlags;
}

StatusOr<Buffer*> VkContext::StagingBuffer(uint64_t bytes) {
  if (staging_ == nullptr || staging_->size() < bytes) {
    staging_.reset();
    REFLCAP_ASSIGN_OR_RETURN(Buffer buffer, Buffer::Create(*this, bytes, MemoryKind::kHost));
    staging_ = std::make_unique<Buffer>(std::move(buffer));
  }
  return staging_.get();
}

Status VkContext::WaitIdle() {
  VK_RETURN_IF_ERROR(vkDeviceWaitIdle(device_));
  return OkStatus();
}

}  // namespace reflcap::gpu
