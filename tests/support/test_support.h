#pragma once
// Helpers shared by reflcap's tests: scratch folders and the optional ../shared data.
#include <filesystem>
#include <functional>
#include <map>
#include <optional>
#include <string>
#include <vector>

namespace reflcap::testing {

// A fresh empty folder, removed (with its contents) when the object dies.
class ScratchDir {
 public:
  ScratchDir();
  ~ScratchDir();
  ScratchDir(const ScratchDir&) = delete;
  ScratchDir& operator=(const ScratchDir&) = delete;
  const std::filesystem::path& path() const { return path_; }
  std::filesystem::path operator/(const std::string& name) const { return path_ / name; }

 private:
  std::filesystem::path path_;
};

// The shared data folder (../shared/data beside the checkout, or $REFLCAP_SHARED_DATA), or
// nullopt when absent: tests that need it call GTEST_SKIP() with a message.
std::optional<std::filesystem::path> SharedDataDir();

// Writes `text` to `path` (creating parent folders); aborts the test process on failure.
void WriteText(const std::filesystem::path& path, const std::string& text);

// Runs `release` when the program's tests have finished — in a ::testing::Environment's
// TearDown, inside RUN_ALL_TESTS — rather than among the static destructors. A binary-wide
// Vulkan object (context, renderer, fitter) kept in a function-local static must be released
// here: a driver loaded after that static was constructed registers its own exit handlers later,
// so they run first, and a vkDestroy* from a static destructor then calls into a torn-down
// driver (NVIDIA 580: SIGSEGV at exit whenever a single test ran alone, as ctest runs them;
// lavapipe tolerates it). Releases run in the reverse order of registration.
void ReleaseBeforeExit(std::function<void()> release);

// A new scratch folder that lives until the program's tests have finished (for fixtures made once
// per test process), then is removed like any ScratchDir. ctest runs each test in its own
// process, so a fixture folder that were never removed would be left behind once per test.
const ScratchDir& NewProcessScratchDir();

}  // namespace reflcap::testing

namespace reflcap::testing {

// What a command printed and how it exited.
struct CliResult {
  int exit_code = -1;  // -1 when the command did not exit normally
  std::string out, err;
};

// Runs `binary args` through the shell with stdout and stderr captured in files under `dir`.
CliResult RunCommand(const std::string& binary, const std::string& args, const ScratchDir& dir);

// Starts `binary args...` (no shell; stdout and stderr to `log`), polls `ready` every 2 ms and
// sends SIGKILL as soon as it is true (or after `timeout_s`), then reaps the process. True when
// the process died of that SIGKILL; false when it had exited by itself first (the test then
// did not interrupt anything) or could not be started.
bool KillWhen(const std::string& binary, const std::vector<std::string>& args,
              const std::filesystem::path& log, const std::function<bool()>& ready,
              double timeout_s = 60);

// `arg` as one POSIX shell word: in single quotes, an inner quote as '\''.
std::string ShellQuote(const std::string& arg);

// An uncompressed scanline OpenEXR of FLOAT channels, written byte by byte so that values (NaN,
// Inf) and header fields (an enormous data window, a missing channel) are exactly as given —
// WriteExr sanitises what it writes. `channels`: name -> width*height values (row-major); with
// `header_only` the offset table and pixels are left out (a truncated file).
std::string RawExr(int width, int height, const std::map<std::string, std::vector<float>>& channels,
                   bool header_only = false);

}  // namespace reflcap::testing
