#include "tests/support/test_support.h"

#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cstdlib>
#include <fstream>
#include <thread>

#include <gtest/gtest.h>
#include <sys/wait.h>

#include "engine/core/atomic_file.h"
#include "engine/core/check.h"

extern char** environ;

namespace reflcap::testing {
namespace fs = std::filesystem;

ScratchDir::ScratchDir() {
  static std::atomic<int> counter{0};
  const char* base = std::getenv("REFLCAP_TEST_TMPDIR");
  fs::path root = base ? fs::path(base) : fs::temp_directory_path() / "reflcap_test";
  path_ = root / ("scratch-" + std::to_string(::getpid()) + "-" + std::to_string(counter++));
  fs::remove_all(path_);
  fs::create_directories(path_);
}

ScratchDir::~ScratchDir() {
  std::error_code ec;
  fs::remove_all(path_, ec);
}

std::optional<fs::path> SharedDataDir() {
  if (const char* env = std::getenv("REFLCAP_SHARED_DATA")) {
    if (fs::is_directory(env)) return fs::path(env);
    return std::nullopt;
  }
  fs::path candidate = fs::path(REFLCAP_SOURCE_DIR) / ".." / "shared" / "data";
  if (fs::is_directory(candidate)) return fs::canonical(candidate);
  return std::nullopt;
}

void WriteText(const fs::path& path, const std::string& text) {
  fs::create_directories(path.parent_path());
  std::ofstream out(path, std::ios::binary);
  out << text;
  REFLCAP_CHECK(bool(out)) << "cannot write " << path;
}

namespace {

class ReleaseEnvironment : public ::testing::Environment {
 public:
  explicit ReleaseEnvironment(std::function<void()> release) : release_(std::move(release)) {}
  void TearDown() override {
    if (release_) release_();
    release_ = nullptr;
  }

 private:
  std::function<void()> release_;
};

}  // namespace

void ReleaseBeforeExit(std::function<void()> release) {
  // gtest owns the environment; environments added while tests run are torn down (in reverse
  // order of addition) with the others after the last test.
  ::testing::AddGlobalTestEnvironment(new ReleaseEnvironment(std::move(release)));
}

const ScratchDir& NewProcessScratchDir() {
  // Each call makes its own folder, so two fixtures in one binary never share one.
  auto* dir = new ScratchDir();
  ReleaseBeforeExit([dir] { delete dir; });
  return *dir;
}

}  // namespace reflcap::testing

namespace reflcap::testing {

CliResult RunCommand(const std::string& binary, const std::string& args, const ScratchDir& dir) {
  const fs::path out = dir / "stdout.txt", err = dir / "stderr.txt";
  const std::string command = binary + " " + args + " >" + out.string() + " 2>" + err.string();
  const int status = std::system(command.c_str());
  CliResult r;
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  r.out = ReadTextFile(out).value();
  r.err = ReadTextFile(err).value();
  return r;
}

bool KillWhen(const std::string& binary, const std::vector<std::string>& args, const fs::path& log,
              const std::function<bool()>& ready, double timeout_s) {
  std::vector<std::string> storage = args;
  storage.insert(storage.begin(), binary);
  std::vector<char*> argv;
  for (auto& a : storage) argv.push_back(a.data());
  argv.push_back(nullptr);
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, 1, log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  posix_spawn_file_actions_adddup2(&actions, 1, 2);
  pid_t pid = -1;
  const int rc = posix_spawn(&pid, binary.c_str(), &actions, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  if (rc != 0) return false;
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
  int status = 0;
  while (!ready() && std::chrono::steady_clock::now() < deadline) {
    if (waitpid(pid, &status, WNOHANG) == pid) return false;  // finished by itself
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  kill(pid, SIGKILL);
  if (waitpid(pid, &status, 0) != pid) return false;
  return WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL;
}

std::string ShellQuote(const std::string& arg) {
  std::string quoted = "'";
  for (char c : arg) quoted += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return quoted + "'";
}

std::string RawExr(int width, int height, const std::map<std::string, std::vector<float>>& channels,
                   bool header_only) {
  auto i32 = [](int32_t v) { return std::string(reinterpret_cast<const char*>(&v), 4); };
  auto attr = [&](const std::string& name, const std::string& type, const std::string& body) {
    return name + '\0' + type + '\0' + i32(int32_t(body.size())) + body;
  };
  std::string chlist;
  for (const auto& [name, values] : channels) {
    chlist += name + '\0' + i32(2) + std::string(4, '\0') + i32(1) + i32(1);  // FLOAT, 1x1
  }
  chlist += '\0';
  const std::string box = i32(0) + i32(0) + i32(width - 1) + i32(height - 1);
  const float one = 1.0f, zero = 0.0f;
  const std::string f1(reinterpret_cast<const char*>(&one), 4), f0(reinterpret_cast<const char*>(&zero), 4);
  std::string exr = i32(20000630) + i32(2) + attr("channels", "chlist", chlist) +
                    attr("compression", "compression", std::string(1, '\0')) +
                    attr("dataWindow", "box2i", box) + attr("displayWindow", "box2i", box) +
                    attr("lineOrder", "lineOrder", std::string(1, '\0')) +
                    attr("pixelAspectRatio", "float", f1) +
                    attr("screenWindowCenter", "v2f", f0 + f0) +
                    attr("screenWindowWidth", "float", f1) + '\0';
  if (header_only) return exr;
  std::vector<std::string> lines;
  for (int y = 0; y < height; ++y) {
    std::string data;
    for (const auto& [name, values] : channels) {
      data.append(reinterpret_cast<const char*>(&values[size_t(y) * width]), size_t(width) * 4);
    }
    lines.push_back(i32(y) + i32(int32_t(data.size())) + data);
  }
  uint64_t offset = exr.size() + 8 * size_t(height);
  for (const std::string& line : lines) {
    exr.append(reinterpret_cast<const char*>(&offset), 8);
    offset += line.size();
  }
  for (const std::string& line : lines) exr += line;
  return exr;
}

}  // namespace reflcap::testing
