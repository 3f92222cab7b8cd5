#include "engine/gpu/device_info.h"

#include <algorithm>
#include <cctype>
#include <sstream>

namespace reflcap::gpu {
namespace {

// VK_DRIVER_ID_MESA_LLVMPIPE (vulkan_core.h); this file stays Vulkan-free.
constexpr uint32_t kDriverIdMesaLlvmpipe = 13;

std::string Lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return s;
}

bool Contains(const std::string& haystack, const std::string& lower_needle) {
  return Lower(haystack).find(lower_needle) != std::string::npos;
}

bool IsIndex(const std::string& s) {
  return !s.empty() && s.size() <= 9 &&
         std::all_of(s.begin(), s.end(), [](unsigned char c) { return std::isdigit(c) != 0; });
}

std::string DeviceList(const std::vector<DeviceInfo>& devices) {
  std::ostringstream out;
  for (const DeviceInfo& d : devices) {
    out << "\n  [" << d.index << "] " << d.ToString();
    if (!d.usable) out << " (not usable: " << d.unusable_reason << ")";
  }
  if (devices.empty()) out << " (none)";
  return out.str();
}

// Positions of the devices in automatic-selection order: by DeviceType, then enumeration order.
std::vector<size_t> PreferenceOrder(const std::vector<DeviceInfo>& devices) {
  std::vector<size_t> order(devices.size());
  for (size_t i = 0; i < order.size(); ++i) order[i] = i;
  std::stable_sort(order.begin(), order.end(), [&](size_t a, size_t b) {
    return static_cast<int>(devices[a].type) < static_cast<int>(devices[b].type);
  });
  return order;
}

}  // namespace

const char* DeviceTypeName(DeviceType type) {
  switch (type) {
    case DeviceType::kDiscreteGpu:
      return "discrete GPU";
    case DeviceType::kIntegratedGpu:
      return "integrated GPU";
    case DeviceType::kVirtualGpu:
      return "virtual GPU";
    case DeviceType::kCpu:
      return "CPU";
    case DeviceType::kOther:
      return "other";
  }
  return "other";
}

bool DeviceInfo::IsLavapipe() const {
  return driver_id == kDriverIdMesaLlvmpipe || Contains(driver_name, "llvmpipe") ||
         Contains(name, "llvmpipe");
}

std::string DeviceInfo::ApiVersionString() const {
  // VK_API_VERSION_MAJOR/MINOR/PATCH: bits 22-28, 12-21, 0-11.
  return StrCat((api_version >> 22) & 0x7Fu, ".", (api_version >> 12) & 0x3FFu, ".",
                api_version & 0xFFFu);
}

std::string DeviceInfo::ToString() const {
  std::ostringstream out;
  out << name << " [" << DeviceTypeName(type);
  if (!driver_name.empty()) out << "; " << driver_name;
  if (!driver_info.empty()) out << ", " << driver_info;
  out << "; Vulkan " << ApiVersionString() << "]";
  return out.str();
}

std::string DeviceInfo::LimitsString() const {
  std::ostringstream out;
  out << "device " << index << ": " << ToString() << "\n"
      << "  vendor/device id: 0x" << std::hex << vendor_id << "/0x" << device_id << std::dec
      << ", driver id " << driver_id << "\n"
      << "  maxStorageBufferRange: " << max_storage_buffer_range << " B\n"
      << "  minStorageBufferOffsetAlignment: " << min_storage_buffer_offset_alignment << " B\n"
      << "  maxMemoryAllocationSize: " << max_memory_allocation_size << " B\n"
      << "  largest device-local heap: " << device_local_heap_size << " B"
      << (unified_memory ? " (host-visible: unified memory)" : "") << "\n"
      << "  maxPushConstantsSize: " << max_push_constants_size << " B\n"
      << "  maxPerStageDescriptorStorageBuffers: " << max_per_stage_storage_buffers << "\n"
      << "  maxComputeWorkGroupInvocations: " << max_compute_work_group_invocations << "\n"
      << "  maxComputeWorkGroupSize: " << max_compute_work_group_size[0] << " x "
      << max_compute_work_group_size[1] << " x " << max_compute_work_group_size[2] << "\n"
      << "  maxComputeWorkGroupCount: " << max_compute_work_group_count[0] << " x "
      << max_compute_work_group_count[1] << " x " << max_compute_work_group_count[2] << "\n"
      << "  maxComputeSharedMemorySize: " << max_compute_shared_memory_size << " B\n"
      << "  subgroupSize: " << subgroup_size
      << (compute_subgroup_shuffle ? " (compute: basic, vote, shuffle)" : "") << "\n"
      << "  timestampPeriod: " << timestamp_period_ns
      << " ns, timestampValidBits: " << timestamp_valid_bits << "\n"
      << "  features: shaderFloat64=" << shader_float64 << " shaderInt64=" << shader_int64
      << " shaderInt16=" << shader_int16
      << " storageBuffer16BitAccess=" << storage_buffer_16bit_access
      << " shaderFloat16=" << shader_float16 << " hostQueryReset=" << host_query_reset
      << " scalarBlockLayout=" << scalar_block_layout << "\n"
      << "  loop iterations per invocation: ";
  const uint32_t loops = MaxLoopIterationsPerInvocation(*this);
  if (loops == kNoLoopIterationLimit) {
    out << "no known limit";
  } else {
    out << loops << " (driver exits longer loops silently)";
  }
  if (!usable) out << "\n  not usable: " << unusable_reason;
  return out.str();
}

StatusOr<size_t> SelectDevice(const std::vector<DeviceInfo>& devices, const std::string& selector) {
  const std::vector<size_t> order = PreferenceOrder(devices);
  if (selector.empty()) {
    for (size_t i : order) {
      if (devices[i].usable) return i;
    }
    return UnavailableError(
        "no usable Vulkan device (reflcap needs Vulkan 1.2 and a compute "
        "queue); devices:",
        DeviceList(devices));
  }
  if (IsIndex(selector)) {
    const uint32_t index = static_cast<uint32_t>(std::stoul(selector));
    for (size_t i = 0; i < devices.size(); ++i) {
      if (devices[i].index != index) continue;
      if (!devices[i].usable) {
        return FailedPreconditionError("Vulkan device ", index, " (", devices[i].name,
                                       ") is not usable: ", devices[i].unusable_reason);
      }
      return i;
    }
    return NotFoundError("no Vulkan device with index ", index, "; devices:", DeviceList(devices));
  }
  std::string needle = Lower(selector);
  // Users call Mesa's CPU driver lavapipe; it reports itself as llvmpipe.
  if (needle == "lavapipe") needle = "llvmpipe";
  const DeviceInfo* unusable_match = nullptr;
  for (size_t i : order) {
    const DeviceInfo& d = devices[i];
    if (!Contains(d.name, needle) && !Contains(d.driver_name, needle) &&
        !Contains(d.driver_info, needle)) {
      continue;
    }
    if (d.usable) return i;
    if (unusable_match == nullptr) unusable_match = &d;
  }
  if (unusable_match != nullptr) {
    return FailedPreconditionError("Vulkan device ", unusable_match->index, " (",
                                   unusable_match->name, ") matches '", selector,
                                   "' but is not usable: ", unusable_match->unusable_reason);
  }
  return NotFoundError("no Vulkan device matches '", selector, "'; devices:", DeviceList(devices));
}

uint32_t MaxLoopIterationsPerInvocation(const DeviceInfo& info) {
  return info.IsLavapipe() ? kLavapipeMaxLoopIterations : kNoLoopIterationLimit;
}

}  // namespace reflcap::gpu
