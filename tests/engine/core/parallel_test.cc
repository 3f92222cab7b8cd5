#include "engine/core/parallel.h"

#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <thread>
#include <vector>

namespace reflcap {
namespace {

TEST(ParallelFor, VisitsEveryIndexExactlyOnce) {
  std::vector<int> hits(10007, 0);
  ParallelFor(0, int64_t(hits.size()), 97, [&](int64_t b, int64_t e, int) {
    for (int64_t i = b; i < e; ++i) hits[i]++;
  });
  for (int h : hits) ASSERT_EQ(h, 1);
}

// Worker indices are what per-worker scratch is indexed by: below the worker count, and never
// held by two bodies at once — also when more threads are asked for than the machine has.
TEST(ParallelFor, WorkerIndicesAreInRangeAndNeverShared) {
  for (int threads : {2, 3, HardwareThreads(), 4 * HardwareThreads()}) {
    std::vector<std::atomic<int>> busy(static_cast<size_t>(threads));
    std::atomic<int> out_of_range{0}, shared{0};
    ParallelFor(0, 4000, 1, [&](int64_t, int64_t, int worker) {
      if (worker < 0 || worker >= threads) {
        ++out_of_range;
        return;
      }
      if (busy[size_t(worker)]++ != 0) ++shared;
      double x = 0;  // a little work, so that bodies overlap
      for (int i = 0; i < 200; ++i) x += std::sqrt(double(i) + x);
      if (!(x >= 0)) ++out_of_range;  // keeps the loop
      --busy[size_t(worker)];
    }, threads);
    EXPECT_EQ(out_of_range.load(), 0) << threads << " threads";
    EXPECT_EQ(shared.load(), 0) << threads << " threads";
  }
}

// A body may run a ParallelFor of its own, and several threads may call it at once: every index
// is visited once and nothing waits for a helper that cannot start (the helpers are shared).
TEST(ParallelFor, NestedAndConcurrentCallsFinishAndVisitEverything) {
  constexpr int kCallers = 4, kOuter = 16, kInner = 500;
  std::vector<std::atomic<int>> hits(size_t(kCallers) * kOuter * kInner);
  std::vector<std::thread> callers;
  for (int c = 0; c < kCallers; ++c) {
    callers.emplace_back([&, c] {
      ParallelFor(0, kOuter, 1, [&](int64_t o0, int64_t o1, int) {
        for (int64_t o = o0; o < o1; ++o) {
          ParallelFor(0, kInner, 7, [&](int64_t i0, int64_t i1, int) {
            for (int64_t i = i0; i < i1; ++i) ++hits[size_t((c * kOuter + o) * kInner + i)];
          });
        }
      });
    });
  }
  for (std::thread& t : callers) t.join();
  int wrong = 0;
  for (const auto& h : hits) wrong += h.load() != 1;
  EXPECT_EQ(wrong, 0);
}

}  // namespace
}  // namespace reflcap
