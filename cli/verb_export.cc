// `reflcap export FIT --gltf OUT.glb`: a fit as glTF 2.0 — mesh, metallic-roughness
// approximation, raw Lafortune parameters in the REFLCAP_lafortune extension, EXR beside it
// (render/export/gltf_export.h).
#include <chrono>
#include <cstdio>
#include <filesystem>

#include "cli/cli.h"
#include "engine/core/progress.h"
#include "render/export/fit_source.h"
#include "render/export/gltf_export.h"

namespace reflcap::cli {
namespace fs = std::filesystem;

int RunExport(int argc, char** argv) {
  std::string fit, gltf, capture;
  int max_texture_size = 16384, threads = 0;
  bool no_exr = false, overwrite = false;
  ArgParser args(
      "export", "FIT --gltf OUT.glb [--capture CAPTURE] [options]",
      "Export a fit as one binary glTF 2.0 file: the capture's mesh (normals, tangents of\n"
      "reflcap's BRDF frames, UVs), a core metallic-roughness material approximating each\n"
      "texel's Lambert + Lafortune BRDF (fitted per texel; its error is printed and stored), and\n"
      "the raw parameters in the material extension REFLCAP_lafortune (README.md documents the\n"
      "schema). Beside it, OUT.lafortune.exr holds the same parameters as a parameter-map EXR\n"
      "plus the per-texel approximation error (channel gltf.error). The capture is found from\n"
      "the fit (fit_report.json -> sample store -> capture) unless --capture names it. Both files\n"
      "appear only when both are complete.");
  args.AddPositional("FIT", &fit, "fit folder holding params.exr (or the params.exr file itself)");
  args.AddString("gltf", &gltf, "OUT.glb", "output .glb file (its folder must exist)");
  args.AddString("capture", &capture, "CAPTURE",
                 "capture.json (or its folder) the fit is of (default: traced from the fit)");
  args.AddInt("max-texture-size", &max_texture_size,
              "largest atlas side accepted, pixels (default 16384, the largest WebGL texture)");
  args.AddFlag("no-exr", &no_exr, "do not write OUT.lafortune.exr");
  args.AddInt("threads", &threads, "worker threads (default 0: all)");
  args.AddFlag("overwrite", &overwrite, "replace OUT.glb and its EXR when they exist");
  bool help = false;
  if (Status s = args.Parse(argc, argv, 2, &help); !s.ok()) {
    std::fprintf(stderr, "reflcap export: %s\n", s.message().c_str());
    return kExitUsage;
  }
  if (help) {
    std::printf("%s", args.Help().c_str());
    return 0;
  }
  auto usage = [](const std::string& message) {
    std::fprintf(stderr, "reflcap export: %s\n", message.c_str());
    return kExitUsage;
  };
  if (gltf.empty()) return usage("--gltf OUT.glb is required");
  if (fs::path(gltf).extension() != ".glb") return usage("--gltf: \"" + gltf + "\" must end in .glb");
  render::GltfExportOptions options;
  options.max_texture_size = max_texture_size;
  options.write_exr = !no_exr;
  options.overwrite = overwrite;
  options.threads = threads;
  if (Status s = options.Validate(); !s.ok()) return usage(s.message());
  const auto start = std::chrono::steady_clock::now();
  auto loaded = render::LoadFitWithMesh(fit, capture, "glTF export");
  if (!loaded.ok()) return ReportError("export", loaded.status());
  const double load_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  auto summary = render::ExportGltf(*loaded->fitted, loaded->params, gltf, options);
  if (!summary.ok()) return ReportError("export", summary.status());
  const double total_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::printf("exported %zu texels (atlas %dx%d, %d lobes), %zu vertices, %zu triangles -> %s "
              "(%.2f MB)\n",
              summary->texels, summary->width, summary->height, summary->num_lobes,
              summary->vertices, summary->triangles, gltf.c_str(), summary->glb_bytes / 1e6);
  if (!summary->exr.empty()) {
    std::printf("  raw parameters also in %s (%.2f MB)\n", summary->exr.string().c_str(),
                summary->exr_bytes / 1e6);
  }
  const render::ApproximationError& e = summary->error;
  std::printf("  metallic-roughness approximation, relative RMS error per texel: median %.3f, "
              "p90 %.3f, p99 %.3f, max %.3f, RMS %.3f; %zu texels metallic\n",
              e.median, e.p90, e.p99, e.max, e.rms, e.metallic_texels);
  std::printf("  capture %s; load %s, approximation %s, write %s, total %s\n",
              loaded->capture_json.string().c_str(), FormatDuration(load_s).c_str(),
              FormatDuration(summary->approximate_s).c_str(),
              FormatDuration(summary->write_s).c_str(), FormatDuration(total_s).c_str());
  return 0;
}

}  // namespace reflcap::cli
