#include "bench/suite/machine.h"

#include <sys/resource.h>
#include <sys/utsname.h>

#include <cstdio>
#include <fstream>
#include <sstream>

#include "engine/core/parallel.h"
#include "engine/core/status.h"

namespace reflcap::benchsuite {
namespace {

std::string Trim(const std::string& s) {
  const size_t a = s.find_first_not_of(" \t\"");
  const size_t b = s.find_last_not_of(" \t\"\n");
  return a == std::string::npos ? std::string() : s.substr(a, b - a + 1);
}

// The value after "key:" (or "key=") on the first line of `path` that starts with `key`.
std::string FindField(const char* path, const std::string& key, char separator) {
  std::ifstream in(path);
  std::string line;
  while (std::getline(in, line)) {
    if (line.compare(0, key.size(), key) != 0) continue;
    const size_t sep = line.find(separator, key.size());
    if (sep == std::string::npos) continue;
    // The key must be the whole word before the separator ("model name", not "model").
    if (Trim(line.substr(0, sep)) != key) continue;
    return Trim(line.substr(sep + 1));
  }
  return {};
}

// "VmHWM:    123456 kB" -> bytes.
uint64_t StatusKilobytes(const std::string& key) {
  const std::string v = FindField("/proc/self/status", key, ':');
  return v.empty() ? 0 : uint64_t(std::strtoull(v.c_str(), nullptr, 10)) * 1024;
}

}  // namespace

std::string MachineInfo::ToString() const {
  std::ostringstream out;
  out.precision(3);
  out << cpu_model << ", " << cores << " cores, " << double(ram_bytes) / (1ull << 30)
      << " GiB RAM, " << os;
  return out.str();
}

MachineInfo DescribeMachine() {
  MachineInfo m;
  m.cpu_model = FindField("/proc/cpuinfo", "model name", ':');
  if (m.cpu_model.empty()) m.cpu_model = "unknown";
  m.cores = HardwareThreads();
  const std::string mem = FindField("/proc/meminfo", "MemTotal", ':');
  m.ram_bytes = mem.empty() ? 0 : uint64_t(std::strtoull(mem.c_str(), nullptr, 10)) * 1024;
  m.os = FindField("/etc/os-release", "PRETTY_NAME", '=');
  utsname u{};
  if (uname(&u) == 0) {
    m.os += StrCat(m.os.empty() ? "" : ", ", u.sysname, " ", u.release, " ", u.machine);
  }
  if (m.os.empty()) m.os = "unknown";
  return m;
}

PeakRssScope::PeakRssScope() {
  std::FILE* f = std::fopen("/proc/self/clear_refs", "w");
  if (f != nullptr) {
    reset_ok_ = std::fputs("5", f) >= 0;
    reset_ok_ = (std::fclose(f) == 0) && reset_ok_;
  }
  // Without VmHWM the reset is of no use.
  reset_ok_ = reset_ok_ && StatusKilobytes("VmHWM") > 0;
}

uint64_t PeakRssScope::PeakBytes() const {
  if (reset_ok_) return StatusKilobytes("VmHWM");
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return uint64_t(usage.ru_maxrss) * 1024;  // Linux reports kilobytes
}

const char* PeakRssScope::method() const {
  return reset_ok_ ? "VmHWM after clear_refs" : "getrusage ru_maxrss (process peak so far)";
}

uint64_t CurrentRssBytes() { return StatusKilobytes("VmRSS"); }

}  // namespace reflcap::benchsuite
