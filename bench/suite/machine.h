#pragma once
// What a benchmark ran on, and how much memory a stage of it took: the machine description every
// `reflcap bench` result carries (CPU model, cores, RAM, OS) and per-stage peak resident memory.
//
// Peak RSS per stage on Linux: writing "5" to /proc/self/clear_refs resets the kernel's
// high-water mark VmHWM to the current RSS, so VmHWM read from /proc/self/status after the stage
// is that stage's peak (proc(5)). Where clear_refs cannot be written (no procfs, a kernel that
// refuses it), the fallback is getrusage's ru_maxrss: the process's peak so far, which is only
// an upper bound for a stage that follows a bigger one; PeakRssScope says which it used.
#include <cstdint>
#include <string>

namespace reflcap::benchsuite {

struct MachineInfo {
  std::string cpu_model;  // /proc/cpuinfo "model name" (or "unknown")
  int cores = 0;          // hardware threads this process may use
  uint64_t ram_bytes = 0; // MemTotal
  std::string os;         // /etc/os-release PRETTY_NAME and the kernel release
  // "AMD EPYC 7B13, 2 cores, 23.5 GiB RAM, Debian GNU/Linux 12 (bookworm), Linux 6.1.0".
  std::string ToString() const;
};
MachineInfo DescribeMachine();

// Measures the peak resident memory of the code run during its lifetime (see the file comment).
class PeakRssScope {
 public:
  PeakRssScope();  // resets the high-water mark when it can
  // Peak RSS in bytes since construction (or the process's peak, see method()).
  uint64_t PeakBytes() const;
  // "VmHWM after clear_refs" (a per-stage peak) or "getrusage ru_maxrss (process peak so far)".
  const char* method() const;

 private:
  bool reset_ok_ = false;
};

// Current resident memory (VmRSS), bytes; 0 when unknown.
uint64_t CurrentRssBytes();

}  // namespace reflcap::benchsuite
