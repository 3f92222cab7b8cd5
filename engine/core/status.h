#pragma once
// Status and StatusOr<T>: how fallible operations at module boundaries (I/O, user input, Embree,
// Vulkan) report failure. No exceptions cross reflcap's APIs; main() maps a Status to an exit code
// (see ExitCodeFor). After uVkCompute's status.h and absl::Status, reduced to what C++17 needs.
#include <optional>
#include <sstream>
#include <string>
#include <utility>

#include "engine/core/check.h"

namespace reflcap {

// Each code names the condition that produces it.
enum class StatusCode {
  kOk = 0,
  kInvalidArgument,     // the caller's input is malformed (bad field value, bad option)
  kNotFound,            // a named file, id or device does not exist
  kDataLoss,            // a file exists but is corrupt or truncated
  kFailedPrecondition,  // the input is well formed but cannot be used as asked
  kUnavailable,         // a backend (Vulkan device, feature) is not available here
  kInternal,            // a bug or an unexpected failure of a library we call
};

const char* StatusCodeName(StatusCode code);

class [[nodiscard]] Status {
 public:
  Status() = default;
  Status(StatusCode code, std::string message) : code_(code), message_(std::move(message)) {}

  bool ok() const { return code_ == StatusCode::kOk; }
  StatusCode code() const { return code_; }
  const std::string& message() const { return message_; }
  // "InvalidArgument: capture.json: cameras[0].K: not invertible".
  std::string ToString() const;

  // Returns a copy whose message is prefixed with `context` and ": ".
  Status WithContext(const std::string& context) const;

 private:
  StatusCode code_ = StatusCode::kOk;
  std::string message_;
};

inline Status OkStatus() { return Status(); }

// Streams every argument into one string: StrCat("cameras[", i, "].K").
template <typename... Args>
std::string StrCat(const Args&... args) {
  std::ostringstream out;
  (out << ... << args);
  return out.str();
}

template <typename... Args>
Status InvalidArgumentError(const Args&... args) {
  return Status(StatusCode::kInvalidArgument, StrCat(args...));
}
template <typename... Args>
Status NotFoundError(const Args&... args) {
  return Status(StatusCode::kNotFound, StrCat(args...));
}
template <typename... Args>
Status DataLossError(const Args&... args) {
  return Status(StatusCode::kDataLoss, StrCat(args...));
}
template <typename... Args>
Status FailedPreconditionError(const Args&... args) {
  return Status(StatusCode::kFailedPrecondition, StrCat(args...));
}
template <typename... Args>
Status UnavailableError(const Args&... args) {
  return Status(StatusCode::kUnavailable, StrCat(args...));
}
template <typename... Args>
Status InternalError(const Args&... args) {
  return Status(StatusCode::kInternal, StrCat(args...));
}

// Process exit code for a status: 0 ok, 2 bad input (invalid/not found/corrupt/precondition),
// 3 unavailable backend, 4 internal error. (The CLI uses 1 for command-line usage errors.)
int ExitCodeFor(const Status& status);

template <typename T>
class [[nodiscard]] StatusOr {
 public:
  StatusOr(const Status& status) : status_(status) {  // NOLINT: implicit by design
    REFLCAP_CHECK(!status_.ok()) << "StatusOr constructed from an OK status without a value";
  }
  StatusOr(T value) : value_(std::move(value)) {}  // NOLINT: implicit by design

  bool ok() const { return status_.ok(); }
  const Status& status() const { return status_; }

  const T& value() const& {
    REFLCAP_CHECK(ok()) << status_.ToString();
    return *value_;
  }
  T& value() & {
    REFLCAP_CHECK(ok()) << status_.ToString();
    return *value_;
  }
  T&& value() && {
    REFLCAP_CHECK(ok()) << status_.ToString();
    return std::move(*value_);
  }
  const T& operator*() const& { return value(); }
  T& operator*() & { return value(); }
  const T* operator->() const { return &value(); }
  T* operator->() { return &value(); }

 private:
  Status status_;
  std::optional<T> value_;
};

}  // namespace reflcap

#define REFLCAP_STATUS_CONCAT_INNER(a, b) a##b
#define REFLCAP_STATUS_CONCAT(a, b) REFLCAP_STATUS_CONCAT_INNER(a, b)

// Returns from the enclosing function when `expr` (a Status) is not OK.
#define REFLCAP_RETURN_IF_ERROR(expr)                      \
  do {                                                     \
    ::reflcap::Status reflcap_status_tmp_ = (expr);        \
    if (!reflcap_status_tmp_.ok()) return reflcap_status_tmp_; \
  } while (0)

// `REFLCAP_ASSIGN_OR_RETURN(auto x, MakeX());` declares/assigns x or returns the error.
#define REFLCAP_ASSIGN_OR_RETURN(lhs, expr) \
  REFLCAP_ASSIGN_OR_RETURN_IMPL(REFLCAP_STATUS_CONCAT(reflcap_statusor_, __LINE__), lhs, expr)
#define REFLCAP_ASSIGN_OR_RETURN_IMPL(tmp, lhs, expr) \
  auto tmp = (expr);                                  \
  if (!tmp.ok()) return tmp.status();                 \
  lhs = std::move(tmp).value()
