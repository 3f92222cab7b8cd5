// `reflcap bench [--quick] --out DIR`: the benchmark matrix on synthetic data the run generates
// itself — fits/s against samples per texel per backend, speed against error, time and peak
// memory per pipeline stage against texel count, seed against fixed start, holdout accuracy
// against viewpoints — written as DIR/bench_results.json, one CSV per sweep, SVG plots and
// DIR/index.html (bench/suite/suite.h; fields in bench/README.md). DIR is staged: it
// appears only when complete. Scratch captures live inside the staging folder and are removed
// before the commit.
#include <algorithm>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <sstream>

#include "cli/cli.h"
#include "bench/suite/suite.h"
#include "engine/core/atomic_file.h"
#include "engine/core/log.h"
#include "engine/fit/fitter.h"

namespace reflcap::cli {
namespace fs = std::filesystem;
namespace {

// Comma-separated list -> items (empty items rejected by the callers' parsers).
std::vector<std::string> SplitList(const std::string& text) {
  std::vector<std::string> items;
  std::stringstream in(text);
  std::string item;
  while (std::getline(in, item, ',')) items.push_back(item);
  if (!text.empty() && text.back() == ',') items.push_back("");
  return items;
}

int Usage(const std::string& message) {
  std::fprintf(stderr, "reflcap bench: %s\n", message.c_str());
  return kExitUsage;
}

}  // namespace

int RunBench(int argc, char** argv) {
  // --tiny (hidden, for tests): the whole matrix in seconds; its numbers mean nothing.
  bool tiny = false;
  std::vector<char*> args_kept;
  for (int i = 0; i < argc; ++i) {
    if (i >= 2 && std::strcmp(argv[i], "--tiny") == 0) {
      tiny = true;
    } else {
      args_kept.push_back(argv[i]);
    }
  }
  std::string out, backends = "cpu,vulkan,ceres", sweeps, device;
  bool quick = false, overwrite = false;
  int threads = 0;
  ArgParser args("bench", "--out DIR [--quick] [options]",
                 "Run the benchmark matrix on synthetic data it generates itself and write\n"
                 "DIR/bench_results.json, one CSV per sweep, SVG plots and DIR/index.html:\n"
                 "  fit             fits/s against samples per texel (16..1024), per backend\n"
                 "  speed_vs_error  iteration caps and tolerances against parameter error and\n"
                 "                  holdout PSNR, with each backend's Pareto front\n"
                 "  init_schemes    seed start + two-stage LM against fixed start + one stage\n"
                 "  scaling         time and peak memory per pipeline stage, 10^3..10^6 texels\n"
                 "  viewpoints      holdout PSNR against cameras x turntable steps\n"
                 "Every record is verified against ground truth before its timing counts; one\n"
                 "that fails is kept with valid = false and the reason. An unavailable backend\n"
                 "(no Vulkan device) is left out with its reason. --quick takes 1-2 minutes on two\n"
                 "cores, the full run up to ~20 minutes (10^6 texels, < 3 GiB).");
  args.AddString("out", &out, "DIR", "output folder (must not exist or be empty)");
  args.AddFlag("quick", &quick, "small sizes and short timings (1-2 minutes)");
  args.AddString("backends", &backends, "LIST",
                 "fit backends to measure, comma-separated (default cpu,vulkan,ceres)");
  args.AddString("device", &device, "NAME|INDEX", "Vulkan device (index or name substring)");
  args.AddString("sweeps", &sweeps, "LIST",
                 "sweeps to run, comma-separated (default: fit,speed_vs_error,init_schemes,"
                 "scaling,viewpoints)");
  args.AddInt("threads", &threads, "worker threads (default 0 = all cores)");
  args.AddFlag("overwrite", &overwrite, "replace DIR if it exists (only once the new one is complete)");
  bool help = false;
  if (Status s = args.Parse(int(args_kept.size()), args_kept.data(), 2, &help); !s.ok()) {
    return Usage(s.message());
  }
  if (help) {
    std::printf("%s", args.Help().c_str());
    return 0;
  }
  if (out.empty()) return Usage("--out DIR is required");
  if (tiny && quick) return Usage("--tiny and --quick exclude each other");

  benchsuite::SuiteOptions options;
  options.scale = tiny ? benchsuite::SuiteScale::kTiny
                       : quick ? benchsuite::SuiteScale::kQuick : benchsuite::SuiteScale::kFull;
  options.threads = threads;
  options.vulkan_device = device;
  options.backends.clear();
  for (const std::string& name : SplitList(backends)) {
    auto backend = fit::ParseBackend(name);
    if (!backend.ok()) return Usage(StrCat("--backends: ", backend.status().message()));
    if (std::find(options.backends.begin(), options.backends.end(), *backend) ==
        options.backends.end()) {
      options.backends.push_back(*backend);
    }
  }
  if (!sweeps.empty()) options.sweeps = SplitList(sweeps);
  if (!device.empty() && std::find(options.backends.begin(), options.backends.end(),
                                   fit::Backend::kVulkan) == options.backends.end()) {
    return Usage("--device needs vulkan in --backends");
  }
  options.work_dir = "unset";  // validated here; set to the staging folder below
  if (Status s = options.Validate(); !s.ok()) return Usage(s.message());

  auto staging = StagingDir::Create(out, overwrite);
  if (!staging.ok()) return ReportError("bench", staging.status());
  options.work_dir = staging->path() / "_work";
  std::error_code ec;
  fs::create_directories(options.work_dir, ec);
  if (ec) {
    return ReportError("bench", InternalError(options.work_dir.string(), ": ", ec.message()));
  }
  auto results = benchsuite::RunSuite(options);
  fs::remove_all(options.work_dir, ec);
  if (!results.ok()) return ReportError("bench", results.status());
  if (Status s = benchsuite::WriteSuiteOutputs(*results, staging->path()); !s.ok()) {
    return ReportError("bench", s);
  }
  if (Status s = staging->Commit(); !s.ok()) return ReportError("bench", s);
  std::printf("%s", benchsuite::SuiteSummaryText(*results).c_str());
  std::printf("reflcap bench: results in %s (open %s)\n", out.c_str(),
              (fs::path(out) / "index.html").string().c_str());
  return 0;
}

}  // namespace reflcap::cli
