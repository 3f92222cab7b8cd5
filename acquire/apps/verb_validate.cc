// `reflcap validate` (placeholder until its issue lands).
#include "acquire/apps/cli.h"

namespace reflcap::cli {

int RunValidate(int argc, char** argv) {
  return ReportError("validate", UnavailableError("not available in this build yet"));
}

}  // namespace reflcap::cli
