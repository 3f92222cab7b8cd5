#include "engine/core/progress.h"

#include <unistd.h>

#include <cstdio>

#include "engine/core/log.h"
#include "engine/core/status.h"

namespace reflcap {

std::string FormatDuration(double seconds) {
  char buf[32];
  if (seconds < 60) {
    std::snprintf(buf, sizeof buf, "%.1fs", seconds);
  } else if (seconds < 3600) {
    std::snprintf(buf, sizeof buf, "%dm%02ds", int(seconds) / 60, int(seconds) % 60);
  } else {
    std::snprintf(buf, sizeof buf, "%dh%02dm", int(seconds) / 3600, (int(seconds) / 60) % 60);
  }
  return buf;
}

Progress::Progress(std::string label, int64_t total)
    : label_(std::move(label)),
      total_(total > 0 ? total : 1),
      start_(std::chrono::steady_clock::now()),
      last_draw_(start_),
      enabled_(LogThreshold() <= LogLevel::kInfo),
      tty_(::isatty(2) == 1) {}

Progress::~Progress() { Finish(); }

double Progress::ElapsedSeconds() const {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
}

void Progress::Advance(int64_t n) {
  const int64_t done = done_ += n;
  if (!enabled_) return;
  auto now = std::chrono::steady_clock::now();
  std::lock_guard<std::mutex> lock(mutex_);
  if (finished_) return;
  const int decile = static_cast<int>(10 * done / total_);
  const double since = std::chrono::duration<double>(now - last_draw_).count();
  if (tty_ ? since > 0.1 : (decile > last_decile_ || since > 5.0)) {
    last_draw_ = now;
    last_decile_ = decile;
    Draw(done, false);
  }
}

void Progress::Finish() {
  if (!enabled_) return;
  std::lock_guard<std::mutex> lock(mutex_);
  if (finished_) return;
  finished_ = true;
  Draw(done_.load(), true);
}

void Progress::Draw(int64_t done, bool final_line) {
  const double elapsed = ElapsedSeconds();
  const double fraction = std::min(1.0, double(done) / double(total_));
  std::string tail;
  if (final_line) {
    tail = StrCat("done in ", FormatDuration(elapsed));
  } else if (fraction > 0) {
    tail = StrCat("ETA ", FormatDuration(elapsed * (1 - fraction) / fraction));
  }
  if (tty_) {
    constexpr int kWidth = 30;
    std::string bar(kWidth, ' ');
    for (int i = 0; i < int(fraction * kWidth); ++i) bar[i] = '#';
    std::fprintf(stderr, "\r%-24s [%s] %3d%% %lld/%lld %s\033[K%s", label_.c_str(), bar.c_str(),
                 int(100 * fraction), (long long)done, (long long)total_, tail.c_str(),
                 final_line ? "\n" : "");
  } else {
    std::fprintf(stderr, "%s: %3d%% (%lld/%lld) %s\n", label_.c_str(), int(100 * fraction),
                 (long long)done, (long long)total_, tail.c_str());
  }
  std::fflush(stderr);
}

}  // namespace reflcap
