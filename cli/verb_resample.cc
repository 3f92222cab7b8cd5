// `reflcap resample CAPTURE --out SAMPLES`: photographs -> per-texel BRDF samples (sample store),
// with resample_report.json and coverage maps. The output folder is staged and moved into place
// only when complete.
#include <cmath>
#include <cstdio>
#include <filesystem>

#include "cli/cli.h"
#include "acquire/resample/resample.h"
#include "engine/capture/capture.h"
#include "engine/core/atomic_file.h"
#include "engine/core/log.h"
#include "engine/core/shard.h"
#include "engine/mesh/texel_atlas.h"

namespace reflcap::cli {
namespace fs = std::filesystem;

int RunResample(int argc, char** argv) {
  std::string capture_path, out, split = "train", backend = "cpu";
  resample::ResampleOptions options;
  bool overwrite = false;
  // NaN = not given (the parser accepts only finite numbers).
  double photon_sigma = std::nan(""), read_sigma = std::nan("");
  ArgParser args(
      "resample", "CAPTURE --out SAMPLES [options]",
      "Project every selected photograph onto the object's texels and store, per texel, its BRDF\n"
      "samples (light and view directions in the texel's tangent frame, radiance / irradiance,\n"
      "noise weight). A sample is kept only when the texel is seen (not occluded) and lit (not in\n"
      "cast shadow), neither direction is grazing, the pixel footprint does not straddle a\n"
      "silhouette, depth or shadow boundary, and the pixel is finite, not clipped and above the\n"
      "noise floor; every rejection is counted by reason in SAMPLES/resample_report.json, next to\n"
      "coverage maps (coverage.exr/.png, domain.exr).");
  args.AddPositional("CAPTURE", &capture_path, "capture.json, or the folder holding it");
  args.AddString("out", &out, "SAMPLES", "output folder (must not exist or be empty)");
  args.AddInt("atlas-res", &options.atlas_resolution,
              StrCat("atlas resolution R (R x R) of a mesh capture (default: the capture's "
                     "ground_truth.atlas size, else ", kDefaultAtlasResolution, ")"));
  args.AddString("split", &split, "S", "photographs to use: train (default), holdout or all");
  args.AddDouble("min-cos", &options.min_cos,
                 StrCat("n.l and n.v must exceed this, in [0, 1) (default ",
                        resample::kDefaultMinCos, " = cos 81.4 deg)"));
  args.AddString("backend", &backend, "B",
                 "cpu (default: Embree rays) or vulkan (visibility and cast shadow from depth maps "
                 "rasterised by Vulkan; exit 3 without a Vulkan device)");
  args.AddString("device", &options.device, "NAME|INDEX",
                 "Vulkan device for --backend vulkan (default: automatic)");
  args.AddFlag("cross-check", &options.cross_check,
               "with --backend vulkan: also run the Embree tests and write their agreement with "
               "the Vulkan masks as mask_agreement into resample_report.json");
  args.AddDouble("noise-sigma", &photon_sigma,
                 StrCat("photon noise std at pixel value 1, for photographs weighted by the noise "
                        "model (default: the capture's "
                        "ground_truth.noise, else ", resample::kDefaultPhotonSigma, ")"));
  args.AddDouble("read-sigma", &read_sigma,
                 StrCat("read noise std; the dark floor is 3x this (default: the capture's, else ",
                        resample::kDefaultReadSigma, ")"));
  args.AddFlag("variance-weights", &options.use_variance,
               "weight the samples of a photograph that has images[].variance (e.g. from reflcap "
               "hdr) by that per-pixel variance, and take its dark/invalid tests from it (default: "
               "the noise model for every photograph)");
  bool no_height_shadows = false;
  args.AddFlag("no-height-shadows", &no_height_shadows,
               "normal-map captures: do not reject samples in cast shadow on the height field "
               "integrated from the normal map (default: rejected as shadowed)");
  std::string sample_point = "pixel";
  args.AddString("sample-point", &sample_point, "pixel|texel",
                 "mesh captures: measure each texel at the pixel whose surface point is nearest "
                 "its centre, with that point's normal and directions (pixel, default), or "
                 "interpolate the four pixels around its projection at the texel centre's "
                 "geometry (texel: less noise, blurs highlights)");
  std::string pixel_filter = "capture";
  args.AddString("pixel-filter", &pixel_filter, "capture|area|point",
                 "with --sample-point pixel: what a photograph's pixel measures — its footprint's "
                 "radiance (area: a texel whose pixels all hit other texels takes the nearest) or "
                 "the ray through its centre (point: such a pair is rejected, as edge, when the "
                 "texel spans >= 0.5 px); default capture: each camera's cameras[].pixel_filter, "
                 "area when absent");
  int chunk_texels = int(options.chunk_texels);
  args.AddInt("chunk-texels", &chunk_texels,
              StrCat("texels per chunk file, >= 1 (default ", resample::kDefaultChunkTexels,
                     "); the unit `fit --shard` divides and `fit --resume` checkpoints"));
  bool no_checkpoint = false;
  std::string shard_text;
  args.AddString("shard", &shard_text, "I/N",
                 "resample only shard I of N (the photographs of a contiguous range of views) and "
                 "write a part to SAMPLES for reflcap merge (default: every photograph)");
  args.AddFlag("resume", &options.resume,
               "continue an interrupted resample from SAMPLES.checkpoint (same capture and options)");
  args.AddDouble("checkpoint-seconds", &options.checkpoint_seconds,
                 StrCat("save the state to SAMPLES.checkpoint every S seconds of work (default ",
                        resample::kDefaultCheckpointSeconds, "; 0 = after every photograph)"));
  args.AddFlag("no-checkpoint", &no_checkpoint,
               "keep no checkpoint (a killed run starts over; the spill files stay in the staging "
               "folder)");
  args.AddInt("threads", &options.threads, "worker threads (default 0 = all cores)");
  args.AddFlag("overwrite", &overwrite,
               "replace SAMPLES if it exists (only once the new one is complete)");
  bool help = false;
  if (Status s = args.Parse(argc, argv, 2, &help); !s.ok()) {
    std::fprintf(stderr, "reflcap resample: %s\n", s.message().c_str());
    return kExitUsage;
  }
  if (help) {
    std::printf("%s", args.Help().c_str());
    return 0;
  }
  if (out.empty()) {
    std::fprintf(stderr, "reflcap resample: --out SAMPLES is required\n");
    return kExitUsage;
  }
  if (!std::isnan(photon_sigma)) options.photon_sigma = photon_sigma;
  if (!std::isnan(read_sigma)) options.read_sigma = read_sigma;
  auto parsed_split = resample::ParseSplit(split);
  auto parsed_backend = resample::ParseBackend(backend);
  auto parsed_point = resample::ParseSamplePoint(sample_point);
  auto parsed_filter = resample::ParsePixelFilter(pixel_filter);
  for (const Status& s : {parsed_split.status(), parsed_backend.status(), parsed_point.status(),
                          parsed_filter.status()}) {
    if (!s.ok()) {
      std::fprintf(stderr, "reflcap resample: %s\n", s.message().c_str());
      return kExitUsage;
    }
  }
  options.split = *parsed_split;
  options.backend = *parsed_backend;
  options.sample_point = *parsed_point;
  options.pixel_filter = *parsed_filter;
  options.height_shadows = !no_height_shadows;
  if (chunk_texels < 1) {
    std::fprintf(stderr, "reflcap resample: --chunk-texels must be >= 1\n");
    return kExitUsage;
  }
  options.chunk_texels = uint32_t(chunk_texels);
  auto shard = ParseShard(shard_text);  // "" = the whole work
  if (!shard.ok()) {
    std::fprintf(stderr, "reflcap resample: %s\n", shard.status().message().c_str());
    return kExitUsage;
  }
  options.shard = *shard;
  if (options.resume && no_checkpoint) {
    std::fprintf(stderr, "reflcap resample: --resume and --no-checkpoint exclude each other\n");
    return kExitUsage;
  }
  if (Status s = options.Validate(); !s.ok()) {
    std::fprintf(stderr, "reflcap resample: %s\n", s.message().c_str());
    return kExitUsage;
  }
  if (Status s = resample::BackendAvailable(options.backend, options.device); !s.ok()) {
    return ReportError("resample", s);
  }

  // Read and check the whole capture before anything is created on disk.
  auto capture = ReadCapture(capture_path);
  if (!capture.ok()) return ReportError("resample", capture.status());
  // A shard checks the photographs it reads (the other shards check theirs).
  auto images = resample::ImagesOfShard(*capture, options);
  if (!images.ok()) return ReportError("resample", images.status());
  CaptureFilesReport files;
  if (Status s = ValidateCaptureFiles(*capture, &files, &*images); !s.ok()) {
    return ReportError("resample", s);
  }
  auto staging = StagingDir::Create(out, overwrite);
  if (!staging.ok()) return ReportError("resample", staging.status());
  if (!no_checkpoint) options.checkpoint_dir = CheckpointDir(staging->destination());
  auto summary = resample::ResampleCapture(*capture, options, staging->path(), files.mesh.get());
  if (!summary.ok()) return ReportError("resample", summary.status());
  if (Status s = staging->Commit(); !s.ok()) return ReportError("resample", s);
  if (!options.checkpoint_dir.empty()) {
    std::error_code ec;
    fs::remove_all(options.checkpoint_dir, ec);
    if (ec) REFLCAP_LOG(kWarning) << options.checkpoint_dir.string() << ": cannot remove: " << ec.message();
  }
  std::printf("%s", summary->text.c_str());
  if (options.shard.count > 1) {
    // A part writes no maps (the merge writes them from every part's coverage.bin).
    std::printf("  part %s; report %s\n", out.c_str(),
                (fs::path(out) / "resample_report.json").string().c_str());
  } else {
    std::printf("  sample store %s; report %s; coverage %s\n", out.c_str(),
                (fs::path(out) / "resample_report.json").string().c_str(),
                (fs::path(out) / "coverage.png").string().c_str());
  }
  if (options.shard.count > 1) {
    PrintShardSummary("resample", options.shard.index, options.shard.count, out, summary->seconds,
                      {{"images", double(summary->images)},
                       {"samples_kept", double(summary->samples_kept)},
                       {"texels_with_samples", double(summary->texels_with_samples)}});
  }
  return 0;
}

}  // namespace reflcap::cli
