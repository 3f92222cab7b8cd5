#include "engine/gpu/vk_status.h"

#include <cstring>
#include <string>

namespace reflcap::gpu {
namespace {

bool MeansUnavailable(VkResult result) {
  switch (result) {
    case VK_TIMEOUT:
    case VK_ERROR_OUT_OF_HOST_MEMORY:
    case VK_ERROR_OUT_OF_DEVICE_MEMORY:
    case VK_ERROR_INITIALIZATION_FAILED:
    case VK_ERROR_DEVICE_LOST:
    case VK_ERROR_MEMORY_MAP_FAILED:
    case VK_ERROR_LAYER_NOT_PRESENT:
    case VK_ERROR_EXTENSION_NOT_PRESENT:
    case VK_ERROR_FEATURE_NOT_PRESENT:
    case VK_ERROR_INCOMPATIBLE_DRIVER:
    case VK_ERROR_TOO_MANY_OBJECTS:
    case VK_ERROR_FORMAT_NOT_SUPPORTED:
    case VK_ERROR_OUT_OF_POOL_MEMORY:
      return true;
    default:
      return false;
  }
}

// Keeps file names short in messages: "engine/gpu/vk_context.cc" rather than the absolute path.
// The repository root is where this file's own __FILE__ ends in engine/gpu/vk_status.cc.
const char* RepoRelative(const char* file) {
  static const std::string root = [] {
    const std::string self = __FILE__;
    const std::string tail = "engine/gpu/vk_status.cc";
    return self.size() >= tail.size() &&
                   self.compare(self.size() - tail.size(), tail.size(), tail) == 0
               ? self.substr(0, self.size() - tail.size())
               : std::string();
  }();
  if (!root.empty() && std::strncmp(file, root.c_str(), root.size()) == 0) {
    return file + root.size();
  }
  return file;
}

}  // namespace

const char* VkResultName(VkResult result) {
  switch (result) {
#define REFLCAP_VK_RESULT_CASE(r) \
  case r:                         \
    return #r
    REFLCAP_VK_RESULT_CASE(VK_SUCCESS);
    REFLCAP_VK_RESULT_CASE(VK_NOT_READY);
    REFLCAP_VK_RESULT_CASE(VK_TIMEOUT);
    REFLCAP_VK_RESULT_CASE(VK_EVENT_SET);
    REFLCAP_VK_RESULT_CASE(VK_EVENT_RESET);
    REFLCAP_VK_RESULT_CASE(VK_INCOMPLETE);
    REFLCAP_VK_RESULT_CASE(VK_ERROR_OUT_OF_HOST_MEMORY);
    REFLCAP_VK_RESULT_CASE(VK_ERROR_OUT_OF_DEVICE_MEMORY);
    REFLCAP_VK_RESULT_CASE(VK_ERROR_INITIALIZATION_FAILED);
    REFLCAP_VK_RESULT_CASE(VK_ERROR_DEVICE_LOST);
    REFLCAP_VK_RESULT_CASE(VK_ERROR_MEMORY_MAP_FAILED);
    REFLCAP_VK_RESULT_CASE(VK_ERROR_LAYER_NOT_PRESENT);
    REFLCAP_VK_RESULT_CASE(VK_ERROR_EXTENSION_NOT_PRESENT);
    REFLCAP_VK_RESULT_CASE(VK_ERROR_FEATURE_NOT_PRESENT);
    REFLCAP_VK_RESULT_CASE(VK_ERROR_INCOMPATIBLE_DRIVER);
    REFLCAP_VK_RESULT_CASE(VK_ERROR_TOO_MANY_OBJECTS);
    REFLCAP_VK_RESULT_CASE(VK_ERROR_FORMAT_NOT_SUPPORTED);
    REFLCAP_VK_RESULT_CASE(VK_ERROR_FRAGMENTED_POOL);
    REFLCAP_VK_RESULT_CASE(VK_ERROR_UNKNOWN);
    REFLCAP_VK_RESULT_CASE(VK_ERROR_OUT_OF_POOL_MEMORY);
    REFLCAP_VK_RESULT_CASE(VK_ERROR_INVALID_EXTERNAL_HANDLE);
    REFLCAP_VK_RESULT_CASE(VK_ERROR_FRAGMENTATION);
    REFLCAP_VK_RESULT_CASE(VK_ERROR_INVALID_OPAQUE_CAPTURE_ADDRESS);
    REFLCAP_VK_RESULT_CASE(VK_PIPELINE_COMPILE_REQUIRED);
    REFLCAP_VK_RESULT_CASE(VK_ERROR_SURFACE_LOST_KHR);
    REFLCAP_VK_RESULT_CASE(VK_ERROR_NATIVE_WINDOW_IN_USE_KHR);
    REFLCAP_VK_RESULT_CASE(VK_SUBOPTIMAL_KHR);
    REFLCAP_VK_RESULT_CASE(VK_ERROR_OUT_OF_DATE_KHR);
    REFLCAP_VK_RESULT_CASE(VK_ERROR_INCOMPATIBLE_DISPLAY_KHR);
    REFLCAP_VK_RESULT_CASE(VK_ERROR_VALIDATION_FAILED_EXT);
    REFLCAP_VK_RESULT_CASE(VK_ERROR_INVALID_SHADER_NV);
#undef REFLCAP_VK_RESULT_CASE
    default:
      return nullptr;
  }
}

std::string VkResultString(VkResult result) {
  const char* name = VkResultName(result);
  return name != nullptr ? std::string(name) : StrCat("VkResult(", static_cast<int>(result), ")");
}

Status VkResultToStatus(VkResult result, const char* what, const char* file, int line) {
  if (result == VK_SUCCESS) return OkStatus();
  std::string message = StrCat(what, " failed: ", VkResultString(result));
  if (file != nullptr) message += StrCat(" (", RepoRelative(file), ":", line, ")");
  return Status(MeansUnavailable(result) ? StatusCode::kUnavailable : StatusCode::kInternal,
                std::move(message));
}

}  // namespace reflcap::gpu
