// `reflcap import-diligent` (placeholder until its issue lands).
#include "acquire/apps/cli.h"

namespace reflcap::cli {

int RunImportDiligent(int argc, char** argv) {
  return ReportError("import-diligent", UnavailableError("not available in this build yet"));
}

}  // namespace reflcap::cli
