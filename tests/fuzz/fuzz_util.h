#pragma once
// Helpers shared by the libFuzzer targets of tests/fuzz (built only with -DREFLCAP_FUZZ=ON and
// clang; README.md, "Hardening").
//
// Most reflcap readers take a path, not bytes: a target writes its input to a file in a scratch
// folder of its own (in /dev/shm when there is one, so the disk is not touched on every
// execution) and calls the reader on it. Invariants a target checks on a successful read fail
// with FUZZ_CHECK, which aborts, so libFuzzer records the input as a crash.
#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>

#include "engine/core/log.h"
#include "engine/core/status.h"

#define FUZZ_CHECK(cond)                                                         \
  do {                                                                           \
    if (!(cond)) {                                                               \
      std::fprintf(stderr, "%s:%d: invariant failed: %s\n", __FILE__, __LINE__, #cond); \
      std::abort();                                                              \
    }                                                                            \
  } while (0)

namespace reflcap::fuzz {

// The scratch folder of this process, created on first use and removed at exit.
inline const std::filesystem::path& ScratchDir() {
  static const std::filesystem::path dir = [] {
    std::error_code ec;
    std::filesystem::path base = "/dev/shm";
    if (!std::filesystem::is_directory(base, ec)) base = std::filesystem::temp_directory_path();
    std::filesystem::path d = base / ("reflcap_fuzz_" + std::to_string(::getpid()));
    std::filesystem::create_directories(d, ec);
    std::atexit([] {
      std::error_code ignored;
      std::filesystem::remove_all(ScratchDir(), ignored);
    });
    return d;
  }();
  return dir;
}

// Writes `size` bytes to ScratchDir()/name (replacing it) and returns the path.
inline std::filesystem::path WriteScratch(const std::string& name, const uint8_t* data,
                                          size_t size) {
  const std::filesystem::path path = ScratchDir() / name;
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(data), std::streamsize(size));
  return path;
}

// Readers log warnings for odd but accepted input; at fuzzing rates that is only noise.
inline void QuietLogs() { SetLogThreshold(LogLevel::kError); }

// A reader's refusal: it must say what is wrong. With REFLCAP_FUZZ_VERBOSE set the message is
// printed, which is how a seed is checked to be accepted (tests/fuzz/run.sh --check-seeds).
inline void Rejected(const Status& status) {
  FUZZ_CHECK(!status.ok() && !status.message().empty());
  if (std::getenv("REFLCAP_FUZZ_VERBOSE")) std::fprintf(stderr, "rejected: %s\n", status.ToString().c_str());
}

}  // namespace reflcap::fuzz
