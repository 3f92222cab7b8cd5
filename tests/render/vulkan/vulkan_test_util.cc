#include "tests/render/vulkan/vulkan_test_util.h"

#include <cstdlib>
#include <memory>

#include "engine/core/status.h"
#include "engine/gpu/vk_context.h"

namespace reflcap::render::testing {

VulkanRenderer* SharedRenderer(std::string* skip_reason, std::string* error) {
  struct State {
    std::unique_ptr<VulkanRenderer> renderer;
    std::string skip_reason, error;
  };
  static State* state = [] {
    static State storage;
    State* s = &storage;
    StatusOr<std::vector<gpu::DeviceInfo>> devices = gpu::ListDevices();
    if (!devices.ok()) {
      if (devices.status().code() == StatusCode::kUnavailable) {
        s->skip_reason =
            "no Vulkan driver or device on this machine: " + devices.status().ToString();
      } else {
        s->error = "ListDevices: " + devices.status().ToString();
      }
      return s;
    }
    const char* device = std::getenv("REFLCAP_TEST_VK_DEVICE");
    auto renderer = VulkanRenderer::Create(device ? device : "");
    if (!renderer.ok()) {
      s->error = "VulkanRenderer::Create: " + renderer.status().ToString();
      return s;
    }
    s->renderer = std::move(renderer).value();
    std::printf("[ vulkan   ] device: %s\n", s->renderer->device().ToString().c_str());
    return s;
  }();
  *skip_reason = state->skip_reason;
  *error = state->error;
  return state->renderer.get();
}

}  // namespace reflcap::render::testing
