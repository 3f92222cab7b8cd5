// The Vulkan masks in a build without Vulkan (REFLCAP_ENABLE_VULKAN=OFF): `--backend vulkan` is
// Unavailable (exit 3) with a message saying why; the CPU path is unchanged.
#include "acquire/resample/vulkan_masks.h"

namespace reflcap::resample {
namespace {
constexpr const char* kNoVulkan =
    "--backend vulkan: this build of reflcap has no Vulkan support (configured with "
    "REFLCAP_ENABLE_VULKAN=OFF); use --backend cpu";
}  // namespace

Status VulkanMaskOptions::Validate() const { return OkStatus(); }

struct VulkanMasks::Impl {
  VulkanMaskStats stats;
  std::string name;
};

VulkanMasks::VulkanMasks() : impl_(new Impl()) {}
VulkanMasks::~VulkanMasks() = default;

StatusOr<std::unique_ptr<VulkanMasks>> VulkanMasks::Create(const Capture&, const TexelAtlas&,
                                                           const TriangleMesh&, float,
                                                           const NoiseModel&, double,
                                                           const VulkanMaskOptions&) {
  return UnavailableError(kNoVulkan);
}

Status VulkanMasks::Process(uint32_t, const Image&, ImageOutput*, CameraMapView*, const Image*) {
  return UnavailableError(kNoVulkan);
}

const std::string& VulkanMasks::device_name() const { return impl_->name; }
bool VulkanMasks::software_device() const { return true; }
const VulkanMaskStats& VulkanMasks::last_stats() const { return impl_->stats; }

Status VulkanMasksAvailable(const std::string&) { return UnavailableError(kNoVulkan); }

StatusOr<bool> VulkanMasksOnGpu(const std::string&, const Capture*) {
  return UnavailableError(kNoVulkan);
}

}  // namespace reflcap::resample
