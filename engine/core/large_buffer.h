#pragma once
// LargeBufferAllocator: DefaultInitAllocator (resize leaves new elements uninitialised) whose
// allocations of at least kLargeBufferBytes are mapped on their own, aligned to 2 MiB and advised
// MADV_HUGEPAGE (Linux), so that their first touch faults the memory in 2 MiB at a time instead
// of 4 KiB. For buffers that are large, written once by a read or a copy, and kept: the sample
// store's chunks. On the project's 2-core VM, reading 0.6 GB of the million store's chunks into
// malloc'd memory took 0.58 s and their checksums 0.27 s (the pages faulted in 4 KiB at a time
// by the kernel's copy, then walked through 4 KiB TLB entries); with huge pages 0.16-0.21 s and
// 0.07 s. Where transparent huge pages are off ("never") the advice is ignored and the memory
// behaves as malloc's. Smaller allocations go to operator new. Not for buffers allocated and
// freed over and over: each large one is a fresh mapping, faulted in again, where glibc's heap
// would reuse the pages.
#include <cstddef>
#include <cstdint>
#include <new>
#include <type_traits>
#include <vector>

#include "engine/core/default_init_allocator.h"

namespace reflcap {

// The size from which an allocation is mapped on its own: one huge page.
inline constexpr size_t kLargeBufferBytes = size_t{2} << 20;

// Maps `bytes` (>= kLargeBufferBytes) of zeroed, 2 MiB-aligned memory advised for huge pages;
// throws std::bad_alloc when the system has none. Freed with FreeLargeBuffer(p, bytes).
void* AllocateLargeBuffer(size_t bytes);
void FreeLargeBuffer(void* p, size_t bytes) noexcept;

// kMinBytes: the size from which allocations are mapped on their own (at least one huge page).
template <typename T, size_t kMinBytes = kLargeBufferBytes>
class LargeBufferAllocator : public DefaultInitAllocator<T> {
  static_assert(kMinBytes >= kLargeBufferBytes, "a mapping smaller than a huge page gains nothing");

 public:
  using value_type = T;
  template <typename U>
  struct rebind {
    using other = LargeBufferAllocator<U, kMinBytes>;
  };
  LargeBufferAllocator() = default;
  template <typename U>
  LargeBufferAllocator(const LargeBufferAllocator<U, kMinBytes>&) noexcept {}

  T* allocate(size_t n) {
    if (n > SIZE_MAX / sizeof(T)) throw std::bad_array_new_length();
    const size_t bytes = n * sizeof(T);
    if (bytes < kMinBytes) return std::allocator<T>().allocate(n);
    return static_cast<T*>(AllocateLargeBuffer(bytes));
  }
  void deallocate(T* p, size_t n) noexcept {
    const size_t bytes = n * sizeof(T);
    if (bytes < kMinBytes) {
      std::allocator<T>().deallocate(p, n);
    } else {
      FreeLargeBuffer(p, bytes);
    }
  }
  // Stateless: memory from one instance is freed by any other.
  template <typename U>
  bool operator==(const LargeBufferAllocator<U, kMinBytes>&) const noexcept { return true; }
  template <typename U>
  bool operator!=(const LargeBufferAllocator<U, kMinBytes>&) const noexcept { return false; }
};

// A vector grown without zeroing, its large buffers on huge pages (see above).
template <typename T>
using LargeBufferVector = std::vector<T, LargeBufferAllocator<T>>;

}  // namespace reflcap
