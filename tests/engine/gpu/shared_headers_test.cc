// shaders/shared/*.h compile as C++ (their std430 static_asserts hold), their constants equal the
// engine's, and every ShaderId has embedded SPIR-V.
#include <gtest/gtest.h>

#include <cstdint>
#include <set>
#include <string>

#include "engine/brdf/lafortune.h"
#include "engine/gpu/shader_blobs.h"
#include "engine/math/safe_math.h"
#include "engine/math/types.h"
#include "shaders/shared/bench.h"
#include "shaders/shared/brdf_probe.h"
#include "shaders/shared/chunk_probe.h"
#include "shaders/shared/interop.h"
#include "shaders/shared/lafortune_constants.h"
#include "shaders/shared/loop_probe.h"
#include "shaders/shared/math_constants.h"

namespace reflcap::gpu {
namespace {

namespace sh = shared;

// The GLSL twins' constants are the C++ twins' (float where the float twin compares in float).
static_assert(sh::kPi == static_cast<float>(kPi));
static_assert(sh::kInvPi == static_cast<float>(kInvPi));
static_assert(sh::kTiny == static_cast<float>(kTiny));
static_assert(sh::kPowBaseMin == static_cast<float>(kPowBaseMin));
static_assert(sh::kMaxLobes == brdf::kMaxLobes);
static_assert(sh::kChannels == brdf::kChannels);
static_assert(sh::kMaxParamsPerChannel == brdf::kMaxParamsPerChannel);
static_assert(sh::kMinExponent == static_cast<float>(brdf::kMinExponent));
static_assert(sh::kMaxExponent == static_cast<float>(brdf::kMaxExponent));
static_assert(sh::kMaxLobeValue == static_cast<float>(brdf::kMaxLobeValue));

// The interop vector types have std430's sizes and alignments.
static_assert(alignof(sh::vec2) == 8 && alignof(sh::vec4) == 16 && alignof(sh::uvec4) == 16);
static_assert(std::is_same_v<sh::uint, std::uint32_t>);

TEST(SharedHeaders, CompileAsCppWithStd430Layouts) {
  // The static_asserts above and in the headers are the test; this records the sizes.
  EXPECT_EQ(sizeof(sh::BrdfProbeCase), 92u);
  EXPECT_EQ(sizeof(sh::BrdfProbeResult), 92u);
  EXPECT_EQ(sizeof(sh::LoopProbeResult), 16u);
  EXPECT_EQ(sizeof(sh::ChunkProbePush), 8u);
  EXPECT_EQ(sizeof(sh::MadThroughputPush), 16u);
}

TEST(ShaderBlobs, EveryShaderIdHasSpirv) {
  constexpr uint32_t kSpirvMagic = 0x07230203;
  std::set<std::string> names;
  for (int i = 0; i < static_cast<int>(ShaderId::kCount); ++i) {
    const ShaderId id = static_cast<ShaderId>(i);
    const Span blob = ShaderBlob(id);
    ASSERT_NE(blob.data, nullptr) << ShaderName(id);
    ASSERT_GE(blob.size, 5u) << ShaderName(id);  // the SPIR-V header is 5 words
    EXPECT_EQ(blob.data[0], kSpirvMagic) << ShaderName(id);
    EXPECT_GE(blob.data[1], 0x00010500u) << ShaderName(id) << ": SPIR-V 1.5 (Vulkan 1.2)";
    EXPECT_TRUE(names.insert(ShaderName(id)).second) << ShaderName(id);
    const std::string source = ShaderSource(id);  // compute, or the renderer's raster stages
    EXPECT_TRUE(source.find(".comp") != std::string::npos ||
                source.find(".vert") != std::string::npos ||
                source.find(".frag") != std::string::npos)
        << source;
  }
  EXPECT_STREQ(ShaderName(ShaderId::kBrdfProbe), "brdf_probe");
  EXPECT_STREQ(ShaderSource(ShaderId::kLoopProbe), "probe/loop_probe.comp");
}

}  // namespace
}  // namespace reflcap::gpu
