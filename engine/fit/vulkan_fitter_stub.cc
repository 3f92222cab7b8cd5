// The Vulkan fitter's entry points in a build without Vulkan (REFLCAP_ENABLE_VULKAN=OFF):
// kVulkan is Unavailable and `--backend auto` always fits on the CPU.
#include "engine/fit/vulkan_fitter.h"

namespace reflcap::fit {

StatusOr<std::unique_ptr<VulkanFitter>> CreateVulkanFitter(const VulkanFitterOptions&) {
  return UnavailableError("--backend vulkan: this build of reflcap has no Vulkan support "
                          "(configured with REFLCAP_ENABLE_VULKAN=OFF); use --backend cpu");
}

StatusOr<AutoBackendChoice> ChooseAutoBackend(const std::string& device) {
  if (!device.empty()) {
    return UnavailableError("--device ", device, ": this build of reflcap has no Vulkan support");
  }
  AutoBackendChoice choice;
  choice.backend = Backend::kCpu;
  choice.fell_back = true;
  choice.reason = "this build has no Vulkan support: fitting on the CPU";
  return choice;
}

}  // namespace reflcap::fit
