#include "engine/core/parallel.h"

#include <algorithm>
#include <atomic>
#include <thread>
#include <vector>

namespace reflcap {

int HardwareThreads() { return std::max(1u, std::thread::hardware_concurrency()); }

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
  std::atomic<int64_t> next{0};
  auto run = [&](int worker) {
    for (int64_t c = next++; c < chunks; c = next++) {
      const int64_t b = begin + c * chunk;
      body(b, std::min(end, b + chunk), worker);
    }
  };
  std::vector<std::thread> pool;
  for (int w = 1; w < workers; ++w) pool.emplace_back(run, w);
  run(0);
  for (auto& t : pool) t.join();
}

}  // namespace reflcap
