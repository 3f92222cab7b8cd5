#pragma once
// Resampling, the seed paper's step 3.4.3 (Fukuda et al.): every selected photograph of a capture
// is projected onto the texels of the object's atlas, light and view directions are expressed in
// each texel's tangent frame, and the BRDF samples are reorganised texel-major into a sample
// store (engine/texel/sample_store.h) so a fitter reads each texel's data once, in one place.
//
// ResampleCapture reads the capture, builds the atlas (and the Embree scene of a mesh), runs
// ImageResampler — or, with Backend::kVulkan, its GPU twin VulkanMasks (vulkan_masks.h) — on one
// photograph at a time (the next one is read while the current one is resampled), streams the kept samples through ChunkedSampleWriter, and writes the store, the
// report and the coverage maps:
//
//   store.json, atlas.bin, chunk_NNNNN.rcs   the sample store
//   resample_report.json                     counts, reasons, percentiles, coverage, timings
//   coverage.exr                             samples per texel (channel Y), atlas layout
//   coverage.png                             the same, tone-mapped (see kCoveragePngFullScale)
//   domain.exr                               per texel: views, domain cells, min half-vector angle
//
// Acceptance of a (texel, image) pair, the rejection reasons and their order: image_resampler.h.
// BRDF value = pixel / (exposure_s · E) per channel, weight = 1 / var(value): from the
// photograph's variance image where the capture gives one (images[].variance, read beside the
// photograph and checked whole: ReadVarianceImage), else from the noise model (NoiseModel):
// ground_truth.noise of a synthetic capture, else kDefaultPhotonSigma / kDefaultReadSigma, either
// overridden by the options. A pixel clips at images[].saturation, or at
// ground_truth.noise.saturation for an image that has none.
//
// Memory stays bounded whatever the number of images: one photograph (plus the one being read),
// the atlas, the scene, per-texel counters, and the writer's buffer budget (the 1,008,600-texel
// synthetic preset, 180 or 288 images of 1024², peaks near 0.6 GB).
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "acquire/resample/image_resampler.h"
#include "engine/capture/capture.h"
#include "engine/core/shard.h"
#include "engine/core/status.h"

