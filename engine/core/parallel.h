#pragma once
// ParallelFor over [begin, end) in chunks on all hardware threads (or `threads` when > 0).
// The body receives a [chunk_begin, chunk_end) range and the worker index (0..workers-1) so it can
// use per-worker scratch without locks. Runs inline when there is one chunk.
// The calling thread takes chunks, helped by a pool of HardwareThreads() - 1 threads kept for the
// process (not threads started per call); so at most that many + 1 bodies run at once, however
// large `threads`. Bodies may call ParallelFor themselves, and several threads may call it at
// once: a caller never waits for a helper that has not started.
#include <algorithm>
#include <cstdint>
#include <functional>

namespace reflcap {

int HardwareThreads();

void ParallelFor(int64_t begin, int64_t end, int64_t chunk,
                 const std::function<void(int64_t chunk_begin, int64_t chunk_end, int worker)>& body,
                 int threads = 0);

// Sets every element of *v to `value` on `threads` threads (0: all): for large buffers allocated
// without initialisation (LargeBufferVector, UninitializedVector), whose pages are then first
// touched in parallel rather than by one thread.
template <typename Vector, typename T>
void ParallelFill(Vector* v, const T& value, int threads = 0) {
  constexpr int64_t kElementsPerTask = int64_t{1} << 16;  // a few hundred KB a task
  ParallelFor(0, int64_t(v->size()), kElementsPerTask, [&](int64_t begin, int64_t end, int) {
    std::fill(v->begin() + begin, v->begin() + end, value);
  }, threads);
}

}  // namespace reflcap
