// `reflcap import-diligent OBJECT_DIR --out CAPTURE`: a DiLiGenT object as a capture/1 with
// normal-map geometry (acquire/diligent/diligent_import.h).
#include <cstdio>

#include "cli/cli.h"
#include "acquire/diligent/diligent_import.h"
#include "engine/core/atomic_file.h"
#include "engine/core/progress.h"

namespace reflcap::cli {

int RunImportDiligent(int argc, char** argv) {
  std::string object_dir, out;
  diligent::ImportOptions options;
  bool overwrite = false;
  ArgParser args(
      "import-diligent", "OBJECT_DIR --out CAPTURE [--holdout-every K]",
      "Write a DiLiGenT object folder (filenames.txt, light_directions.txt,\n"
      "light_intensities.txt, mask.png, normals.exr, 001..096.png) as a capture/1: normal-map\n"
      "geometry in the DiLiGenT camera frame (= world; x right, y up, z towards the camera), one\n"
      "orthographic camera looking down -z (nominal pixel size), 96 directional lights with\n"
      "their intensities, linear float EXR images (units of the 16-bit full scale), and a\n"
      "holdout split: light i is holdout when i is a multiple of K. bear's images 1-20 (known\n"
      "bad) are left out.");
  args.AddPositional("OBJECT_DIR", &object_dir, "a DiLiGenT object folder");
  args.AddString("out", &out, "CAPTURE", "output folder (must not exist or be empty)");
  args.AddInt("holdout-every", &options.holdout_every,
              StrCat("every K-th light is holdout (default ", diligent::kDefaultHoldoutEvery, ")"));
  args.AddFlag("overwrite", &overwrite, "replace CAPTURE if it exists (only once the new one is complete)");
  bool help = false;
  if (Status s = args.Parse(argc, argv, 2, &help); !s.ok()) {
    std::fprintf(stderr, "reflcap import-diligent: %s\n", s.message().c_str());
    return kExitUsage;
  }
  if (help) {
    std::printf("%s", args.Help().c_str());
    return 0;
  }
  if (out.empty()) {
    std::fprintf(stderr, "reflcap import-diligent: --out CAPTURE is required\n");
    return kExitUsage;
  }
  if (Status s = options.Validate(); !s.ok()) {
    std::fprintf(stderr, "reflcap import-diligent: %s\n", s.message().c_str());
    return kExitUsage;
  }
  auto staging = StagingDir::Create(out, overwrite);
  if (!staging.ok()) return ReportError("import-diligent", staging.status());
  auto summary = diligent::ImportDiligent(object_dir, staging->path(), options);
  if (!summary.ok()) return ReportError("import-diligent", summary.status());
  if (Status s = staging->Commit(); !s.ok()) return ReportError("import-diligent", s);
  const diligent::ImportSummary& r = *summary;
  std::printf("imported DiLiGenT %s: %dx%d, %zu texels (of %zu mask pixels), %zu lights, %zu images "
              "(train %zu, holdout %zu: every %d-th light)",
              r.object.c_str(), r.width, r.height, r.normal_texels, r.mask_pixels, r.lights,
              r.images, r.train, r.holdout, options.holdout_every);
  if (!r.excluded.empty()) {
    std::printf("; left out %zu known-bad images (%d-%d)", r.excluded.size(), r.excluded.front(),
                r.excluded.back());
  }
  std::printf(" in %s\ncapture: %s/capture.json\n", FormatDuration(r.seconds).c_str(), out.c_str());
  return 0;
}

}  // namespace reflcap::cli
