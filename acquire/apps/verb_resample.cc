// `reflcap resample` (placeholder until its issue lands).
#include <cstdio>

#include "acquire/apps/cli.h"

namespace reflcap::cli {

int RunResample(int argc, char** argv) {
  return ReportError("resample", UnavailableError("not available in this build yet"));
}

}  // namespace reflcap::cli
