// `reflcap bench` end to end: usage errors exit 1 with a clear message, a tiny run writes its
// outputs atomically, and an existing folder is kept unless --overwrite.
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include "engine/core/atomic_file.h"
#include "tests/support/test_support.h"

namespace reflcap {
namespace {
namespace fs = std::filesystem;

using testing::CliResult;

CliResult RunCli(const std::string& args, const testing::ScratchDir& dir) {
  return testing::RunCommand(REFLCAP_BINARY, args, dir);
}

TEST(BenchCli, BadOptionsAreUsageErrors) {
  testing::ScratchDir dir;
  const std::string out = (dir / "out").string();
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"bench", "--out DIR is required"},
      {"bench --quick", "--out DIR is required"},
      {"bench --out " + out + " --backends cpu,gpu", "--backends"},
      {"bench --out " + out + " --backends ,", "--backends"},
      {"bench --out " + out + " --sweeps fit,nope", "unknown sweep \"nope\""},
      {"bench --out " + out + " --quick --tiny", "exclude each other"},
      {"bench --out " + out + " --threads -2", "threads"},
      {"bench --out " + out + " --backends cpu --device 0", "--device needs vulkan"},
      {"bench --out " + out + " --frobnicate", "frobnicate"},
      {"bench --out " + out + " --threads many", "many"},
  };
  for (const auto& [args, message] : cases) {
    const CliResult r = RunCli(args, dir);
    EXPECT_EQ(r.exit_code, 1) << args << "\n" << r.err;
    EXPECT_NE(r.err.find("reflcap bench: "), std::string::npos) << args << "\n" << r.err;
    EXPECT_NE(r.err.find(message), std::string::npos) << args << "\n" << r.err;
    EXPECT_FALSE(fs::exists(out)) << args;
  }
  const CliResult help = RunCli("bench --help", dir);
  EXPECT_EQ(help.exit_code, 0);
  EXPECT_NE(help.out.find("--quick"), std::string::npos);
  EXPECT_EQ(help.out.find("--tiny"), std::string::npos);  // test-only, not advertised
}

TEST(BenchCli, TinyRunWritesOutputsAtomicallyAndRespectsOverwrite) {
  testing::ScratchDir dir;
  const fs::path out = dir / "bench";
  const std::string args = "bench --quiet --tiny --backends cpu --sweeps fit,init_schemes --out " + out.string();
  CliResult r = RunCli(args, dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("machine: "), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("device:  "), std::string::npos) << r.out;
  for (const char* file : {"bench_results.json", "fit.csv", "init_schemes.csv", "index.html",
                           "fit_speed.svg"}) {
    EXPECT_TRUE(fs::exists(out / file)) << file;
  }
  EXPECT_FALSE(fs::exists(out / "_work"));
  // Nothing but the output (and the captured stdout/stderr) beside it: no staging leftovers.
  for (const auto& entry : fs::directory_iterator(dir.path())) {
    const std::string name = entry.path().filename().string();
    EXPECT_TRUE(name == "bench" || name == "stdout.txt" || name == "stderr.txt") << name;
  }
  const auto j = nlohmann::json::parse(ReadTextFile(out / "bench_results.json").value());
  EXPECT_EQ(j["scale"], "tiny");
  EXPECT_FALSE(j["fit"].empty());
  EXPECT_TRUE(j["scaling"].empty());

  // An existing output is refused without --overwrite and left as it was.
  testing::WriteText(out / "marker.txt", "keep");
  r = RunCli(args, dir);
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.exit_code, 1);  // not a usage error: the folder exists
  EXPECT_TRUE(fs::exists(out / "marker.txt"));
  r = RunCli(args + " --overwrite", dir);
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_FALSE(fs::exists(out / "marker.txt"));
  EXPECT_TRUE(fs::exists(out / "bench_results.json"));
}

}  // namespace
}  // namespace reflcap
