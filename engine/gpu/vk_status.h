#pragma once
// VkResult -> Status: VK_RETURN_IF_ERROR(vkCreateFoo(...)) returns from the enclosing function
// (which returns Status or StatusOr<T>) with a Status naming the call, the VkResult and the source
// line when the call does not return VK_SUCCESS. After uVkCompute's vulkan/status_util.h.
//
// Mapping: results that mean "this device or driver cannot do it here" (missing driver, layer,
// extension or feature; out of host or device memory; device lost; too many objects; VK_TIMEOUT)
// become Unavailable, so `--backend auto` can fall back to the CPU; anything else is Internal.
#include <vulkan/vulkan.h>

#include "engine/core/status.h"

namespace reflcap::gpu {

// "VK_ERROR_OUT_OF_DEVICE_MEMORY"; nullptr for values this build does not know.
const char* VkResultName(VkResult result);
// VkResultName, or "VkResult(-12345)" for unknown values.
std::string VkResultString(VkResult result);

// OK for VK_SUCCESS, else "<what> failed: <VkResult name> (<file>:<line>)" with the code above.
Status VkResultToStatus(VkResult result, const char* what, const char* file = nullptr,
                        int line = 0);

}  // namespace reflcap::gpu

#define VK_RETURN_IF_ERROR(expr)                                                              \
  do {                                                                                        \
    const VkResult reflcap_vk_result_ = (expr);                                               \
    if (reflcap_vk_result_ != VK_SUCCESS) {                                                   \
      return ::reflcap::gpu::VkResultToStatus(reflcap_vk_result_, #expr, __FILE__, __LINE__); \
    }                                                                                         \
  } while (0)
