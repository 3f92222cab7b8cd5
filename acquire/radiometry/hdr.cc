// `reflcap hdr` pipeline (see hdr.h).
#include "acquire/radiometry/hdr.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <mutex>

#include <nlohmann/json.hpp>

#include "acquire/radiometry/hdr_report.h"
#include "acquire/radiometry/merge.h"
#include "engine/core/atomic_file.h"
#include "engine/core/log.h"
#include "engine/core/parallel.h"
#include "engine/core/progress.h"
#include "engine/image/exr_io.h"

namespace reflcap::radiometry {
namespace fs = std::filesystem;
using Json = nlohmann::json;

namespace {

// A saturated pixel is written one part in 10⁶ above the largest measurable value, so that the
// resampler's ">= saturation" test catches it and no measured value does (float keeps 7 digits).
constexpr double kSaturationMargin = 1e-6;
// Ground-truth comparison of merged values: only channels whose true raw value in the longest
// exposure reaches this code (of the true response) count — darker ones sit at the noise floor
// of the whole bracket (code 13 is the floor the brackets/1 validation uses).
constexpr int kTruthMinCode = 13;

double Seconds(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

Json Vec(const Vec3d& v) { return Json::array({v[0], v[1], v[2]}); }
Json Mat(const Mat3d& m) {
  Json j = Json::array();
  for (int r = 0; r < 3; ++r) j.push_back(Json::array({m(r, 0), m(r, 1), m(r, 2)}));
  return j;
}

// Where the output's geometry comes from.
struct Geometry {
  fs::path mesh;  // source file, empty for a normal map
  fs::path normals, mask;
  std::string normal_map_camera;
  fs::path source_folder;  // the source capture's folder (masks), empty when none
};

StatusOr<Geometry> ResolveGeometry(const BracketSet& set, const HdrOptions& options) {
  const std::string file = set.json_path.string();
  Geometry g;
  if (!options.mesh.empty()) {
    g.mesh = options.mesh;
    std::error_code ec;
    if (!fs::is_regular_file(g.mesh, ec)) return NotFoundError("--mesh: ", options.mesh, ": not found");
  }
  if (set.source_capture.empty()) {
    if (g.mesh.empty()) {
      return InvalidArgumentError(file, ": source_capture: absent, and no --mesh given: the output "
                                        "capture needs the object's geometry");
    }
    return g;
  }
  const fs::path source = set.Resolve(set.source_capture);
  auto capture = ReadCapture(source);
  if (!capture.ok()) {
    if (!g.mesh.empty()) return g;  // --mesh stands in for an unreadable source capture
    return Status(capture.status().code(),
                  StrCat(file, ": source_capture: ", capture.status().message()));
  }
  g.source_folder = capture->Folder();
  if (!g.mesh.empty()) return g;
  if (capture->normal_map) {
    g.normals = capture->Resolve(capture->normal_map->normals);
    g.mask = capture->Resolve(capture->normal_map->mask);
    g.normal_map_camera = capture->cameras[size_t(capture->normal_map->camera)].id;
  } else {
    g.mesh = capture->Resolve(capture->mesh);
  }
  std::error_code ec;
  for (const fs::path& p : {g.mesh, g.normals, g.mask}) {
    if (!p.empty() && !fs::is_regular_file(p, ec)) {
      return NotFoundError(file, ": source_capture: ", p.string(), ": not found");
    }
  }
  return g;
}

// All-clipped and all-black brackets measure nothing.
Status CheckBracket(const BracketImages& images, const std::string& file, size_t index) {
  size_t measured = 0;
  int lo = 255, hi = 0;
  for (const auto& codes : images.codes) {
    for (uint8_t z : codes) {
      measured += z > 0 && z < kClipCode;
      lo = std::min<int>(lo, z);
      hi = std::max<int>(hi, z);
    }
  }
  if (measured > 0) return OkStatus();
  const std::string at = StrCat(file, ": photos[", index, "].exposures: ");
  if (lo == kClipCode) {
    return InvalidArgumentError(at, "every exposure is clipped (all codes 255): nothing is measured "
                                    "(shorten the exposures)");
  }
  if (hi == 0) {
    return InvalidArgumentError(at, "every exposure is black (all codes 0): nothing is measured "
                                    "(lengthen the exposures, or check the files)");
  }
  return InvalidArgumentError(at, "no pixel has a code between 0 and 255 in any exposure (every "
                                  "pixel is black or clipped): nothing is measured");
}

// Copies a file of the source capture; the copy is the user's to change (a read-only source stays
// readable but would otherwise make its copy read-only too).
Status CopyInto(const fs::path& from, const fs::path& to) {
  std::error_code ec;
  fs::create_directories(to.parent_path(), ec);
  fs::copy_file(from, to, fs::copy_options::overwrite_existing, ec);
  if (ec) return InternalError(to.string(), ": cannot copy ", from.string(), ": ", ec.message());
  fs::permissions(to, fs::perms::owner_write, fs::perm_options::add, ec);
  return OkStatus();
}

std::vector<double> ExposureTimes(const BracketPhoto& photo) {
  std::vector<double> t;
  for (const BracketExposure& e : photo.exposures) t.push_back(e.exposure_s);
  return t;
}

// Declared chart geometry: corners_px of each patch, the world_from_chart pose and the layout.
struct DeclaredChart {
  std::string file;
  std::optional<ChartCorners> corners;
  std::optional<Rigid3> world_from_chart;
  std::optional<ChartLayout> layout;
};

StatusOr<DeclaredChart> ReadDeclaredChart(const BracketSet& set, const BracketPhoto& photo) {
  DeclaredChart d;
  std::string relative = photo.chart;
  if (relative.empty() && !set.truth.chart_geometry.empty() &&
      (set.truth.chart_photo_id.empty() || set.truth.chart_photo_id == photo.id)) {
    relative = set.truth.chart_geometry;
  }
  if (relative.empty()) return d;
  const fs::path path = set.Resolve(relative);
  d.file = path.string();
  auto text = ReadTextFile(path);
  if (!text.ok()) return NotFoundError(path.string(), ": chart geometry: cannot open");
  Json root = Json::parse(*text, nullptr, false);
  if (root.is_discarded() || !root.is_object()) {
    return InvalidArgumentError(path.string(), ": chart geometry: not a JSON object");
  }
  if (auto chart = root.find("chart"); chart != root.end() && chart->is_object()) {
    if (chart->contains("patch_m") && chart->contains("gap_m") && (*chart)["patch_m"].is_number() &&
        (*chart)["gap_m"].is_number()) {
      ChartLayout layout;
      layout.patch_m = (*chart)["patch_m"].get<double>();
      layout.gap_m = (*chart)["gap_m"].get<double>();
      if (!layout.Validate().ok()) return InvalidArgumentError(path.string(), ": chart.patch_m/gap_m: must be positive");
      d.layout = layout;
    }
    if (auto m = chart->find("world_from_chart"); m != chart->end() && m->is_array() && m->size() >= 3) {
      Mat4d T = Mat4d::Identity();
      bool ok = true;
      for (int r = 0; r < 3 && ok; ++r) {
        ok = (*m)[size_t(r)].is_array() && (*m)[size_t(r)].size() == 4;
        for (int c = 0; c < 4 && ok; ++c) {
          ok = (*m)[size_t(r)][size_t(c)].is_number();
          if (ok) T(r, c) = (*m)[size_t(r)][size_t(c)].get<double>();
        }
      }
      if (ok) d.world_from_chart = Rigid3::FromMatrix(T);
    }
  }
  if (auto patches = root.find("patches"); patches != root.end() && patches->is_array() &&
                                           patches->size() == size_t(kChartPatches)) {
    ChartCorners corners{};
    for (size_t i = 0; i < patches->size(); ++i) {
      const Json& p = (*patches)[i];
      const std::string at = StrCat(path.string(), ": patches[", i, "].corners_px");
      if (!p.contains("corners_px") || !p["corners_px"].is_array() || p["corners_px"].size() != 4) {
        return InvalidArgumentError(at, ": must be 4 [x, y] points");
      }
      for (size_t k = 0; k < 4; ++k) {
        const Json& q = p["corners_px"][k];
        if (!q.is_array() || q.size() != 2 || !q[0].is_number() || !q[1].is_number()) {
          return InvalidArgumentError(at, ": must be 4 [x, y] points");
        }
        corners[i][k] = Vec2d(q[0].get<double>(), q[1].get<double>());
      }
    }
    d.corners = corners;
  }
  return d;
}

struct Percentiles {
  size_t n = 0;
  double median = 0, p95 = 0, p99 = 0;
};
Percentiles PercentilesOf(std::vector<double> v) {
  Percentiles p;
  p.n = v.size();
  if (v.empty()) return p;
  std::sort(v.begin(), v.end());
  auto at = [&](double q) { return v[std::min(v.size() - 1, size_t(q * double(v.size())))]; };
  p.median = at(0.5);
  p.p95 = at(0.95);
  p.p99 = at(0.99);
  return p;
}

Json ResponseJson(const InverseResponse& r) {
  Json j = {{"model", r.model}, {"normalisation", "x(255) = 1: raw value relative to the clip level"}};
  Json log_x = Json::array(), x = Json::array(), noise = Json::array(), covered = Json::array();
  for (int c = 0; c < 3; ++c) {
    log_x.push_back(std::vector<double>(r.log_x[size_t(c)].begin(), r.log_x[size_t(c)].end()));
    std::vector<double> xs;
    for (int z = 0; z < kCodeCount; ++z) xs.push_back(r.X(c, z));
    x.push_back(xs);
    noise.push_back({{"read_sigma", r.noise[size_t(c)].read_sigma},
                     {"photon_gain", r.noise[size_t(c)].photon_gain}});
    covered.push_back({r.first_code[size_t(c)], r.last_code[size_t(c)]});
  }
  j["x_of_code"] = x;
  j["log_x_of_code"] = log_x;
  j["code_0"] = "code 0 is censored (below the first rounding threshold); its entry is half that threshold";
  j["noise"] = noise;
  j["codes_with_data"] = covered;
  return j;
}

}  // namespace

Status HdrOptions::Validate() const {
  REFLCAP_RETURN_IF_ERROR(response.Validate());
  REFLCAP_RETURN_IF_ERROR(layout.Validate());
  if (threads < 0) return InvalidArgumentError("--threads must be >= 0, got ", threads);
  if (colour_matrix && !use_chart) return InvalidArgumentError("--colour-matrix needs the chart (drop --no-chart)");
  return OkStatus();
}

StatusOr<HdrSummary> RunHdrPipeline(const fs::path& brackets_json, const fs::path& out_dir,
                                    const HdrOptions& options) {
  REFLCAP_RETURN_IF_ERROR(options.Validate());
  const auto start = std::chrono::steady_clock::now();
  Json timings = Json::object();
  REFLCAP_ASSIGN_OR_RETURN(BracketSet set, ReadBrackets(brackets_json));
  const std::string file = set.json_path.string();
  for (const std::string& id : options.holdout_lights) {
    if (set.rig.FindLight(id) < 0) {
      return InvalidArgumentError("--holdout-lights: unknown light id \"", id, "\" (not in ", file, ")");
    }
  }
  REFLCAP_ASSIGN_OR_RETURN(Geometry geometry, ResolveGeometry(set, options));
  int chart_photo = -1;
  if (options.use_chart) {
    chart_photo = set.ChartPhoto();
    if (chart_photo < 0) {
      return FailedPreconditionError(file, ": photos: no photo has subject \"colorchecker\": white "
                                           "balance needs a chart photograph (--no-chart skips it)");
    }
  }
  std::vector<size_t> objects;
  for (size_t i = 0; i < set.photos.size(); ++i) {
    if (set.photos[i].subject == Subject::kObject) objects.push_back(i);
  }
  std::string weight_photo = options.weight_map_photo;
  if (weight_photo.empty()) weight_photo = set.photos[objects.front()].id;
  if (std::none_of(objects.begin(), objects.end(),
                   [&](size_t i) { return set.photos[i].id == weight_photo; })) {
    return InvalidArgumentError("--weight-map-photo: no object photo has id \"", weight_photo, "\"");
  }

  // ---- 1. Read every bracket, check it, sample the object photos. ----
  std::vector<std::vector<double>> lists;
  for (const BracketPhoto& p : set.photos) lists.push_back(ExposureTimes(p));
  ResponseSampler sampler(options.response, lists);
  {
    auto t0 = std::chrono::steady_clock::now();
    Progress progress("hdr: reading brackets", int64_t(set.photos.size()));
    std::vector<Status> status(set.photos.size());
    ParallelFor(0, int64_t(set.photos.size()), 1, [&](int64_t b, int64_t e, int) {
      for (int64_t i = b; i < e; ++i) {
        auto images = ReadBracketImages(set, size_t(i));
        if (!images.ok()) {
          status[size_t(i)] = images.status();
        } else {
          status[size_t(i)] = CheckBracket(*images, file, size_t(i));
          if (status[size_t(i)].ok() && set.photos[size_t(i)].subject == Subject::kObject) {
            sampler.AddPhoto(size_t(i), *images);
          }
        }
        progress.Advance();
      }
    }, options.threads);
    progress.Finish();
    for (const Status& s : status) REFLCAP_RETURN_IF_ERROR(s);
    timings["read_and_sample"] = Seconds(t0);
  }
  SampleSet samples = sampler.Finish();

  // ---- 2. Response from the object photos. ----
  auto t_response = std::chrono::steady_clock::now();
  REFLCAP_ASSIGN_OR_RETURN(ResponseFit fit, EstimateResponse(samples, options.response));
  ResponseFit first_fit = fit;
  timings["response"] = Seconds(t_response);
  REFLCAP_LOG(kInfo) << "hdr: response " << fit.response.model << " from "
                     << fit.samples[1] << " samples per channel (" << FormatDuration(fit.seconds) << ")";

  Json report = Json::object();
  report["format"] = "reflcap-hdr-report/1";
  report["brackets"] = fs::absolute(set.json_path).lexically_normal().string();

  // ---- 3. Chart: detect, anchor the response, colour calibration. ----
  ColourCalibration colour;
  std::optional<ChartDetection> detection;
  std::optional<MergedBracket> chart_merged;
  Json chart_json = Json::object();
  ChartLayout layout = options.layout;
  std::string layout_source = options.layout_given ? "command line" : "default (ColorChecker Classic, brackets/1)";
  DeclaredChart declared;
  if (chart_photo >= 0) {
    auto t0 = std::chrono::steady_clock::now();
    const BracketPhoto& photo = set.photos[size_t(chart_photo)];
    const Camera& camera = set.rig.cameras[size_t(photo.camera)];
    const Light& light = set.rig.lights[size_t(photo.light)];
    REFLCAP_ASSIGN_OR_RETURN(declared, ReadDeclaredChart(set, photo));
    if (declared.layout && !options.layout_given) {
      layout = *declared.layout;
      layout_source = "declared (" + declared.file + ")";
    }
    REFLCAP_ASSIGN_OR_RETURN(BracketImages images, ReadBracketImages(set, size_t(chart_photo)));
    const std::vector<double> times = ExposureTimes(photo);
    MergedBracket merged = MergeBracket(images, times, fit.response);
    auto found = DetectChart(merged.value, camera, layout, declared.corners, options.chart_mcc);
    if (!found.ok()) {
      return Status(found.status().code(), StrCat(file, ": photos[", chart_photo, "] (\"", photo.id,
                                                  "\"): ", found.status().message()));
    }
    detection = *found;
    const std::vector<ChartPixel> pixels = ChartInnerPixels(*detection, camera, layout, light);
    if (options.anchor_response) {
      const uint16_t list = samples.list_of_photo[size_t(chart_photo)];
      for (const ChartPixel& px : pixels) {
        const size_t p = size_t(px.y) * size_t(images.width) + size_t(px.x);
        const Vec3d albedo = PatchAlbedo(px.patch);
        for (int c = 0; c < 3; ++c) {
          const double radiance = albedo[c] * kInvPi * light.intensity[c] * px.geometry;
          if (!(radiance > 0)) continue;
          AnchoredSample a;
          a.codes.list = list;
          a.codes.count = uint8_t(times.size());
          for (size_t e = 0; e < times.size(); ++e) a.codes.codes[e] = images.codes[e][p * 3 + size_t(c)];
          a.log_radiance = std::log(radiance);
          samples.anchored[size_t(c)].push_back(a);
        }
      }
      REFLCAP_ASSIGN_OR_RETURN(fit, EstimateResponse(samples, options.response));
      merged = MergeBracket(images, times, fit.response);
    }
    REFLCAP_ASSIGN_OR_RETURN(colour, CalibrateColour(merged, pixels, light, options.colour_matrix));
    chart_merged = std::move(merged);
    timings["chart"] = Seconds(t0);
    chart_json["photo"] = photo.id;
    chart_json["inner_pixels"] = pixels.size();
  }
  const Mat3d correction = colour.Correction();

  // Saturation: the largest measurable corrected value (see hdr.h).
  double saturation = 0;
  {
    double t_min = 1e300;
    for (size_t i : objects) t_min = std::min(t_min, set.photos[i].exposures.front().exposure_s);
    for (int r = 0; r < 3; ++r) {
      double bound = 0;
      for (int c = 0; c < 3; ++c) {
        bound += std::max(correction(r, c), 0.0) * fit.response.X(c, kClipCode - 1) / t_min;
      }
      saturation = std::max(saturation, bound);
    }
    saturation *= 1 + kSaturationMargin;
    // The images hold floats: use a float value, so that the capture's number and the pixels
    // written at it compare equal however a reader rounds.
    saturation = double(float(saturation));
  }

  // ---- 4. Merge every object photo and write the capture. ----
  std::error_code ec;
  fs::create_directories(out_dir / "images", ec);
  fs::create_directories(out_dir / "variance", ec);
  fs::create_directories(out_dir / "radiometry", ec);
  if (ec) return InternalError(out_dir.string(), ": cannot create folders: ", ec.message());
  std::vector<double> truth_errors;
  std::mutex truth_mutex;
  std::atomic<size_t> measured{0}, dark{0}, clipped{0}, truth_photos{0};
  std::vector<Status> status(objects.size());
  std::optional<MergedBracket> weight_merged;
  std::mutex weight_mutex;
  std::optional<Vec3d> true_gains = set.truth.wb_gains;
  {
    auto t0 = std::chrono::steady_clock::now();
    Progress progress("hdr: merging", int64_t(objects.size()));
    ParallelFor(0, int64_t(objects.size()), 1, [&](int64_t b, int64_t e, int) {
      for (int64_t k = b; k < e; ++k) {
        const size_t i = objects[size_t(k)];
        const BracketPhoto& photo = set.photos[i];
        auto images = ReadBracketImages(set, i);
        if (!images.ok()) {
          status[size_t(k)] = images.status();
          progress.Advance();
          continue;
        }
        const std::vector<double> times = ExposureTimes(photo);
        const bool keep_weights = photo.id == weight_photo;
        MergedBracket m = MergeBracket(*images, times, fit.response, keep_weights);
        measured += m.measured;
        dark += m.dark;
        clipped += m.clipped;
        Image value(m.value.width, m.value.height, 3), variance(m.value.width, m.value.height, 3);
        for (size_t p = 0; p < m.value.PixelCount(); ++p) {
          bool saturated = false;
          Vec3d v, var;
          for (int c = 0; c < 3; ++c) {
            saturated = saturated || m.flags[p * 3 + size_t(c)] == uint8_t(MergeFlag::kClipped);
            v[c] = m.value.data[p * 3 + size_t(c)];
            var[c] = m.variance.data[p * 3 + size_t(c)];
          }
          const Vec3d out = correction * v;
          const Vec3d out_var = correction.cwiseAbs2() * var;
          for (int c = 0; c < 3; ++c) {
            value.data[p * 3 + size_t(c)] = float(saturated ? saturation : out[c]);
            variance.data[p * 3 + size_t(c)] = float(saturated ? saturation * saturation : out_var[c]);
          }
        }
        Status s = WriteExr(out_dir / "images" / (photo.id + ".exr"), value, ExrPixelType::kFloat);
        if (s.ok()) s = WriteExr(out_dir / "variance" / (photo.id + ".exr"), variance, ExrPixelType::kFloat);
        status[size_t(k)] = s;
        // Ground truth: the linear photo this bracket was made from.
        if (!photo.source_hdr.empty()) {
          auto truth = ReadExrRgb(set.Resolve(photo.source_hdr));
          if (truth.ok() && truth->width == value.width && truth->height == value.height) {
            std::vector<double> errors;
            const double t_max = times.back();
            for (size_t p = 0; p < value.PixelCount(); ++p) {
              bool all_measured = true;
              for (int c = 0; c < 3; ++c) all_measured = all_measured && m.flags[p * 3 + size_t(c)] == 0;
              if (!all_measured) continue;
              for (int c = 0; c < 3; ++c) {
                const double L = truth->data[p * 3 + size_t(c)];
                if (!(L > 0)) continue;
                if (true_gains && set.truth.x_of_code.size() == size_t(kCodeCount) &&
                    (*true_gains)[c] * t_max * L < set.truth.x_of_code[kTruthMinCode]) {
                  continue;
                }
                errors.push_back(std::abs(double(value.data[p * 3 + size_t(c)]) - L) / L);
              }
            }
            std::lock_guard<std::mutex> lock(truth_mutex);
            truth_errors.insert(truth_errors.end(), errors.begin(), errors.end());
            ++truth_photos;
          } else if (!truth.ok()) {
            REFLCAP_LOG(kWarning) << file << ": photos[" << i << "].source_hdr: " << truth.status().message()
                                  << " (ground truth left out)";
          }
        }
        if (keep_weights) {
          std::lock_guard<std::mutex> lock(weight_mutex);
          weight_merged = std::move(m);
        }
        progress.Advance();
      }
    }, options.threads);
    progress.Finish();
    for (const Status& s : status) REFLCAP_RETURN_IF_ERROR(s);
    timings["merge"] = Seconds(t0);
  }

  // Geometry: mesh (or normal map) and the source capture's silhouette masks.
  Capture capture;
  capture.json_path = out_dir / "capture.json";
  capture.cameras = set.rig.cameras;
  capture.lights = set.rig.lights;
  capture.turntable = set.rig.turntable;
  if (!geometry.mesh.empty()) {
    capture.mesh = geometry.mesh.filename().string();
    REFLCAP_RETURN_IF_ERROR(CopyInto(geometry.mesh, out_dir / capture.mesh));
  } else {
    NormalMapGeometry nm;
    nm.camera = capture.FindCamera(geometry.normal_map_camera);
    if (nm.camera < 0) {
      return InvalidArgumentError(file, ": source_capture: normal_map.camera \"", geometry.normal_map_camera,
                                  "\" is not a camera of the brackets file");
    }
    nm.normals = "normals" + geometry.normals.extension().string();
    nm.mask = "mask" + geometry.mask.extension().string();
    REFLCAP_RETURN_IF_ERROR(CopyInto(geometry.normals, out_dir / nm.normals));
    REFLCAP_RETURN_IF_ERROR(CopyInto(geometry.mask, out_dir / nm.mask));
    capture.normal_map = nm;
  }
  size_t masks_copied = 0;
  HdrSummary summary;
  for (size_t i : objects) {
    const BracketPhoto& photo = set.photos[i];
    CaptureImage image;
    image.file = "images/" + photo.id + ".exr";
    image.camera = photo.camera;
    image.light = photo.light;
    image.turntable_deg = photo.turntable_deg;
    image.exposure_s = 1;
    const bool held_out =
        photo.split == "holdout" ||
        std::find(options.holdout_lights.begin(), options.holdout_lights.end(),
                  set.rig.lights[size_t(photo.light)].id) != options.holdout_lights.end();
    image.split = held_out ? Split::kHoldout : Split::kTrain;
    image.saturation = saturation;
    capture.images.push_back(image);
    (held_out ? summary.holdout : summary.train) += 1;
    if (!geometry.source_folder.empty() && !capture.normal_map) {
      char name[200];
      std::snprintf(name, sizeof name, "masks/%s_%03ld.png", set.rig.cameras[size_t(photo.camera)].id.c_str(),
                    std::lround(photo.turntable_deg));
      const fs::path from = geometry.source_folder / name, to = out_dir / name;
      if (fs::is_regular_file(from, ec) && !fs::exists(to, ec)) {
        REFLCAP_RETURN_IF_ERROR(CopyInto(from, to));
        ++masks_copied;
      }
    }
  }
  Json capture_json = Json::parse(CaptureToJson(capture));
  for (size_t k = 0; k < objects.size(); ++k) {
    capture_json["images"][k]["variance"] = "variance/" + set.photos[objects[k]].id + ".exr";
    capture_json["images"][k]["brackets_photo"] = set.photos[objects[k]].id;
  }
  capture_json["radiometry"] = {
      {"source", fs::absolute(set.json_path).lexically_normal().string()},
      {"response", "radiometry/response.json"},
      {"report", "radiometry/report.json"},
      {"units", chart_photo >= 0 ? "radiance in the rig's light units (the chart's reference albedos "
                                   "under the calibrated light)"
                                 : "camera RGB, normalised raw (clip = 1) per second: no white balance"},
      {"correction", Mat(correction)},
      {"variance", "images[].variance: per-pixel variance of each channel, same units squared"},
      {"saturation", "images[].saturation: a pixel with any channel at or above it was clipped in "
                     "every exposure"}};
  REFLCAP_RETURN_IF_ERROR(WriteTextFileAtomic(capture.json_path, capture_json.dump(2) + "\n"));

  // ---- 5. Report. ----
  summary.object_photos = objects.size();
  summary.response_model = fit.response.model;
  for (int c = 0; c < 3; ++c) summary.read_sigma[size_t(c)] = fit.response.noise[size_t(c)].read_sigma;
  summary.chart_method = detection ? detection->method : "none";
  summary.gains = colour.gains;
  summary.mean_delta_e_before = colour.mean_delta_e_before;
  summary.mean_delta_e_after = colour.matrix_applied ? colour.mean_delta_e_matrix : colour.mean_delta_e_gains;

  Json photos_json = {{"object", objects.size()}, {"train", summary.train}, {"holdout", summary.holdout},
                      {"chart", chart_photo >= 0 ? set.photos[size_t(chart_photo)].id : ""},
                      {"masks_copied", masks_copied}};
  report["photos"] = photos_json;
  report["options"] = {{"response", options.response.model},
                       {"smoothness", options.response.smoothness},
                       {"log_smoothness", options.response.log_smoothness},
                       {"samples_per_bin", options.response.samples_per_bin},
                       {"iterations", options.response.iterations},
                       {"use_chart", options.use_chart},
                       {"anchor_response", options.anchor_response},
                       {"colour_matrix", options.colour_matrix},
                       {"chart_mcc", options.chart_mcc},
                       {"holdout_lights", options.holdout_lights}};
  const bool have_truth_curve = set.truth.x_of_code.size() == size_t(kCodeCount);
  auto candidates_json = [&](const ResponseFit& f) {
    Json list = Json::array();
    for (const ModelFit& m : f.candidates) {
      Json j = {{"model", m.model}, {"parameters", m.parameters}, {"chi2", m.chi2}, {"bic", m.bic},
                {"monotone", m.monotone}, {"chosen", m.model == f.response.model}};
      Json params = Json::array();
      for (int c = 0; c < 3; ++c) params.push_back(m.params[size_t(c)]);
      j["params"] = params;
      if (have_truth_curve) {
        const ResponseError err = CompareResponse(m.response, set.truth.x_of_code);
        j["truth_max_abs_log_error"] = err.max_over_channels;
        j["truth_median_abs_log_error"] = err.median_over_channels;
      }
      list.push_back(j);
    }
    return list;
  };
  Json response_json = ResponseJson(fit.response);
  response_json["candidates"] = candidates_json(fit);
  response_json["samples"] = fit.samples;
  response_json["observations"] = fit.observations;
  response_json["anchored_observations"] = fit.anchored_observations;
  response_json["reduced_chi2"] = fit.reduced_chi2;
  response_json["iterations"] = fit.iterations;
  response_json["candidates_without_chart"] = candidates_json(first_fit);
  response_json["model_without_chart"] = first_fit.response.model;
  response_json["pixels_sampled_from"] = {{"photos", samples.photos},
                                          {"candidates_per_channel", samples.candidates}};
  if (have_truth_curve) {
    const ResponseError err = CompareResponse(fit.response, set.truth.x_of_code);
    const ResponseError err0 = CompareResponse(first_fit.response, set.truth.x_of_code);
    summary.response_max_log_error = err.max_over_channels;
    summary.response_median_log_error = err.median_over_channels;
    response_json["truth"] = {
        {"codes", {20, 235}},
        {"definition", "|ln x(code) - ln x_true(code)| after removing each channel's median log ratio"},
        {"max_abs_log_error", err.max_over_channels},
        {"median_abs_log_error", err.median_over_channels},
        {"max_abs_log_error_per_channel", err.max_abs_log},
        {"max_abs_log_error_absolute_per_channel", err.max_abs_log_absolute},
        {"scale_per_channel", err.scale},
        {"max_abs_log_error_without_chart", err0.max_over_channels},
        {"x_of_code", set.truth.x_of_code}};
    if (set.truth.read_noise_sigma) response_json["truth"]["read_noise_sigma"] = *set.truth.read_noise_sigma;
  }
  report["response"] = response_json;

  if (detection) {
    const ChartDetection& d = *detection;
    chart_json["method"] = d.method;
    chart_json["found_without_help"] = d.method == "mcc";
    chart_json["seed"] = d.seed;
    Json box = Json::array();
    for (const Vec2d& p : d.mcc_box) box.push_back({p.x(), p.y()});
    chart_json["mcc_box"] = box;
    Json corners = Json::array();
    for (const PatchQuad& q : d.corners_px) {
      Json quad = Json::array();
      for (const Vec2d& p : q) quad.push_back({p.x(), p.y()});
      corners.push_back(quad);
    }
    chart_json["corners_px"] = corners;
    chart_json["edges_refined"] = d.edges_refined;
    chart_json["reprojection_rms_px"] = d.reprojection_rms_px;
    chart_json["colour_residual"] = d.colour_residual;
    Json wfc = Json::array();
    const Mat4d T = d.world_from_chart.ToMatrix();
    for (int r = 0; r < 4; ++r) wfc.push_back({T(r, 0), T(r, 1), T(r, 2), T(r, 3)});
    chart_json["world_from_chart"] = wfc;
    chart_json["layout"] = {{"patch_m", layout.patch_m}, {"gap_m", layout.gap_m}, {"source", layout_source}};
    if (declared.world_from_chart) {
      const Rigid3 diff = declared.world_from_chart->Inverse() * d.world_from_chart;
      const double angle = RadToDeg(Eigen::AngleAxisd(diff.rotation).angle());
      const double normal_deg = RadToDeg(std::acos(std::clamp(
          declared.world_from_chart->rotation.col(2).dot(d.world_from_chart.rotation.col(2)), -1.0, 1.0)));
      chart_json["pose_vs_declared"] = {
          {"file", declared.file},
          {"rotation_deg", angle},
          {"normal_deg", normal_deg},
          {"translation_m", (d.world_from_chart.translation - declared.world_from_chart->translation).norm()}};
    }
    chart_json["gains"] = Vec(colour.gains);
    chart_json["gains_green_normalised"] = Vec(colour.gains / colour.gains[1]);
    chart_json["neutral_ratio_spread"] = Vec(colour.neutral_ratio_spread);
    chart_json["matrix"] = Mat(colour.matrix);
    chart_json["matrix_applied"] = colour.matrix_applied;
    chart_json["correction"] = Mat(correction);
    Json patches = Json::array();
    for (int i = 0; i < kChartPatches; ++i) {
      const PatchColour& p = colour.patches[size_t(i)];
      patches.push_back({{"index", i + 1}, {"name", p.name}, {"reference_albedo", Vec(p.reference_albedo)},
                         {"camera_albedo", Vec(p.camera_albedo)}, {"corrected_albedo", Vec(p.corrected_albedo)},
                         {"pixels", p.pixels}, {"clipped_or_dark_pixels", p.clipped},
                         {"delta_e00_before", p.delta_e_before}, {"delta_e00_gains", p.delta_e_gains},
                         {"delta_e00_matrix", p.delta_e_matrix}});
    }
    chart_json["patches"] = patches;
    chart_json["mean_delta_e00_before"] = colour.mean_delta_e_before;
    chart_json["mean_delta_e00_gains"] = colour.mean_delta_e_gains;
    chart_json["mean_delta_e00_matrix"] = colour.mean_delta_e_matrix;
    chart_json["max_delta_e00_gains"] = colour.max_delta_e_gains;
    if (true_gains) {
      Vec3d rel, rel_g;
      const Vec3d g_n = colour.gains / colour.gains[1], t_n = *true_gains / (*true_gains)[1];
      for (int c = 0; c < 3; ++c) {
        rel[c] = colour.gains[c] / (*true_gains)[c] - 1;
        rel_g[c] = g_n[c] / t_n[c] - 1;
      }
      summary.gains_max_rel_error = rel.cwiseAbs().maxCoeff();
      summary.gains_max_rel_error_green_normalised = rel_g.cwiseAbs().maxCoeff();
      chart_json["truth"] = {{"gains", Vec(*true_gains)},
                             {"gains_relative_error", Vec(rel)},
                             {"gains_green_normalised_relative_error", Vec(rel_g)},
                             {"max_relative_error", summary.gains_max_rel_error},
                             {"max_relative_error_green_normalised", summary.gains_max_rel_error_green_normalised}};
    }
    // The corrected chart against the chart's true radiance (patch inner means).
    if (!set.truth.chart_hdr.empty() && chart_merged) {
      auto truth = ReadExrRgb(set.Resolve(set.truth.chart_hdr));
      if (truth.ok() && truth->width == chart_merged->value.width && truth->height == chart_merged->value.height) {
        const BracketPhoto& photo = set.photos[size_t(chart_photo)];
        const auto pixels = ChartInnerPixels(d, set.rig.cameras[size_t(photo.camera)], layout,
                                             set.rig.lights[size_t(photo.light)]);
        std::array<Vec3d, kChartPatches> est, tru;
        for (int i = 0; i < kChartPatches; ++i) est[size_t(i)] = tru[size_t(i)] = Vec3d::Zero();
        for (const ChartPixel& px : pixels) {
          const size_t p = size_t(px.y) * size_t(truth->width) + size_t(px.x);
          Vec3d v;
          for (int c = 0; c < 3; ++c) v[c] = chart_merged->value.data[p * 3 + size_t(c)];
          est[size_t(px.patch)] += correction * v;
          for (int c = 0; c < 3; ++c) tru[size_t(px.patch)][c] += truth->data[p * 3 + size_t(c)];
        }
        std::vector<double> ratios;
        for (int i = 0; i < kChartPatches; ++i) {
          for (int c = 0; c < 3; ++c) {
            if (tru[size_t(i)][c] > 0) ratios.push_back(est[size_t(i)][c] / tru[size_t(i)][c] - 1);
          }
        }
        std::vector<double> abs_r;
        for (double r : ratios) abs_r.push_back(std::abs(r));
        const Percentiles pr = PercentilesOf(abs_r);
        chart_json["truth"]["corrected_chart_vs_true_radiance"] = {
            {"patch_channel_means", pr.n}, {"median_abs_rel_error", pr.median},
            {"max_abs_rel_error", abs_r.empty() ? 0.0 : *std::max_element(abs_r.begin(), abs_r.end())}};
      }
    }
    report["chart"] = chart_json;
  } else {
    report["chart"] = {{"method", "none"}, {"note", "--no-chart: no white balance, camera RGB"}};
  }

  Json merge_json = {{"photos", objects.size()}, {"pixel_channels_measured", measured.load()},
                     {"pixel_channels_dark", dark.load()}, {"pixel_channels_clipped", clipped.load()},
                     {"saturation", saturation}, {"weight_map_photo", weight_photo}};
  if (!truth_errors.empty()) {
    const Percentiles p = PercentilesOf(truth_errors);
    summary.hdr_median_rel_error = p.median;
    summary.hdr_p95_rel_error = p.p95;
    merge_json["truth"] = {
        {"photos", truth_photos.load()}, {"pixel_channels", p.n}, {"median_rel_error", p.median},
        {"p95_rel_error", p.p95}, {"p99_rel_error", p.p99},
        {"definition", StrCat("|merged - source_hdr| / source_hdr over the channels of pixels measured "
                              "in every channel whose true value reaches code ",
                              kTruthMinCode, " in the longest exposure")}};
  }
  report["merge"] = merge_json;
  summary.seconds = Seconds(start);
  timings["total"] = summary.seconds;
  report["timings_s"] = timings;
  summary.report_json = report.dump(2) + "\n";

  // Files of the report.
  Json response_file = ResponseJson(fit.response);
  REFLCAP_RETURN_IF_ERROR(
      WriteTextFileAtomic(out_dir / "radiometry" / "response.json", response_file.dump(2) + "\n"));
  REFLCAP_RETURN_IF_ERROR(WriteTextFileAtomic(out_dir / "radiometry" / "report.json", summary.report_json));
  ReportImages figures;
  if (weight_merged) figures.weights = &*weight_merged;
  if (chart_merged) {
    figures.chart = &*chart_merged;
    REFLCAP_RETURN_IF_ERROR(WriteExr(out_dir / "radiometry" / "chart_hdr.exr", chart_merged->value));
  }
  if (detection) figures.detection = &*detection;
  figures.response = &fit.response;
  if (have_truth_curve) figures.truth_x_of_code = &set.truth.x_of_code;
  REFLCAP_RETURN_IF_ERROR(WriteHdrReport(out_dir / "radiometry", report, figures));
  return summary;
}

}  // namespace reflcap::radiometry
