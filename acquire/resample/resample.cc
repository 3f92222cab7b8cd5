// ResampleCapture: capture -> sample store, report and coverage maps (see resample.h).
#include "acquire/resample/resample.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <deque>
#include <future>
#include <map>
#include <memory>
#include <numeric>
#include <sstream>

#include <nlohmann/json.hpp>

#include "acquire/resample/chunk_writer.h"
#include "acquire/resample/coverage.h"
#include "acquire/resample/image_resampler.h"
#include "acquire/resample/mask_agreement.h"
#include "acquire/resample/resample_outputs.h"
#include "acquire/resample/vulkan_masks.h"
#include "engine/core/atomic_file.h"
#include "engine/core/log.h"
#include "engine/core/parallel.h"
#include "engine/core/progress.h"
#include "engine/core/shard.h"
#include "engine/image/exr_io.h"
#include "engine/image/image_io.h"
#include "engine/image/png_io.h"
#include "engine/mesh/height_field.h"
#include "engine/mesh/mesh_io.h"
#include "engine/mesh/ray_scene.h"
#include "engine/mesh/texel_atlas.h"
#include "engine/texel/sample_store.h"

namespace reflcap::resample {
namespace fs = std::filesystem;
using Json = nlohmann::json;

namespace {

using Clock = std::chrono::steady_clock;
double Seconds(Clock::time_point since) {
  return std::chrono::duration<double>(Clock::now() - since).count();
}

// Largest atlas side accepted (as `reflcap info`): 16384² texel slots.
constexpr int kMaxAtlasResolution = 16384;
struct NoiseChoice {
  NoiseModel model;
  double saturation = 0;  // ground_truth.noise.saturation, 0 when absent
};

StatusOr<NoiseChoice> ChooseNoiseModel(const Capture& capture, const ResampleOptions& options) {
  NoiseChoice choice;
  NoiseModel& m = choice.model;
  m.photon_sigma_at_1 = kDefaultPhotonSigma;
  m.read_sigma = kDefaultReadSigma;
  m.source = "default (the capture records no noise model)";
  if (!capture.ground_truth_json.empty()) {
    const Json truth = Json::parse(capture.ground_truth_json, nullptr, false);
    if (truth.is_object() && truth.contains("noise") && truth["noise"].is_object()) {
      const Json& noise = truth["noise"];
      auto number = [&](const char* key, double* out) -> Status {
        if (!noise.contains(key)) return OkStatus();
        if (!noise[key].is_number() || !(noise[key].get<double>() >= 0) ||
            !std::isfinite(noise[key].get<double>())) {
          return InvalidArgumentError(capture.json_path.string(), ": ground_truth.noise.", key,
                                      ": must be a finite number >= 0");
        }
        *out = noise[key].get<double>();
        return OkStatus();
      };
      if (noise.contains("photon_sigma_at_1") || noise.contains("read_sigma")) {
        REFLCAP_RETURN_IF_ERROR(number("photon_sigma_at_1", &m.photon_sigma_at_1));
        REFLCAP_RETURN_IF_ERROR(number("read_sigma", &m.read_sigma));
        m.source = "capture ground_truth.noise";
      }
      REFLCAP_RETURN_IF_ERROR(number("saturation", &choice.saturation));
    }
  }
  if (options.photon_sigma || options.read_sigma) {
    if (options.photon_sigma) m.photon_sigma_at_1 = *options.photon_sigma;
    if (options.read_sigma) m.read_sigma = *options.read_sigma;
    m.source = "command line (--noise-sigma / --read-sigma), rest " + m.source;
  }
  return choice;
}

// The atlas size of a mesh capture (see ResampleOptions::atlas_resolution).
void AtlasSize(const Capture& capture, int requested, int* width, int* height, std::string* why) {
  if (requested > 0) {
    *width = *height = requested;
    *why = "--atlas-res";
    return;
  }
  if (!capture.ground_truth_json.empty()) {
    const Json truth = Json::parse(capture.ground_truth_json, nullptr, false);
    if (truth.is_object() && truth.contains("atlas") && truth["atlas"].is_object()) {
      const Json& a = truth["atlas"];
      if (a.contains("width") && a["width"].is_number_integer()) {
        const int w = a["width"].get<int>();
        const int h = a.contains("height") && a["height"].is_number_integer() ? a["height"].get<int>() : w;
        if (w >= 1 && h >= 1 && w <= kMaxAtlasResolution && h <= kMaxAtlasResolution) {
          *width = w;
          *height = h;
          *why = "capture ground_truth.atlas";
          return;
        }
      }
    }
  }
  *width = *height = kDefaultAtlasResolution;
  *why = "default";
}

bool Selected(const CaptureImage& image, SplitSelection split) {
  switch (split) {
    case SplitSelection::kTrain: return image.split == Split::kTrain;
    case SplitSelection::kHoldout: return image.split == Split::kHoldout;
    case SplitSelection::kAll: return true;
  }
  return false;
}

// ---- Checkpoints (ResampleOptions::checkpoint_dir) --------------------------------------------
constexpr const char* kCheckpointFormat = "reflcap-resample-checkpoint/1";
constexpr const char* kCheckpointFile = "checkpoint.json";

// What a checkpoint must match to be continued: the capture's bytes, the options that change a
// sample, the atlas and the photographs' order.
Json CheckpointIdentity(const Capture& capture, const ResampleOptions& options,
                        const TexelAtlas& atlas, const NoiseChoice& noise,
                        const std::vector<std::pair<int, uint32_t>>& order) {
  const StatusOr<std::string> text = ReadTextFile(capture.json_path);
  const uint32_t capture_crc = text.ok() ? Crc32(text->data(), text->size()) : 0;
  std::vector<uint32_t> images;
  for (const auto& o : order) images.push_back(o.second);
  std::error_code ec;
  return Json{{"capture", fs::absolute(capture.json_path, ec).lexically_normal().string()},
              {"capture_crc32", capture_crc},
              {"split", SplitSelectionName(options.split)},
              {"min_cos", options.min_cos},
              {"atlas", {atlas.width, atlas.height, atlas.TexelCount()}},
              {"chunk_texels", options.chunk_texels},
              {"backend", BackendName(options.backend)},
              {"noise", {noise.model.photon_sigma_at_1, noise.model.read_sigma, noise.saturation}},
              {"variance_weights", options.use_variance},
              {"height_shadows", options.height_shadows},
              {"sample_point", SamplePointName(options.sample_point)},
              {"pixel_filter", options.pixel_filter ? PixelFilterName(*options.pixel_filter)
                                                    : "capture"},
              {"images", images.size()},
              {"images_crc32", Crc32(images.data(), images.size() * sizeof(uint32_t))}};
}

// resample_report.json pixel_filter: per camera, what its pixels were taken to measure.
Json PixelFilterReport(const Capture& capture, const ResampleOptions& options, bool normal_map) {
  Json cameras = Json::object();
  for (const Camera& cam : capture.cameras) {
    cameras[cam.id] = PixelFilterName(options.pixel_filter.value_or(cam.pixel_filter));
  }
  return {{"source", options.pixel_filter ? "--pixel-filter" : "capture cameras[].pixel_filter"},
          {"cameras", cameras},
          {"used", !normal_map && options.sample_point == SamplePoint::kPixel},
          {"definition", "area: a pixel integrates its footprint, so a texel whose four pixels "
                         "all hit other texels takes the one hitting nearest its centre; point: "
                         "a pixel is the ray through its centre, so such a pair is rejected "
                         "(edge_other_texel) when the texel spans >= 0.5 px in the view, else "
                         "takes the nearest too"}};
}

}  // namespace

ImageOrder OrderImages(const Capture& capture, SplitSelection split) {
  ImageOrder out;
  std::map<std::pair<int, double>, int> view_ids;
  for (size_t i = 0; i < capture.images.size(); ++i) {
    const CaptureImage& image = capture.images[i];
    if (!Selected(image, split)) continue;
    if (capture.normal_map.has_value() && image.camera != capture.normal_map->camera) {
      ++out.skipped;
      continue;
    }
    auto [it, inserted] = view_ids.try_emplace({image.camera, image.turntable_deg}, int(view_ids.size()));
    out.order.push_back({it->second, uint32_t(i)});
  }
  std::stable_sort(out.order.begin(), out.order.end(),
                   [](const auto& a, const auto& b) { return a.first < b.first; });
  out.views = uint32_t(view_ids.size());
  return out;
}

StatusOr<std::vector<bool>> ImagesOfShard(const Capture& capture, const ResampleOptions& options) {
  const ImageOrder ordered = OrderImages(capture, options.split);
  std::vector<bool> take(capture.images.size(), options.shard.count <= 1);
  if (options.shard.count <= 1) return take;
  REFLCAP_ASSIGN_OR_RETURN(ItemRange views, ShardRange(options.shard, ordered.views,
                                                       "views (camera x turntable poses)"));
  for (const auto& [view, image] : ordered.order) {
    if (uint32_t(view) >= views.begin && uint32_t(view) < views.end) take[image] = true;
  }
  return take;
}

StatusOr<Backend> ParseBackend(const std::string& name) {
  if (name == "cpu") return Backend::kCpu;
  if (name == "vulkan") return Backend::kVulkan;
  return InvalidArgumentError("--backend: \"", name, "\" is not a backend (cpu, vulkan)");
}

StatusOr<SplitSelection> ParseSplit(const std::string& name) {
  if (name == "train") return SplitSelection::kTrain;
  if (name == "holdout") return SplitSelection::kHoldout;
  if (name == "all") return SplitSelection::kAll;
  return InvalidArgumentError("--split: \"", name, "\" is not a split (train, holdout, all)");
}

const char* SplitSelectionName(SplitSelection split) {
  switch (split) {
    case SplitSelection::kTrain: return "train";
    case SplitSelection::kHoldout: return "holdout";
    case SplitSelection::kAll: return "all";
  }
  return "?";
}

Status BackendAvailable(Backend backend, const std::string& device) {
  if (backend == Backend::kVulkan) return VulkanMasksAvailable(device);
  return OkStatus();
}

const char* BackendName(Backend backend) {
  return backend == Backend::kVulkan ? "vulkan" : "cpu";
}

Status ResampleOptions::Validate() const {
  if (read_ahead < 0 || read_ahead > kMaxReadAhead) {
    return InvalidArgumentError("read_ahead: must be in [0, ", kMaxReadAhead, "] (0 = auto), got ",
                                read_ahead);
  }
  if (atlas_resolution < 0 || atlas_resolution > kMaxAtlasResolution) {
    return InvalidArgumentError("--atlas-res: must be in [1, ", kMaxAtlasResolution, "], got ",
                                atlas_resolution);
  }
  if (!(min_cos >= 0 && min_cos < 1)) {
    return InvalidArgumentError("--min-cos: must be in [0, 1), got ", min_cos);
  }
  if (photon_sigma && !(*photon_sigma >= 0 && *photon_sigma <= 1)) {
    return InvalidArgumentError("--noise-sigma: must be in [0, 1], got ", *photon_sigma);
  }
  if (read_sigma && !(*read_sigma >= 0 && *read_sigma <= 1)) {
    return InvalidArgumentError("--read-sigma: must be in [0, 1], got ", *read_sigma);
  }
  if (chunk_texels == 0) return InvalidArgumentError("chunk_texels must be >= 1");
  if (threads < 0) return InvalidArgumentError("threads must be >= 0");
  if (!(checkpoint_seconds >= 0) || !std::isfinite(checkpoint_seconds)) {
    return InvalidArgumentError("--checkpoint-seconds: must be >= 0, got ", checkpoint_seconds);
  }
  if (shard.count > 1 && cross_check) {
    return InvalidArgumentError("--cross-check and --shard exclude each other (the agreement "
                                "statistics are not merged)");
  }
  if (cross_check && backend != Backend::kVulkan) {
    return InvalidArgumentError("--cross-check compares the Vulkan masks with Embree: it needs "
                                "--backend vulkan");
  }
  return OkStatus();
}

StatusOr<ResampleSummary> ResampleCapture(const fs::path& capture_path,
                                          const ResampleOptions& options, const fs::path& out_dir) {
  REFLCAP_RETURN_IF_ERROR(options.Validate());
  REFLCAP_RETURN_IF_ERROR(BackendAvailable(options.backend, options.device));
  REFLCAP_ASSIGN_OR_RETURN(Capture capture, ReadCapture(capture_path));
  CaptureFilesReport files;
  REFLCAP_RETURN_IF_ERROR(ValidateCaptureFiles(capture, &files));
  return ResampleCapture(capture, options, out_dir, files.mesh.get());
}

StatusOr<ResampleSummary> ResampleCapture(const Capture& original, const ResampleOptions& options,
                                          const fs::path& out_dir, const TriangleMesh* given_mesh) {
  const auto start = Clock::now();
  REFLCAP_RETURN_IF_ERROR(options.Validate());
  const std::string file = original.json_path.string();
  REFLCAP_ASSIGN_OR_RETURN(NoiseChoice noise, ChooseNoiseModel(original, options));
  // An image without its own saturation level clips at the capture's ground_truth.noise one.
  Capture capture = original;
  for (CaptureImage& image : capture.images) {
    if (image.saturation == 0) image.saturation = noise.saturation;
  }

  // ---- Images, grouped by view (camera, turntable angle) --------------------------------------
  ImageOrder ordered = OrderImages(capture, options.split);
  std::vector<std::pair<int, uint32_t>>& order = ordered.order;  // (view, image index)
  const size_t skipped = ordered.skipped;
  if (skipped > 0) {
    REFLCAP_LOG(kWarning) << skipped << " selected images are not from the normal map's camera "
                          << "and were skipped";
  }
  if (order.empty()) {
    return FailedPreconditionError(file, ": images: no image in split \"",
                                   SplitSelectionName(options.split), "\"",
                                   skipped ? " from the normal map's camera" : "");
  }
  // A shard keeps the photographs of its views (contiguous in `order`, which is grouped by view).
  const std::vector<std::pair<int, uint32_t>> all_order = order;
  const uint32_t views_total = ordered.views;
  const bool sharded = options.shard.count > 1;
  ItemRange view_range{0, views_total};
  if (sharded) {
    REFLCAP_ASSIGN_OR_RETURN(view_range,
                             ShardRange(options.shard, views_total, "views (camera x turntable poses)"));
    order.clear();
    for (const auto& o : all_order) {
      if (uint32_t(o.first) >= view_range.begin && uint32_t(o.first) < view_range.end) order.push_back(o);
    }
  }
  // A photograph and, when it has one and it is used, its variance image (read together).
  struct Photograph {
    StatusOr<Image> pixels = Image();
    std::optional<StatusOr<Image>> variance;
  };
  const bool use_variance = options.use_variance;
  // Seconds the reading threads spent reading and decoding, summed (this process's): against
  // read_wait_s it says whether the loop waited for slow decodes or for too few of them.
  auto read_thread_ns = std::make_shared<std::atomic<int64_t>>(0);
  auto read_image = [&capture, use_variance, read_thread_ns](uint32_t index) {
    return std::async(std::launch::async, [&capture, use_variance, index, read_thread_ns] {
      const auto start = Clock::now();
      Photograph photo;
      photo.pixels = ReadImageRgb(capture.Resolve(capture.images[index].file));
      if (photo.pixels.ok() && use_variance && !capture.images[index].variance.empty()) {
        photo.variance = ReadVarianceImage(capture, index);
      }
      *read_thread_ns += std::chrono::duration_cast<std::chrono::nanoseconds>(Clock::now() - start)
                             .count();
      return photo;
    });
  };
  // Photographs are read ahead of the one being resampled, on their own threads
  // (ResampleOptions::read_ahead; a GPU resamples a photograph faster than one thread decodes the
  // next: on an NVIDIA H100, one ahead, the loop waited 3.8 s of 14.1 s for decoding). The first
  // is read while the geometry is built (each shard pays that setup).
  std::deque<std::future<Photograph>> ahead;
  size_t next_read = 0;  // position in `order` of the next photograph to start reading
  auto start_reads = [&](size_t up_to) {
    for (; next_read < std::min(up_to, order.size()); ++next_read) {
      ahead.push_back(read_image(order[next_read].second));
    }
  };
  start_reads(1);

  // ---- Geometry -------------------------------------------------------------------------------
  TexelAtlas atlas;
  TriangleMesh loaded_mesh;              // when the caller gave none
  const TriangleMesh* mesh_data = given_mesh;
  std::unique_ptr<RayScene> scene;
  std::string atlas_source;
  const bool normal_map = capture.normal_map.has_value();
  std::unique_ptr<HeightField> height_field;  // normal-map captures with height_shadows
  std::string height_field_note;
  if (!normal_map) {
    if (mesh_data == nullptr) {
      auto mesh = LoadMesh(capture.Resolve(capture.mesh));
      if (!mesh.ok()) return Status(mesh.status().code(), StrCat(file, ": mesh: ", mesh.status().message()));
      loaded_mesh = std::move(*mesh);
      mesh_data = &loaded_mesh;
    }
    int w, h;
    AtlasSize(capture, options.atlas_resolution, &w, &h, &atlas_source);
    REFLCAP_ASSIGN_OR_RETURN(atlas, BuildTexelAtlas(*mesh_data, w, h));
    REFLCAP_ASSIGN_OR_RETURN(scene, RayScene::Create(*mesh_data));
  } else {
    if (options.atlas_resolution > 0) {
      REFLCAP_LOG(kWarning) << "--atlas-res is ignored: the texels of a normal-map capture are its "
                               "camera's masked pixels";
    }
    const NormalMapGeometry& g = *capture.normal_map;
    auto normals = ReadExrRgb(capture.Resolve(g.normals));
    if (!normals.ok()) {
      return Status(normals.status().code(), StrCat(file, ": normal_map.normals: ", normals.status().message()));
    }
    auto mask = ReadPng(capture.Resolve(g.mask));
    if (!mask.ok()) {
      return Status(mask.status().code(), StrCat(file, ": normal_map.mask: ", mask.status().message()));
    }
    auto built = BuildNormalMapAtlas(*normals, *mask);
    if (!built.ok()) {
      return Status(built.status().code(), StrCat(file, ": normal_map: ", built.status().message()));
    }
    atlas = std::move(*built);
    atlas_source = "normal map (the camera's masked pixels)";
    const Camera& camera = capture.cameras[g.camera];
    if (!options.height_shadows) {
      height_field_note = "off (--no-height-shadows)";
    } else if (camera.model != CameraModel::kOrthographic) {
      height_field_note = StrCat("off: camera \"", camera.id, "\" is not orthographic");
      REFLCAP_LOG(kWarning) << file << ": normal_map: " << height_field_note
                            << "; no cast-shadow test";
    } else {
      auto integrated = IntegrateNormalMap(atlas, camera);
      if (!integrated.ok()) {
        return Status(integrated.status().code(),
                      StrCat(file, ": normal_map: ", integrated.status().message()));
      }
      height_field = std::make_unique<HeightField>(std::move(*integrated));
      height_field_note = "on";
      REFLCAP_LOG(kInfo) << "height field: " << height_field->stats.ToString();
      if (height_field->stats.backfacing > 0) {
        REFLCAP_LOG(kWarning) << file << ": normal_map.normals: "
                              << height_field->stats.backfacing
                              << " normals face away from the camera; integrated as the steepest "
                                 "slope along their image-plane direction";
      }
    }
  }
  const size_t texels = atlas.TexelCount();
  if (texels == 0) return FailedPreconditionError(file, ": the atlas has no texels");
  if (texels > std::numeric_limits<uint32_t>::max()) {
    return FailedPreconditionError(file, ": ", texels, " texels exceed the sample store's 2^32");
  }
  REFLCAP_ASSIGN_OR_RETURN(std::unique_ptr<ImageResampler> resampler,
                           ImageResampler::Create(capture, atlas, scene.get(), noise.model,
                                                  options.min_cos, options.threads));
  REFLCAP_RETURN_IF_ERROR(resampler->SetHeightField(height_field.get()));
  resampler->SetSamplePoint(options.sample_point);
  resampler->SetPixelFilter(options.pixel_filter);
  // The Vulkan masks replace the Embree path for mesh captures (a normal-map capture casts no
  // ray: it runs the CPU path under either backend).
  std::unique_ptr<VulkanMasks> masks;
  std::string device = "cpu";
  if (options.backend == Backend::kVulkan && !normal_map) {
    VulkanMaskOptions mo;
    mo.device = options.device;
    mo.sample_point = options.sample_point;
    mo.pixel_filter = options.pixel_filter;
    REFLCAP_ASSIGN_OR_RETURN(masks, VulkanMasks::Create(capture, atlas, *mesh_data,
                                                        scene->SurfaceOffset(), noise.model,
                                                        options.min_cos, mo));
    device = masks->device_name();
  } else if (options.backend == Backend::kVulkan) {
    REFLCAP_LOG(kWarning) << "--backend vulkan: a normal-map capture casts no ray (visibility is "
                             "given; cast shadows come from its height field); resampling it on "
                             "the CPU";
  }
  const bool gpu_masks = masks != nullptr && !masks->software_device();
  // On a GPU the loop waits for decoding unless enough photographs decode at once: an H200 host
  // (16 threads) decodes a million-preset photograph (2048^2 float EXR) in 77 ms on one thread
  // (BM_ReadPhotograph) while the device resamples one in ~12 ms, so about seven must be in
  // flight; with eight ahead the million preset's resample waited 0.08 s of 3.96 s. Half the
  // host's threads ahead (the other half streams, tallies and feeds the device), at least 3, at
  // most 8: each one ahead holds a decoded photograph (50 MB at 2048^2).
  const size_t gpu_depth =
      std::clamp<size_t>(size_t(HardwareThreads()) / 2, 3, 8);
  const size_t read_depth = options.read_ahead != kAutoReadAhead ? size_t(options.read_ahead)
                            : gpu_masks                          ? gpu_depth
                                                                 : 1;
  const bool stream_alongside = read_depth > 1;
  const bool cross_check = options.cross_check && masks != nullptr;
  MaskAgreement agreement;
  double cross_check_s = 0;
  VulkanMaskStats mask_stats;

  const double setup_s = Seconds(start);

  // ---- Checkpoint: start one, or continue from one ----------------------------------------------
  const bool checkpointing = !options.checkpoint_dir.empty() && !cross_check;
  if (!options.checkpoint_dir.empty() && cross_check) {
    REFLCAP_LOG(kWarning) << "--cross-check: no checkpoints (the agreement statistics are not "
                             "checkpointed); a killed run starts over";
  }
  const fs::path checkpoint_dir = options.checkpoint_dir;
  const fs::path spill_dir = checkpointing ? checkpoint_dir / "spill" : out_dir / ".spill";
  // What this run is of: the same for every shard of a run (the merge compares them); a
  // checkpoint also names its shard.
  const Json identity = CheckpointIdentity(capture, options, atlas, noise, all_order);
  Json checkpoint_identity = identity;
  checkpoint_identity["shard"] = {options.shard.index, options.shard.count};
  std::optional<Json> resume_state;
  if (checkpointing) {
    std::error_code ec;
    if (fs::exists(checkpoint_dir, ec)) {
      if (!options.resume) {
        return FailedPreconditionError(
            checkpoint_dir.string(), ": holds the state of an interrupted resample to this output "
                                     "(pass --resume to continue it, or delete the folder to start "
                                     "over)");
      }
      const fs::path state_file = checkpoint_dir / kCheckpointFile;
      if (fs::exists(state_file, ec)) {
        REFLCAP_ASSIGN_OR_RETURN(std::string text, ReadTextFile(state_file));
        Json state = Json::parse(text, nullptr, false);
        if (!state.is_object() || state.value("format", "") != kCheckpointFormat ||
            !state.contains("identity")) {
          return DataLossError(state_file.string(), ": not a resample checkpoint");
        }
        const std::string differs = FirstDifference(checkpoint_identity, state["identity"]);
        if (!differs.empty()) {
          return FailedPreconditionError(state_file.string(), ": identity.", differs,
                                         " differs from this run: the checkpoint belongs to another "
                                         "resample (delete ", checkpoint_dir.string(),
                                         " to start over)");
        }
        resume_state = std::move(state);
      } else {
        // Killed before its first checkpoint: nothing to keep.
        fs::remove_all(spill_dir, ec);
      }
    } else if (options.resume) {
      REFLCAP_LOG(kWarning) << "resample: --resume: no checkpoint at " << checkpoint_dir.string()
                            << "; resampling from the start";
    }
    fs::create_directories(checkpoint_dir, ec);
    if (ec) return InternalError(checkpoint_dir.string(), ": cannot create folder: ", ec.message());
  }
  // A run that fails before its first checkpoint leaves no folder behind (the CLI removes it
  // after a successful run).
  std::optional<CheckpointCleanup> cleanup;
  if (checkpointing) cleanup.emplace(checkpoint_dir, kCheckpointFile);

  // ---- Resample, streaming into chunks ------------------------------------------------------
  REFLCAP_ASSIGN_OR_RETURN(std::unique_ptr<ChunkedSampleWriter> writer,
                           ChunkedSampleWriter::Create(spill_dir, uint32_t(texels),
                                                       options.chunk_texels,
                                                       options.spill_buffer_bytes));
  if (checkpointing) writer->KeepSpillOnError();
  TexelCoverage coverage(texels);
  Tally tally;
  size_t first_image = 0;
  std::string last_coverage_file;
  if (resume_state) {
    const Json& state = *resume_state;
    const fs::path state_file = checkpoint_dir / kCheckpointFile;
    if (!state.contains("images_done") || !state["images_done"].is_number_unsigned() ||
        !state.contains("spill_records") || !state.contains("coverage_file") ||
        !state["coverage_file"].is_string() || !state.contains("tally") ||
        !tally.FromJson(state["tally"])) {
      return DataLossError(state_file.string(), ": images_done/spill_records/coverage_file/tally: "
                                                "missing or malformed");
    }
    first_image = state["images_done"].get<size_t>();
    std::vector<uint64_t> records;
    try {
      records = state["spill_records"].get<std::vector<uint64_t>>();
    } catch (const Json::exception&) {
      return DataLossError(state_file.string(), ": spill_records: expected a list of counts");
    }
    if (first_image == 0 || first_image >= order.size() || records.size() != writer->chunks()) {
      return DataLossError(state_file.string(), ": images_done ", first_image, " / spill_records ",
                           records.size(), " do not fit this run (", order.size(), " images, ",
                           writer->chunks(), " chunks)");
    }
    last_coverage_file = state["coverage_file"].get<std::string>();
    REFLCAP_ASSIGN_OR_RETURN(coverage, TexelCoverage::Load(checkpoint_dir / last_coverage_file, texels));
    std::vector<uint32_t> counts(texels);
    for (size_t t = 0; t < texels; ++t) counts[t] = coverage.samples(t);
    REFLCAP_RETURN_IF_ERROR(writer->Restore(records, std::move(counts)));
    REFLCAP_LOG(kInfo) << "resample: resumed after " << first_image << " of " << order.size()
                       << " photographs from " << checkpoint_dir.string();
  }
  // Makes the state after `images_done` photographs durable in the checkpoint folder: spill
  // files synced, coverage written under a new name, then checkpoint.json (atomically) naming
  // both; the previous coverage file goes last, so a kill at any point leaves one consistent
  // checkpoint.
  auto checkpoint = [&](size_t images_done) -> Status {
    REFLCAP_ASSIGN_OR_RETURN(std::vector<uint64_t> records, writer->FlushAll());
    const std::string coverage_file = StrCat("coverage_", images_done, ".bin");
    REFLCAP_RETURN_IF_ERROR(coverage.Save(checkpoint_dir / coverage_file));
    const Json state = {{"format", kCheckpointFormat},
                        {"identity", checkpoint_identity},
                        {"images_done", images_done},
                        {"spill_records", records},
                        {"coverage_file", coverage_file},
                        {"tally", tally.ToJson()}};
    REFLCAP_RETURN_IF_ERROR(
        WriteTextFileAtomic(checkpoint_dir / kCheckpointFile, state.dump(1) + "\n"));
    if (!last_coverage_file.empty() && last_coverage_file != coverage_file) {
      std::error_code ec;
      fs::remove(checkpoint_dir / last_coverage_file, ec);
    }
    last_coverage_file = coverage_file;
    return OkStatus();
  };
  tally.ignored_variance_images = 0;  // selected photographs whose variance is not used
  if (!options.use_variance) {
    for (const auto& entry : order) {
      tally.ignored_variance_images += !capture.images[entry.second].variance.empty();
    }
  }
  auto last_checkpoint = Clock::now();
  std::array<uint64_t, kOutcomeCount>& outcome_counts = tally.outcome_counts;
  uint64_t& primary_rays = tally.primary_rays;
  uint64_t& tap_shadow_rays = tally.tap_shadow_rays;
  uint64_t& visibility_rays = tally.visibility_rays;
  uint64_t& shadow_rays = tally.shadow_rays;
  uint64_t& variance_images = tally.variance_images;  // photographs weighted by images[].variance
  double& read_wait_s = tally.read_wait_s;
  double& resample_s = tally.resample_s;
  double& stream_s = tally.stream_s;
  Progress progress("resample", int64_t(order.size()));
  if (first_image > 0) {
    progress.Advance(int64_t(first_image));
    // The prefetched first photograph is not needed: read where the run resumes.
    for (auto& f : ahead) f.wait();
    ahead.clear();
    next_read = first_image;
  }
  // Each photograph's outcomes and samples are tallied and streamed to the store (in order) on
  // their own thread while the next photograph is resampled: two outputs, used in turn; the
  // stream of photograph k is waited for before photograph k + 1's is started, and before a
  // checkpoint (which reads the writer, the coverage and the tally).
  ImageOutput outputs[2], embree_output;
  CameraMapView camera_map;
  std::future<Status> streaming;
  auto stream_done = [&]() -> Status {
    return streaming.valid() ? streaming.get() : OkStatus();
  };
  for (size_t k = first_image; k < order.size(); ++k) {
    const uint32_t index = order[k].second;
    ImageOutput& output = outputs[k % 2];
    start_reads(k + 1 + read_depth);
    auto t0 = Clock::now();
    Photograph photo = ahead.front().get();
    ahead.pop_front();
    read_wait_s += Seconds(t0);
    const StatusOr<Image>& pixels = photo.pixels;
    if (!pixels.ok()) {
      return Status(pixels.status().code(),
                    StrCat(file, ": images[", index, "].file: ", pixels.status().message()));
    }
    // ReadVarianceImage's errors already name capture.json and images[i].variance.
    if (photo.variance && !photo.variance->ok()) return photo.variance->status();
    const Image* variance = photo.variance ? &photo.variance->value() : nullptr;
    variance_images += variance != nullptr;
    t0 = Clock::now();
    if (masks != nullptr) {
      REFLCAP_RETURN_IF_ERROR(masks->Process(index, *pixels, &output,
                                             cross_check ? &camera_map : nullptr, variance));
      tally.gpu_s += masks->last_stats().gpu_seconds;
      mask_stats = masks->last_stats();
    } else {
      REFLCAP_RETURN_IF_ERROR(resampler->Process(index, *pixels, &output, variance));
    }
    resample_s += Seconds(t0);
    if (cross_check) {
      t0 = Clock::now();
      REFLCAP_RETURN_IF_ERROR(resampler->Process(index, *pixels, &embree_output, variance));
      agreement.Add(atlas.position, embree_output.outcome, output.outcome, embree_output.kept,
                    output.kept, camera_map);
      cross_check_s += Seconds(t0);
    }
    REFLCAP_RETURN_IF_ERROR(stream_done());  // photograph k - 1's, which used the other output
    const int view = order[k].first;
    const ImageOutput* done = &output;
    streaming = std::async(stream_alongside ? std::launch::async : std::launch::deferred,
                           [&, view, done]() -> Status {
      const auto start = Clock::now();
      for (uint8_t o : done->outcome) ++outcome_counts[o];
      primary_rays += done->primary_rays;
      tap_shadow_rays += done->tap_shadow_rays;
      visibility_rays += done->visibility_rays;
      shadow_rays += done->shadow_rays;
      coverage.AddImage(done->outcome, done->kept, view, options.threads);
      const Status appended = writer->Append(done->kept.data(), done->kept.size());
      stream_s += Seconds(start);
      return appended;
    });
    if (!stream_alongside) REFLCAP_RETURN_IF_ERROR(stream_done());  // in turn
    progress.Advance();
    if (checkpointing && k + 1 < order.size() &&
        Seconds(last_checkpoint) >= options.checkpoint_seconds) {
      REFLCAP_RETURN_IF_ERROR(stream_done());
      REFLCAP_RETURN_IF_ERROR(checkpoint(k + 1));
      last_checkpoint = Clock::now();
    }
  }
  REFLCAP_RETURN_IF_ERROR(stream_done());
  progress.Finish();
  outputs[0] = outputs[1] = ImageOutput();
  embree_output = ImageOutput();

  auto t0 = Clock::now();
  const uint64_t spilled_bytes = writer->spilled_bytes();
  REFLCAP_RETURN_IF_ERROR(writer->Finish(out_dir, options.threads));
  const double reorder_s = Seconds(t0);

  // ---- Store, maps, report ----------------------------------------------------------------------
  t0 = Clock::now();
  SampleStoreInfo info;
  info.texels = uint32_t(texels);
  info.chunk_texels = options.chunk_texels;
  info.chunks = writer->chunks();
  info.samples = writer->samples();
  info.atlas_width = atlas.width;
  info.atlas_height = atlas.height;
  info.pixel_of_texel = atlas.pixel_of_texel;
  std::error_code ec;
  const fs::path absolute_capture = fs::absolute(capture.json_path, ec);
  info.capture = (ec ? capture.json_path : absolute_capture.lexically_normal()).string();
  info.split = SplitSelectionName(options.split);
  info.min_cos = options.min_cos;
  info.images = uint32_t(order.size());
  info.geometry = normal_map ? "normal_map" : "mesh";
  REFLCAP_RETURN_IF_ERROR(WriteSampleStoreInfo(out_dir, info));

  const double total_s = Seconds(start);
  Json report = {
      {"format", "reflcap-resample-report/1"},
      {"capture", info.capture},
      {"backend", BackendName(masks != nullptr ? Backend::kVulkan : Backend::kCpu)},
      {"backend_requested", BackendName(options.backend)},
      {"device", device},
      {"split", info.split},
      {"geometry", info.geometry},
      {"sample_point", normal_map ? std::string("own pixel (a normal map's texel is one)")
                                  : std::string(SamplePointName(options.sample_point))},
      {"pixel_filter", PixelFilterReport(capture, options, normal_map)},
      {"visibility", normal_map && height_field != nullptr
                         ? "normal map: every texel is visible (an orthographic view sees each of "
                           "its pixels; no occlusion or footprint test); cast shadow from the "
                           "height field integrated from the normals: a march from the texel "
                           "towards the light that passes more than the bias below the field "
                           "rejects it as shadowed (see height_field)"
                     : normal_map
                         ? "not tested: a normal-map capture has no mesh, so every texel counts as "
                           "visible and unshadowed (no occlusion, shadow or footprint rays; height "
                           "field " + height_field_note + ")"
                     : masks != nullptr
                         ? "Vulkan depth maps: camera map (the mesh rasterised from the camera: "
                           "distance, hit, lit per pixel ray) and light map (cube, fitted frustum "
                           "or orthographic box), receiver-plane depth with a slope-scaled bias; "
                           "footprint: each bilinear tap's camera-map texel must be the texel's "
                           "lit surface"
                         : "Embree occlusion rays texel->camera and texel->light; footprint: the "
                           "camera ray through each bilinear tap must hit the texel's lit surface"},
      {"min_cos", options.min_cos},
      {"noise_model", {{"photon_sigma_at_1", noise.model.photon_sigma_at_1},
                       {"read_sigma", noise.model.read_sigma},
                       {"relative_sigma_floor", kRelativeSigmaFloor},
                       {"dark_floor", noise.model.DarkFloor()},
                       {"invalid_below", noise.model.InvalidFloor()},
                       {"source", noise.model.source}}},
      {"atlas", {{"width", atlas.width}, {"height", atlas.height}, {"source", atlas_source}}},
      {"images_skipped", skipped},
      {"read_ahead", read_depth},
      {"views", view_range.end - view_range.begin},
      {"timings", {{"setup_s", setup_s},
                   {"read_wait_s", read_wait_s},
                   {"read_thread_s", double(read_thread_ns->load()) * 1e-9},
                   {"resample_s", resample_s},
                   {"stream_s", stream_s},
                   {"reorder_s", reorder_s},
                   {"outputs_s", 0.0},
                   {"total_s", total_s},
                   {"texel_image_pairs_per_s",
                    resample_s > 0 ? double(texels) * double(order.size()) / resample_s : 0.0}}},
      {"store", {{"chunks", info.chunks},
                 {"chunk_texels", info.chunk_texels},
                 {"spilled_bytes", spilled_bytes}}},
      {"files", {{"coverage.exr", "samples per texel (Y), atlas layout"},
                 {"coverage.png", "log2(1 + samples) / log2(256) as grey (255 at >= 255 samples); "
                                  "dark red: texel without samples; black: no texel"},
                 {"domain.exr", "per texel: cells (distinct domain cells of 126), "
                                "min_half_angle_deg (90 without samples), observations (images "
                                "showing it lit), samples, seen (0/1), views (distinct camera x "
                                "turntable poses with a sample)"}}}};
  if (normal_map) {
    Json hf = {{"cast_shadows", height_field_note}};
    if (height_field != nullptr) {
      const HeightFieldStats& st = height_field->stats;
      hf["method"] =
          "least-squares integration of the gradients (-n_x/n_z, -n_y/n_z) over 4-neighbour texel "
          "pairs (sparse Cholesky), gradients clamped to max_slope; shadow: march along the "
          "light's image-plane direction, blocked where the bilinear field exceeds the ray by "
          "more than bias_px";
      hf["units"] = height_field->pixel_size_m > 0
                        ? StrCat("pixels (", height_field->pixel_size_m, " m each)")
                        : std::string("pixels");
      hf["texels"] = st.texels;
      hf["components"] = st.components;
      hf["equations"] = st.equations;
      hf["clamped_gradients"] = st.clamped;
      hf["backfacing_normals"] = st.backfacing;
      hf["max_slope"] = kMaxHeightFieldSlope;
      hf["residual_rms_px"] = st.rms_residual_px;
      hf["residual_max_px"] = st.max_residual_px;
      hf["height_range_px"] = {st.min_height_px, st.max_height_px};
      hf["bias_px"] = kHeightFieldShadowBiasPx;
      hf["max_march_steps"] = kMaxHeightFieldMarchSteps;
      hf["integrate_s"] = st.seconds;
      hf["limits"] =
          "least squares smooths across depth discontinuities (a step's shadow starts too close "
          "and is too short there); residual_* measure how far the normals are from integrable";
    }
    report["height_field"] = hf;
  }
  if (masks != nullptr) {
    report["vulkan"] = {{"light_map", mask_stats.light_map},
                        {"light_map_resolution", mask_stats.light_resolution},
                        {"camera_map", {mask_stats.map_width, mask_stats.map_height}},
                        {"gpu_s", tally.gpu_s},
                        {"note", "gpu_s: submit + fence wait of the per-photograph submissions "
                                 "(light map, camera map, per-texel tests); on lavapipe the "
                                 "'GPU' is the CPU"}};
  }
  if (cross_check) {
    const uint64_t disagreeing = agreement.disagreeing();
    report["mask_agreement"] = {
        {"pairs_compared", agreement.pairs},
        {"agreeing", agreement.agreeing},
        {"agreeing_fraction", agreement.AgreeingFraction()},
        {"disagreeing", disagreeing},
        {"disagreements",
         {{"visible_only_on_vulkan", agreement.visible_only_vulkan},
          {"visible_only_on_embree", agreement.visible_only_embree},
          {"lit_only_on_vulkan", agreement.lit_only_vulkan},
          {"lit_only_on_embree", agreement.lit_only_embree},
          {"footprint_ok_only_on_vulkan", agreement.footprint_only_vulkan},
          {"footprint_ok_only_on_embree", agreement.footprint_only_embree},
          {"other", agreement.other}}},
        {"near_edge", agreement.near_edge},
        {"near_edge_fraction",
         disagreeing ? double(agreement.near_edge) / double(disagreeing) : 1.0},
        {"kept_by_both", agreement.kept_both},
        {"max_value_relative_difference", agreement.max_value_rel_diff},
        {"max_weight_relative_difference", agreement.max_weight_rel_diff},
        {"max_direction_difference", agreement.max_direction_diff},
        {"kept_by_both_from_another_pixel", agreement.other_pixel},
        {"cross_check_s", cross_check_s},
        {"definition",
         StrCat("a (texel, image) pair agrees when Embree's rays and the Vulkan masks give it the "
                "same outcome; a disagreement is classed by the first mask that differs (visible, "
                "lit, footprint), 'other' when a grazing/projection test or a pixel test differs "
                "by float rounding; near_edge: a depth discontinuity (hit next to background, or "
                "a distance jump > ", kDepthJumpFootprints, " pixel footprints) or a shadow edge "
                "lies within ", kNearEdgePixels, " camera-map texels of the texel's projection")}};
  }
  REFLCAP_ASSIGN_OR_RETURN(Counted counted,
                           WriteCountedOutputs(out_dir, atlas, coverage, tally, order.size(),
                                               info.samples, &report, /*write_maps=*/!sharded));
  report["timings"]["outputs_s"] = Seconds(t0);
  report["timings"]["total_s"] = Seconds(start);
  if (sharded) {
    // The part: a store of this shard's photographs' samples, its coverage and what the merge
    // needs to sum (resample_merge.cc).
    REFLCAP_RETURN_IF_ERROR(coverage.Save(out_dir / kPartCoverageFile));
    const Json part = {{"format", kResamplePartFormat},
                       {"identity", identity},
                       {"shard", {{"index", options.shard.index}, {"count", options.shard.count}}},
                       {"views", {view_range.begin, view_range.end}},
                       {"views_total", views_total},
                       {"images_total", all_order.size()},
                       {"tally", tally.ToJson()},
                       {"report", report}};
    REFLCAP_RETURN_IF_ERROR(WriteTextFileAtomic(out_dir / kResamplePartFile, part.dump(1) + "\n"));
  }
  const std::string report_text = report.dump(2) + "\n";
  REFLCAP_RETURN_IF_ERROR(WriteTextFileAtomic(out_dir / "resample_report.json", report_text));

  ResampleSummary summary;
  summary.texels = texels;
  summary.texels_seen = counted.texels_seen;
  summary.texels_with_samples = counted.texels_with_samples;
  summary.images = order.size();
  summary.samples_kept = counted.kept;
  summary.samples_rejected = counted.rejected_total;
  summary.seconds = Seconds(start);
  summary.report_json = report_text;
  summary.text = SummaryText(report, summary.seconds);
  return summary;
}

}  // namespace reflcap::resample
