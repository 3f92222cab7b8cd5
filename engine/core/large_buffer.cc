#include "engine/core/large_buffer.h"

#include <new>

#if defined(__linux__)
#include <sys/mman.h>
#include <unistd.h>
#else
#include <cstdlib>
#endif

namespace reflcap {
namespace {

constexpr size_t kHugePage = size_t{2} << 20;

#if defined(__linux__)
size_t PageRounded(size_t bytes) {
  const size_t page = size_t(sysconf(_SC_PAGESIZE));
  return (bytes + page - 1) / page * page;
}
#endif

}  // namespace

void* AllocateLargeBuffer(size_t bytes) {
#if defined(__linux__)
  const size_t length = PageRounded(bytes);
  // Mapped one huge page longer, then trimmed to a 2 MiB-aligned start: only whole aligned
  // 2 MiB ranges can be huge pages. The tail past the last whole one stays in 4 KiB pages, so
  // nothing beyond `length` is ever resident.
  if (length > SIZE_MAX - kHugePage) throw std::bad_alloc();
  void* mapped = mmap(nullptr, length + kHugePage, PROT_READ | PROT_WRITE,
                      MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
  if (mapped == MAP_FAILED) throw std::bad_alloc();
  const uintptr_t begin = reinterpret_cast<uintptr_t>(mapped);
  const uintptr_t aligned = (begin + kHugePage - 1) / kHugePage * kHugePage;
  if (aligned > begin) munmap(mapped, aligned - begin);
  const size_t tail = begin + length + kHugePage - (aligned + length);
  if (tail > 0) munmap(reinterpret_cast<void*>(aligned + length), tail);
  void* p = reinterpret_cast<void*>(aligned);
  // Advice only: a kernel built without transparent huge pages refuses it, one with them set to
  // "never" ignores it, and the buffer is served in 4 KiB pages as malloc's would be.
  madvise(p, length, MADV_HUGEPAGE);
  return p;
#else
  void* p = std::aligned_alloc(kHugePage, (bytes + kHugePage - 1) / kHugePage * kHugePage);
  if (p == nullptr) throw std::bad_alloc();
  return p;
#endif
}

void FreeLargeBuffer(void* p, size_t bytes) noexcept {
  if (p == nullptr) return;
#if defined(__linux__)
  munmap(p, PageRounded(bytes));
#else
  (void)bytes;
  std::free(p);
#endif
}

}  // namespace reflcap
