// The Slurm flow (cli/batch/reflcap-slurm.sh) on a real single-node Slurm that the test starts
// on this machine (cli/batch/slurm-local.sh: munged, slurmctld and slurmd on localhost, all state
// in a scratch folder): resample, fit and render as 3-task job arrays with dependent merges, then
// validate; every output must equal the single-machine verbs' bit for bit. Skips, saying why,
// where Slurm cannot start (no slurm-wlm/munge, not root).
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include "engine/core/atomic_file.h"
#include "tests/support/test_support.h"

namespace reflcap {
namespace {
namespace fs = std::filesystem;
using testing::CliResult;

const std::string kBatch = REFLCAP_BATCH_DIR;

// Stops the private Slurm however the test ends.
class LocalSlurm {
 public:
  explicit LocalSlurm(fs::path dir) : dir_(std::move(dir)) {}
  ~LocalSlurm() { std::system((kBatch + "/slurm-local.sh stop " + dir_.string() + " >/dev/null 2>&1").c_str()); }
  LocalSlurm(const LocalSlurm&) = delete;
  LocalSlurm& operator=(const LocalSlurm&) = delete;

 private:
  fs::path dir_;
};

void ExpectSameFiles(const fs::path& a, const fs::path& b, const std::string& skip, int at_least) {
  int compared = 0;
  for (const auto& e : fs::recursive_directory_iterator(a)) {
    if (!e.is_regular_file() || e.path().filename() == skip) continue;
    const fs::path rel = fs::relative(e.path(), a);
    EXPECT_TRUE(ReadTextFile(e.path()).value() == ReadTextFile(b / rel).value()) << rel << " differs";
    ++compared;
  }
  EXPECT_GE(compared, at_least) << a;
}

TEST(Slurm, JobArraysAndMergesEqualTheSingleMachineRun) {
  testing::ScratchDir dir;
  const fs::path slurm = dir / "slurm";
  LocalSlurm stopper(slurm);
  CliResult started = testing::RunCommand(kBatch + "/slurm-local.sh", "start " + slurm.string(), dir);
  if (started.exit_code == 2) GTEST_SKIP() << "Slurm cannot start here: " << started.err;
  ASSERT_EQ(started.exit_code, 0) << started.err;
  const std::string env = "SLURM_CONF=" + (slurm / "slurm.conf").string() + " ";

  const std::string R = REFLCAP_BINARY;
  CliResult r = testing::RunCommand(R, "synth --quiet --out " + (dir / "cap").string() +
                                           " --texels 3000 --image-size 48 --cameras 2 --lights 2 --steps 6",
                                    dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const std::string cap = (dir / "cap").string();
  // One machine: the verbs one after the other.
  r = testing::RunCommand(R, "resample --quiet " + cap + " --out " + (dir / "samples").string() +
                                 " --chunk-texels 1000", dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  r = testing::RunCommand(R, "fit --quiet " + (dir / "samples").string() + " --out " + (dir / "fit").string(), dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  r = testing::RunCommand(R, "render --quiet " + cap + " " + (dir / "fit").string() + " --out " +
                                 (dir / "renders").string(), dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;

  // Slurm: 3 shards per stage; --wait returns when validate has run.
  r = testing::RunCommand(env + kBatch + "/reflcap-slurm.sh",
                          cap + " " + (dir / "out").string() + " --shards 3 --wait --reflcap " + R +
                              " --resample-args \"--chunk-texels 1000\"",
                          dir);
  ASSERT_EQ(r.exit_code, 0) << r.out << r.err;
  ExpectSameFiles(dir / "samples", dir / "out/samples", "resample_report.json", 6);
  ExpectSameFiles(dir / "fit", dir / "out/fit", "fit_report.json", 3);
  ExpectSameFiles(dir / "renders", dir / "out/renders", "render_report.json", 3);
  EXPECT_TRUE(fs::exists(dir / "out/report/report.html"));
  const nlohmann::json fit = nlohmann::json::parse(ReadTextFile(dir / "out/fit/fit_report.json").value());
  EXPECT_EQ(fit["shards"]["count"], 3);
}

}  // namespace
}  // namespace reflcap
