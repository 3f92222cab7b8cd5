// `reflcap synth` and `reflcap demo`.
#include <chrono>
#include <cstdio>
#include <filesystem>

#include "cli/cli.h"
#include "cli/pipeline.h"
#include "acquire/synth/synth.h"
#include "engine/core/atomic_file.h"
#include "engine/core/log.h"
#include "engine/core/progress.h"

namespace reflcap::cli {
namespace fs = std::filesystem;
namespace {

void AddSynthOptions(ArgParser* args, synth::SynthOptions* o, std::string* materials) {
  args->AddString("preset", &o->preset, "NAME", "small (default), medium, or million (>= 1e6 texels)");
  args->AddUint64("seed", &o->seed, "random seed of object relief, materials and noise (default 1)");
  args->AddDouble("noise", &o->noise,
                  "photon noise std at pixel value 1 (read noise = 0.2 x that); 0 = none (default 0.01)");
  args->AddDouble("saturation", &o->saturation, "clip pixel values at this level (default 0 = no clipping)");
  args->AddInt64("texels", &o->texels, "target texel count of the atlas (default: preset)");
  args->AddInt("image-size", &o->image_size, "image width = height in pixels (default: preset)");
  args->AddInt("cameras", &o->cameras, "cameras on the arc (default: preset)");
  args->AddInt("lights", &o->lights, "point lights (default: preset)");
  args->AddInt("steps", &o->steps, "turntable steps over 360 degrees (default: preset)");
  args->AddInt("supersample", &o->supersampling, "N x N samples per pixel (default 1)");
  args->AddDouble("pixel-footprint", &o->pixel_footprint,
                  "the square, in pixels (1..4), that those samples cover (default 1: the pixel)");
  args->AddString("materials", materials, "LIST",
                  "comma-separated subset of matte, glossy, sharp_highlight, anisotropic, "
                  "coloured_texture, coloured_lobe (default: all six)");
}

// "a,b" -> {"a", "b"}; empty items are kept, so Validate names them.
std::vector<std::string> SplitList(const std::string& list) {
  std::vector<std::string> items;
  if (list.empty()) return items;
  size_t start = 0;
  for (size_t comma; (comma = list.find(',', start)) != std::string::npos; start = comma + 1) {
    items.push_back(list.substr(start, comma - start));
  }
  items.push_back(list.substr(start));
  return items;
}

StatusOr<synth::SynthSummary> Synthesize(const synth::SynthOptions& options, const fs::path& out,
                                         bool overwrite) {
  REFLCAP_RETURN_IF_ERROR(options.Validate());
  REFLCAP_ASSIGN_OR_RETURN(StagingDir staging, StagingDir::Create(out, overwrite));
  REFLCAP_ASSIGN_OR_RETURN(synth::SynthSummary summary,
                           synth::WriteSyntheticCapture(options, staging.path()));
  REFLCAP_RETURN_IF_ERROR(staging.Commit());
  return summary;
}

void PrintSummary(const synth::SynthSummary& s, const fs::path& out) {
  std::printf("synthetic capture  %s\n", (out / "capture.json").string().c_str());
  std::printf("  texels %zu (atlas %dx%d), triangles %zu\n", s.texels, s.atlas_resolution,
              s.atlas_resolution, s.triangles);
  std::printf("  images %zu (train %zu, holdout %zu), written in %s\n", s.images, s.train_images,
              s.holdout_images, FormatDuration(s.seconds).c_str());
  std::printf("  ground truth: %s, %s; masks in %s\n", (out / "gt/params.exr").string().c_str(),
              (out / "gt/material.exr").string().c_str(), (out / "masks").string().c_str());
}

}  // namespace

int RunSynth(int argc, char** argv) {
  synth::SynthOptions options;
  std::string out, materials;
  bool overwrite = false;
  ArgParser args("synth", "--out DIR [options]",
                 "Write a complete synthetic capture/1 dataset with ground truth: a relief object\n"
                 "that shadows itself, six spatially varying Lambert + Lafortune materials, the\n"
                 "seed paper's turntable rig with a holdout split, rendered by the CPU reference\n"
                 "renderer with photon + read noise.");
  args.AddString("out", &out, "DIR", "output folder (must not exist or be empty)");
  AddSynthOptions(&args, &options, &materials);
  args.AddFlag("overwrite", &overwrite, "replace DIR if it exists (only once the new one is complete)");
  bool help = false;
  if (Status s = args.Parse(argc, argv, 2, &help); !s.ok()) {
    std::fprintf(stderr, "reflcap synth: %s\n", s.message().c_str());
    return kExitUsage;
  }
  if (help) {
    std::printf("%s", args.Help().c_str());
    return 0;
  }
  if (out.empty()) {
    std::fprintf(stderr, "reflcap synth: --out DIR is required\n");
    return kExitUsage;
  }
  options.materials = SplitList(materials);
  if (Status s = options.Validate(); !s.ok()) {
    std::fprintf(stderr, "reflcap synth: %s\n", s.message().c_str());
    return kExitUsage;
  }
  auto summary = Synthesize(options, out, overwrite);
  if (!summary.ok()) return ReportError("synth", summary.status());
  PrintSummary(*summary, out);
  return 0;
}

int RunDemo(int argc, char** argv) {
  std::string out = "reflcap_demo";
  ArgParser args("demo", "[--out DIR]",
                 "Synthesise a small capture, then resample its train split, fit, re-render the\n"
                 "holdout split and validate (as `reflcap run`), print the holdout PSNR next to\n"
                 "the bound the capture's noise allows, and say where the files are. DIR is replaced if it holds an earlier demo; any other non-empty\n"
                 "folder is refused.");
  args.AddString("out", &out, "DIR", "output folder (default ./reflcap_demo)");
  bool help = false;
  if (Status s = args.Parse(argc, argv, 2, &help); !s.ok()) {
    std::fprintf(stderr, "reflcap demo: %s\n", s.message().c_str());
    return kExitUsage;
  }
  if (help) {
    std::printf("%s", args.Help().c_str());
    return 0;
  }
  // A folder holding the marker is an earlier demo's: safe to replace.
  const fs::path marker = fs::path(out) / ".reflcap-demo";
  const bool replace = fs::exists(marker);
  auto staging = StagingDir::Create(out, replace);
  if (!staging.ok()) return ReportError("demo", staging.status());
  const auto start = std::chrono::steady_clock::now();
  std::printf("reflcap demo: 1/2 synthesising a small capture (relief object, 6 materials, noise 1%%)\n");
  std::fflush(stdout);
  synth::SynthOptions options;
  auto summary = synth::WriteSyntheticCapture(options, staging->path() / "capture");
  if (!summary.ok()) return ReportError("demo", summary.status());
  PrintSummary(*summary, fs::path(out) / "capture");
  std::printf("reflcap demo: 2/2 resample (train) -> fit -> render (holdout) -> validate\n");
  std::fflush(stdout);
  PipelineOptions pipeline_options;  // the fit backend as --backend auto picks it
  auto fit_backend = ResolveFitBackend("auto", "");
  if (!fit_backend.ok()) return ReportError("demo", fit_backend.status());
  pipeline_options.fit_backend = fit_backend->backend;
  pipeline_options.fit_backend_choice = fit_backend->choice;
  auto pipeline = RunPipeline(staging->path() / "capture", staging->path() / "run", pipeline_options);
  if (!pipeline.ok()) return ReportError("demo", pipeline.status());
  if (Status s = WriteTextFileAtomic(staging->path() / ".reflcap-demo", "reflcap demo output\n"); !s.ok()) {
    return ReportError("demo", s);
  }
  if (Status s = staging->NameFinalPaths(); !s.ok()) return ReportError("demo", s);
  if (Status s = staging->Commit(); !s.ok()) return ReportError("demo", s);
  const fs::path run = fs::path(out) / "run";
  std::printf("  %s\n", PipelineSummaryLine(*pipeline).c_str());
  std::printf("  samples %s, fit %s, renders %s\n", (run / "samples").string().c_str(),
              (run / "fit").string().c_str(), (run / "renders").string().c_str());
  std::printf("  report  %s\n", (run / "report" / "report.html").string().c_str());
  std::printf("demo finished in %s\n",
              FormatDuration(std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count()).c_str());
  return 0;
}

}  // namespace reflcap::cli
