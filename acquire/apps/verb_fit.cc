// `reflcap fit` (placeholder until its issue lands).
#include <cstdio>

#include "acquire/apps/cli.h"

namespace reflcap::cli {

int RunFit(int argc, char** argv) {
  return ReportError("fit", UnavailableError("not available in this build yet"));
}

}  // namespace reflcap::cli
