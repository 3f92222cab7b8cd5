#pragma once
// Minimal leveled logging to stderr: REFLCAP_LOG(kWarning) << "skipped " << n << " faces";
// Libraries never printf; the CLI sets the threshold (--quiet raises it to kWarning).
#include <sstream>

namespace reflcap {

enum class LogLevel { kDebug = 0, kInfo = 1, kWarning = 2, kError = 3 };

// Messages below `level` are dropped. Default kInfo. Thread-safe.
void SetLogThreshold(LogLevel level);
LogLevel LogThreshold();

namespace internal {
class LogMessage {
 public:
  explicit LogMessage(LogLevel level) : level_(level) {}
  ~LogMessage();
  std::ostream& stream() { return stream_; }

 private:
  LogLevel level_;
  std::ostringstream stream_;
};
}  // namespace internal

}  // namespace reflcap

#define REFLCAP_LOG(level) ::reflcap::internal::LogMessage(::reflcap::LogLevel::level).stream()
