// VulkanFitterOptions and the kernel names: built with and without Vulkan (the CLI validates
// and prints them either way).
#include "engine/fit/vulkan_fitter.h"

namespace reflcap::fit {

Status VulkanFitterOptions::Validate() const {
  if (threads < 0) return InvalidArgumentError("Vulkan fitter: threads must be >= 0, got ", threads);
  if (cluster_size > kMaxVulkanFitClusterSize || (cluster_size & (cluster_size - 1)) != 0) {
    return InvalidArgumentError("Vulkan fitter: cluster size must be 0 (automatic) or a power of "
                                "two up to ", kMaxVulkanFitClusterSize, ", got ", cluster_size);
  }
  if (chunks_in_flight > 2) {
    return InvalidArgumentError("Vulkan fitter: chunks in flight must be 0 (automatic), 1 or 2, "
                                "got ", chunks_in_flight);
  }
  return OkStatus();
}

const char* VulkanFitKernelName(VulkanFitKernel kernel) {
  switch (kernel) {
    case VulkanFitKernel::kLanes: return "lanes";
    case VulkanFitKernel::kClusters: return "clusters";
    default: return "auto";
  }
}

}  // namespace reflcap::fit
