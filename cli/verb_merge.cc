// `reflcap merge PARTS... --out DIR`: joins the parts that `--shard I/N` runs wrote into the
// output one run would have written. Which stage the parts are of is read from them.
#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

#include "cli/cli.h"
#include "engine/core/progress.h"
#include "acquire/resample/resample.h"
#include "engine/core/atomic_file.h"
#include "engine/fit/fit_driver.h"
#include "render/reference/render_capture.h"

namespace reflcap::cli {
namespace fs = std::filesystem;

int RunMerge(int argc, char** argv) {
  std::vector<std::string> part_names;
  std::string out, samples;
  int threads = 0;
  bool overwrite = false, link = false;
  ArgParser args(
      "merge", "PARTS... --out DIR [--link] [--samples SAMPLES] [--threads N] [--overwrite]",
      "Join the parts written by `reflcap resample|fit|render --shard I/N`\n"
      "(one per shard, N in all) into the folder a single run writes.\n"
      "Resample parts (a shard = the photographs of a range of views) must be of one capture and\n"
      "one set of options; every texel takes the parts' samples in shard order: the store and\n"
      "maps are bit-identical to a single run's. With --link the store names the parts instead of\n"
      "holding their samples joined (fit and the other readers join each chunk as they read it:\n"
      "the same samples, without writing the store once more); the parts must stay in place.\n"
      "Fit parts (a shard = a range of chunks) must be of one sample store (its fingerprint), one\n"
      "set of options and backend; the merge runs the stages that need the whole atlas (lobe\n"
      "transfer, albedo fill, material clusters) and writes params.exr, sigma.exr and status.exr\n"
      "bit-identical to a single run's.\n"
      "Render parts (a shard = a range of the selected photographs) must be of one capture,\n"
      "fit and options; their files are copied and one render_report.json lists them all.\n"
      "Each shard exactly once; nothing is written when a part is missing, duplicated, corrupt or\n"
      "of another run.");
  args.AddPositionalList("PARTS", &part_names, "the part folders (any order)");
  args.AddString("out", &out, "DIR", "output folder (must not exist or be empty)");
  args.AddString("samples", &samples, "SAMPLES",
                 "the sample store the parts were fitted from (default: the path the parts "
                 "record; give it when the store has moved)");
  args.AddFlag("link", &link,
               "resample parts: write a linked store that reads the parts' chunks (no copy)");
  args.AddInt("threads", &threads, "worker threads (default 0 = all cores)");
  args.AddFlag("overwrite", &overwrite, "replace DIR if it exists (only once the new one is complete)");
  bool help = false;
  if (Status s = args.Parse(argc, argv, 2, &help); !s.ok()) {
    std::fprintf(stderr, "reflcap merge: %s\n", s.message().c_str());
    return kExitUsage;
  }
  if (help) {
    std::printf("%s", args.Help().c_str());
    return 0;
  }
  if (out.empty()) {
    std::fprintf(stderr, "reflcap merge: --out DIR is required\n");
    return kExitUsage;
  }
  if (threads < 0) {
    std::fprintf(stderr, "reflcap merge: --threads must be >= 0\n");
    return kExitUsage;
  }
  std::vector<fs::path> parts(part_names.begin(), part_names.end());
  std::error_code ec;
  for (const fs::path& part : parts) {
    if (!fs::is_directory(part, ec)) {
      return ReportError("merge", NotFoundError(part.string(), ": no such part folder"));
    }
  }
  const bool resample_parts = fs::exists(parts.front() / "resample_part.json", ec);
  if (link && !resample_parts) {
    std::fprintf(stderr, "reflcap merge: --link: only resample parts can be linked (%s is not one)\n",
                 parts.front().c_str());
    return kExitUsage;
  }
  if (fs::exists(parts.front() / fit::kFitPartFile, ec)) {
    auto summary = fit::MergeFitParts(parts, out, overwrite, threads, samples);
    if (!summary.ok()) return ReportError("merge", summary.status());
    std::printf("merged %zu fit parts into %s: %zu texels (with samples %zu), %s\n", parts.size(),
                out.c_str(), summary->texels, summary->texels_with_samples,
                FormatDuration(summary->total_seconds).c_str());
    return 0;
  }
  if (resample_parts) {
    auto staging = StagingDir::Create(out, overwrite);
    if (!staging.ok()) return ReportError("merge", staging.status());
    auto summary = resample::MergeResampleParts(parts, staging->path(), threads, link);
    if (!summary.ok()) return ReportError("merge", summary.status());
    if (Status s = staging->Commit(); !s.ok()) return ReportError("merge", s);
    std::printf("%s %zu resample parts into %s\n%s", link ? "linked" : "merged", parts.size(),
                out.c_str(), summary->text.c_str());
    return 0;
  }
  if (fs::exists(parts.front() / "render_report.json", ec)) {
    auto staging = StagingDir::Create(out, overwrite);
    if (!staging.ok()) return ReportError("merge", staging.status());
    if (Status s = render::MergeRenderParts(parts, staging->path()); !s.ok()) {
      return ReportError("merge", s);
    }
    if (Status s = staging->Commit(); !s.ok()) return ReportError("merge", s);
    std::printf("merged %zu render parts into %s\n", parts.size(), out.c_str());
    return 0;
  }
  return ReportError("merge", NotFoundError(parts.front().string(),
                                            ": not a part (no ", fit::kFitPartFile,
                                            ", resample_part.json or render_report.json): parts "
                                            "are what `reflcap resample|fit|render --shard I/N` "
                                            "write"));
}

}  // namespace reflcap::cli
