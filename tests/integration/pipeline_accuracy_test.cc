// Holdout accuracy of the whole pipeline (synth -> run) on an in-model synthetic capture, through
// the executable: lobe transfer must never cost holdout PSNR against the same fit without it,
// material clusters and measuring samples at their pixel's own hit must add to it, and the lobe
// must beat the Lambert-only baseline. The rig is the one on which lobe transfer
// without its evidence bound (engine/fit/lobe_transfer.h) fell to 19.8 dB against 33.8 dB
// without transfer (at the 10-degree highlight cone of the time): wrong borrowed lobes made a few
// holdout images many times too bright. And the
// in-model noise bound on an all-matte capture.
#include <gtest/gtest.h>

#include <cstdio>
#include <fstream>

#include <nlohmann/json.hpp>

#include "engine/core/atomic_file.h"
#include "engine/core/check.h"
#include "tests/support/test_support.h"

namespace reflcap {
namespace {
namespace fs = std::filesystem;

// The pipeline is deterministic (the same capture, fit and renders each time), so any loss
// from lobe transfer is real; 0.25 dB admits a changed donor choice somewhere without letting
// a single wrong highlight through (those cost several dB on this capture).
constexpr double kTransferMayCostDb = 0.25;
// Measured on this rig: 40.3 dB (the default fit: lobe + transfer) against 25.1 dB (Lambert
// only); the lobe must keep at least a third of that 15 dB. (The lobes texels fit on their own,
// without transfer, reach 28.1 dB at the default 5-degree highlight cone, 33.8 dB at 10 degrees:
// the narrower cone leaves more texels to borrow a lobe measured near its peak.)
constexpr double kMinLobeGainDb = 5.0;
// Material clusters (engine/fit/material_clusters.h) on this rig: 40.29 -> 42.57 dB holdout PSNR,
// relative RMSE 0.388 -> 0.302 (measured). They must keep at least 1 dB and a tenth of the
// relative RMSE: less would mean the pooled lobes stopped reaching the texels that missed their
// highlights.
constexpr double kMinClusterGainDb = 1.0;
constexpr double kMinClusterRmseRatio = 0.9;
// The k-fold model choice (texels with a lobe take their cluster's when it predicts their
// held-out photographs better) against the information criterion on this rig: 44.83 against
// 42.95 dB, relative RMSE 0.202 against 0.274 (measured); it must keep about half of that gain.
constexpr double kMinKFoldGainDb = 0.8;
constexpr double kMinKFoldRmseRatio = 0.9;
// (The numbers above were measured with `--sample-point texel`, the resampler's only choice then.)
// Measuring each texel at its nearest pixel's own hit (`--sample-point pixel`, the default)
// against interpolating pixels at the texel centre: 49.69 against 44.83 dB, relative RMSE 0.081
// against 0.202 on this rig (measured): the interpolation blurred every highlight in angle, and
// the pooled lobes came out broad and weak. It must keep half of the gain in dB and in RMSE.
constexpr double kMinPixelSampleGainDb = 2.5;
constexpr double kMinPixelSampleRmseRatio = 0.6;

testing::CliResult RunCli(const std::string& args, const testing::ScratchDir& dir) {
  return testing::RunCommand(REFLCAP_BINARY, args, dir);
}

nlohmann::json Overall(const fs::path& run) {
  std::ifstream in(run / "report" / "metrics.json");
  REFLCAP_CHECK(in.good()) << run;
  return nlohmann::json::parse(in)["overall"];
}

TEST(PipelineAccuracy, LobeTransferAndClustersNeverCostHoldoutPsnrAndTheLobeBeatsLambert) {
  testing::ScratchDir dir;
  const std::string capture = (dir / "capture").string();
  auto r = RunCli("synth --quiet --out " + capture +
                      " --texels 20000 --image-size 192 --cameras 3 --lights 8 --steps 24",
                  dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const char* variants[6] = {"", "--no-lobe-transfer", "--lobes 0", "--no-material-clusters",
                             "--model-choice bic", "--sample-point texel"};
  double psnr[6] = {0, 0, 0, 0, 0, 0}, rmse[6] = {0, 0, 0, 0, 0, 0}, bound = 0;
  for (int v = 0; v < 6; ++v) {
    const fs::path out = dir / ("run" + std::to_string(v));
    // --backend cpu: the same numbers on every machine (auto would pick a GPU where there is one).
    r = RunCli("run --quiet --backend cpu " + capture + " --out " + out.string() + " " + variants[v],
               dir);
    ASSERT_EQ(r.exit_code, 0) << variants[v] << ": " << r.err;
    const auto overall = Overall(out);
    psnr[v] = overall["psnr_db"].get<double>();
    rmse[v] = overall["rel_rmse"].get<double>();
    bound = overall["noise_bound_psnr_db"].get<double>();
  }
  std::printf("holdout PSNR: lobe + transfer + clusters %.2f dB, without transfer %.2f dB, Lambert "
              "only %.2f dB, without clusters %.2f dB, model choice by BIC %.2f dB (noise bound "
              "%.2f dB); rel. RMSE %.4f, by BIC %.4f; --sample-point texel %.2f dB, %.4f\n",
              psnr[0], psnr[1], psnr[2], psnr[3], psnr[4], bound, rmse[0], rmse[4], psnr[5],
              rmse[5]);
  EXPECT_GT(psnr[0], psnr[5] + kMinPixelSampleGainDb);
  EXPECT_LT(rmse[0], kMinPixelSampleRmseRatio * rmse[5]);
  EXPECT_GT(psnr[0], psnr[4] + kMinKFoldGainDb);
  EXPECT_LT(rmse[0], kMinKFoldRmseRatio * rmse[4]);
  EXPECT_GT(psnr[0], psnr[3] + kMinClusterGainDb);
  EXPECT_LT(rmse[0], kMinClusterRmseRatio * rmse[3]);
  EXPECT_GE(psnr[0], psnr[1] - kTransferMayCostDb);
  EXPECT_GT(psnr[0], psnr[2] + kMinLobeGainDb);
  EXPECT_GT(psnr[1], psnr[2]);  // own lobes alone still beat no lobes
  EXPECT_LT(psnr[0], bound);  // a PSNR above what the noise allows would mean a broken metric
}

// The in-model bound (issue: holdout PSNR within 0.5 dB of what the capture's noise allows),
// on a capture whose every texel the model identifies: one matte material (a Lafortune fit with
// no lobe is in the model). Measured 0.25 dB from the bound; 0.5 dB is the goal itself. Without
// the lobe-evidence cone (engine/fit/problem.h) spurious lobes put it 2.7 dB away; without the
// albedo fill (engine/fit/albedo_fill.h) unlit dimples put it 0.53 dB away.
constexpr double kInModelGapDb = 0.5;

TEST(PipelineAccuracy, AllMatteInModelCaptureReachesTheNoiseBound) {
  testing::ScratchDir dir;
  const std::string capture = (dir / "capture").string();
  auto r = RunCli("synth --quiet --materials matte --out " + capture, dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const fs::path out = dir / "run";
  r = RunCli("run --quiet --backend cpu " + capture + " --out " + out.string(), dir);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const auto overall = Overall(out);
  const double psnr = overall["psnr_db"].get<double>();
  const double bound = overall["noise_bound_psnr_db"].get<double>();
  std::printf("all-matte capture: holdout PSNR %.2f dB, noise bound %.2f dB\n", psnr, bound);
  EXPECT_GT(psnr, bound - kInModelGapDb);
  EXPECT_LT(psnr, bound);
  // The reports name the run's folders as they are after it, not the staging folder.
  int reports = 0;
  for (const auto& e : fs::recursive_directory_iterator(out)) {
    const fs::path& p = e.path();
    if (p.extension() != ".json" && p.extension() != ".html") continue;
    ++reports;
    const std::string text = ReadTextFile(p).value();
    EXPECT_EQ(text.find(".tmp-"), std::string::npos) << p << " names a staging folder";
  }
  EXPECT_GE(reports, 5);  // store.json, resample, fit, render reports, metrics.json, report.html
  const std::string fit_report = ReadTextFile(out / "fit/fit_report.json").value();
  EXPECT_NE(fit_report.find(fs::absolute(out / "samples").lexically_normal().string()), std::string::npos);
}

}  // namespace
}  // namespace reflcap
