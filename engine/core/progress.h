#pragma once
// Progress reporting for long work, on stderr: a redrawn bar with rate and ETA on a terminal,
// plain lines (every 10 % or 5 s) when stderr is not a TTY. Silent when the log threshold is above
// kInfo (the CLI's --quiet). Advance() is thread-safe.
#include <atomic>
#include <chrono>
#include <cstdint>
#include <mutex>
#include <string>

namespace reflcap {

class Progress {
 public:
  Progress(std::string label, int64_t total);
  ~Progress();  // calls Finish() if needed
  void Advance(int64_t n = 1);
  void Finish();
  double ElapsedSeconds() const;

 private:
  void Draw(int64_t done, bool final_line);

  std::string label_;
  int64_t total_;
  std::atomic<int64_t> done_{0};
  std::chrono::steady_clock::time_point start_;
  std::chrono::steady_clock::time_point last_draw_;
  int last_decile_ = -1;
  bool enabled_;
  bool tty_;
  bool finished_ = false;
  std::mutex mutex_;
};

// "1h02m", "3m05s", "12.3s".
std::string FormatDuration(double seconds);

}  // namespace reflcap
