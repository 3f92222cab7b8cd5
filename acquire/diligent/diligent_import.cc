// DiLiGenT import (see diligent_import.h).
#include "acquire/diligent/diligent_import.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <sstream>

#include <nlohmann/json.hpp>

#include "engine/capture/capture.h"
#include "engine/core/atomic_file.h"
#include "engine/core/log.h"
#include "engine/core/parallel.h"
#include "engine/core/progress.h"
#include "engine/image/exr_io.h"
#include "engine/image/png_io.h"

namespace reflcap::diligent {
namespace fs = std::filesystem;
using Json = nlohmann::json;

namespace {

// Non-empty lines of a text file with their 1-based line numbers ('\r' stripped, so files with
// Windows line ends read the same). Blank lines are skipped.
StatusOr<std::vector<std::pair<int, std::string>>> ReadLines(const fs::path& path) {
  auto text = ReadTextFile(path);
  if (!text.ok()) return NotFoundError(path.string(), ": missing (a DiLiGenT object folder has it)");
  std::vector<std::pair<int, std::string>> lines;
  std::istringstream in(*text);
  std::string line;
  int number = 0;
  while (std::getline(in, line)) {
    ++number;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.find_first_not_of(" \t") == std::string::npos) continue;
    lines.push_back({number, line});
  }
  return lines;
}

// Exactly three finite numbers on a line.
StatusOr<Vec3d> ParseTriple(const fs::path& path, int line_number, const std::string& line) {
  std::istringstream in(line);
  std::vector<double> values;
  std::string token;
  while (in >> token) {
    char* stop = nullptr;
    const double v = std::strtod(token.c_str(), &stop);
    if (*stop != '\0' || !std::isfinite(v)) {
      return DataLossError(path.filename().string(), ":", line_number, ": \"", token,
                           "\" is not a finite number");
    }
    values.push_back(v);
  }
  if (values.size() != 3) {
    return DataLossError(path.filename().string(), ":", line_number, ": expected 3 numbers, got ",
                         values.size());
  }
  return Vec3d(values[0], values[1], values[2]);
}

double SecondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

}  // namespace

Status ImportOptions::Validate() const {
  if (holdout_every < 2 || holdout_every > 1000) {
    return InvalidArgumentError("--holdout-every must be in [2, 1000], got ", holdout_every);
  }
  return OkStatus();
}

std::vector<int> KnownBadImages(const std::string& object) {
  std::vector<int> bad;
  if (object == "bear" || object == "bearPNG") {
    for (int i = 1; i <= 20; ++i) bad.push_back(i);
  }
  return bad;
}