namespace reflcap::resample {

enum class Backend { kCpu, kVulkan };
enum class SplitSelection { kTrain, kHoldout, kAll };

// "cpu" / "vulkan"; InvalidArgument otherwise.
StatusOr<Backend> ParseBackend(const std::string& name);
// "train" / "holdout" / "all"; InvalidArgument otherwise.
StatusOr<SplitSelection> ParseSplit(const std::string& name);
const char* SplitSelectionName(SplitSelection split);
// OK for kCpu; for kVulkan OK when a Vulkan device matching `device` ("" = any; an index or a
// piece of its name) with a graphics queue can be opened, else Unavailable saying why (no
// driver, no device, or a build without Vulkan).
Status BackendAvailable(Backend backend, const std::string& device = "");
const char* BackendName(Backend backend);

// cos 81.4°. Below it a sample carries more geometric error than reflectance: a 1° error in the
// normal changes cos θ by tan θ · 1.7 % = 11 % of itself, and a pixel's footprint on the surface
// is stretched 1/cos θ = 6.7-fold, so it averages radiance over several texels. The seed paper's
// samples near grazing were its least reliable; 0.15 keeps 81° of the 90° range.
constexpr double kDefaultMinCos = 0.15;
// Texels per chunk file: 16384 texels of ~50 samples are ~40 MB, a convenient unit to read,
// fit and free; a 1,000,000-texel atlas makes 62 files.
constexpr uint32_t kDefaultChunkTexels = 16384;
// How often a checkpointed resample saves its state: a killed run loses at most this much work;
// each checkpoint costs a sync of the spill files and ~35 bytes per texel of coverage state
// (35 MB at a million texels, well under a second).
constexpr double kDefaultCheckpointSeconds = 30;
// Memory budget of the reorder buffers (all chunks together) before they spill to disk.
constexpr size_t kDefaultSpillBufferBytes = size_t(128) << 20;
// Noise model of a capture that records none (no ground_truth.noise; see NoiseModel): photon
// noise of 1 % at pixel value 1 and read noise of 1e-3, i.e. a photon-dominated sensor whose
// well-exposed pixels are ~0.1-1, and a dark floor of 3e-3 (kDarkSigmas read sigmas). Override
// with --noise-sigma / --read-sigma.
constexpr double kDefaultPhotonSigma = 0.01;
constexpr double kDefaultReadSigma = 1e-3;
// coverage.png: grey = 255 · log2(1 + n) / log2(1 + kCoveragePngFullScale) for n >= 1 samples
// (1 -> 32, 20 -> 140, >= 255 -> 255); texels with no sample are dark red (160, 0, 0); pixels
// that are not texels are black.
constexpr double kCoveragePngFullScale = 255;

// ResampleOptions::read_ahead: chosen from the backend.
constexpr int kAutoReadAhead = 0;
// Largest ResampleOptions::read_ahead (each photograph ahead is held decoded in memory).
constexpr int kMaxReadAhead = 16;

struct ResampleOptions {
  // Atlas resolution R (R x R) of a mesh capture; 0 = the capture's ground_truth.atlas size when
  // it has one (synthetic captures), else kDefaultAtlasResolution (512). Range [0, 16384].
  // Normal-map captures ignore it (their texels are the camera's masked pixels).
  int atlas_resolution = 0;
  SplitSelection split = SplitSelection::kTrain;
  // Both n·l and n·v (shading normal) must exceed it. Range [0, 1).
  double min_cos = kDefaultMinCos;
  // kCpu: Embree rays (image_resampler.h). kVulkan: the Vulkan masks (vulkan_masks.h) for mesh
  // captures; a normal-map capture casts no ray, so it runs the CPU path under either backend.
  Backend backend = Backend::kCpu;
  // Vulkan device for kVulkan: "" = automatic, an index, or a piece of its name.
  std::string device;
  // kVulkan only: also run the Embree tests on every photograph and write `mask_agreement`
  // (mask_agreement.h) into the report; the store holds the Vulkan path's samples.
  bool cross_check = false;
  // Noise model overrides, each in [0, 1]; unset = from the capture's ground_truth.noise, else
  // kDefaultPhotonSigma / kDefaultReadSigma.
  std::optional<double> photon_sigma;
  std::optional<double> read_sigma;
  // Weight the samples of a photograph with a variance image (images[].variance) by that
  // variance; false: the noise model weights every photograph and no variance image is read.
  // Off by default: on the merged suzanne brackets the fit's residuals are model error, not
  // noise, and the measured variance (which down-weights the highlights) lost up to 0.5 dB of
  // holdout PSNR against the noise model (README, "Per-pixel variance").
  bool use_variance = false;
  // Normal-map captures: integrate the normal map into a height field (engine/mesh/height_field.h)
  // and reject, as `shadowed`, the samples whose texel lies in its cast shadow under the
  // photograph's light. false (--no-height-shadows): no shadow test, as before the height field
  // (every texel counts as unshadowed). Needs an orthographic camera; with a pinhole one the test
  // is skipped with a warning and the report says why. Mesh captures ignore it.
  bool height_shadows = true;
  // Mesh captures: where each texel's sample is measured (image_resampler.h SamplePoint): the
  // pixel whose hit is nearest the texel, with that hit's geometry (kPixel, `--sample-point
  // pixel`, the default), or the bilinear interpolation at the texel centre (kTexel).
  SamplePoint sample_point = SamplePoint::kPixel;
  // What the photographs' pixels measure (engine/camera/camera.h PixelFilter), for kPixel's
  // choice when no tap's hit lies in the texel: nullopt (`--pixel-filter capture`, the default)
  // = each camera's cameras[].pixel_filter, else this for every camera.
  std::optional<PixelFilter> pixel_filter;
  uint32_t chunk_texels = kDefaultChunkTexels;  // >= 1
  // Checkpoints (`resample --resume`). When not empty, the reorder's spill files live in this
  // folder (the CLI uses OUT.checkpoint beside OUT) and, every checkpoint_seconds of work (0:
  // after every photograph), the run's state is made durable there: the spill files synced, the
  // per-texel coverage and the counters written, then checkpoint.json naming how many
  // photographs they hold. With `resume`, a run continues from the last checkpoint (the spill
  // files cut back to it) when the folder is of the same capture and options, and its store is
  // bit-identical to an uninterrupted run's; without `resume` an existing folder is refused
  // (`resume` without a folder does nothing). Not
  // with cross_check (its agreement statistics are not checkpointed): no checkpoints then.
  std::filesystem::path checkpoint_dir;
  // Shard `shard.index` of `shard.count` (`--shard I/N`): only the photographs of a contiguous
  // range of views (camera x turntable poses, in the order the run processes them), written as a
  // part (a store of their samples, coverage.bin, resample_part.json) for MergeResampleParts.
  // Not with cross_check.
  Shard shard;
  bool resume = false;
  double checkpoint_seconds = kDefaultCheckpointSeconds;
  size_t spill_buffer_bytes = kDefaultSpillBufferBytes;
  int threads = 0;  // 0 = all cores
  // Photographs decoded ahead of the one being resampled, on their own threads, and whether each
  // one's samples are streamed to the store while the next is resampled: kAutoReadAhead = half the
  // host's threads (3 to 8) and streaming alongside when the masks run on a GPU (the host's cores
  // are then mostly idle), else 1 and in turn (Embree, or lavapipe, keeps every core busy:
  // overlapping there made the million preset 30 -> 35 s on 2 cores). The store is the same byte
  // for byte either way.
  int read_ahead = kAutoReadAhead;

