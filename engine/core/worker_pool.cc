// WorkerPool (see worker_pool.h).
#include "engine/core/worker_pool.h"

#include <algorithm>
#include <atomic>

#include "engine/core/check.h"

namespace reflcap {

WorkerPool::WorkerPool(int threads, int max_queued) : max_queued_(size_t(std::max(1, max_queued))) {
  REFLCAP_CHECK(threads >= 1) << "WorkerPool needs at least one thread, got " << threads;
  threads_.reserve(size_t(threads));
  for (int i = 0; i < threads; ++i) threads_.emplace_back([this] { Work(); });
}

WorkerPool::~WorkerPool() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stopping_ = true;
  }
  work_ready_.notify_all();
  for (std::thread& t : threads_) t.join();
}

void WorkerPool::Work() {
  for (;;) {
    std::function<void()> task;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      work_ready_.wait(lock, [&] { return stopping_ || !queue_.empty(); });
      if (queue_.empty()) return;  // stopping, and nothing left to run
      task = std::move(queue_.front());
      queue_.pop_front();
      ++running_;
    }
    space_ready_.notify_one();
    task();
    {
      std::lock_guard<std::mutex> lock(mutex_);
      --running_;
      if (running_ == 0 && queue_.empty()) idle_.notify_all();
    }
  }
}

void WorkerPool::Submit(std::function<void()> task) {
  {
    std::unique_lock<std::mutex> lock(mutex_);
    space_ready_.wait(lock, [&] { return queue_.size() < max_queued_; });
    queue_.push_back(std::move(task));
  }
  work_ready_.notify_one();
}

void WorkerPool::WaitIdle() {
  std::unique_lock<std::mutex> lock(mutex_);
  idle_.wait(lock, [&] { return running_ == 0 && queue_.empty(); });
}

void WorkerPool::ParallelFor(int64_t n, const std::function<void(int64_t)>& body) {
  if (n <= 0) return;
  if (n == 1) {
    body(0);
    return;
  }
  // Helpers and the caller take indices from one counter; the caller then waits for the helpers
  // it queued (not for unrelated tasks of the pool).
  struct Shared {
    std::atomic<int64_t> next{0};
    std::mutex mutex;
    std::condition_variable done;
    int helpers_left = 0;
  } shared;
  auto drain = [&shared, &body, n] {
    for (int64_t i = shared.next++; i < n; i = shared.next++) body(i);
  };
  const int helpers = int(std::min<int64_t>(n - 1, int64_t(threads_.size())));
  shared.helpers_left = helpers;
  for (int h = 0; h < helpers; ++h) {
    Submit([&shared, drain] {
      drain();
      std::lock_guard<std::mutex> lock(shared.mutex);
      if (--shared.helpers_left == 0) shared.done.notify_all();
    });
  }
  drain();
  std::unique_lock<std::mutex> lock(shared.mutex);
  shared.done.wait(lock, [&] { return shared.helpers_left == 0; });
}

}  // namespace reflcap
