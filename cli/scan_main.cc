// reflcap-scan: the `scan` verb as its own executable, which `reflcap scan` runs (reflcap_main.cc):
// only it loads Open3D. Takes the arguments `reflcap` was given, verb included.
#include <cstdio>
#include <cstring>

#include "cli/cli.h"

int main(int argc, char** argv) {
  using namespace reflcap;
  // --quiet anywhere applies to every verb; strip it before the verb parses.
  argc = cli::TakeGlobalOptions(argc, argv);
  if (argc < 2 || std::strcmp(argv[1], "scan") != 0) {
    std::fprintf(stderr, "usage: reflcap scan SCAN.json --out MESH_DIR (reflcap-scan is run by "
                         "`reflcap scan`)\n");
    return cli::kExitUsage;
  }
  return cli::RunScan(argc, argv);
}
