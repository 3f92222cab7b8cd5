#pragma once
// REFLCAP_CHECK(cond) << "message": aborts with file:line on a violated invariant (a bug, never bad
// user input — that is a Status). REFLCAP_DCHECK is the same in debug builds and free in release.
// After pbrt-v4's util/check.h.
#include <sstream>

namespace reflcap::internal {

class CheckFailure {
 public:
  CheckFailure(const char* file, int line, const char* condition);
  [[noreturn]] ~CheckFailure();
  std::ostream& stream() { return stream_; }

 private:
  std::ostringstream stream_;
};

// Lets `REFLCAP_CHECK(x) << ...` be an expression of type void in both branches.
struct Voidify {
  void operator&(std::ostream&) {}
};

}  // namespace reflcap::internal

#define REFLCAP_CHECK(cond)                  \
  (cond) ? (void)0                           \
         : ::reflcap::internal::Voidify() &  \
               ::reflcap::internal::CheckFailure(__FILE__, __LINE__, #cond).stream()

#ifdef NDEBUG
#define REFLCAP_DCHECK(cond) \
  true ? (void)0 : ::reflcap::internal::Voidify() & ::reflcap::internal::NullStream()
namespace reflcap::internal {
inline std::ostream& NullStream() {
  static std::ostringstream sink;
  return sink;
}
}  // namespace reflcap::internal
#else
#define REFLCAP_DCHECK(cond) REFLCAP_CHECK(cond)
#endif
