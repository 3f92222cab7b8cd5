// Held-out accuracy on data this project did not make, through the reflcap executable: the
// Lafortune fit must beat the Lambert-only fit (`--lobes 0`) on the holdout split — on the
// Blender-rendered suzanne turntable capture (holdout PSNR) and on every DiLiGenT object (holdout
// relative RMSE). Both need ../shared/data and skip with a message without it (a user's checkout,
// CI); README.md's "Held-out accuracy on independent data" has the full-resolution numbers. The
// runs use --backend cpu so the numbers are the same on every machine.
#include <gtest/gtest.h>

#include <cstdio>
#include <fstream>

#include <nlohmann/json.hpp>

#include "engine/core/check.h"
#include "tests/support/test_support.h"

namespace reflcap {
namespace {
namespace fs = std::filesystem;

// Suzanne at a 128² atlas (the test's size; README's numbers are at 512²) gained 2.1 dB from the
// lobe (512²: 2.6 dB). 1 dB is half of that: a fit that loses the lobe's benefit on the glossy
// patches (a broken start, stage or fallback) falls well below it; noise between runs is < 0.05 dB.
constexpr double kMinSuzanneLobeGainDb = 1.0;
// Interreflection (--indirect auto): suzanne's far sides and cast shadows hold light bounced from
// its lit parts, which a direct-light render leaves black; the LDR metric weighs those dark pixels
// most. With it the holdout PSNR-L rose 24.8 -> 27.4 dB at this test's 128² atlas (25.6 -> 29.1 at
// 512²); the run is deterministic, so the margin is not noise. 2 dB: a prediction that
// is wrong in level or place (a broken table, a missed bounce) falls below it.
constexpr double kMinSuzanneIndirectGainDb = 2.0;
// Stray light (--indirect auto on a normal-map capture): ball16's side away from each lamp reads
// 1–4 % of the image's white in the photographs and 0 in a direct-light render; adding the
// room's light estimated from the train photographs raised the holdout PSNR-L 28.66 -> 32.99 dB
// (with the point spread it picks; 32.87 without).
// 2 dB (half of that) fails an estimate that is wrong in level or place; the run is deterministic.
constexpr double kMinBallStrayGainDb = 2.0;

// Diffuse fall-off (fit, default on): pot1's lit pixels read 0.41 of a Lambert render at
// cos theta_i 0.1 and 1.0 at 0.7; its texels, all Lambert-only, take the generalized diffuse
// lobe where their held-out photographs prefer it, and the holdout PSNR-L rose 20.63 -> 21.71 dB
// (relative RMSE 0.108 -> 0.087). 0.5 dB, half of the gain, fails a pass that picks the wrong
// exponent or albedo; the run is deterministic.
constexpr double kMinPotFalloffGainDb = 0.5;

nlohmann::json Overall(const fs::path& run) {
  std::ifstream in(run / "report" / "metrics.json");
  REFLCAP_CHECK(in.good()) << run;
  return nlohmann::json::parse(in)["overall"];
}

testing::CliResult RunCli(const std::string& args, const testing::ScratchDir& dir) {
  return testing::RunCommand(REFLCAP_BINARY, args, dir);
}

// Holdout PSNR-L of `fit` rendered with `--indirect off` (direct light only), validated.
double PsnrLWithoutIndirect(const std::string& capture, const fs::path& fit,
                            const testing::ScratchDir& dir) {
  const fs::path off = dir / "off", off_report = dir / "off_report";
  auto r = RunCli("render " + capture + " " + fit.string() + " --out " + off.string() +
                      " --indirect off --quiet", dir);
  REFLCAP_CHECK(r.exit_code == 0) << r.err;
  r = RunCli("validate " + capture + " " + off.string() + " --out " + off_report.string() +
                 " --quiet", dir);
  REFLCAP_CHECK(r.exit_code == 0) << r.err;
  std::ifstream in(off_report / "metrics.json");
  REFLCAP_CHECK(in.good()) << off_report;
  return nlohmann::json::parse(in)["overall"]["psnr_l_db"].get<double>();
}

TEST(HeldOutRealData, SuzanneLafortuneBeatsLambertOnHoldoutPsnr) {
  const auto shared = testing::SharedDataDir();
  if (!shared || !fs::is_directory(*shared / "turntable" / "suzanne")) {
    GTEST_SKIP() << "../shared/data/turntable/suzanne is absent: skipping the suzanne holdout test";
  }
  testing::ScratchDir dir;
  const std::string capture = (*shared / "turntable" / "suzanne").string();
  double psnr[2] = {0, 0};
  for (int lobes : {0, 1}) {
    const fs::path out = dir / ("lobes" + std::to_string(lobes));
    auto r = RunCli("run --quiet --backend cpu " + capture + " --out " + out.string() +
                        " --atlas-res 128 --lobes " + std::to_string(lobes),
                    dir);
    ASSERT_EQ(r.exit_code, 0) << r.err;
    psnr[lobes] = Overall(out)["psnr_db"].get<double>();
    // The report says where the error is: every region is present with its share.
    const auto regions = Overall(out)["regions"];
    for (const char* region : {"shadow_edge", "high_curvature", "grazing", "elsewhere"}) {
      EXPECT_TRUE(regions.contains(region)) << region;
    }
    EXPECT_TRUE(fs::is_regular_file(out / "report" / "report.html"));
  }
  std::printf("suzanne (128^2 atlas) holdout PSNR: Lafortune %.2f dB, Lambert only %.2f dB\n",
              psnr[1], psnr[0]);
  EXPECT_GT(psnr[1], psnr[0] + kMinSuzanneLobeGainDb);
}

TEST(HeldOutRealData, SuzanneShowsInterreflectionAndItsRenderPredictsTheDarkPixels) {
  const auto shared = testing::SharedDataDir();
  if (!shared || !fs::is_directory(*shared / "turntable" / "suzanne")) {
    GTEST_SKIP() << "../shared/data/turntable/suzanne is absent: skipping the interreflection test";
  }
  testing::ScratchDir dir;
  const std::string capture = (*shared / "turntable" / "suzanne").string();
  const fs::path run = dir / "run";
  auto r = RunCli("run --quiet --backend cpu " + capture + " --out " + run.string() +
                      " --atlas-res 128", dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  std::ifstream in(run / "renders" / "render_report.json");
  const auto indirect = nlohmann::json::parse(in)["indirect"];
  EXPECT_EQ(indirect["used"], true) << indirect.dump();
  const double with = Overall(run)["psnr_l_db"].get<double>();
  const double without = PsnrLWithoutIndirect(capture, run / "fit", dir);
  std::printf("suzanne (128^2 atlas) holdout PSNR-L: with interreflection %.2f dB, direct light "
              "only %.2f dB (evidence: %s)\n", with, without, indirect["evidence"].dump().c_str());
  EXPECT_GT(with, without + kMinSuzanneIndirectGainDb);
}

TEST(HeldOutRealData, DiligentBallShowsStrayLightAndItsRenderPredictsTheUnlitSide) {
  const auto shared = testing::SharedDataDir();
  if (!shared || !fs::is_directory(*shared / "diligent" / "ball16")) {
    GTEST_SKIP() << "../shared/data/diligent/ball16 is absent: skipping the stray-light test";
  }
  testing::ScratchDir dir;
  const fs::path capture = dir / "ball16", run = dir / "run";
  auto r = RunCli("import-diligent --quiet " + (*shared / "diligent" / "ball16").string() +
                      " --out " + capture.string(), dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  r = RunCli("run --quiet --backend cpu " + capture.string() + " --out " + run.string(), dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  std::ifstream in(run / "renders" / "render_report.json");
  const auto indirect = nlohmann::json::parse(in)["indirect"];
  EXPECT_EQ(indirect["kind"], "stray_light") << indirect.dump();
  EXPECT_EQ(indirect["used"], true) << indirect.dump();
  const double with = Overall(run)["psnr_l_db"].get<double>();
  const double without = PsnrLWithoutIndirect(capture.string(), run / "fit", dir);
  std::printf("ball16 holdout PSNR-L: with stray light %.2f dB, direct light only %.2f dB "
              "(evidence: %s)\n", with, without, indirect["evidence"].dump().c_str());
  EXPECT_GT(with, without + kMinBallStrayGainDb);
}

TEST(HeldOutRealData, DiligentPotDarkensAtGrazingLightAndTheFalloffLobePredictsIt) {
  const auto shared = testing::SharedDataDir();
  if (!shared || !fs::is_directory(*shared / "diligent" / "pot1")) {
    GTEST_SKIP() << "../shared/data/diligent/pot1 is absent: skipping the diffuse fall-off test";
  }
  testing::ScratchDir dir;
  const fs::path capture = dir / "pot1";
  auto r = RunCli("import-diligent --quiet " + (*shared / "diligent" / "pot1").string() +
                      " --out " + capture.string(), dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  double psnr_l[2] = {0, 0};
  for (int falloff : {0, 1}) {
    const fs::path run = dir / (falloff ? "with" : "without");
    r = RunCli("run --quiet --backend cpu " + capture.string() + " --out " + run.string() +
                   (falloff ? "" : " --no-diffuse-falloff"), dir);
    ASSERT_EQ(r.exit_code, 0) << r.err;
    psnr_l[falloff] = Overall(run)["psnr_l_db"].get<double>();
    std::ifstream in(run / "fit" / "fit_report.json");
    const auto report = nlohmann::json::parse(in);
    const size_t taken = report["model_counts"]["falloff_lobe"].get<size_t>();
    if (falloff) {
      // Most of pot1's texels are darker at grazing light (45,953-46,539 of 57,721 take it).
      EXPECT_GT(taken, report["texels"].get<size_t>() / 2) << report["diffuse_falloff"].dump();
    } else {
      EXPECT_EQ(taken, 0u);
    }
  }
  std::printf("pot1 holdout PSNR-L: with the diffuse fall-off lobe %.2f dB, without %.2f dB\n",
              psnr_l[1], psnr_l[0]);
  EXPECT_GT(psnr_l[1], psnr_l[0] + kMinPotFalloffGainDb);
}

TEST(HeldOutRealData, DiligentLafortuneBeatsLambertOnHoldoutRelativeRmse) {
  const auto shared = testing::SharedDataDir();
  if (!shared || !fs::is_directory(*shared / "diligent")) {
    GTEST_SKIP() << "../shared/data/diligent is absent: skipping the DiLiGenT holdout test";
  }
  testing::ScratchDir dir;
  // Few or none of cat's and pot1's texels show a highlight: their margin comes from the diffuse
  // fall-off lobe (which a --lobes 0 fit has no slot for; pot1's margin was ~1e-6 without it),
  // so the test asserts the ordering, not a margin.
  for (const char* object : {"ball16", "bear", "buddha", "cat", "goblet", "pot1"}) {
    const fs::path capture = dir / object;
    auto r = RunCli(std::string("import-diligent --quiet ") + (*shared / "diligent" / object).string() +
                     " --out " + capture.string(),
                 dir);
    ASSERT_EQ(r.exit_code, 0) << object << ": " << r.err;
    double rel_rmse[2] = {0, 0};
    for (int lobes : {0, 1}) {
      const fs::path out = dir / (std::string(object) + "_lobes" + std::to_string(lobes));
      r = RunCli("run --quiet --backend cpu " + capture.string() + " --out " + out.string() +
                     " --lobes " + std::to_string(lobes),
                 dir);
      ASSERT_EQ(r.exit_code, 0) << object << ": " << r.err;
      rel_rmse[lobes] = Overall(out)["rel_rmse"].get<double>();
    }
    std::printf("DiLiGenT %-7s holdout rel. RMSE: Lafortune %.5f, Lambert only %.5f\n", object,
                rel_rmse[1], rel_rmse[0]);
    EXPECT_LT(rel_rmse[1], rel_rmse[0]) << object;
    fs::remove_all(capture);  // keep the scratch folder small
  }
}

}  // namespace
}  // namespace reflcap
