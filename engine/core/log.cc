#include "engine/core/log.h"

#include <atomic>
#include <cstdio>
#include <mutex>

namespace reflcap {
namespace {
std::atomic<int> g_threshold{static_cast<int>(LogLevel::kInfo)};
std::mutex g_log_mutex;
}  // namespace

void SetLogThreshold(LogLevel level) { g_threshold = static_cast<int>(level); }
LogLevel LogThreshold() { return static_cast<LogLevel>(g_threshold.load()); }

namespace internal {
LogMessage::~LogMessage() {
  if (static_cast<int>(level_) < g_threshold.load()) return;
  static const char* kPrefix[] = {"debug: ", "", "warning: ", "error: "};
  std::lock_guard<std::mutex> lock(g_log_mutex);
  std::fprintf(stderr, "%s%s\n", kPrefix[static_cast<int>(level_)], stream_.str().c_str());
  std::fflush(stderr);
}
}  // namespace internal

}  // namespace reflcap
