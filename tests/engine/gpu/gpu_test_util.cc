#include "tests/engine/gpu/gpu_test_util.h"

#include <cstdlib>
#include <memory>

#include "engine/core/status.h"
#include "tests/support/test_support.h"

namespace reflcap::gpu::testing {

VkContext* SharedContext(std::string* skip_reason, std::string* error) {
  struct State {
    std::unique_ptr<VkContext> ctx;
    std::string skip_reason;
    std::string error;
  };
  // Released after the last test, before static destructors (ReleaseBeforeExit says why).
  static State* state = [] {
    static State storage;
    State* s = &storage;
    StatusOr<std::vector<DeviceInfo>> devices = ListDevices();
    if (!devices.ok()) {
      if (devices.status().code() == StatusCode::kUnavailable) {
        s->skip_reason =
            "no Vulkan driver or device on this machine: " + devices.status().ToString();
      } else {
        s->error = "ListDevices: " + devices.status().ToString();
      }
      return s;
    }
    ContextOptions options;
    if (const char* device = std::getenv("REFLCAP_TEST_VK_DEVICE")) options.device = device;
    StatusOr<std::unique_ptr<VkContext>> ctx = VkContext::Create(options);
    if (!ctx.ok()) {
      s->error = "VkContext::Create: " + ctx.status().ToString();
      return s;
    }
    s->ctx = std::move(ctx).value();
    reflcap::testing::ReleaseBeforeExit([s] { s->ctx.reset(); });
    return s;
  }();
  *skip_reason = state->skip_reason;
  *error = state->error;
  return state->ctx.get();
}

}  // namespace reflcap::gpu::testing
