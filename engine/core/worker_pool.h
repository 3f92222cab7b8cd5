#pragma once
// WorkerPool: a fixed set of threads that stays alive across calls. Its users: the helpers of
// every engine/core/parallel.h ParallelFor (Submit), the large host copies of engine/gpu
// (vk_buffer.cc, ParallelFor), the Vulkan renderer's read-back of each finished batch
// (ParallelFor, many times a second at GPU speed) and `reflcap render`'s file writers (Submit,
// overlapped with rendering).
//
// Tasks must not throw. The destructor runs every queued task, then joins the threads.
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <mutex>
#include <thread>
#include <vector>

namespace reflcap {

class WorkerPool {
 public:
  // `threads` workers (>= 1); Submit blocks while `max_queued` (>= 1) tasks wait to start.
  explicit WorkerPool(int threads, int max_queued = 1 << 20);
  ~WorkerPool();
  WorkerPool(const WorkerPool&) = delete;
  WorkerPool& operator=(const WorkerPool&) = delete;

  int threads() const { return int(threads_.size()); }

  // Queues `task` for a worker, waiting first while max_queued tasks are queued (back-pressure).
  void Submit(std::function<void()> task);
  // Waits until every task submitted so far has finished.
  void WaitIdle();

  // Runs body(i) for every i in [0, n), on the workers and the calling thread, and returns when
  // all have finished. Which thread runs which i is unspecified: bodies must not depend on it.
  // Not to be called from one of this pool's tasks.
  void ParallelFor(int64_t n, const std::function<void(int64_t)>& body);

 private:
  void Work();

  std::mutex mutex_;
  std::condition_variable work_ready_, space_ready_, idle_;
  std::deque<std::function<void()>> queue_;
  size_t max_queued_;
  int running_ = 0;  // tasks started and not yet finished
  bool stopping_ = false;
  std::vector<std::thread> threads_;
};

}  // namespace reflcap
