// WorkerPool (engine/core/worker_pool.h): every index of a ParallelFor runs exactly once,
// whatever the thread count; Submit's back-pressure bounds the queue; WaitIdle waits for all
// submitted tasks; the destructor runs what is still queued.
#include "engine/core/worker_pool.h"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <thread>
#include <vector>

namespace reflcap {
namespace {

TEST(WorkerPool, ParallelForRunsEveryIndexOnce) {
  for (int threads : {1, 3, 8}) {
    WorkerPool pool(threads);
    EXPECT_EQ(pool.threads(), threads);
    for (int64_t n : {0, 1, 2, 7, 1000}) {
      std::vector<std::atomic<int>> hits(static_cast<size_t>(n));
      pool.ParallelFor(n, [&](int64_t i) { hits[size_t(i)]++; });
      for (int64_t i = 0; i < n; ++i) EXPECT_EQ(hits[size_t(i)].load(), 1) << threads << " " << i;
    }
  }
}

TEST(WorkerPool, SubmitIsBoundedAndWaitIdleWaitsForEverything) {
  WorkerPool pool(2, /*max_queued=*/1);
  std::atomic<int> done{0}, running{0}, most{0};
  for (int k = 0; k < 20; ++k) {
    pool.Submit([&] {
      const int now = ++running;
      int seen = most.load();
      while (now > seen && !most.compare_exchange_weak(seen, now)) {
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(2));
      --running;
      ++done;
    });
  }
  pool.WaitIdle();
  EXPECT_EQ(done.load(), 20);
  EXPECT_LE(most.load(), 2) << "never more tasks at once than threads";
}

TEST(WorkerPool, DestructorRunsQueuedTasks) {
  std::atomic<int> done{0};
  {
    WorkerPool pool(1);
    for (int k = 0; k < 10; ++k) pool.Submit([&] { ++done; });
  }
  EXPECT_EQ(done.load(), 10);
}

}  // namespace
}  // namespace reflcap
