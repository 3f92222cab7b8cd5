// The benchmark matrix at its test-only `tiny` scale: every documented key and file, valid
// records, a failed verification marking records invalid, an unavailable Vulkan device omitted
// with its reason, the Pareto front and the machine description.
#include "bench/suite/suite.h"

#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include <algorithm>
#include <map>
#include <set>

#include "bench/suite/machine.h"
#include "engine/core/atomic_file.h"
#include "tests/support/test_support.h"

namespace reflcap::benchsuite {
namespace {
namespace fs = std::filesystem;
using Json = nlohmann::json;

// The keys bench/README.md documents for each list of bench_results.json.
const std::vector<std::string> kTopKeys = {"format", "machine", "device", "device_available",
                                           "date", "reflcap_version", "quick", "scale",
                                           "total_seconds", "peak_rss_method", "backends_omitted",
                                           "fit", "speed_vs_error", "scaling", "init_schemes",
                                           "viewpoints", "notes"};
const std::vector<std::string> kAccuracyKeys = {
    "median_rel_error_rho_d", "median_rel_error_n", "median_rel_error_peak",
    "converged_fraction", "mean_iterations", "holdout_psnr_db", "valid", "invalid_reason"};
const std::map<std::string, std::vector<std::string>> kRecordKeys = {
    {"fit", {"backend", "samples_per_texel", "texels", "fits", "repetitions", "seconds",
             "fits_per_second", "fits_per_cpu_second"}},
    {"speed_vs_error", {"backend", "max_iterations", "tolerance", "samples_per_texel", "texels",
                        "seconds", "fits_per_second", "fits_per_cpu_second", "pareto"}},
    {"init_schemes", {"backend", "init", "samples_per_texel", "texels", "seconds",
                      "fits_per_second", "fits_per_cpu_second"}},
    {"scaling", {"texels_target", "texels", "image_size", "images", "stage", "seconds",
                 "texels_per_second", "peak_rss_bytes", "peak_rss_mib", "start_rss_bytes",
                 "detail", "valid", "invalid_reason"}},
    {"viewpoints", {"cameras", "steps", "lights", "viewpoints", "train_images", "holdout_images",
                    "texels", "texels_with_samples_fraction", "holdout_psnr_db",
                    "noise_bound_psnr_db", "median_rel_error_rho_d", "median_rel_error_n",
                    "lobe_fraction", "seconds", "valid", "invalid_reason"}}};

SuiteOptions TinyOptions(const fs::path& work) {
  SuiteOptions o;
  o.scale = SuiteScale::kTiny;
  o.work_dir = work;
  return o;
}

// The whole tiny matrix, run once for the tests that read it.
const SuiteResults& TinyResults() {
  static const SuiteResults results = [] {
    testing::ScratchDir work;
    auto r = RunSuite(TinyOptions(work.path()));
    REFLCAP_CHECK(r.ok()) << r.status().ToString();
    return *r;
  }();
  return results;
}

TEST(BenchSuite, TinyMatrixWritesEveryDocumentedKeyAndFile) {
  const SuiteResults& results = TinyResults();
  testing::ScratchDir out;
  ASSERT_TRUE(WriteSuiteOutputs(results, out.path()).ok());
  auto text = ReadTextFile(out / "bench_results.json");
  ASSERT_TRUE(text.ok());
  const Json j = Json::parse(*text);
  for (const std::string& key : kTopKeys) EXPECT_TRUE(j.contains(key)) << key;
  for (const char* key : {"cpu_model", "cores", "ram_bytes", "os"}) {
    EXPECT_TRUE(j["machine"].contains(key)) << key;
  }
  EXPECT_FALSE(j["quick"].get<bool>());
  EXPECT_EQ(j["scale"], "tiny");
  EXPECT_FALSE(j["device"].get<std::string>().empty());
  for (const auto& [list, keys] : kRecordKeys) {
    ASSERT_TRUE(j[list].is_array()) << list;
    EXPECT_FALSE(j[list].empty()) << list;
    for (const Json& rec : j[list]) {
      for (const std::string& key : keys) EXPECT_TRUE(rec.contains(key)) << list << "." << key;
      if (list == "fit" || list == "speed_vs_error" || list == "init_schemes") {
        for (const std::string& key : kAccuracyKeys) EXPECT_TRUE(rec.contains(key)) << list << "." << key;
      }
      EXPECT_TRUE(rec["valid"].get<bool>()) << list << ": " << rec.dump();
    }
  }
  // Every backend that could be created fitted; cpu always can.
  std::set<std::string> backends;
  for (const Json& rec : j["fit"]) backends.insert(rec["backend"].get<std::string>());
  EXPECT_TRUE(backends.count("cpu"));
  EXPECT_TRUE(backends.count("ceres"));
  EXPECT_EQ(backends.count("vulkan"), j["device_available"].get<bool>() ? 1u : 0u);
  for (const Json& rec : j["fit"]) {
    EXPECT_GT(rec["fits_per_second"].get<double>(), 0);
    EXPECT_GE(rec["converged_fraction"].get<double>(), 0.9);
    EXPECT_LE(rec["median_rel_error_rho_d"].get<double>(), 0.1);
  }
  // Every pipeline stage was measured, each with a peak RSS.
  std::set<std::string> stages;
  for (const Json& rec : j["scaling"]) {
    stages.insert(rec["stage"].get<std::string>());
    EXPECT_GT(rec["peak_rss_bytes"].get<uint64_t>(), 0u);
  }
  EXPECT_EQ(stages, (std::set<std::string>{"synth", "resample", "fit", "render", "validate"}));
  for (const char* file : {"fit.csv", "speed_vs_error.csv", "scaling.csv", "init_schemes.csv",
                           "viewpoints.csv", "index.html", "fit_speed.svg", "speed_vs_error.svg",
                           "speed_vs_psnr.svg", "scaling_time.svg", "scaling_memory.svg",
                           "init_converged.svg", "init_error.svg", "init_speed.svg", "viewpoints.svg"}) {
    EXPECT_TRUE(fs::exists(out / file)) << file;
  }
  // CSV: a header naming the JSON fields, one line per record.
  auto csv = ReadTextFile(out / "fit.csv");
  ASSERT_TRUE(csv.ok());
  EXPECT_EQ(csv->rfind("backend,samples_per_texel,texels,", 0), 0u) << *csv;
  EXPECT_EQ(size_t(std::count(csv->begin(), csv->end(), '\n')), j["fit"].size() + 1);
  auto html = ReadTextFile(out / "index.html");
  ASSERT_TRUE(html.ok());
  EXPECT_NE(html->find("<img src=\"fit_speed.svg\""), std::string::npos);
}

TEST(BenchSuite, FailedVerificationMarksRecordsInvalid) {
  testing::ScratchDir work;
  SuiteOptions o = TinyOptions(work.path());
  o.backends = {fit::Backend::kCpu};
  o.sweeps = {"fit"};
  o.bounds.max_median_rel_error = 1e-9;  // no fit is that exact
  auto r = RunSuite(o);
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  ASSERT_FALSE(r->fit.empty());
  for (const FitRecord& f : r->fit) {
    EXPECT_FALSE(f.valid);
    EXPECT_NE(f.invalid_reason.find("median rel. error"), std::string::npos) << f.invalid_reason;
  }
  const Json j = Json::parse(SuiteResultsJson(*r));
  EXPECT_FALSE(j["fit"][0]["valid"].get<bool>());
  EXPECT_FALSE(j["fit"][0]["invalid_reason"].get<std::string>().empty());
  // Invalid records stay out of the plots, with a note.
  testing::ScratchDir out;
  ASSERT_TRUE(WriteSuiteOutputs(*r, out.path()).ok());
  const Json written = Json::parse(ReadTextFile(out / "bench_results.json").value());
  bool noted = false;
  for (const Json& n : written["notes"]) noted = noted || n.get<std::string>().find("failed their verification") != std::string::npos;
  EXPECT_TRUE(noted) << written["notes"].dump();
}

TEST(BenchSuite, UnavailableVulkanDeviceIsOmittedWithItsReason) {
  testing::ScratchDir work;
  SuiteOptions o = TinyOptions(work.path());
  o.backends = {fit::Backend::kCpu, fit::Backend::kVulkan};
  o.vulkan_device = "no-such-device-anywhere";
  o.sweeps = {"fit"};
  auto r = RunSuite(o);
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  ASSERT_EQ(r->omitted.size(), 1u);
  EXPECT_EQ(r->omitted[0].backend, "vulkan");
  EXPECT_FALSE(r->omitted[0].reason.empty());
  EXPECT_FALSE(r->device_available);
  EXPECT_EQ(r->device.rfind("unavailable: ", 0), 0u) << r->device;
  ASSERT_FALSE(r->fit.empty());
  for (const FitRecord& f : r->fit) EXPECT_EQ(f.backend, "cpu");
}

TEST(BenchSuite, OptionsAreValidated) {
  SuiteOptions o = TinyOptions("/tmp");
  EXPECT_TRUE(o.Validate().ok());
  o.sweeps = {"fit", "nope"};
  EXPECT_EQ(o.Validate().code(), StatusCode::kInvalidArgument);
  o = TinyOptions("");
  EXPECT_FALSE(o.Validate().ok());
  o = TinyOptions("/tmp");
  o.backends.clear();
  EXPECT_FALSE(o.Validate().ok());
  o = TinyOptions("/tmp");
  o.threads = -1;
  EXPECT_FALSE(o.Validate().ok());
}

TEST(BenchSuite, ParetoFrontKeepsOnlyUndominatedValidRecords) {
  auto rec = [](const char* backend, double fps, double err, bool valid) {
    SpeedErrorRecord r;
    r.backend = backend;
    r.fits_per_second = fps;
    r.accuracy.median_rel_error_rho_d = err / 2;
    r.accuracy.median_rel_error_n = err;
    r.valid = valid;
    return r;
  };
  std::vector<SpeedErrorRecord> records = {
      rec("cpu", 100, 0.01, true),   // front: most accurate
      rec("cpu", 200, 0.02, true),   // front
      rec("cpu", 150, 0.03, true),   // dominated by 200 / 0.02
      rec("cpu", 300, 0.5, false),   // invalid: never on the front
      rec("vulkan", 50, 0.05, true)  // alone on its own backend's front
  };
  MarkParetoFront(&records);
  EXPECT_TRUE(records[0].pareto);
  EXPECT_TRUE(records[1].pareto);
  EXPECT_FALSE(records[2].pareto);
  EXPECT_FALSE(records[3].pareto);
  EXPECT_TRUE(records[4].pareto);
}

TEST(BenchMachine, DescribesTheMachineAndMeasuresAStagesPeak) {
  const MachineInfo m = DescribeMachine();
  EXPECT_GT(m.cores, 0);
  EXPECT_GT(m.ram_bytes, 0u);
  EXPECT_FALSE(m.cpu_model.empty());
  EXPECT_FALSE(m.os.empty());
  EXPECT_NE(m.ToString().find("cores"), std::string::npos);
  constexpr size_t kBytes = 64 << 20;
  PeakRssScope scope;
  const uint64_t before = CurrentRssBytes();
  {
    std::vector<char> block(kBytes, 1);  // touched: resident
    volatile char sink = block[kBytes / 2];
    (void)sink;
  }
  // The 64 MiB were resident during the scope, though freed since.
  EXPECT_GE(scope.PeakBytes(), before + kBytes * 9 / 10) << scope.method();
}

}  // namespace
}  // namespace reflcap::benchsuite
