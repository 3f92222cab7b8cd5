// VkContext creation, device description and choice, and VkResult -> Status.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cstdlib>
#include <string>
#include <vector>

#include "engine/gpu/device_info.h"
#include "engine/gpu/vk_context.h"
#include "engine/gpu/vk_status.h"
#include "tests/engine/gpu/gpu_test_util.h"

namespace reflcap::gpu {
namespace {

using ::testing::HasSubstr;

class ContextTest : public testing::VulkanTest {};

TEST_F(ContextTest, CreatesHeadlessContextAndDescribesItsDevice) {
  const DeviceInfo& d = ctx().info();
  EXPECT_TRUE(d.usable);
  EXPECT_FALSE(d.name.empty());
  EXPECT_GE(d.api_version, VK_API_VERSION_1_2) << d.ApiVersionString();
  EXPECT_NE(ctx().device(), VK_NULL_HANDLE);
  EXPECT_NE(ctx().queue(), VK_NULL_HANDLE);
  EXPECT_NE(ctx().command_pool(), VK_NULL_HANDLE);
  EXPECT_GE(d.max_storage_buffer_range, uint64_t{1} << 27);  // Vulkan minimum is 2^27
  EXPECT_GE(d.max_compute_work_group_invocations, 128u);
  EXPECT_GE(d.max_push_constants_size, 128u);
  EXPECT_GT(d.max_memory_allocation_size, 0u);
  EXPECT_GT(d.device_local_heap_size, 0u);
  EXPECT_GT(d.timestamp_period_ns, 0.0f);
  EXPECT_LE(ctx().max_allocation_bytes(), kMaxAllocationBytes);
  EXPECT_THAT(d.ToString(), HasSubstr(d.name));
  EXPECT_THAT(d.ToString(), HasSubstr("Vulkan " + d.ApiVersionString()));
  EXPECT_THAT(d.LimitsString(), HasSubstr("maxStorageBufferRange"));
  RecordProperty("device", d.ToString());
  RecordProperty("limits", d.LimitsString());

  if (d.IsLavapipe()) {
    // What the engine/gpu code assumes about lavapipe (Mesa 22.3 on this project's machines).
    EXPECT_EQ(d.type, DeviceType::kCpu);
    EXPECT_EQ(d.max_storage_buffer_range, uint64_t{128} << 20);
    EXPECT_EQ(d.subgroup_size, 8u);
    EXPECT_GT(d.timestamp_valid_bits, 0u);
    EXPECT_TRUE(d.shader_float64);
    EXPECT_TRUE(d.shader_int64);
    EXPECT_TRUE(d.storage_buffer_16bit_access);
    EXPECT_TRUE(d.unified_memory);
    EXPECT_EQ(MaxLoopIterationsPerInvocation(ctx()), kLavapipeMaxLoopIterations);
    EXPECT_EQ(ctx().max_allocation_bytes(), kMaxAllocationBytes);
  }
}

TEST_F(ContextTest, ListsTheDeviceItUses) {
  StatusOr<std::vector<DeviceInfo>> devices = ListDevices();
  ASSERT_TRUE(devices.ok()) << devices.status().ToString();
  bool found = false;
  for (const DeviceInfo& d : *devices) {
    if (d.index == ctx().info().index) {
      EXPECT_EQ(d.name, ctx().info().name);
      found = true;
    }
  }
  EXPECT_TRUE(found);
}

TEST_F(ContextTest, ChoosesDeviceByIndexOrNameSubstring) {
  const DeviceInfo& used = ctx().info();
  ContextOptions by_index;
  by_index.device = std::to_string(used.index);
  StatusOr<std::unique_ptr<VkContext>> a = VkContext::Create(by_index);
  ASSERT_TRUE(a.ok()) << a.status().ToString();
  EXPECT_EQ((*a)->info().name, used.name);

  // A case-changed piece of the name.
  ContextOptions by_name;
  by_name.device = used.name.substr(0, std::min<size_t>(used.name.size(), 6));
  for (char& c : by_name.device) c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
  StatusOr<std::unique_ptr<VkContext>> b = VkContext::Create(by_name);
  ASSERT_TRUE(b.ok()) << b.status().ToString();
  EXPECT_EQ((*b)->info().name.substr(0, 6), used.name.substr(0, 6));

  if (used.IsLavapipe()) {
    ContextOptions lavapipe;
    lavapipe.device = "lavapipe";
    StatusOr<std::unique_ptr<VkContext>> c = VkContext::Create(lavapipe);
    ASSERT_TRUE(c.ok()) << c.status().ToString();
    EXPECT_TRUE((*c)->info().IsLavapipe());
  }

  ContextOptions missing;
  missing.device = "no-such-device-xyzzy";
  StatusOr<std::unique_ptr<VkContext>> d = VkContext::Create(missing);
  ASSERT_FALSE(d.ok());
  EXPECT_EQ(d.status().code(), StatusCode::kNotFound);
  EXPECT_THAT(d.status().message(), HasSubstr(used.name));  // lists the devices

  missing.device = "999";
  StatusOr<std::unique_ptr<VkContext>> e = VkContext::Create(missing);
  ASSERT_FALSE(e.ok());
  EXPECT_EQ(e.status().code(), StatusCode::kNotFound);
}

TEST(ContextOptions, RejectsNonPositiveTimeout) {
  ContextOptions options;
  options.submit_timeout_s = 0;
  EXPECT_EQ(options.Validate().code(), StatusCode::kInvalidArgument);
  StatusOr<std::unique_ptr<VkContext>> ctx = VkContext::Create(options);
  EXPECT_EQ(ctx.status().code(), StatusCode::kInvalidArgument);
}

// Without any Vulkan driver the loader finds no ICD: Create must say so with Unavailable (the
// CLI's --backend auto then falls back to the CPU). Run in a child process (a death test that
// exits normally) so that the environment change cannot leak into other tests.
TEST(VkContextWithoutDriver, CreateAndListDevicesAreUnavailable) {
  GTEST_FLAG_SET(death_test_style, "threadsafe");
  EXPECT_EXIT(
      {
        setenv("VK_DRIVER_FILES", "/nonexistent/reflcap_no_icd.json", 1);
        setenv("VK_ICD_FILENAMES", "/nonexistent/reflcap_no_icd.json", 1);
        StatusOr<std::unique_ptr<VkContext>> ctx = VkContext::Create();
        StatusOr<std::vector<DeviceInfo>> devices = ListDevices();
        const bool ok = !ctx.ok() && ctx.status().code() == StatusCode::kUnavailable &&
                        ctx.status().message().find("no Vulkan driver") != std::string::npos &&
                        !devices.ok() && devices.status().code() == StatusCode::kUnavailable;
        std::fprintf(stderr, "%s | %s\n", ctx.status().ToString().c_str(),
                     devices.status().ToString().c_str());
        std::exit(ok ? 0 : 1);
      },
      ::testing::ExitedWithCode(0), "Unavailable: no Vulkan driver");
}

// ---- SelectDevice, on made-up device lists -------------------------------------------------

DeviceInfo FakeDevice(uint32_t index, const std::string& name, DeviceType type, bool usable = true,
                      const std::string& driver = "") {
  DeviceInfo d;
  d.index = index;
  d.name = name;
  d.type = type;
  d.usable = usable;
  d.driver_name = driver;
  if (!usable) d.unusable_reason = "supports Vulkan 1.1.0; reflcap needs 1.2";
  return d;
}

TEST(SelectDevice, PrefersDiscreteThenIntegratedThenVirtualThenCpu) {
  std::vector<DeviceInfo> devices = {
      FakeDevice(0, "llvmpipe (LLVM 15.0.6, 256 bits)", DeviceType::kCpu, true, "llvmpipe"),
      FakeDevice(1, "Virtio GPU", DeviceType::kVirtualGpu),
      FakeDevice(2, "Intel(R) UHD Graphics", DeviceType::kIntegratedGpu),
      FakeDevice(3, "NVIDIA H100 80GB HBM3", DeviceType::kDiscreteGpu),
      FakeDevice(4, "NVIDIA H100 80GB HBM3", DeviceType::kDiscreteGpu)};
  EXPECT_EQ(*SelectDevice(devices, ""), 3u);  // the first discrete GPU
  devices[3].usable = false;
  EXPECT_EQ(*SelectDevice(devices, ""), 4u);  // unusable devices are passed over
  devices[4].usable = false;
  EXPECT_EQ(*SelectDevice(devices, ""), 2u);
  devices[2].usable = false;
  EXPECT_EQ(*SelectDevice(devices, ""), 1u);
  devices[1].usable = false;
  EXPECT_EQ(*SelectDevice(devices, ""), 0u);
  devices[0].usable = false;
  EXPECT_EQ(SelectDevice(devices, "").status().code(), StatusCode::kUnavailable);
  EXPECT_EQ(SelectDevice({}, "").status().code(), StatusCode::kUnavailable);
}

TEST(SelectDevice, ByIndexOrCaseInsensitiveSubstring) {
  const std::vector<DeviceInfo> devices = {
      FakeDevice(0, "llvmpipe (LLVM 15.0.6, 256 bits)", DeviceType::kCpu, true, "llvmpipe"),
      FakeDevice(1, "Old GPU", DeviceType::kDiscreteGpu, false),
      FakeDevice(2, "NVIDIA H100 80GB HBM3", DeviceType::kDiscreteGpu)};
  EXPECT_EQ(*SelectDevice(devices, "0"), 0u);
  EXPECT_EQ(*SelectDevice(devices, "2"), 2u);
  EXPECT_EQ(*SelectDevice(devices, "h100"), 2u);
  EXPECT_EQ(*SelectDevice(devices, "LLVMPIPE"), 0u);
  EXPECT_EQ(*SelectDevice(devices, "lavapipe"), 0u);
  EXPECT_EQ(SelectDevice(devices, "1").status().code(), StatusCode::kFailedPrecondition);
  EXPECT_EQ(SelectDevice(devices, "old gpu").status().code(), StatusCode::kFailedPrecondition);
  EXPECT_EQ(SelectDevice(devices, "7").status().code(), StatusCode::kNotFound);
  const Status missing = SelectDevice(devices, "radeon").status();
  EXPECT_EQ(missing.code(), StatusCode::kNotFound);
  EXPECT_THAT(missing.message(), HasSubstr("NVIDIA H100"));
}

TEST(MaxLoopIterationsPerInvocation, IsFiniteOnlyOnLavapipe) {
  DeviceInfo lavapipe = FakeDevice(0, "llvmpipe (LLVM 15.0.6, 256 bits)", DeviceType::kCpu);
  EXPECT_EQ(MaxLoopIterationsPerInvocation(lavapipe), kLavapipeMaxLoopIterations);
  lavapipe.name = "something";
  lavapipe.driver_id = 13;  // VK_DRIVER_ID_MESA_LLVMPIPE
  EXPECT_EQ(MaxLoopIterationsPerInvocation(lavapipe), kLavapipeMaxLoopIterations);
  static_assert(VK_DRIVER_ID_MESA_LLVMPIPE == 13);
  const DeviceInfo gpu = FakeDevice(0, "NVIDIA H100 80GB HBM3", DeviceType::kDiscreteGpu);
  EXPECT_EQ(MaxLoopIterationsPerInvocation(gpu), kNoLoopIterationLimit);
  EXPECT_LE(kLavapipeMaxLoopIterations, kLavapipeLoopCounter);
  EXPECT_EQ(LoopSteps(10), 11u);
}

// ---- VkResult -> Status ----------------------------------------------------------------------

Status CallThatFails(VkResult result) {
  VK_RETURN_IF_ERROR(result);
  return OkStatus();
}

TEST(VkStatus, MapsResultsToCodesWithTheirNames) {
  EXPECT_TRUE(CallThatFails(VK_SUCCESS).ok());
  const Status oom = CallThatFails(VK_ERROR_OUT_OF_DEVICE_MEMORY);
  EXPECT_EQ(oom.code(), StatusCode::kUnavailable);
  EXPECT_THAT(oom.message(), HasSubstr("VK_ERROR_OUT_OF_DEVICE_MEMORY"));
  EXPECT_THAT(oom.message(), HasSubstr("result failed"));  // the expression
  EXPECT_THAT(oom.message(), HasSubstr("tests/engine/gpu/context_test.cc:"));
  EXPECT_EQ(CallThatFails(VK_ERROR_DEVICE_LOST).code(), StatusCode::kUnavailable);
  EXPECT_EQ(CallThatFails(VK_ERROR_INCOMPATIBLE_DRIVER).code(), StatusCode::kUnavailable);
  EXPECT_EQ(CallThatFails(VK_ERROR_UNKNOWN).code(), StatusCode::kInternal);
  EXPECT_EQ(CallThatFails(VK_INCOMPLETE).code(), StatusCode::kInternal);
  EXPECT_STREQ(VkResultName(VK_TIMEOUT), "VK_TIMEOUT");
  EXPECT_EQ(VkResultName(static_cast<VkResult>(-12345)), nullptr);
  EXPECT_EQ(VkResultString(static_cast<VkResult>(-12345)), "VkResult(-12345)");
}

}  // namespace
}  // namespace reflcap::gpu
