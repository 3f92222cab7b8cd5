#pragma once
// Shared by the engine/gpu tests: one VkContext for the whole binary, and a fixture that skips a
// test only when the machine has no Vulkan driver (ICD) or device at all. Everywhere else — CI
// runs these tests on lavapipe — context creation must succeed, and a failure fails the test.
#include <gtest/gtest.h>

#include <string>

#include "engine/gpu/vk_context.h"

namespace reflcap::gpu::testing {

// The binary's context, created on first use with default options (automatic device choice, or
// $REFLCAP_TEST_VK_DEVICE as ContextOptions::device). nullptr when there is no Vulkan driver or
// device; *skip_reason then says why. A context creation failure on a machine that has a device
// is reported through *error (and nullptr returned).
VkContext* SharedContext(std::string* skip_reason, std::string* error);

class VulkanTest : public ::testing::Test {
 protected:
  void SetUp() override {
    std::string skip_reason, error;
    ctx_ = SharedContext(&skip_reason, &error);
    ASSERT_TRUE(error.empty()) << error;
    if (ctx_ == nullptr) GTEST_SKIP() << skip_reason;
  }
  VkContext& ctx() { return *ctx_; }

 private:
  VkContext* ctx_ = nullptr;
};

}  // namespace reflcap::gpu::testing
