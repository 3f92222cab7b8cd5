// No heap allocation in the batched fitter's per-texel loop: with a counting global operator
// new, fitting 1,000 texels allocates exactly as often as fitting 100 (the per-call constant:
// the result vector and ParallelFor's closure), once the fitter's workspaces have grown.
#include <gtest/gtest.h>

#include <atomic>
#include <cstdlib>
#include <new>

#include "engine/fit/fitter.h"
#include "engine/fit/synthetic_samples.h"

namespace {
std::atomic<long> g_allocations{0};
}  // namespace

void* operator new(std::size_t size) {
  ++g_allocations;
  if (void* p = std::malloc(size ? size : 1)) return p;
  throw std::bad_alloc();
}
void operator delete(void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }

namespace reflcap::fit {
namespace {

long AllocationsOfFit(Fitter& fitter, const TexelSampleChunk& chunk, const FitOptions& options) {
  std::vector<TexelFit> results;
  const long before = g_allocations.load();
  const Status s = fitter.Fit(chunk, options, &results);
  const long count = g_allocations.load() - before;
  EXPECT_TRUE(s.ok());
  return count;
}

TEST(FitAllocations, PerTexelLoopDoesNotAllocate) {
  SyntheticSampleOptions so;
  const TexelSampleChunk small = MakeSyntheticChunk(SynthMaterialTexels(100, 1), so);
  const TexelSampleChunk large = MakeSyntheticChunk(SynthMaterialTexels(1000, 2), so);
  for (LobeModel model : {LobeModel::kAniso, LobeModel::kShared}) {
    FitOptions options;
    options.threads = 1;  // one worker: ParallelFor runs inline, no thread objects
    options.lobe_model = model;
    auto fitter = CreateFitter(Backend::kCpu);
    ASSERT_TRUE(fitter.ok());
    AllocationsOfFit(**fitter, large, options);  // grows the workspaces
    const long for_small = AllocationsOfFit(**fitter, small, options);
    const long for_large = AllocationsOfFit(**fitter, large, options);
    EXPECT_EQ(for_small, for_large) << LobeModelName(model);
    EXPECT_LE(for_large, 4) << LobeModelName(model);
  }
}

}  // namespace
}  // namespace reflcap::fit
