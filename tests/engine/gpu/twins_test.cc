// GLSL twins vs C++ twins: shaders/common/safe_math.glsl and shaders/common/lafortune.glsl,
// evaluated on the device by shaders/probe/brdf_probe.comp, against engine/math/safe_math.h and
// engine/brdf/lafortune.h instantiated for float, element by element, on a grid of ordinary and
// edge-case inputs (base <= 0 and at the cut-off, pow(0, 0), n at its bounds, saturation,
// grazing and below-horizon directions).
//
// Tolerance. Both sides compute in float (eps = 1.2e-7) from the same float inputs; the lobe base
// is bit-identical (the GLSL marks it `precise`, so it is not fused into an FMA), and the GLSL's
// log, pow and acos are shaders/common/precise_math.glsl's, accurate to a few ulp like libm's
// (the built-ins are not: Vulkan allows log 2^-21 absolute error near 1 and acos 4096 ulp, and
// lavapipe's are that far off). What remains is exp2, which Vulkan lets err by 3 + 2|y| ulp for
// 2^y, plus the rounding of y = n log2 b: about |y| ulp, with |y| = |log2 result| up to 100 for
// results above kTiny. Hence kRelTol = 1e-5 (~80 ulp) plus kUlpPerBinade * eps * |log2 result|
// for results that go through pow. A real bug — a wrong constant, branch, clamp, layout or
// parameter index — gives errors of 1e-3 and more, or 0 against non-zero. Values decided by a
// guard (a lobe at or below the cut-off and its gradient, SafePow's 0, SafeDiv's fallback, Clamp,
// saturation at kMaxLobeValue) must match exactly. Results below kTiny carry no weight
// (engine/math/safe_math.h) and may be flushed to 0 by the device, so they are not compared.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "engine/brdf/lafortune.h"
#include "engine/gpu/chunking.h"
#include "engine/gpu/vk_buffer.h"
#include "engine/gpu/vk_commands.h"
#include "engine/gpu/vk_pipeline.h"
#include "engine/math/safe_math.h"
#include "shaders/shared/brdf_probe.h"
#include "tests/engine/gpu/gpu_test_util.h"

