// `reflcap render` (placeholder until its issue lands).
#include "acquire/apps/cli.h"

namespace reflcap::cli {

int RunRender(int argc, char** argv) {
  return ReportError("render", UnavailableError("not available in this build yet"));
}

}  // namespace reflcap::cli
