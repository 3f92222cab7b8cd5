#pragma once
// What reflcap knows about a Vulkan device, without including Vulkan: the description
// (name, type, driver, API version), the limits and features the compute code plans with, how a
// device is chosen (SelectDevice), and driver quirks that change how work must be split
// (MaxLoopIterationsPerInvocation). Filled in by engine/gpu/vk_context.cc (ListDevices,
// VkContext); Vulkan-free so that the CLI and reports can use it.
#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "engine/core/status.h"

namespace reflcap::gpu {

// VkPhysicalDeviceType, in the order automatic selection prefers.
enum class DeviceType { kDiscreteGpu, kIntegratedGpu, kVirtualGpu, kCpu, kOther };
// "discrete GPU", "integrated GPU", "virtual GPU", "CPU", "other".
const char* DeviceTypeName(DeviceType type);

// One physical device as vkEnumeratePhysicalDevices reports it.
struct DeviceInfo {
  uint32_t index = 0;  // position in vkEnumeratePhysicalDevices order (what --device INDEX means)
  std::string name;    // VkPhysicalDeviceProperties::deviceName, "llvmpipe (LLVM 15.0.6, 256 bits)"
  DeviceType type = DeviceType::kOther;
  uint32_t vendor_id = 0;
  uint32_t device_id = 0;
  uint32_t api_version = 0;     // VK_MAKE_API_VERSION packing; ApiVersionString() prints it
  uint32_t driver_version = 0;  // vendor-specific packing
  uint32_t driver_id = 0;       // VkDriverId (13 = VK_DRIVER_ID_MESA_LLVMPIPE); 0 before Vulkan 1.2
  std::string driver_name;      // VkPhysicalDeviceVulkan12Properties::driverName, "llvmpipe"
  std::string driver_info;      // ...::driverInfo, "Mesa 22.3.6 (LLVM 15.0.6)"

  // Whether reflcap can run on it (Vulkan >= 1.2 and a compute queue); otherwise why not.
  bool usable = false;
  std::string unusable_reason;

  // Limits (VkPhysicalDeviceLimits unless noted).
  uint64_t max_storage_buffer_range = 0;             // bytes one storage-buffer binding may span
  uint64_t min_storage_buffer_offset_alignment = 1;  // bytes; binding offsets are multiples
  uint64_t non_coherent_atom_size = 1;
  uint32_t max_push_constants_size = 0;  // bytes
  uint32_t max_per_stage_storage_buffers = 0;
  uint32_t max_compute_work_group_invocations = 0;
  std::array<uint32_t, 3> max_compute_work_group_size{};
  std::array<uint32_t, 3> max_compute_work_group_count{};
  uint32_t max_compute_shared_memory_size = 0;  // bytes
  uint64_t max_memory_allocation_size = 0;      // VkPhysicalDeviceVulkan11Properties, bytes
  uint64_t device_local_heap_size = 0;          // largest DEVICE_LOCAL heap, bytes
  bool unified_memory = false;    // a DEVICE_LOCAL memory type is also HOST_VISIBLE|HOST_COHERENT
  uint32_t subgroup_size = 0;     // VkPhysicalDeviceVulkan11Properties
  // Subgroup operations usable in compute shaders: basic, vote and shuffle
  // (VkPhysicalDeviceVulkan11Properties subgroupSupportedStages / subgroupSupportedOperations).
  bool compute_subgroup_shuffle = false;
  float timestamp_period_ns = 0;  // nanoseconds per timestamp tick
  // Valid bits of timestamps on the compute queue family reflcap uses (0 = no timestamps there;
  // for a device not opened yet, the best compute family's value).
  uint32_t timestamp_valid_bits = 0;

  // Optional features (supported by the device; a VkContext enables every one that is).
  bool shader_float64 = false;
  bool shader_int64 = false;
  bool shader_int16 = false;
  bool storage_buffer_16bit_access = false;
  bool shader_float16 = false;       // Vulkan 1.2 shaderFloat16 (arithmetic)
  bool host_query_reset = false;     // Vulkan 1.2 hostQueryReset
  bool scalar_block_layout = false;  // Vulkan 1.2 scalarBlockLayout

