// `reflcap calibrate`: placeholder until issue 15 lands.
#include <cstdio>

#include "cli/cli.h"

namespace reflcap::cli {

int RunCalibrate(int argc, char** argv) {
  std::fprintf(stderr, "reflcap calibrate: not implemented yet\n");
  return 4;
}

}  // namespace reflcap::cli
