// reflcap: one executable, one verb per stage. See README.md for each verb.
#include <cstdio>
#include <cstring>
#include <string>

#include "cli/cli.h"
#include "engine/core/log.h"

namespace {

constexpr char kUsage[] =
    "usage: reflcap <verb> [options]     (reflcap <verb> --help for each)\n"
    "\n"
    "verbs:\n"
    "  calibrate intrinsics|turntable CALIB.json --out FILE   camera and turntable calibration\n"
    "  hdr BRACKETS.json --out CAPTURE  exposure brackets -> linear HDR capture, white-balanced\n"
    "  scan SCAN.json --out MESH_DIR    structured light -> watertight mesh with a UV atlas\n"
    "  info CAPTURE        validate a capture/1 dataset completely and summarise it\n"
    "  synth --out DIR     write a synthetic capture with ground truth\n"
    "  demo [--out DIR]    run the pipeline end to end on a small synthetic capture\n"
    "  resample CAPTURE --out SAMPLES   photographs -> per-texel BRDF samples\n"
    "  fit SAMPLES --out FIT            per-texel Lambert + Lafortune fit\n"
    "  merge PARTS... --out DIR         join the parts of --shard I/N runs\n"
    "  render CAPTURE FIT --out DIR     re-render photographs from a fit\n"
    "  run CAPTURE --out DIR            resample -> fit -> render holdout -> validate\n"
    "  validate CAPTURE RENDERS --out REPORT   compare re-renders with photographs\n"
    "  export FIT --gltf OUT.glb        a fit as glTF 2.0 (+ raw Lafortune parameters)\n"
    "  view FIT --out DIR               a self-contained relightable viewer page\n"
    "  import-diligent OBJECT_DIR --out CAPTURE   DiLiGenT object -> capture/1\n"
    "  bench --out DIR [--quick]        benchmark matrix: speed, error, scaling, viewpoints\n"
    "\n"
    "global options: --quiet (warnings and errors only), --version\n"
    "exit codes: 0 ok, 1 usage error, 2 bad input, 3 backend unavailable, 4 internal error\n";

}  // namespace

int main(int argc, char** argv) {
  using namespace reflcap;
  // --quiet anywhere applies to every verb; strip it before the verb parses.
  int kept = 1;
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--quiet") == 0) {
      SetLogThreshold(LogLevel::kWarning);
    } else {
      argv[kept++] = argv[i];
    }
  }
  argc = kept;
  if (argc < 2 || std::strcmp(argv[1], "--help") == 0 || std::strcmp(argv[1], "-h") == 0 ||
      std::strcmp(argv[1], "help") == 0) {
    std::printf("%s", kUsage);
    return argc < 2 ? cli::kExitUsage : 0;
  }
  const std::string verb = argv[1];
  if (verb == "--version") {
    std::printf("reflcap 0.1.0\n");
    return 0;
  }
  if (verb == "info") return cli::RunInfo(argc, argv);
  if (verb == "synth") return cli::RunSynth(argc, argv);
  if (verb == "demo") return cli::RunDemo(argc, argv);
  if (verb == "resample") return cli::RunResample(argc, argv);
  if (verb == "fit") return cli::RunFit(argc, argv);
  if (verb == "render") return cli::RunRender(argc, argv);
  if (verb == "run") return cli::RunRun(argc, argv);
  if (verb == "validate") return cli::RunValidate(argc, argv);
  if (verb == "import-diligent") return cli::RunImportDiligent(argc, argv);
  if (verb == "bench") return cli::RunBench(argc, argv);
  if (verb == "calibrate") return cli::RunCalibrate(argc, argv);
  if (verb == "hdr") return cli::RunHdr(argc, argv);
  if (verb == "scan") return cli::RunScan(argc, argv);
  if (verb == "merge") return cli::RunMerge(argc, argv);
  if (verb == "export") return cli::RunExport(argc, argv);
  if (verb == "view") return cli::RunView(argc, argv);
  std::fprintf(stderr, "reflcap: unknown verb \"%s\"\n\n%s", verb.c_str(), kUsage);
  return cli::kExitUsage;
}