StatusOr<ImportSummary> ImportDiligent(const fs::path& object_dir, const fs::path& out_dir,
                                       const ImportOptions& options) {
  REFLCAP_RETURN_IF_ERROR(options.Validate());
  const auto start = std::chrono::steady_clock::now();
  std::error_code ec;
  if (!fs::is_directory(object_dir, ec)) {
    return NotFoundError(object_dir.string(), ": not a folder (expected a DiLiGenT object folder)");
  }
  ImportSummary summary;
  summary.object = fs::absolute(object_dir).lexically_normal().filename().string();
  if (summary.object.empty()) {
    summary.object = fs::absolute(object_dir).lexically_normal().parent_path().filename().string();
  }

  // Text files.
  const fs::path names_path = object_dir / "filenames.txt";
  const fs::path dirs_path = object_dir / "light_directions.txt";
  const fs::path ints_path = object_dir / "light_intensities.txt";
  REFLCAP_ASSIGN_OR_RETURN(auto names, ReadLines(names_path));
  REFLCAP_ASSIGN_OR_RETURN(auto dir_lines, ReadLines(dirs_path));
  REFLCAP_ASSIGN_OR_RETURN(auto int_lines, ReadLines(ints_path));
  if (names.empty()) return DataLossError(names_path.string(), ": no image names");
  for (const auto& [file, lines] : {std::pair<const fs::path*, const decltype(dir_lines)*>{&dirs_path, &dir_lines},
                                    {&ints_path, &int_lines}}) {
    if (lines->size() != names.size()) {
      return InvalidArgumentError(file->string(), ": ", lines->size(), " lights but filenames.txt names ",
                                  names.size(), " images (one line per light, in the same order)");
    }
  }

  Capture capture;
  capture.json_path = out_dir / "capture.json";
  for (size_t i = 0; i < names.size(); ++i) {
    REFLCAP_ASSIGN_OR_RETURN(Vec3d direction, ParseTriple(dirs_path, dir_lines[i].first, dir_lines[i].second));
    REFLCAP_ASSIGN_OR_RETURN(Vec3d intensity, ParseTriple(ints_path, int_lines[i].first, int_lines[i].second));
    const double length = direction.norm();
    if (!(length > 0.5)) {
      return DataLossError(dirs_path.filename().string(), ":", dir_lines[i].first,
                           ": not a unit direction (length ", length, ")");
    }
    if (std::abs(length - 1) > kDirectionLengthTolerance) {
      REFLCAP_LOG(kWarning) << dirs_path.filename().string() << ":" << dir_lines[i].first
                            << ": direction of length " << length << ", normalised";
    }
    if (!(intensity.minCoeff() > 0)) {
      return DataLossError(ints_path.filename().string(), ":", int_lines[i].first,
                           ": intensities must be positive");
    }
    Light light;
    char id[32];
    std::snprintf(id, sizeof id, "L%03zu", i + 1);
    light.id = id;
    light.type = LightType::kDirectional;
    light.direction = direction / length;
    light.intensity = intensity;
    capture.lights.push_back(light);
  }
  summary.lights = capture.lights.size();

  // Geometry.
  REFLCAP_ASSIGN_OR_RETURN(Image mask_rgb, ReadPng(object_dir / "mask.png"));
  REFLCAP_ASSIGN_OR_RETURN(Image normals, ReadExrRgb(object_dir / "normals.exr"));
  summary.width = mask_rgb.width;
  summary.height = mask_rgb.height;
  if (normals.width != mask_rgb.width || normals.height != mask_rgb.height) {
    return InvalidArgumentError((object_dir / "normals.exr").string(), ": is ", normals.width, "x",
                                normals.height, " but mask.png is ", mask_rgb.width, "x",
                                mask_rgb.height);
  }
  Image mask(mask_rgb.width, mask_rgb.height, 1, 0.0f);
  for (size_t p = 0; p < mask.PixelCount(); ++p) {
    bool on = false;
    for (int c = 0; c < mask_rgb.channels; ++c) on |= mask_rgb.data[p * mask_rgb.channels + c] > 0;
    mask.data[p] = on ? 1.0f : 0.0f;
    if (!on) continue;
    ++summary.mask_pixels;
    const float* n = &normals.data[p * 3];
    const float length = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    summary.normal_texels += std::isfinite(length) && length > 0.5f;
  }
  if (summary.mask_pixels == 0) return InvalidArgumentError((object_dir / "mask.png").string(), ": empty mask");
  // A capture without a single texel would only fail later, in resample, far from the cause
  // (tests/cli/bad_input_corpus_test: a normals.exr of NaN was imported).
  if (summary.normal_texels == 0) {
    return InvalidArgumentError((object_dir / "normals.exr").string(), ": none of the ",
                                summary.mask_pixels, " masked pixels has a finite, non-zero normal");
  }
  if (summary.normal_texels < summary.mask_pixels) {
    REFLCAP_LOG(kWarning) << (object_dir / "normals.exr").string() << ": "
                          << summary.mask_pixels - summary.normal_texels
                          << " masked pixels have no valid normal; they are not texels";
  }

  Camera cam;
  cam.id = "cam0";
  cam.model = CameraModel::kOrthographic;
  cam.width = mask.width;
  cam.height = mask.height;
  cam.pixel_size_m = kNominalPixelSizeM;
  cam.cam_from_world.rotation = Vec3d(1, -1, -1).asDiagonal();
  cam.cam_from_world.translation = Vec3d(0, 0, 1);
  capture.cameras.push_back(cam);
  capture.normal_map = NormalMapGeometry{0, "normals.exr", "mask.png"};

  // Images.
  const std::vector<int> bad = KnownBadImages(summary.object);
  summary.excluded = bad;
  std::vector<size_t> kept;
  std::vector<std::string> out_files(names.size());
  for (size_t i = 0; i < names.size(); ++i) {
    const int light_number = int(i) + 1;
    if (std::find(bad.begin(), bad.end(), light_number) != bad.end()) continue;
    const std::string& name = names[i].second;
    const std::string trimmed = name.substr(name.find_first_not_of(" \t"),
                                            name.find_last_not_of(" \t") - name.find_first_not_of(" \t") + 1);
    names[i].second = trimmed;
    out_files[i] = "images/" + fs::path(trimmed).stem().string() + ".exr";
    for (size_t j : kept) {
      if (out_files[j] == out_files[i]) {
        return InvalidArgumentError(names_path.filename().string(), ":", names[i].first, ": \"",
                                    trimmed, "\" repeats an earlier image name");
      }
    }
    kept.push_back(i);
    CaptureImage image;
    image.file = out_files[i];
    image.camera = 0;
    image.light = int(i);
    image.exposure_s = 1;
    // The PNG's full scale (65535, or 255 in the 8-bit crops) is 1.0 here: a pixel at it is
    // clipped (ball16's highlights are), so resampling drops it and validation does not score it.
    image.saturation = kDiligentFullScale;
    image.split = light_number % options.holdout_every == 0 ? Split::kHoldout : Split::kTrain;
    capture.images.push_back(image);
  }
  if (capture.images.empty()) return InvalidArgumentError(names_path.string(), ": every image is excluded");
  summary.images = capture.images.size();
  summary.train = capture.CountSplit(Split::kTrain);
  summary.holdout = capture.CountSplit(Split::kHoldout);

  fs::create_directories(out_dir / "images", ec);
  if (ec) return InternalError((out_dir / "images").string(), ": cannot create: ", ec.message());
  REFLCAP_RETURN_IF_ERROR(WriteExr(out_dir / "normals.exr", normals, ExrPixelType::kFloat));
  REFLCAP_RETURN_IF_ERROR(WritePng(out_dir / "mask.png", mask));

  std::vector<Status> errors(kept.size());
  Progress progress("import-diligent", int64_t(kept.size()));
  ParallelFor(0, int64_t(kept.size()), 1, [&](int64_t b, int64_t e, int) {
    for (int64_t k = b; k < e; ++k) {
      const size_t i = kept[size_t(k)];
      const fs::path source = object_dir / names[i].second;
      auto run = [&]() -> Status {
        auto photo = ReadPng(source);
        if (!photo.ok()) {
          return Status(photo.status().code(), StrCat(names_path.filename().string(), ":",
                                                      names[i].first, ": ", photo.status().message()));
        }
        if (photo->width != mask.width || photo->height != mask.height) {
          return InvalidArgumentError(source.string(), ": is ", photo->width, "x", photo->height,
                                      " but mask.png is ", mask.width, "x", mask.height);
        }
        // Grey photographs are replicated to RGB; alpha is dropped. Values stay linear.
        Image rgb(photo->width, photo->height, 3);
        const int ch = photo->channels;
        for (size_t p = 0; p < rgb.PixelCount(); ++p) {
          for (int c = 0; c < 3; ++c) {
            rgb.data[p * 3 + c] = photo->data[p * ch + size_t(ch >= 3 ? c : 0)];
          }
        }
        return WriteExr(out_dir / out_files[i], rgb, ExrPixelType::kFloat);
      };
      errors[size_t(k)] = run();
      progress.Advance();
    }
  });
  progress.Finish();
  for (const Status& s : errors) REFLCAP_RETURN_IF_ERROR(s);

  REFLCAP_RETURN_IF_ERROR(WriteCapture(capture, capture.json_path));
  Json provenance = {
      {"source", fs::absolute(object_dir).lexically_normal().string()},
      {"dataset", "DiLiGenT (Shi et al., CVPR 2016 / TPAMI 2019)"},
      {"object", summary.object},
      {"frame", "world = DiLiGenT camera frame (x right, y up, z towards the camera); cam0 is "
                "orthographic with cam_from_world = [diag(1,-1,-1) | (0,0,1)] (OpenCV axes)"},
      {"pixel_size_m", kNominalPixelSizeM},
      {"pixel_size_note", "nominal: DiLiGenT gives none; unused by directional lights and normal maps"},
      {"radiometry", "images keep DiLiGenT's linear values in units of the 16-bit full scale "
                     "(16-bit PNG / 65535; 8-bit crops: byte / 255 = (16-bit / 257) / 255); light "
                     "intensities from light_intensities.txt; exposure_s = 1; saturation = 1 "
                     "(the full scale: clipped)"},
      {"holdout_every", options.holdout_every},
      {"split_rule", "light i (1-based) is holdout when i % holdout_every == 0"},
      {"excluded_images", summary.excluded},
      {"excluded_reason", summary.excluded.empty() ? "" : "known bad photographs (dataset notes)"},
      {"mask_pixels", summary.mask_pixels},
      {"normal_texels", summary.normal_texels}};
  REFLCAP_RETURN_IF_ERROR(
      WriteTextFileAtomic(out_dir / "diligent_import.json", provenance.dump(2) + "\n"));
  summary.seconds = SecondsSince(start);
  return summary;
}

}  // namespace reflcap::diligent
