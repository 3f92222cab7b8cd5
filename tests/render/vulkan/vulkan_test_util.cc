#include "tests/render/vulkan/vulkan_test_util.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <vector>

#include "engine/core/status.h"
#include "engine/gpu/vk_context.h"
#include "engine/image/exr_io.h"
#include "tests/support/test_support.h"

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
    // Released after the last test, before static destructors (ReleaseBeforeExit says why).
    reflcap::testing::ReleaseBeforeExit([s] { s->renderer.reset(); });
    std::printf("[ vulkan   ] device: %s\n", s->renderer->device().ToString().c_str());
    return s;
  }();
  *skip_reason = state->skip_reason;
  *error = state->error;
  return state->renderer.get();
}

void PrintWorstPixels(const RenderResult& cpu, const RenderResult& gpu, const Agreement& a,
                      size_t count) {
  struct Error {
    double error;
    int x, y;
  };
  std::vector<Error> errors;
  for (int y = 0; y < cpu.pixels.height; ++y) {
    for (int x = 0; x < cpu.pixels.width; ++x) {
      if (a.excluded.width > 0 && a.excluded.at(x, y) > 0.5f) continue;
      double e = 0;
      for (int c = 0; c < 3; ++c) e += std::abs(cpu.pixels.at(x, y, c) - gpu.pixels.at(x, y, c));
      if (e > 0) errors.push_back({e, x, y});
    }
  }
  std::sort(errors.begin(), errors.end(),
            [](const Error& p, const Error& q) { return p.error > q.error; });
  const bool aux = !cpu.aux.data.empty() && !gpu.aux.data.empty();
  for (size_t i = 0; i < std::min(count, errors.size()); ++i) {
    const int x = errors[i].x, y = errors[i].y;
    std::printf("    pixel %d,%d: RGB cpu %.5g %.5g %.5g vulkan %.5g %.5g %.5g", x, y,
                cpu.pixels.at(x, y, 0), cpu.pixels.at(x, y, 1), cpu.pixels.at(x, y, 2),
                gpu.pixels.at(x, y, 0), gpu.pixels.at(x, y, 1), gpu.pixels.at(x, y, 2));
    if (aux) {
      std::printf("; cast_shadow %g/%g cos_i %.6f/%.6f cos_o %.6f/%.6f curvature %.3g/%.3g",
                  cpu.aux.at(x, y, kAuxCastShadow), gpu.aux.at(x, y, kAuxCastShadow),
                  cpu.aux.at(x, y, kAuxCosThetaI), gpu.aux.at(x, y, kAuxCosThetaI),
                  cpu.aux.at(x, y, kAuxCosThetaO), gpu.aux.at(x, y, kAuxCosThetaO),
                  cpu.aux.at(x, y, kAuxCurvature), gpu.aux.at(x, y, kAuxCurvature));
    }
    std::printf("\n");
  }
}

void DumpRenders(const std::string& label, const RenderResult& cpu, const RenderResult& gpu) {
  const char* dir = std::getenv("REFLCAP_TEST_DUMP_DIR");
  if (dir == nullptr || *dir == '\0') return;
  std::filesystem::create_directories(dir);
  for (const auto& [name, r] : {std::pair<const char*, const RenderResult*>{"cpu", &cpu},
                                std::pair<const char*, const RenderResult*>{"vulkan", &gpu}}) {
    const std::filesystem::path base = std::filesystem::path(dir) / (label + "_" + name);
    Status s = WriteExr(base.string() + "_rgb.exr", r->pixels);
    if (s.ok()) s = WriteExr(base.string() + "_mask.exr", r->mask);
    if (s.ok() && !r->aux.data.empty()) {
      std::vector<std::string> names;
      for (int c = 0; c < r->aux.channels; ++c) names.push_back("aux" + std::to_string(c));
      s = WriteExrChannels(base.string() + "_aux.exr", r->aux, names);
    }
    if (!s.ok()) std::printf("[ vulkan   ] dump %s: %s\n", base.c_str(), s.ToString().c_str());
  }
}

}  // namespace reflcap::render::testing
