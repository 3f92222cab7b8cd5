// `reflcap render CAPTURE FIT --out DIR`: re-renders a capture's photographs from a fit's
// parameter map with the CPU reference renderer (render/reference/render_capture.h) or, with
// --backend vulkan, the Vulkan renderer (render/vulkan/vulkan_render_capture.h); both write the
// same files.
#include <cstdio>
#include <filesystem>
#include <memory>

#include "cli/cli.h"
#include "engine/capture/capture.h"
#include "engine/core/atomic_file.h"
#include "engine/core/progress.h"
#include "render/reference/render_capture.h"
#ifdef REFLCAP_HAVE_VULKAN_RENDERER
#include "render/vulkan/vulkan_render_capture.h"
#endif

namespace reflcap::cli {
namespace fs = std::filesystem;

int RunRender(int argc, char** argv) {
  std::string capture_path, fit, out, split = "holdout", backend = "cpu", device, shadow_map;
  int writers = 0, indirect_bounces = 2, indirect_rays = 64;
  std::string indirect = "auto", supersample = "auto", psf = "auto", height_field = "auto";
  std::string footprint = "auto";
  bool no_shadows = false, no_height_shadows = false, overwrite = false;
  ArgParser args(
      "render", "CAPTURE FIT --out DIR [--split holdout|train|all] [--backend cpu|vulkan] [options]",
      "Re-render the selected photographs of a capture from a fit: one float EXR per photograph\n"
      "with the same relative name (images/0003.exr -> DIR/images/0003.exr), its object mask\n"
      "(DIR/masks/0003.png) and validation buffers (DIR/aux/0003.exr: cast_shadow, cos_theta_i,\n"
      "cos_theta_o, curvature, mask), and DIR/render_report.json. FIT/params.exr holds the\n"
      "parameter maps in the capture's atlas layout (mesh: BuildTexelAtlas at params.exr's size;\n"
      "normal map: the camera's pixels). A synthetic capture's gt/ folder is a valid FIT.\n"
      "--backend vulkan rasterises on a Vulkan device (a GPU, or lavapipe on the CPU) and writes\n"
      "the same files; render_report.json names the device. It renders many images per\n"
      "submission with several submissions in flight; files are written by a pool of threads\n"
      "while later images render.");
  args.AddPositional("CAPTURE", &capture_path, "capture.json, or the folder holding it");
  args.AddPositional("FIT", &fit, "fit folder holding params.exr (or the params.exr file itself)");
  args.AddString("out", &out, "DIR", "output folder (must not exist or be empty)");
  args.AddString("split", &split, "S", "holdout (default), train or all");
  args.AddString("backend", &backend, "B", "cpu (default) or vulkan");
  args.AddString("device", &device, "NAME|INDEX",
                 "Vulkan device: index or name substring (default: automatic; --backend vulkan)");
  args.AddString("shadow-map", &shadow_map, "KIND",
                 "Vulkan point-light shadow map: auto (default), cube or fitted");
  args.AddString("supersample", &supersample, "N|auto",
                 "N x N rays per pixel averaged over it (a box filter), 1..16, or auto (default): "
                 "4 x 4 when the train photographs integrate over their pixels, else 1 (the pixel "
                 "centre); mesh captures");
  args.AddString("pixel-footprint", &footprint, "W|auto",
                 "mesh captures: the square, W px wide (1..4), that a pixel's N x N rays cover: "
                 "1 = the pixel, wider = the pixel also sees light from beside it (lens blur, a "
                 "path tracer's filter); auto (default): with --supersample auto the train "
                 "photographs decide, else 1");
  args.AddString("psf", &psf, "auto|none|SIGMA",
                 "normal-map captures: the photographs' point spread, a Gaussian of SIGMA px "
                 "(0..4) applied within the mask; auto (default: the train photographs decide) "
                 "or none");
  args.AddString("height-field", &height_field, "auto|ls|l1",
                 "normal-map captures: the shadows' height field, integrated by least squares "
                 "(ls) or by L1, which keeps depth steps sharp (l1); auto (default: the train "
                 "photographs decide)");
  args.AddFlag("no-shadows", &no_shadows,
               "no cast shadows: no shadow rays (mesh captures), no height-field shadows (normal "
               "maps)");
  args.AddFlag("no-height-shadows", &no_height_shadows,
               "normal-map captures: no cast shadows from the height field integrated from the "
               "normal map (mesh captures keep theirs)");
  args.AddString("indirect", &indirect, "MODE",
                 "light not straight from the lamp: interreflection (mesh captures) or the "
                 "room's stray light (normal-map captures); auto (default: added when the train "
                 "photographs show light where no direct light reaches), on or off");
  args.AddInt("indirect-bounces", &indirect_bounces, "bounces of interreflection, 1..8 (default 2)");
  args.AddInt("indirect-rays", &indirect_rays,
              "rays per texel gathering interreflection, 1..1024 (default 64)");
  args.AddInt("writers", &writers,
              "threads writing the output files while later images render (default 0: one per "
              "hardware thread)");
  args.AddFlag("overwrite", &overwrite, "replace DIR if it exists (only once the new one is complete)");
  std::string shard_text;
  args.AddString("shard", &shard_text, "I/N",
                 "render only shard I of N of the selected photographs (a contiguous range) and "
                 "write a part for reflcap merge (default: all of them)");
  bool help = false;
  if (Status s = args.Parse(argc, argv, 2, &help); !s.ok()) {
    std::fprintf(stderr, "reflcap render: %s\n", s.message().c_str());
    return kExitUsage;
  }
  if (help) {
    std::printf("%s", args.Help().c_str());
    return 0;
  }
  auto usage = [](const std::string& message) {
    std::fprintf(stderr, "reflcap render: %s\n", message.c_str());
    return kExitUsage;
  };
  if (out.empty()) return usage("--out DIR is required");
  auto selection = render::ParseSplitSelection(split, "--split");
  if (!selection.ok()) return usage(selection.status().message());
  if (backend != "cpu" && backend != "vulkan") {
    return usage("--backend: \"" + backend + "\" is not one of cpu, vulkan");
  }
  const StatusOr<int> supersampling = render::ParseSupersampling(supersample, "--supersample");
  if (!supersampling.ok()) return usage(supersampling.status().message());
  const StatusOr<double> pixel_footprint =
      render::ParsePixelFootprint(footprint, "--pixel-footprint");
  if (!pixel_footprint.ok()) return usage(pixel_footprint.status().message());
  const StatusOr<double> psf_sigma = render::ParsePsf(psf, "--psf");
  if (!psf_sigma.ok()) return usage(psf_sigma.status().message());
  const auto height_choice = render::ParseHeightFieldChoice(height_field, "--height-field");
  if (!height_choice.ok()) return usage(height_choice.status().message());
  if (writers < 0 || writers > 256) {
    return usage(StrCat("--writers must be in [0, 256], got ", writers));
  }
  if (!device.empty() && backend != "vulkan") return usage("--device needs --backend vulkan");
  if (!shadow_map.empty() && backend != "vulkan") return usage("--shadow-map needs --backend vulkan");
  if (!shadow_map.empty() && shadow_map != "auto" && shadow_map != "cube" && shadow_map != "fitted") {
    return usage("--shadow-map: \"" + shadow_map + "\" is not one of auto, cube, fitted");
  }
  auto indirect_mode = render::ParseIndirectMode(indirect, "--indirect");
  if (!indirect_mode.ok()) return usage(indirect_mode.status().message());
  auto parsed_shard = ParseShard(shard_text);  // "" = every selected photograph
  if (!parsed_shard.ok()) return usage(parsed_shard.status().message());
  const Shard shard = *parsed_shard;
  render::CaptureRenderOptions options;
  options.split = *selection;
  options.supersampling = *supersampling;
  options.pixel_footprint = *pixel_footprint;
  options.psf_sigma_px = *psf_sigma;
  options.height_field = *height_choice;
  options.cast_shadows = !no_shadows;
  options.height_shadows = !no_height_shadows;
  options.writers = writers;
  options.indirect = *indirect_mode;
  options.indirect_bounces = indirect_bounces;  // range checked by Validate
  options.indirect_rays = indirect_rays;
  options.shard = shard;
  if (Status s = options.Validate(); !s.ok()) return usage(s.message());
  auto capture = ReadCapture(capture_path);
  if (!capture.ok()) return ReportError("render", capture.status());
  fs::path params = fit;
  std::error_code ec;
  if (fs::is_directory(params, ec)) params /= "params.exr";
  if (!fs::is_regular_file(params, ec)) {
    return ReportError("render", NotFoundError(params.string(), ": missing (FIT must hold params.exr)"));
  }
#ifdef REFLCAP_HAVE_VULKAN_RENDERER
  std::unique_ptr<render::VulkanRenderer> renderer;
  if (backend == "vulkan") {
    render::VulkanRenderOptions vulkan_options;
    if (shadow_map == "cube") vulkan_options.shadow_map = render::ShadowMapKind::kCube;
    if (shadow_map == "fitted") vulkan_options.shadow_map = render::ShadowMapKind::kFitted;
    auto created = render::VulkanRenderer::Create(device, vulkan_options);
    if (!created.ok()) {
      // A device that is missing, does not match --device or cannot run the renderer: the
      // requested backend is unavailable (exit 3).
      return ReportError("render", UnavailableError("--backend vulkan: ",
                                                    created.status().message()));
    }
    renderer = std::move(created).value();
  }
#else
  if (backend == "vulkan") {
    return ReportError("render", UnavailableError("--backend vulkan: this build has no Vulkan "
                                                  "support (REFLCAP_ENABLE_VULKAN=OFF); use "
                                                  "--backend cpu"));
  }
#endif
  auto staging = StagingDir::Create(out, overwrite);
  if (!staging.ok()) return ReportError("render", staging.status());
  std::string device_name = "the cpu";
  StatusOr<render::CaptureRenderSummary> summary = InternalError("no backend ran");
#ifdef REFLCAP_HAVE_VULKAN_RENDERER
  if (renderer != nullptr) {
    device_name = renderer->device().name + " (Vulkan)";
    summary = render::RenderCaptureVulkan(*capture, params, staging->path(), options, *renderer);
  } else {
    summary = render::RenderCapture(*capture, params, staging->path(), options);
  }
#else
  summary = render::RenderCapture(*capture, params, staging->path(), options);
#endif
  if (!summary.ok()) return ReportError("render", summary.status());
  if (Status s = staging->Commit(); !s.ok()) return ReportError("render", s);
  std::printf("rendered %zu %s images (%zu texels, %d lobes) on %s in %s -> %s\n",
              summary->images, render::SplitSelectionName(*selection), summary->texels,
              summary->num_lobes, device_name.c_str(), FormatDuration(summary->total_s).c_str(),
              out.c_str());
  if (shard.count > 1) {
    PrintShardSummary("render", shard.index, shard.count, out, summary->total_s,
                      {{"images", double(summary->images)}});
  } else {
    std::printf("next: reflcap validate %s %s --out REPORT\n", capture_path.c_str(), out.c_str());
  }
  return 0;
}

}  // namespace reflcap::cli
