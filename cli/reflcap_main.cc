// reflcap: one executable, one verb per stage. See README.md for each verb.
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <string>

#include "cli/cli.h"

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

// Replaces this process with `name` from the folder of this executable, given the same
// arguments; returns (with a message) only when that fails.
int ExecSibling(const char* name, char** argv) {
  std::error_code ec;
  const std::filesystem::path self = std::filesystem::read_symlink("/proc/self/exe", ec);
  const std::filesystem::path sibling = (ec ? std::filesystem::path(argv[0]) : self).parent_path() / name;
  execv(sibling.c_str(), argv);
  std::fprintf(stderr, "reflcap %s: cannot run %s (%s): it is built beside reflcap (cmake target "
                       "%s)\n", argv[1], sibling.c_str(), std::strerror(errno), name);
  return 4;  // internal error: the installation is incomplete
}

}  // namespace

int main(int argc, char** argv) {
  using namespace reflcap;
  // Verbs with their own executable get the arguments untouched.
  if (argc >= 2 && std::strcmp(argv[1], "scan") == 0) return ExecSibling("reflcap-scan", argv);
  // --quiet anywhere applies to every verb; strip it before the verb parses.
  argc = cli::TakeGlobalOptions(argc, argv);
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
  if (verb == "merge") return cli::RunMerge(argc, argv);
  if (verb == "export") return cli::RunExport(argc, argv);
  if (verb == "view") return cli::RunView(argc, argv);
  std::fprintf(stderr, "reflcap: unknown verb \"%s\"\n\n%s", verb.c_str(), kUsage);
  return cli::kExitUsage;
}