  Status Validate() const;  // InvalidArgument naming the option
};

// What a run did (also written as resample_report.json).
struct ResampleSummary {
  uint64_t texels = 0;
  uint64_t texels_seen = 0;
  uint64_t texels_with_samples = 0;
  uint64_t images = 0;
  uint64_t samples_kept = 0;
  uint64_t samples_rejected = 0;
  double seconds = 0;
  std::string report_json;  // the report's text
  std::string text;         // a few lines for people: counts, reasons, coverage, where the files are
};

// Resamples the capture at `capture_path` (capture.json or its folder) into `out_dir`, which
// must exist (the caller stages it: nothing is written anywhere else). Errors: those of
// ReadCapture/ValidateCaptureFiles and of reading images and variance images (naming
// capture.json and the field: a missing file, a wrong size, a NaN, Inf or negative variance),
// Unavailable for Backend::kVulkan without a usable Vulkan device, InvalidArgument for bad
// options.
StatusOr<ResampleSummary> ResampleCapture(const std::filesystem::path& capture_path,
                                          const ResampleOptions& options,
                                          const std::filesystem::path& out_dir);
// The same for a capture already read and checked with ReadCapture and ValidateCaptureFiles;
// `mesh`, when given, is the capture's mesh as ValidateCaptureFiles loaded it (else it is
// loaded again).
StatusOr<ResampleSummary> ResampleCapture(const Capture& capture, const ResampleOptions& options,
                                          const std::filesystem::path& out_dir,
                                          const TriangleMesh* mesh = nullptr);

// The photographs a run takes from `capture` for `split`, in the order it takes them: grouped by
// view (camera, turntable angle; view ids in order of first appearance), ascending image index
// within a view; `views` views in all. A normal-map capture takes only its camera's photographs
// (`skipped`: the others).
struct ImageOrder {
  std::vector<std::pair<int, uint32_t>> order;  // (view, image index)
  uint32_t views = 0;
  size_t skipped = 0;
};
ImageOrder OrderImages(const Capture& capture, SplitSelection split);
// Which of the capture's images the run of `options` reads (one flag per image): all of them
// without a shard; a shard's views' photographs with one. InvalidArgument for a shard beyond
// the views.
StatusOr<std::vector<bool>> ImagesOfShard(const Capture& capture, const ResampleOptions& options);

// `reflcap merge` of resample parts: checks that `parts` are the shards 0..N-1 of one resample
// (the same capture bytes, options, atlas and photographs; each shard once; their views tiling
// the run's), then writes into `out_dir` (which must exist: the caller stages it) the store,
// maps and report one run writes: every chunk's texels take the parts' samples in shard order,
// so chunks, store.json, atlas.bin and the maps are bit-identical to a single run's (the report
// differs in timings and says `shards`). `threads` chunks are joined at a time (0 = all cores).
// With `link` (`merge --link`), no chunk is written: the store is a linked one
// (sample_store.h) whose store.json names the parts (absolute paths, with their fingerprints)
// and whose readers join each chunk as they read it: the same samples as the joined store's,
// without reading and writing them all once more; the parts must then stay where they are.
// FailedPrecondition naming the part and field for parts
// that do not belong together; NotFound/DataLoss naming a missing or corrupt file.
StatusOr<ResampleSummary> MergeResampleParts(const std::vector<std::filesystem::path>& parts,
                                             const std::filesystem::path& out_dir, int threads = 0,
                                             bool link = false);

}  // namespace reflcap::resample
