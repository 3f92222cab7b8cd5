#include "engine/core/parallel.h"

#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <memory>
#include <mutex>
#include <thread>

#include "engine/core/worker_pool.h"

namespace reflcap {

int HardwareThreads() { return std::max(1u, std::thread::hardware_concurrency()); }

namespace {

// The helpers of every ParallelFor: HardwareThreads() - 1 threads started on first use and kept
// for the process's life. Starting threads per call cost ~15 starts and joins per call on a
// 16-thread host, and `reflcap fit` on the million preset makes ~1,200 calls. Never destroyed:
// idle workers end with the process, and no static destructor can find the pool gone.
WorkerPool& Helpers() {
  static WorkerPool* const pool = new WorkerPool(std::max(1, HardwareThreads() - 1));
  return *pool;
}

// One ParallelFor call, shared with its queued helpers (which may start after it returned).
struct Call {
  std::atomic<int64_t> next{0};      // next chunk to take
  std::atomic<int> next_worker{1};   // worker index of the next helper that joins (0: the caller)
  std::mutex mutex;
  std::condition_variable done;
  int joined = 0;       // helpers inside the chunk loop
  bool closed = false;  // the caller ran out of chunks: helpers starting later do nothing
};

}  // namespace

void ParallelFor(int64_t begin, int64_t end, int64_t chunk,
                 const std::function<void(int64_t, int64_t, int)>& body, int threads) {
  if (end <= begin) return;
  chunk = std::max<int64_t>(1, chunk);
  const int64_t chunks = (end - begin + chunk - 1) / chunk;
  const int workers =
      static_cast<int>(std::min<int64_t>(chunks, threads > 0 ? threads : HardwareThreads()));
  if (workers <= 1) {
    for (int64_t b = begin; b < end; b += chunk) body(b, std::min(end, b + chunk), 0);
    return;
  }
  auto call = std::make_shared<Call>();
  auto drain = [&body, begin, end, chunk, chunks](Call& c, int worker) {
    for (int64_t k = c.next++; k < chunks; k = c.next++) {
      const int64_t b = begin + k * chunk;
      body(b, std::min(end, b + chunk), worker);
    }
  };
  // The caller takes chunks too and, once none is left, waits only for the helpers that joined
  // before: a helper still queued (the pool busy with other calls, or this is a nested call from
  // one of its workers) never touches `body`, so nothing waits on a queue that cannot move.
  for (int h = 1; h < workers; ++h) {
    Helpers().Submit([call, drain] {
      {
        const std::lock_guard<std::mutex> lock(call->mutex);
        if (call->closed) return;
        ++call->joined;
      }
      drain(*call, call->next_worker++);
      const std::lock_guard<std::mutex> lock(call->mutex);
      if (--call->joined == 0) call->done.notify_all();
    });
  }
  drain(*call, 0);
  std::unique_lock<std::mutex> lock(call->mutex);
  call->closed = true;
  call->done.wait(lock, [&] { return call->joined == 0; });
}

}  // namespace reflcap
