#pragma once
// Shared by the Vulkan renderer tests: one VulkanRenderer for the whole binary (skipped only
// when the machine has no Vulkan driver or device at all — CI runs these on lavapipe), and short
// names for the acceptance criterion (render/vulkan/render_agreement.h).
#include <gtest/gtest.h>

#include <string>

#include "render/reference/reference_renderer.h"
#include "render/vulkan/render_agreement.h"
#include "render/vulkan/vulkan_renderer.h"

namespace reflcap::render::testing {

// The binary's renderer (automatic device, or $REFLCAP_TEST_VK_DEVICE), created on first use.
// nullptr with *skip_reason set when there is no Vulkan driver or device; a creation failure on
// a machine that has one goes to *error.
VulkanRenderer* SharedRenderer(std::string* skip_reason, std::string* error);

class VulkanRendererTest : public ::testing::Test {
 protected:
  void SetUp() override {
    std::string skip_reason, error;
    renderer_ = SharedRenderer(&skip_reason, &error);
    ASSERT_TRUE(error.empty()) << error;
    if (renderer_ == nullptr) GTEST_SKIP() << skip_reason;
  }
  VulkanRenderer& renderer() { return *renderer_; }

 private:
  VulkanRenderer* renderer_ = nullptr;
};

// The acceptance criterion lives in the library (render/vulkan/render_agreement.h), shared with
// bench/render.
using Agreement = RenderAgreement;
inline Agreement Compare(const RenderResult& cpu, const RenderResult& gpu,
                         double exclusion_px = kEdgeExclusionPx) {
  return CompareRenders(cpu, gpu, exclusion_px);
}
constexpr double kMinPsnrDb = kMinAgreementPsnrDb;

// On failure: the `count` compared pixels with the largest errors, with both renders' aux.
void PrintWorstPixels(const RenderResult& cpu, const RenderResult& gpu, const Agreement& a,
                      size_t count);

// With $REFLCAP_TEST_DUMP_DIR set: writes both renders (radiance, mask, aux) as EXR files
// `<label>_{cpu,vulkan}.exr` there, for looking at a disagreement found on a machine one cannot
// debug on. Does nothing otherwise.
void DumpRenders(const std::string& label, const RenderResult& cpu, const RenderResult& gpu);

}  // namespace reflcap::render::testing
