// `reflcap fit SAMPLES --out FIT`: per-texel Lambert + Lafortune fit of a sample store.
#include <cstdio>

#include "cli/cli.h"
#include "cli/pipeline.h"
#include "engine/core/log.h"
#include "engine/core/progress.h"
#include "engine/fit/fit_driver.h"
#include "engine/fit/fitter.h"
#include "engine/fit/vulkan_fitter.h"

namespace reflcap::cli {

void FitFlags::Register(ArgParser* args, fit::FitOptions* options) {
  args->AddInt("lobes", &options->lobes,
               "Lafortune lobes per texel, 0..3 (default 1; 0 = Lambert only; shared: <= 2)");
  args->AddString("lobe-model", &lobe_model, "MODEL",
                  "aniso (default), iso (Cx = Cy), shared (one lobe shape, per-channel scale), or "
                  "auto (aniso or iso per texel, the better by BIC)");
  args->AddString("init", &init, "NAME",
                  "seed (data-driven start + two-stage LM, default) or fixed (fixed start, one "
                  "stage)");
  args->AddString("loss", &loss, "NAME", "none (default), huber or cauchy");
  args->AddFlag("no-channel-retry", &no_channel_retry,
                "keep each channel's own LM result even where it ended far worse than the "
                "texel's best channel, instead of solving it again from that channel's lobe");
  args->AddFlag("no-albedo-fill", &no_albedo_fill,
                "leave texels with no sample at zero albedo instead of giving them the mean "
                "albedo of the texels around them");
  args->AddFlag("no-lobe-transfer", &no_lobe_transfer,
                "keep Lambert-only the texels that never saw their mirror configuration, instead "
                "of lending them a similar neighbour's lobe");
  args->AddInt("lobe-transfer-radius", &options->lobe_transfer.radius,
               "lobe transfer: donors within N atlas texels (default 6)");
  args->AddDouble("lobe-transfer-albedo", &options->lobe_transfer.albedo_tolerance,
                  "lobe transfer: largest relative albedo difference of a donor (default 0.15)");
  args->AddInt("lobe-transfer-rounds", &options->lobe_transfer.rounds,
               "lobe transfer: rounds; a borrowed lobe is lent on in the next (default 4)");
  args->AddFlag("no-material-clusters", &no_material_clusters,
                "do not cluster texels by albedo to lend the texels still without a lobe one "
                "that the pooled samples of their material support");
  args->AddFlag("no-diffuse-falloff", &no_diffuse_falloff,
                "do not offer the texels without a lobe of their own (Lambert-only, or one "
                "borrowed) a generalized diffuse lobe (Cx = Cy = 0: darker towards grazing "
                "light) where their own held-out photographs prefer it");
  args->AddInt("max-material-clusters", &options->clusters.max_clusters,
               "material clusters: at most N (default 64)");
  args->AddString("model-choice", &model_choice, "NAME",
                  "material clusters: a texel with a lobe takes its cluster's instead when it "
                  "predicts the texel's held-out photographs better (kfold, default) or when the "
                  "information criterion prefers it (bic)");
  args->AddInt("model-folds", &options->clusters.folds,
               "--model-choice kfold: folds of the texel's photographs, 2..20 (default 5)");
  args->AddDouble("highlight-cone", &options->highlight_cone_deg,
                  "a lobe is fitted only where some sample lies within DEG of the mirror "
                  "direction (default 5)");
  args->AddInt("max-iterations", &options->max_iterations,
               "LM steps per stage, 1..10000 (default 100)");
  args->AddString("vulkan-kernel", &vulkan_kernel, "NAME",
                  "Vulkan LM kernel: auto (default: clusters on a GPU, lanes on lavapipe), lanes "
                  "(one problem per invocation) or clusters (a subgroup cluster per problem)");
  args->AddInt("cluster-size", &cluster_size,
               "clusters kernel: invocations per problem, a power of two up to 32 and the "
               "device's subgroup size (default 0 = 8)");
  args->AddInt("vulkan-chunks-in-flight", &chunks_in_flight,
               "store chunks fitted at once on the Vulkan device: 2 (a second fitter: one "
               "chunk's LM runs while the host prepares the next), 1, or 0 = automatic (default: "
               "2 on a GPU, 1 on lavapipe)");
}

Status FitFlags::Apply(fit::FitOptions* options) {
  if (vulkan_kernel == "auto") {
    vulkan.kernel = fit::VulkanFitKernel::kAuto;
  } else if (vulkan_kernel == "lanes") {
    vulkan.kernel = fit::VulkanFitKernel::kLanes;
  } else if (vulkan_kernel == "clusters") {
    vulkan.kernel = fit::VulkanFitKernel::kClusters;
  } else {
    return InvalidArgumentError("--vulkan-kernel: \"", vulkan_kernel,
                                "\" is not auto, lanes or clusters");
  }
  if (cluster_size < 0) {
    return InvalidArgumentError("--cluster-size must be >= 0, got ", cluster_size);
  }
  vulkan.cluster_size = uint32_t(cluster_size);
  if (Status s = vulkan.Validate(); !s.ok()) {
    return InvalidArgumentError("--cluster-size: ", s.message());
  }
  if (chunks_in_flight < 0 || chunks_in_flight > 2) {
    return InvalidArgumentError("--vulkan-chunks-in-flight must be 0, 1 or 2, got ",
                                chunks_in_flight);
  }
  vulkan.chunks_in_flight = uint32_t(chunks_in_flight);
  // auto: aniso and iso per texel, the better by BIC (FitOptions::select_lobe_model).
  const bool auto_model = lobe_model == "auto";
  REFLCAP_ASSIGN_OR_RETURN(options->lobe_model,
                           fit::ParseLobeModel(auto_model ? "aniso" : lobe_model));
  REFLCAP_ASSIGN_OR_RETURN(options->init, fit::ParseInitScheme(init));
  REFLCAP_ASSIGN_OR_RETURN(options->loss, fit::ParseLossKind(loss));
  options->select_lobe_model = auto_model;
  options->lobe_transfer.enabled = !no_lobe_transfer;
  options->clusters.enabled = !no_material_clusters;
  options->diffuse_falloff = !no_diffuse_falloff;
  REFLCAP_ASSIGN_OR_RETURN(options->clusters.model_choice, fit::ParseModelChoice(model_choice));
  options->albedo_fill.enabled = !no_albedo_fill;
  options->channel_retry = !no_channel_retry;
  return OkStatus();
}

int RunFit(int argc, char** argv) {
  std::string samples, out, backend_name = "auto", device;
  fit::FitOptions options;
  FitFlags fit_flags;
  bool overwrite = false;
  ArgParser args("fit", "SAMPLES --out FIT [options]",
                 "Fit every texel's BRDF (Lambert + K Lafortune lobes per RGB channel) to the\n"
                 "samples of a store written by `reflcap resample`: the seed paper's data-driven\n"
                 "start and two-stage Levenberg-Marquardt, batched across SIMD lanes and cores,\n"
                 "or on a Vulkan GPU (--backend vulkan: the same algorithm, same outputs).\n"
                 "--backend auto (default) fits on a GPU when there is one (discrete, integrated\n"
                 "or virtual) and on the CPU otherwise, also when the only Vulkan device is\n"
                 "lavapipe (the CPU's own cores run the batched kernel faster); it says which.\n"
                 "Writes FIT/params.exr, sigma.exr, status.exr and fit_report.json (with the\n"
                 "backend and the device's name). Each fitted chunk is checkpointed in\n"
                 "FIT.checkpoint until FIT is complete: --resume continues a killed run.\n"
                 "--shard I/N fits one shard into a part; reflcap merge joins the N parts.");
  args.AddPositional("SAMPLES", &samples, "sample store folder (reflcap resample --out)");
  args.AddString("out", &out, "FIT", "output folder (must not exist or be empty)");
  args.AddString("backend", &backend_name, "NAME",
                 "auto (default: a GPU if there is one, else cpu), cpu (batched SIMD), "
                 "ceres (reference), vulkan (GPU, or lavapipe)");
  args.AddString("device", &device, "NAME|INDEX",
                 "Vulkan device: index or name substring (default: automatic, a discrete GPU "
                 "first); with auto it asks for that device");
  fit_flags.Register(&args, &options);
  args.AddDouble("loss-scale", &options.loss_scale,
                 "robust loss scale in noise standard deviations (default 3)");
  args.AddInt("threads", &options.threads, "worker threads (default 0 = all cores)");
  args.AddFlag("overwrite", &overwrite, "replace FIT if it exists (only once the new one is complete)");
  std::string shard_text;
  fit::FitRunControl control;
  args.AddString("shard", &shard_text, "I/N",
                 "fit only shard I of N (chunk-aligned texel ranges) and write a part to FIT for "
                 "reflcap merge (default: the whole store)");
  args.AddFlag("resume", &control.resume,
               "continue an interrupted fit from FIT.checkpoint (its fitted chunks are kept)");
  bool help = false;
  if (Status s = args.Parse(argc, argv, 2, &help); !s.ok()) {
    std::fprintf(stderr, "reflcap fit: %s\n", s.message().c_str());
    return kExitUsage;
  }
  if (help) {
    std::printf("%s", args.Help().c_str());
    return 0;
  }
  if (out.empty()) {
    std::fprintf(stderr, "reflcap fit: --out FIT is required\n");
    return kExitUsage;
  }
  auto backend = ResolveFitBackend(backend_name, device);
  if (!backend.ok()) {
    if (backend.status().code() == StatusCode::kInvalidArgument) {
      std::fprintf(stderr, "reflcap fit: %s\n", backend.status().message().c_str());
      return kExitUsage;
    }
    return ReportError("fit", backend.status());
  }
  if (Status s = fit_flags.Apply(&options); !s.ok()) {
    std::fprintf(stderr, "reflcap fit: %s\n", s.message().c_str());
    return kExitUsage;
  }
  if (Status s = options.Validate(); !s.ok()) {
    std::fprintf(stderr, "reflcap fit: %s\n", s.message().c_str());
    return kExitUsage;
  }
  auto shard = ParseShard(shard_text);  // "" = the whole work
  if (!shard.ok()) {
    std::fprintf(stderr, "reflcap fit: %s\n", shard.status().message().c_str());
    return kExitUsage;
  }
  control.shard = *shard;
  fit::VulkanFitterOptions vulkan = fit_flags.vulkan;
  vulkan.device = device;
  auto summary = fit::RunFit(samples, out, backend->backend, options, overwrite, vulkan,
                              backend->choice, control);
  if (!summary.ok()) return ReportError("fit", summary.status());
  if (control.shard.count > 1) {
    std::printf("fit part %d/%d  %s  (%s): %zu texels, %.0f fits/s, %s\n", control.shard.index,
                control.shard.count, out.c_str(), summary->device.c_str(), summary->texels,
                summary->fits_per_second, FormatDuration(summary->total_seconds).c_str());
    PrintShardSummary("fit", control.shard.index, control.shard.count, out, summary->total_seconds,
                      {{"texels", double(summary->texels)},
                       {"fit_seconds", summary->fit_seconds},
                       {"fits_per_second", summary->fits_per_second}});
    return 0;
  }
  std::printf("fit  %s  (%s%s)\n", out.c_str(), backend->backend == fit::Backend::kVulkan ? "vulkan: " : "",
              summary->device.c_str());
  std::printf("  texels %zu (with samples %zu), %.0f fits/s, %s\n", summary->texels,
              summary->texels_with_samples, summary->fits_per_second,
              FormatDuration(summary->total_seconds).c_str());
  std::printf("  status:");
  for (int s = 0; s < fit::kFitStatusCount; ++s) {
    if (summary->status_counts[s]) {
      std::printf(" %s %zu", fit::FitStatusName(fit::FitStatus(s)), summary->status_counts[s]);
    }
  }
  std::printf("\n");
  if (options.lobes > 0) {
    std::printf("  lobes lent: %zu by neighbours; material clusters %d (%d with a lobe): %zu lent, "
                "%zu replaced a texel's own\n",
                summary->lobes_transferred, summary->material_clusters,
                summary->material_clusters_with_lobe, summary->cluster_lobes_lent,
                summary->cluster_lobes_replaced);
    if (options.diffuse_falloff) {
      std::printf("  diffuse fall-off lobe: %zu of %zu texels tested (%zu in place of a borrowed "
                  "lobe)\n",
                  summary->falloff_taken, summary->falloff_candidates,
                  summary->falloff_replaced);
    }
  }
  return 0;
}

}  // namespace reflcap::cli
