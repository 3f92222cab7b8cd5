#pragma once
// DefaultInitAllocator: std::allocator whose value-less construct() default-initialises, so that
// std::vector<float, DefaultInitAllocator<float>>::resize(n) leaves new elements uninitialised
// instead of zeroing them. For large buffers that are written before they are read: zeroing
// 3.84 GB of fresh pages took 2.0 s on one thread here (page faults included), where the writers
// touch the pages first and in parallel. Reading an element that was never written is a bug, as
// with any uninitialised value.
#include <memory>
#include <new>
#include <type_traits>
#include <utility>
#include <vector>

namespace reflcap {

template <typename T>
class DefaultInitAllocator : public std::allocator<T> {
 public:
  template <typename U>
  struct rebind {
    using other = DefaultInitAllocator<U>;
  };
  DefaultInitAllocator() = default;
  template <typename U>
  DefaultInitAllocator(const DefaultInitAllocator<U>&) noexcept {}

  template <typename U>
  void construct(U* p) noexcept(std::is_nothrow_default_constructible_v<U>) {
    ::new (static_cast<void*>(p)) U;
  }
  template <typename U, typename... Args>
  void construct(U* p, Args&&... args) {
    std::allocator_traits<std::allocator<T>>::construct(static_cast<std::allocator<T>&>(*this), p,
                                                         std::forward<Args>(args)...);
  }
};

// A vector whose resize leaves new elements uninitialised (see above).
template <typename T>
using UninitializedVector = std::vector<T, DefaultInitAllocator<T>>;

}  // namespace reflcap