  bool IsSoftware() const { return type == DeviceType::kCpu; }
  // True for Mesa's llvmpipe-based Vulkan driver (lavapipe), by driver id or name.
  bool IsLavapipe() const;
  // "1.3.230".
  std::string ApiVersionString() const;
  // "llvmpipe (LLVM 15.0.6, 256 bits) [CPU; llvmpipe, Mesa 22.3.6 (LLVM 15.0.6); Vulkan 1.3.230]".
  std::string ToString() const;
  // Multi-line listing of the limits and features above, for --verbose output and bug reports.
  std::string LimitsString() const;
};

// Picks a device from `devices` (as ListDevices returns them) and returns its position there.
//   selector ""         : automatic: the first usable device of the most preferred DeviceType
//                         (discrete > integrated > virtual > CPU > other), enumeration order
//                         breaking ties;
//   selector "2"        : the device with DeviceInfo::index 2;
//   anything else       : the first usable device, in the automatic order, whose name, driver
//                         name or driver info contains `selector`, ignoring case ("lavapipe"
//                         also matches Mesa's llvmpipe driver).
// Errors: Unavailable when no device is usable (automatic); NotFound when nothing matches the
// selector (the message lists the devices); FailedPrecondition when the selected device is not
// usable (with the reason).
StatusOr<size_t> SelectDevice(const std::vector<DeviceInfo>& devices, const std::string& selector);

// Loop budgets. lavapipe (Mesa's llvmpipe, gallivm) gives every shader invocation one counter
// of kLavapipeLoopCounter loop passes. Every pass through any loop's header takes one step: each
// iteration, plus the pass that leaves a loop normally, so a loop of n iterations takes n + 1 and
// nested loops take every inner pass; consecutive loops share the counter. Lanes that run in
// lockstep (a subgroup of 8 invocations on this build) share one counter, so each loop takes
// steps for the largest trip count among them. When the counter runs out, every loop of the
// invocation exits at once, silently: results are wrong, no error is reported. Measured on Mesa
// 22.3.6 by tests/engine/gpu/loop_limit_test.cc: a single loop asking for 65,535 or more
// iterations runs 65,533 (the other 2 steps are the probe shader's own overhead); two
// consecutive loops of 40,000 run 40,000 and 25,532; 65,535 outer x 1 inner runs 21,845 x 1;
// with lanes alternating (60,000, 0) and (0, 60,000), the second lanes' loop runs 5,532.
inline constexpr uint32_t kLavapipeLoopCounter = 65535;
// What MaxLoopIterationsPerInvocation promises on lavapipe: the counter less a reserve of 535
// steps for loops the compiler adds.
inline constexpr uint32_t kLavapipeMaxLoopIterations = 65000;
// No limit known: only the submit's duration bounds a loop (see CommandBuffer::SubmitAndWait).
inline constexpr uint32_t kNoLoopIterationLimit = 0xFFFFFFFFu;

// Loop steps a loop of `iterations` iterations takes from the budget: iterations + 1. For nested
// loops, sum over every loop instance run: outer n x inner m takes n (m + 1) + n + 1.
constexpr uint64_t LoopSteps(uint64_t iterations) { return iterations + 1; }

// The loop budget of one invocation on this device, in LoopSteps summed over all loop instances
// it runs (each at the largest trip count among the invocations of its subgroup): every
// invocation within it gets correct results. kLavapipeMaxLoopIterations on lavapipe,
// kNoLoopIterationLimit elsewhere. Kernels with long or data-dependent loops (the GPU fitter's
// LM iterations x samples) bound their worst case by it and split the work across dispatches
// (e.g. a few LM iterations per dispatch, state kept in buffers) when it does not fit.
uint32_t MaxLoopIterationsPerInvocation(const DeviceInfo& info);

}  // namespace reflcap::gpu
