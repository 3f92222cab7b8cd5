// `reflcap view FIT --out DIR`: a self-contained relightable viewer page for a fit
// (render/viewer/viewer_page.h).
#include <chrono>
#include <cstdio>

#include "cli/cli.h"
#include "engine/core/atomic_file.h"
#include "engine/core/progress.h"
#include "render/export/fit_source.h"
#include "render/viewer/viewer_page.h"

namespace reflcap::cli {

int RunView(int argc, char** argv) {
  std::string fit, out, capture;
  int views = 4;
  bool overwrite = false;
  ArgParser args(
      "view", "FIT --out DIR [--capture CAPTURE] [--views N] [--overwrite]",
      "Write a self-contained, relightable viewer page for a fit: DIR/index.html (three.js and\n"
      "all data inline; opens from the file system, no network) shades the capture's mesh with\n"
      "each texel's Lambert + Lafortune BRDF in WebGL2 — the model of the CPU reference renderer,\n"
      "without cast shadows — at the camera and light of N held-out photographs, shown beside\n"
      "it; drag to orbit, shift-drag to move the light. DIR/views.json lists the views. The\n"
      "capture is found from the fit as for `reflcap export` unless --capture names it.");
  args.AddPositional("FIT", &fit, "fit folder holding params.exr (or the params.exr file itself)");
  args.AddString("out", &out, "DIR", "output folder (must not exist or be empty)");
  args.AddString("capture", &capture, "CAPTURE",
                 "capture.json (or its folder) the fit is of (default: traced from the fit)");
  args.AddInt("views", &views, "held-out photographs carried, evenly spaced (default 4)");
  args.AddFlag("overwrite", &overwrite, "replace DIR if it exists (only once the new one is complete)");
  bool help = false;
  if (Status s = args.Parse(argc, argv, 2, &help); !s.ok()) {
    std::fprintf(stderr, "reflcap view: %s\n", s.message().c_str());
    return kExitUsage;
  }
  if (help) {
    std::printf("%s", args.Help().c_str());
    return 0;
  }
  if (out.empty()) {
    std::fprintf(stderr, "reflcap view: --out DIR is required\n");
    return kExitUsage;
  }
  render::ViewerOptions options;
  options.views = views;
  if (Status s = options.Validate(); !s.ok()) {
    std::fprintf(stderr, "reflcap view: --views: %s\n", s.message().c_str());
    return kExitUsage;
  }
  if (!render::ViewerHasThreeJs()) {
    return ReportError("view", UnavailableError("this reflcap was built without three.js "
                                                "(render/viewer/node_modules was missing at "
                                                "configure time): run .ci/install-deps, then "
                                                "cmake and rebuild"));
  }
  const auto start = std::chrono::steady_clock::now();
  auto loaded = render::LoadFitWithMesh(fit, capture, "the viewer");
  if (!loaded.ok()) return ReportError("view", loaded.status());
  auto staging = StagingDir::Create(out, overwrite);
  if (!staging.ok()) return ReportError("view", staging.status());
  auto summary = render::WriteViewerPage(*loaded->fitted, staging->path(), options);
  if (!summary.ok()) return ReportError("view", summary.status());
  if (Status s = staging->Commit(); !s.ok()) return ReportError("view", s);
  const double total_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::printf("viewer for %zu texels, %zu triangles, %zu held-out views -> %s/index.html "
              "(%.2f MB) in %s\n",
              summary->texels, summary->triangles, summary->images.size(), out.c_str(),
              summary->page_bytes / 1e6, FormatDuration(total_s).c_str());
  return 0;
}

}  // namespace reflcap::cli
