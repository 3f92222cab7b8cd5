#pragma once
// Helpers shared by reflcap's tests: scratch folders and the optional ../shared data.
#include <filesystem>
#include <optional>
#include <string>

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

}  // namespace reflcap::testing

namespace reflcap::testing {

// What a command printed and how it exited.
struct CliResult {
  int exit_code = -1;  // -1 when the command did not exit normally
  std::string out, err;
};

// Runs `binary args` through the shell with stdout and stderr captured in files under `dir`.
CliResult RunCommand(const std::string& binary, const std::string& args, const ScratchDir& dir);

}  // namespace reflcap::testing