namespace reflcap::gpu {
namespace {

using shared::BrdfProbeCase;
using shared::BrdfProbePush;
using shared::BrdfProbeResult;

constexpr double kRelTol = 1e-5;
constexpr double kUlpPerBinade = 3;
constexpr double kFloatEps = std::numeric_limits<float>::epsilon();
constexpr int kNumRandomCases = 4000;
constexpr int kNumParams = brdf::kMaxParamsPerChannel;

// ---- Inputs ----------------------------------------------------------------------------------

std::array<float, 3> Direction(double theta_deg, double phi_deg) {
  const double t = DegToRad(theta_deg), p = DegToRad(phi_deg);
  return {static_cast<float>(std::sin(t) * std::cos(p)),
          static_cast<float>(std::sin(t) * std::sin(p)), static_cast<float>(std::cos(t))};
}

// Scalar arguments of the safe_math twins: zero of both signs, the kTiny/kPowBaseMin boundary,
// the [-1, 1] ends of acos, powers of ten from 1e-20 to 1e30.
const std::vector<float> kScalarA = {-1.0005f, -1.0f,   -0.5f,  -1e-4f, -0.0f, 0.0f, 1e-31f,
                                     1e-30f,   2e-30f,  1e-20f, 1e-7f,  0.25f, 0.5f, 0.9999999f,
                                     1.0f,     1.0005f, 2.0f,   100.0f, 1e30f};
// Exponents / divisors / lower clamp bounds, including pow(x, 0) and negative exponents.
const std::vector<float> kScalarB = {-2.0f, -0.5f, 0.0f, 0.5f, 1.0f, 2.0f, 10.0f, 1e4f};
// Clamp's hi = b + kScalarCOffset (>= b); SafeDiv's fallback is the same c.
const std::vector<float> kScalarCOffset = {0.0f, 0.5f, 3.0f};

void SetLobe(BrdfProbeCase* c, int k, float cx, float cy, float cz, float n) {
  c->params[1 + 4 * k] = cx;
  c->params[2 + 4 * k] = cy;
  c->params[3 + 4 * k] = cz;
  c->params[4 + 4 * k] = n;
}

void SetDirections(BrdfProbeCase* c, const std::array<float, 3>& wi,
                   const std::array<float, 3>& wo) {
  for (int j = 0; j < 3; ++j) {
    c->wi[j] = wi[j];
    c->wo[j] = wo[j];
  }
}

std::vector<BrdfProbeCase> MakeCases() {
  std::vector<BrdfProbeCase> cases;
  std::mt19937 rng(20240611);
  std::uniform_real_distribution<float> unit(0.0f, 1.0f);
  std::uniform_real_distribution<float> coefficient(-1.2f, 1.2f);
  std::uniform_real_distribution<float> theta(0.0f, 90.0f);
  std::uniform_real_distribution<float> theta_any(0.0f, 180.0f);
  std::uniform_real_distribution<float> phi(0.0f, 360.0f);
  std::uniform_real_distribution<float> log_n(0.0f, 4.0f);  // n = 10^U(0, 4) in [1, 1e4]

  // Random cases: upper-hemisphere directions mostly, some below; 0-3 lobes; signed C's.
  for (int i = 0; i < kNumRandomCases; ++i) {
    BrdfProbeCase c{};
    const bool below = i % 10 == 9;
    SetDirections(&c, Direction(below ? theta_any(rng) : theta(rng), phi(rng)),
                  Direction(theta(rng), phi(rng)));
    c.num_lobes = i % (brdf::kMaxLobes + 1);
    c.params[0] = unit(rng);
    for (int k = 0; k < brdf::kMaxLobes; ++k) {
      SetLobe(&c, k, coefficient(rng), coefficient(rng), coefficient(rng),
              std::pow(10.0f, log_n(rng)));
    }
    cases.push_back(c);
  }

  // Edge cases of the lobe, each as lobe 0 of a one-lobe channel and as the last of three.
  const std::array<float, 3> normal = Direction(0, 0);
  const std::array<float, 3> oblique = Direction(60, 30);
  const std::array<float, 3> grazing = Direction(89.9, 200);
  struct Edge {
    float cx, cy, cz, n;
    std::array<float, 3> wi, wo;
  };
  const std::vector<Edge> edges = {
      {0, 0, 0, 1, oblique, oblique},         // base exactly 0
      {-1, -1, -1, 2, normal, normal},        // base < 0
      {0, 0, -0.5f, 1e4f, normal, normal},    // base < 0, n at its maximum
      {0, 0, 1e-31f, 1, normal, normal},      // 0 < base < kPowBaseMin
      {0, 0, 1e-30f, 1, normal, normal},      // base == kPowBaseMin: still cut off
      {0, 0, 2e-30f, 1, normal, normal},      // just above the cut-off, n = 1
      {0, 0, 1, 1, normal, normal},           // base 1: b^n = 1, log b = 0
      {0, 0, 0.5f, 1, normal, normal},        // n at its minimum
      {0, 0, 0.5f, 1e4f, normal, normal},     // n at its maximum: 0.5^1e4 underflows
      {0, 0, 0.999f, 1e4f, normal, normal},   // n at its maximum: e^-10
      {0, 0, 0.9999f, 1e4f, normal, normal},  // base near 1, n at its maximum
      {0, 0, 1.001f, 1e4f, normal, normal},   // b^n = 2.2e4
      {0, 0, 1.01f, 1e4f, normal, normal},    // b^n = 1.6e43: saturated
      {0, 0, 2, 1e4f, normal, normal},        // overflow to inf: saturated
      {-1, -1, 1, 50, oblique, oblique},      // off-mirror: base = cos 2*60 < 0
      {-1, -1, 1, 50, grazing, grazing},      // grazing
      {1, 1, 1, 3, grazing, oblique},
  };
  for (const Edge& e : edges) {
    for (int lobes : {1, 3}) {
      BrdfProbeCase c{};
      SetDirections(&c, e.wi, e.wo);
      c.num_lobes = lobes;
      c.params[0] = 0.5f;
      for (int k = 0; k < brdf::kMaxLobes; ++k) SetLobe(&c, k, 0.3f, -0.2f, 0.8f, 5.0f);
      SetLobe(&c, lobes - 1, e.cx, e.cy, e.cz, e.n);
      SetLobe(&c, 0, e.cx, e.cy, e.cz, e.n);  // LafortuneLobe probes lobe 0
      cases.push_back(c);
    }
  }

  // Scalar arguments: the full product a x b x c, spread over the cases (cycling when there are
  // more combinations than cases).
  const size_t combos = kScalarA.size() * kScalarB.size() * kScalarCOffset.size();
  while (cases.size() < combos) cases.push_back(cases[cases.size() % kNumRandomCases]);
  for (size_t i = 0; i < cases.size(); ++i) {
    const size_t k = i % combos;
    cases[i].a = kScalarA[k % kScalarA.size()];
    cases[i].b = kScalarB[(k / kScalarA.size()) % kScalarB.size()];
    cases[i].c = cases[i].b + kScalarCOffset[k / (kScalarA.size() * kScalarB.size())];
  }
  return cases;
}

// ---- The C++ twin ----------------------------------------------------------------------------

// What the probe computes, by the C++ float twins, and which results a guard decides (compared
// exactly). SafeSqrt and SafeAcos are not compared where the C++ twin's debug checks forbid the
// argument (below -kSafeDomainSlack, or beyond [-1, 1] by more than it).
struct Expected {
  BrdfProbeResult r{};
  bool checked_sqrt = true;
  bool checked_acos = true;
  bool exact_pow = false;                         // a <= kPowBaseMin: SafePow is 0
  bool exact_div = false;                         // b == 0: SafeDiv is the fallback c
  bool exact_lobe = false;                        // lobe 0 cut off or saturated
  std::array<bool, kNumParams> exact_gradient{};  // entries of cut-off or saturated lobes
  int cut_off_lobes = 0;
  int saturated_lobes = 0;
};

// The lobe's base as lafortune.h forms it (products first).
float Base(const BrdfProbeCase& c, const float* lobe) {
  return lobe[0] * (c.wi[0] * c.wo[0]) + lobe[1] * (c.wi[1] * c.wo[1]) +
         lobe[2] * (c.wi[2] * c.wo[2]);
}

Expected EvaluateOnCpu(const BrdfProbeCase& c) {
  Expected e;
  BrdfProbeResult& r = e.r;
  const float a = c.a, b = c.b, cc = c.c;
  e.checked_sqrt = !(a < -kSafeDomainSlack);
  e.checked_acos = !(a < -1.0 - kSafeDomainSlack) && !(a > 1.0 + kSafeDomainSlack);
  r.safe_sqrt = e.checked_sqrt ? SafeSqrt(a) : 0.0f;
  r.safe_acos = e.checked_acos ? SafeAcos(a) : 0.0f;
  r.safe_div = SafeDiv(a, b, cc);
  r.safe_log = SafeLog(a);
  r.safe_pow = SafePow(a, b);
  r.clamp = Clamp(a, b, cc);
  r.raw_pow = std::pow(a, b);
  r.lobe = brdf::LafortuneLobe(c.wi, c.wo, c.params[1], c.params[2], c.params[3], c.params[4]);
  r.value = brdf::EvalChannel(c.wi, c.wo, c.params, c.num_lobes);
  r.value_with_gradient =
      brdf::EvalChannelWithGradient(c.wi, c.wo, c.params, c.num_lobes, r.gradient);
  e.exact_pow = a <= static_cast<float>(kPowBaseMin);
  e.exact_div = b == 0.0f;
  for (int k = 0; k < brdf::kMaxLobes; ++k) {
    const float* lobe = c.params + 1 + 4 * k;
    const bool cut_off = Base(c, lobe) <= static_cast<float>(kPowBaseMin);
    const bool saturated = brdf::LafortuneLobe(c.wi, c.wo, lobe[0], lobe[1], lobe[2], lobe[3]) ==
                           static_cast<float>(brdf::kMaxLobeValue);
    if (k == 0) e.exact_lobe = cut_off || saturated;
    if (k >= c.num_lobes) continue;
    e.cut_off_lobes += cut_off;
    e.saturated_lobes += saturated;
    for (int i = 1; i <= 4; ++i) e.exact_gradient[4 * k + i] = cut_off || saturated;
  }
  return e;
}

// ---- Comparison ------------------------------------------------------------------------------

struct FieldStats {
  double max_rel = 0;
  int failures = 0;
};

class TwinsTest : public testing::VulkanTest {};

TEST_F(TwinsTest, GpuMatchesCppFloatElementByElement) {
  const std::vector<BrdfProbeCase> cases = MakeCases();
  const uint32_t n = static_cast<uint32_t>(cases.size());

  ComputePipelineOptions options;
  options.shader = ShaderId::kBrdfProbe;
  options.num_buffers = 2;
  options.push_constant_bytes = sizeof(BrdfProbePush);
  StatusOr<ComputePipeline> pipeline = ComputePipeline::Create(ctx(), options);
  ASSERT_TRUE(pipeline.ok()) << pipeline.status().ToString();
  StatusOr<Buffer> in = CreateBufferFrom(ctx(), cases);
  ASSERT_TRUE(in.ok()) << in.status().ToString();
  StatusOr<Buffer> out = Buffer::Create(ctx(), n * sizeof(BrdfProbeResult), MemoryKind::kDevice);
  ASSERT_TRUE(out.ok()) << out.status().ToString();
  StatusOr<CommandBuffer> cmd = CommandBuffer::Create(ctx());
  ASSERT_TRUE(cmd.ok()) << cmd.status().ToString();
  ASSERT_TRUE(cmd->Begin().ok());
  const BrdfProbePush push{n};
  const Status dispatched =
      cmd->Dispatch(*pipeline, {Bind(*in), Bind(*out)}, PushConstants::Of(push),
                    static_cast<uint32_t>(GroupCount(n, options.local_size_x)));
  ASSERT_TRUE(dispatched.ok()) << dispatched.ToString();
  const Status submitted = cmd->SubmitAndWait();
  ASSERT_TRUE(submitted.ok()) << submitted.ToString();
  StatusOr<std::vector<BrdfProbeResult>> gpu = DownloadVector<BrdfProbeResult>(ctx(), *out, n);
  ASSERT_TRUE(gpu.ok()) << gpu.status().ToString();

  enum Field { kSqrt, kAcos, kDiv, kLog, kPow, kClamp, kLobe, kValue, kValueWithGradient, kGrad0 };
  const char* kNames[] = {"SafeSqrt",      "SafeAcos",    "SafeDiv",
                          "SafeLog",       "SafePow",     "Clamp",
                          "LafortuneLobe", "EvalChannel", "EvalChannelWithGradient"};
  std::vector<FieldStats> stats(kGrad0 + kNumParams);
  int cut_off_lobes = 0, saturated_lobes = 0, exact_pows = 0, exact_divs = 0;
  for (uint32_t i = 0; i < n; ++i) {
    const BrdfProbeCase& c = cases[i];
    const Expected e = EvaluateOnCpu(c);
    const BrdfProbeResult& g = (*gpu)[i];
    cut_off_lobes += e.cut_off_lobes;
    saturated_lobes += e.saturated_lobes;
    exact_pows += e.exact_pow;
    exact_divs += e.exact_div;
    // `through_pow`: the result goes through exp2, whose error grows with |log2 result|.
    auto check = [&](int field, float want, float got, bool exact, bool through_pow) {
      const double diff = std::abs(double(want) - double(got));
      const double scale = std::max(std::abs(double(want)), std::abs(double(got)));
      const double rel = diff / std::max(scale, std::numeric_limits<double>::min());
      double tol = kRelTol;
      if (through_pow && scale > 0) tol += kUlpPerBinade * kFloatEps * std::abs(std::log2(scale));
      const bool ok = want == got || (!exact && (diff <= tol * scale || scale < kTiny));
      FieldStats& s = stats[field];
      if (scale >= kTiny) s.max_rel = std::max(s.max_rel, rel);
      if (!ok && s.failures++ < 5) {
        const std::string name =
            field < kGrad0 ? kNames[field] : "gradient[" + std::to_string(field - kGrad0) + "]";
        ADD_FAILURE() << name << (exact ? " (exact)" : "") << ", case " << i << ": GPU " << got
                      << " vs C++ " << want << " (relative " << rel << ", tolerance " << tol
                      << "); a=" << c.a << " b=" << c.b << " c=" << c.c
                      << " num_lobes=" << c.num_lobes << " lobe0=(" << c.params[1] << ", "
                      << c.params[2] << ", " << c.params[3] << ", " << c.params[4] << ")";
      }
    };
    if (e.checked_sqrt) check(kSqrt, e.r.safe_sqrt, g.safe_sqrt, false, false);
    if (e.checked_acos) check(kAcos, e.r.safe_acos, g.safe_acos, false, false);
    check(kDiv, e.r.safe_div, g.safe_div, e.exact_div, false);
    check(kLog, e.r.safe_log, g.safe_log, false, false);
    check(kPow, e.r.safe_pow, g.safe_pow, e.exact_pow, true);
    check(kClamp, e.r.clamp, g.clamp, true, false);
    check(kLobe, e.r.lobe, g.lobe, e.exact_lobe, true);
    check(kValue, e.r.value, g.value, false, true);
    check(kValueWithGradient, e.r.value_with_gradient, g.value_with_gradient, false, true);
    for (int p = 0; p < brdf::ParamsPerChannel(c.num_lobes); ++p) {
      check(kGrad0 + p, e.r.gradient[p], g.gradient[p], e.exact_gradient[p], true);
    }
    for (int p = brdf::ParamsPerChannel(c.num_lobes); p < kNumParams; ++p) {
      EXPECT_EQ(g.gradient[p], 0.0f) << "case " << i << ": gradient past num_lobes";
    }
    // pow(0, 0): the guarded twin is 0 on both sides (C's pow gives 1; GLSL leaves it undefined).
    if (c.a == 0.0f && c.b == 0.0f) {
      EXPECT_EQ(g.safe_pow, 0.0f);
      EXPECT_EQ(e.r.safe_pow, 0.0f);
      RecordProperty("device_raw_pow_0_0", StrCat(g.raw_pow));
    }
  }
  // The grid must keep reaching the guarded branches.
  EXPECT_GT(cut_off_lobes, 100);
  EXPECT_GT(saturated_lobes, 0);
  EXPECT_GT(exact_pows, 100);
  EXPECT_GT(exact_divs, 100);
  for (size_t f = 0; f < stats.size(); ++f) {
    const std::string name =
        f < kGrad0 ? kNames[f] : "gradient[" + std::to_string(f - kGrad0) + "]";
    RecordProperty("max_relative_error_" + name, StrCat(stats[f].max_rel));
  }
}

}  // namespace
}  // namespace reflcap::gpu
