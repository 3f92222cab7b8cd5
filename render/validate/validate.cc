// `reflcap validate` as a library (see validate.h).
#include "render/validate/validate.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <mutex>
#include <sstream>

#include <nlohmann/json.hpp>

#include "engine/core/atomic_file.h"
#include "engine/core/html.h"
#include "engine/core/log.h"
#include "engine/core/parallel.h"
#include "engine/core/progress.h"
#include "engine/image/exr_io.h"
#include "engine/image/image_io.h"
#include "engine/image/png_io.h"
#include "render/reference/reference_renderer.h"
#include "render/validate/figures.h"

namespace reflcap::validate {
namespace fs = std::filesystem;
using Json = nlohmann::json;

namespace {

double SecondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

Json OrNull(const std::optional<double>& v) {
  return v && std::isfinite(*v) ? Json(*v) : Json(nullptr);
}

// Adds the worst-pixel share fields to *j.
void SharesJson(const std::array<std::optional<double>, kWorstShareCount>& shares, Json* j) {
  static_assert(kWorstShareCount == 2 && kWorstPerMille[0] == 1 && kWorstPerMille[1] == 10,
                "the field names below name 0.1 % and 1 %");
  (*j)["worst_0_1pct_error_share"] = OrNull(shares[0]);
  (*j)["worst_1pct_error_share"] = OrNull(shares[1]);
}

std::string RegionList(uint8_t bits) {
  std::string out;
  for (int k = 0; k < kRegionCount; ++k) {
    if (bits & (1u << k)) out += (out.empty() ? "" : " ") + std::string(RegionName(k));
  }
  return out;
}

std::string Fixed(const std::optional<double>& v, int digits) {
  if (!v) return "&ndash;";
  char text[64];
  std::snprintf(text, sizeof text, "%.*f", digits, *v);
  return text;
}

// A key usable as one file name: "raw/a" -> "raw_a".
std::string FlatKey(const std::string& key) {
  std::string out = key;
  std::replace(out.begin(), out.end(), '/', '_');
  return out;
}

// Capture-side silhouette mask of a photograph, when the capture has one (see metrics.h).
std::optional<fs::path> CaptureMaskPath(const Capture& capture, const CaptureImage& image) {
  if (capture.normal_map) return capture.Resolve(capture.normal_map->mask);
  char name[160];
  std::snprintf(name, sizeof name, "masks/%s_%03ld.png", capture.cameras[image.camera].id.c_str(),
                std::lround(image.turntable_deg));
  const fs::path path = capture.Resolve(name);
  std::error_code ec;
  if (fs::is_regular_file(path, ec)) return path;
  return std::nullopt;
}

// Aux buffers re-ordered to render::AuxChannel, or nullopt when a channel is missing.
std::optional<Image> ReadAux(const fs::path& path, std::string* problem) {
  std::vector<std::string> names;
  auto image = ReadExrChannels(path, &names);
  if (!image.ok()) {
    *problem = image.status().message();
    return std::nullopt;
  }
  const auto& wanted = render::AuxChannelNames();
  std::vector<int> index(wanted.size(), -1);
  for (size_t k = 0; k < wanted.size(); ++k) {
    for (size_t j = 0; j < names.size(); ++j) {
      if (names[j] == wanted[k]) index[k] = int(j);
    }
    if (index[k] < 0) {
      *problem = StrCat(path.string(), ": no channel \"", wanted[k], "\"");
      return std::nullopt;
    }
  }
  Image aux(image->width, image->height, int(wanted.size()));
  for (size_t p = 0; p < image->PixelCount(); ++p) {
    for (size_t k = 0; k < wanted.size(); ++k) {
      aux.data[p * wanted.size() + k] = image->data[p * image->channels + size_t(index[k])];
    }
  }
  return aux;
}

struct Entry {
  size_t index = 0;  // into capture.images
  std::string render, mask, aux, key;
  bool figure = false;
  bool has_aux = false;
  ImageScore score;
  size_t geometric_pixels = 0;
  double p99_error = 0;
};

Json SumsJson(const ErrorSums& s, bool with_ssim) {
  Json j = {{"psnr_db", OrNull(s.PsnrDb())},
            {"psnr_l_db", OrNull(s.PsnrLDb())},
            {"rel_rmse", OrNull(s.RelRmse())}};
  if (with_ssim) j["ssim"] = OrNull(s.Ssim());
  return j;
}

Json RegionsJson(const std::array<ErrorSums, kRegionCount>& regions, const ErrorSums& total,
                 bool noise) {
  Json j = Json::object();
  for (int k = 0; k < kRegionCount; ++k) {
    const ErrorSums& r = regions[k];
    Json region = {{"pixels", size_t(r.pixels)},
                   {"fraction", total.pixels > 0 ? r.pixels / total.pixels : 0.0},
                   {"psnr_db", OrNull(r.PsnrDb())},
                   {"psnr_l_db", OrNull(r.PsnrLDb())},
                   {"rel_rmse", OrNull(r.RelRmse())},
                   {"sse_share", total.sse_over_peak2 > 0 ? r.sse_over_peak2 / total.sse_over_peak2
                                                          : 0.0}};
    if (noise) region["noise_bound_psnr_db"] = OrNull(r.NoiseBoundDb());
    j[RegionName(k)] = region;
  }
  return j;
}

Json Definitions(const ValidateOptions& o) {
  return {
      {"evaluated_pixels",
       StrCat("erode(render mask AND capture silhouette mask when present, ", o.score.erode_px,
              " px disc), minus photograph pixels that are non-finite or at/above "
              "images[].saturation")},
      {"peak", "max of the photograph over the evaluated pixels and RGB channels, per image"},
      {"psnr_db", StrCat("10 log10(peak^2 / MSE) over evaluated pixels and RGB channels; an exact "
                         "match reports the cap ", kMaxPsnrDb, " dB")},
      {"rel_rmse", "sqrt(sum (r - p)^2 / sum p^2) over evaluated pixels and RGB channels"},
      {"psnr_l_db",
       StrCat("Stanford-ORB LDR PSNR: photograph and render divided by q99 = the photograph's "
              "99th percentile over evaluated pixels and RGB channels (nearest rank; psnr_l_white), "
              "clipped to [0, 1], sRGB-encoded (IEC 61966-2-1 OETF); 10 log10(1 / MSE) over "
              "evaluated pixels and RGB, capped at ", kMaxPsnrDb, " dB; null when q99 is not "
              "positive and finite. Pooled: the mean LDR squared error over all pixel channels of "
              "the images that have one")},
      {"worst_error_share",
       "worst_0_1pct_error_share / worst_1pct_error_share: share of sum e over the evaluated pixels "
       "carried by the ceil(0.001 n) / ceil(0.01 n) pixels of largest e, e = sum over RGB of "
       "(r - p)^2 (raw render); pooled over images with e divided by its image's peak^2 (as "
       "psnr_db pools); null when sum e = 0"},
      {"worst_pixels",
       StrCat("the ", kWorstPixelsListed, " evaluated pixels of largest e / peak^2 over all "
              "images: image file, pixel x (column) and y (row, 0 = top), photograph and render RGB, "
              "error = e, error_share = its share of the pooled e / peak^2, regions")},
      {"tone_map", "t(x) = (y / (1 + y))^(1/2.2), y = max(x, 0) / m, m = mean of the photograph "
                   "over the evaluated pixels and channels; same t for photograph and render"},
      {"ssim", "Wang et al. 2004 on tone-mapped images per channel: 11x11 Gaussian window, sigma "
               "1.5 px, C1 = (0.01 L)^2, C2 = (0.03 L)^2, L = 1; window statistics restricted to "
               "evaluated pixels (weights renormalised); mean over evaluated pixels and channels"},
      {"scaled", "Stanford-ORB convention: render multiplied per channel by the least-squares "
                 "scale s_c = sum p_c r_c / sum r_c^2 over the image's evaluated pixels"},
      {"regions",
       {{"shadow_edge", StrCat("within ", o.score.shadow_edge_px,
                               " px of a cast-shadow boundary (4-neighbours, one cast-shadowed, "
                               "one lit) of the render's aux buffers")},
        {"high_curvature", StrCat("scale-free curvature (max normal turning rate x object size; "
                                  "1 on a sphere) > ", o.score.high_curvature)},
        {"grazing", StrCat("cos theta_i < ", o.score.grazing_cos, " or cos theta_o < ",
                           o.score.grazing_cos, " at the shading normal")},
        {"elsewhere", "none of the three; the first three may overlap"},
        {"metrics", "raw (unscaled) psnr_db and rel_rmse; sse_share = region's share of the "
                    "pooled peak-normalised squared error"}}},
      {"noise_bound_psnr_db",
       "10 log10(peak^2 / mean variance), variance = photon_sigma_at_1^2 max(v, 0) + read_sigma^2 "
       "with v the render (noise-free estimate), from the capture's ground_truth.noise"},
      {"overall", "pooled over all evaluated pixels of all selected images: squared errors divided "
                  "by their image's peak^2 are pooled for psnr_db (and variances for the bound), "
                  "sum (r - p)^2 and sum p^2 for rel_rmse, SSIM averaged over pixels; "
                  "per_image_mean averages the per-image values"}};
}

// PSNR, PSNR-L, rel. RMSE, SSIM.
std::string MetricCells(const ErrorSums& s) {
  return "<td>" + Fixed(s.PsnrDb(), 2) + "</td><td>" + Fixed(s.PsnrLDb(), 2) + "</td><td>" +
         Fixed(s.RelRmse(), 4) + "</td><td>" + Fixed(s.Ssim(), 4) + "</td>";
}

std::string Share(const std::optional<double>& share) {
  return share ? Fixed(100 * *share, 2) + "%" : Fixed(share, 2);
}

std::string RgbText(const std::array<float, 3>& v) {
  char text[96];
  std::snprintf(text, sizeof text, "%.4g, %.4g, %.4g", double(v[0]), double(v[1]), double(v[2]));
  return text;
}

// Scalars of fit_report.json, flattened two levels deep ("timings.total_s").
void FlattenJson(const Json& j, const std::string& prefix, int depth,
                 std::vector<std::pair<std::string, std::string>>* rows) {
  for (auto it = j.begin(); it != j.end(); ++it) {
    const std::string key = prefix.empty() ? it.key() : prefix + "." + it.key();
    if (it->is_object()) {
      if (depth < 2) FlattenJson(*it, key, depth + 1, rows);
    } else if (it->is_primitive()) {
      rows->push_back({key, it->is_string() ? it->get<std::string>() : it->dump()});
    } else if (it->is_array() && it->size() <= 8) {
      rows->push_back({key, it->dump()});
    }
  }
}

}  // namespace

Status ValidateOptions::Validate() const {
  if (max_figures < 0) return InvalidArgumentError("--max-figures must be >= 0, got ", max_figures);
  if (!(error_scale >= 0) || !std::isfinite(error_scale)) {
    return InvalidArgumentError("--error-scale must be >= 0 (0 = automatic), got ", error_scale);
  }
  if (threads < 0 || threads > 1024) {
    return InvalidArgumentError("threads must be in [0, 1024], got ", threads);
  }
  if (!(score.erode_px >= 0) || score.erode_px > 64) {
    return InvalidArgumentError("erosion must be in [0, 64] px, got ", score.erode_px);
  }
  return OkStatus();
}

StatusOr<ValidateSummary> RunValidation(const Capture& capture, const fs::path& renders_dir,
                                        const fs::path& out_dir, const ValidateOptions& options) {
  REFLCAP_RETURN_IF_ERROR(options.Validate());
  const auto start = std::chrono::steady_clock::now();
  std::vector<Entry> entries;
  for (size_t i = 0; i < capture.images.size(); ++i) {
    const CaptureImage& image = capture.images[i];
    if (!render::IsSelected(options.split, image.split)) continue;
    Entry e;
    e.index = i;
    e.render = render::RenderPathFor(image.file);
    e.mask = render::MaskPathFor(image.file);
    e.aux = render::AuxPathFor(image.file);
    e.key = FlatKey(render::ImageKey(image.file));
    for (const std::string& f : {e.render, e.mask}) {
      std::error_code ec;
      if (!fs::is_regular_file(renders_dir / f, ec)) {
        return NotFoundError((renders_dir / f).string(), ": missing (the re-render of ",
                             image.file, "; run reflcap render with --split ",
                             render::SplitSelectionName(options.split), ")");
      }
    }
    entries.push_back(std::move(e));
  }
  if (entries.empty()) {
    return FailedPreconditionError(capture.json_path.string(), ": no image in split \"",
                                   render::SplitSelectionName(options.split), "\"");
  }
  // Figures: evenly spaced over the selection when it has more images than the cap.
  const size_t figure_count = std::min(entries.size(), size_t(options.max_figures));
  for (size_t k = 0; k < figure_count; ++k) entries[k * entries.size() / figure_count].figure = true;

  const std::optional<NoiseModel> noise = NoiseModelFromGroundTruth(capture.ground_truth_json);
  std::vector<Status> errors(entries.size());
  std::atomic<size_t> missing_aux{0};
  std::mutex log_mutex;
  Progress progress("validate", int64_t(entries.size()));
  ParallelFor(0, int64_t(entries.size()), 1, [&](int64_t b, int64_t e_end, int) {
    for (int64_t k = b; k < e_end; ++k) {
      Entry& e = entries[size_t(k)];
      const CaptureImage& image = capture.images[e.index];
      auto run = [&]() -> Status {
        REFLCAP_ASSIGN_OR_RETURN(Image photo, ReadImageRgb(capture.Resolve(image.file)));
        REFLCAP_ASSIGN_OR_RETURN(Image render, ReadExrRgb(renders_dir / e.render));
        REFLCAP_ASSIGN_OR_RETURN(Image render_mask, ReadPng(renders_dir / e.mask));
        for (const auto& [name, img] : {std::pair<std::string, const Image*>{e.render, &render},
                                        {e.mask, &render_mask}}) {
          if (img->width != photo.width || img->height != photo.height) {
            return InvalidArgumentError((renders_dir / name).string(), ": is ", img->width, "x",
                                        img->height, " but the photograph ", image.file, " is ",
                                        photo.width, "x", photo.height);
          }
        }
        Image geometric = BinaryMask(render_mask);
        if (auto path = CaptureMaskPath(capture, image)) {
          REFLCAP_ASSIGN_OR_RETURN(Image capture_mask, ReadPng(*path));
          if (capture_mask.width != photo.width || capture_mask.height != photo.height) {
            return InvalidArgumentError(path->string(), ": is ", capture_mask.width, "x",
                                        capture_mask.height, " but ", image.file, " is ",
                                        photo.width, "x", photo.height);
          }
          const Image m = BinaryMask(capture_mask);
          for (size_t p = 0; p < geometric.data.size(); ++p) geometric.data[p] *= m.data[p];
        }
        for (float v : geometric.data) e.geometric_pixels += v > 0.5f;
        std::optional<Image> aux;
        std::string problem;
        std::error_code ec;
        if (fs::is_regular_file(renders_dir / e.aux, ec)) {
          aux = ReadAux(renders_dir / e.aux, &problem);
          if (aux && (aux->width != photo.width || aux->height != photo.height)) {
            problem = StrCat((renders_dir / e.aux).string(), ": wrong size");
            aux.reset();
          }
        } else {
          problem = StrCat((renders_dir / e.aux).string(), ": missing");
        }
        if (!aux) {
          if (missing_aux++ == 0) {
            std::lock_guard<std::mutex> lock(log_mutex);
            REFLCAP_LOG(kWarning) << problem << "; no region breakdown for such images";
          }
        }
        e.has_aux = aux.has_value();
        size_t excluded = 0;
        const Image eval = EvaluationMask(geometric, photo, image.saturation,
                                          options.score.erode_px, &excluded);
        ScoreOptions score_options = options.score;
        score_options.keep_figure_data = e.figure;
        e.score = ScoreImage(photo, render, eval, aux ? &*aux : nullptr, noise, score_options);
        e.score.excluded_invalid = excluded;
        if (e.figure) {
          std::vector<float> errs;
          for (float v : e.score.error.data) {
            if (v >= 0) errs.push_back(v);
          }
          if (!errs.empty()) {
            const size_t q = std::min(errs.size() - 1, size_t(0.99 * double(errs.size())));
            std::nth_element(errs.begin(), errs.begin() + long(q), errs.end());
            e.p99_error = errs[q];
          }
        }
        return OkStatus();
      };
      errors[size_t(k)] = run();
      progress.Advance();
    }
  }, options.threads);
  progress.Finish();
  for (const Status& s : errors) REFLCAP_RETURN_IF_ERROR(s);
  const double score_s = SecondsSince(start);

  // Aggregate.
  ErrorSums raw, scaled;
  std::array<ErrorSums, kRegionCount> regions;
  bool all_regions = true;
  double mean_psnr = 0, mean_rel = 0, mean_ssim = 0, mean_spsnr = 0, mean_srel = 0, mean_sssim = 0,
         mean_bound = 0, mean_psnr_l = 0, mean_spsnr_l = 0;
  size_t scored = 0, scored_l = 0;
  // Pooled worst-pixel shares: every image's e / P², concatenated in image order (each image's
  // list is freed as it is moved, so the peak memory is one float per evaluated pixel).
  std::vector<float> pixel_errors;
  size_t total_pixels = 0;
  for (const Entry& e : entries) total_pixels += e.score.pixel_errors.size();
  pixel_errors.reserve(total_pixels);
  struct ListedPixel {
    size_t entry;
    WorstPixel pixel;
  };
  std::vector<ListedPixel> worst_pixels;
  Json images = Json::array();
  for (size_t n = 0; n < entries.size(); ++n) {
    Entry& e = entries[n];
    const CaptureImage& image = capture.images[e.index];
    const ImageScore& s = e.score;
    pixel_errors.insert(pixel_errors.end(), s.pixel_errors.begin(), s.pixel_errors.end());
    e.score.pixel_errors = std::vector<float>();
    for (const WorstPixel& px : s.worst_pixels) worst_pixels.push_back({n, px});
    if (s.raw.PsnrLDb()) {
      ++scored_l;
      mean_psnr_l += *s.raw.PsnrLDb();
      mean_spsnr_l += *s.scaled.PsnrLDb();
    }
    raw.Add(s.raw);
    scaled.Add(s.scaled);
    all_regions &= s.has_regions;
    if (s.has_regions) {
      for (int k = 0; k < kRegionCount; ++k) regions[k].Add(s.regions[k]);
    }
    if (s.raw.values > 0) {
      ++scored;
      mean_psnr += *s.raw.PsnrDb();
      mean_rel += s.raw.RelRmse().value_or(0);
      mean_ssim += *s.raw.Ssim();
      mean_spsnr += *s.scaled.PsnrDb();
      mean_srel += s.scaled.RelRmse().value_or(0);
      mean_sssim += *s.scaled.Ssim();
      if (noise) mean_bound += *s.raw.NoiseBoundDb();
    }
    Json j = {{"file", image.file},
              {"render", e.render},
              {"camera", capture.cameras[image.camera].id},
              {"light", capture.lights[image.light].id},
              {"turntable_deg", image.turntable_deg},
              {"split", SplitName(image.split)},
              {"pixels", size_t(s.raw.pixels)},
              {"excluded_saturated_or_nonfinite", s.excluded_invalid},
              {"peak", s.peak},
              {"psnr_db", OrNull(s.raw.PsnrDb())},
              {"psnr_l_db", OrNull(s.raw.PsnrLDb())},
              {"psnr_l_white", OrNull(s.q99)},
              {"rel_rmse", OrNull(s.raw.RelRmse())},
              {"ssim", OrNull(s.raw.Ssim())}};
    SharesJson(s.worst_share, &j);
    Json sj = SumsJson(s.scaled, true);
    sj["scale"] = {s.scale[0], s.scale[1], s.scale[2]};
    j["scaled"] = sj;
    j["regions"] = s.has_regions ? RegionsJson(s.regions, s.raw, noise.has_value()) : Json(nullptr);
    if (noise) j["noise_bound_psnr_db"] = OrNull(s.raw.NoiseBoundDb());
    if (e.figure) j["figure"] = "figures/" + e.key + ".png";
    images.push_back(j);
  }
  auto mean = [&](double sum) { return scored ? Json(sum / double(scored)) : Json(nullptr); };
  auto mean_l = [&](double sum) { return scored_l ? Json(sum / double(scored_l)) : Json(nullptr); };
  const auto worst_share = WorstErrorShares(&pixel_errors);
  pixel_errors = std::vector<float>();
  // Worst first; ties keep image order, then each image's own order (stable sort).
  std::stable_sort(worst_pixels.begin(), worst_pixels.end(),
                   [](const ListedPixel& a, const ListedPixel& b) {
                     return a.pixel.error_over_peak2 > b.pixel.error_over_peak2;
                   });
  if (worst_pixels.size() > size_t(kWorstPixelsListed)) worst_pixels.resize(kWorstPixelsListed);
  Json worst_json = Json::array();
  for (const ListedPixel& w : worst_pixels) {
    const Entry& e = entries[w.entry];
    const WorstPixel& px = w.pixel;
    Json region_names = Json::array();
    for (int k = 0; k < kRegionCount; ++k) {
      if (px.region_bits & (1u << k)) region_names.push_back(RegionName(k));
    }
    worst_json.push_back(
        {{"file", capture.images[e.index].file},
         {"x", px.x},
         {"y", px.y},
         {"photo", {px.photo[0], px.photo[1], px.photo[2]}},
         {"render", {px.render[0], px.render[1], px.render[2]}},
         {"error", OrNull(px.error)},
         {"error_share",
          OrNull(raw.sse_over_peak2 > 0
                     ? std::optional<double>(px.error_over_peak2 / raw.sse_over_peak2)
                     : std::nullopt)},
         {"regions", e.score.has_regions ? region_names : Json(nullptr)}});
  }
  Json overall = {{"images", entries.size()},
                  {"pixels", size_t(raw.pixels)},
                  {"psnr_db", OrNull(raw.PsnrDb())},
                  {"psnr_l_db", OrNull(raw.PsnrLDb())},
                  {"rel_rmse", OrNull(raw.RelRmse())},
                  {"ssim", OrNull(raw.Ssim())},
                  {"scaled", SumsJson(scaled, true)},
                  {"regions", all_regions ? RegionsJson(regions, raw, noise.has_value())
                                          : Json(nullptr)},
                  {"noise_bound_psnr_db", noise ? OrNull(raw.NoiseBoundDb()) : Json(nullptr)},
                  {"per_image_mean",
                   {{"psnr_db", mean(mean_psnr)},
                    {"psnr_l_db", mean_l(mean_psnr_l)},
                    {"rel_rmse", mean(mean_rel)},
                    {"ssim", mean(mean_ssim)},
                    {"scaled", {{"psnr_db", mean(mean_spsnr)}, {"psnr_l_db", mean_l(mean_spsnr_l)},
                                {"rel_rmse", mean(mean_srel)}, {"ssim", mean(mean_sssim)}}},
                    {"noise_bound_psnr_db", noise ? mean(mean_bound) : Json(nullptr)}}}};
  SharesJson(worst_share, &overall);
  overall["worst_pixels"] = worst_json;
  if (noise) {
    overall["noise_model"] = {{"photon_sigma_at_1", noise->photon_sigma_at_1},
                              {"read_sigma", noise->read_sigma}};
  }

  // Figures.
  const auto figures_start = std::chrono::steady_clock::now();
  std::error_code ec;
  fs::create_directories(out_dir / "figures", ec);
  if (ec) return InternalError((out_dir / "figures").string(), ": cannot create: ", ec.message());
  double error_scale = options.error_scale;
  if (error_scale <= 0) {
    double worst = 0;
    for (const Entry& e : entries) {
      if (e.figure) worst = std::max(worst, e.p99_error);
    }
    error_scale = NiceCeil(worst);
  }
  // Figures, composed and written in parallel (each from its own image's data).
  std::vector<const Entry*> figure_entries;
  for (const Entry& e : entries) {
    if (e.figure && !e.score.photo_tm.empty()) figure_entries.push_back(&e);
  }
  std::vector<Status> figure_errors(figure_entries.size());
  ParallelFor(0, int64_t(figure_entries.size()), 1, [&](int64_t b, int64_t end, int) {
    for (int64_t k = b; k < end; ++k) {
      const Entry& e = *figure_entries[size_t(k)];
      const CaptureImage& image = capture.images[e.index];
      char caption[256];
      std::snprintf(caption, sizeof caption, "%s  PSNR %s DB  REL RMSE %s  SSIM %s",
                    image.file.c_str(), Fixed(e.score.raw.PsnrDb(), 2).c_str(),
                    Fixed(e.score.raw.RelRmse(), 4).c_str(), Fixed(e.score.raw.Ssim(), 3).c_str());
      const Image figure = ComposeFigure(e.score.photo_tm, e.score.render_tm, e.score.error,
                                         error_scale, caption);
      Status s = WritePng(out_dir / "figures" / (e.key + ".png"), figure);
      if (s.ok() && e.has_aux) {
        s = WritePng(out_dir / "figures" / (e.key + "_regions.png"),
                     ComposeRegionMap(e.score.photo_tm, e.score.region_bits));
      }
      figure_errors[size_t(k)] = s;
    }
  }, options.threads);
  for (const Status& s : figure_errors) REFLCAP_RETURN_IF_ERROR(s);
  const size_t figures = figure_entries.size();
  const double figures_s = SecondsSince(figures_start);

  // Fit and sample sections.
  std::string fit_html, samples_html;
  if (!options.fit_dir.empty()) {
    const fs::path report = options.fit_dir / "fit_report.json";
    const fs::path status = options.fit_dir / "status.exr";
    std::vector<std::string> status_names, model_names;
    auto text = ReadTextFile(report);
    if (text.ok()) {
      const Json j = Json::parse(*text, nullptr, false);
      if (j.is_object()) {
        std::vector<std::pair<std::string, std::string>> rows;
        FlattenJson(j, "", 0, &rows);
        fit_html += "<table><tr><th>field</th><th>value</th></tr>\n";
        for (const auto& [k, v] : rows) {
          fit_html += "<tr><td>" + HtmlEscape(k) + "</td><td>" + HtmlEscape(v) + "</td></tr>\n";
        }
        fit_html += "</table>\n";
        if (auto it = j.find("model_names"); it != j.end() && it->is_array()) {
          for (const auto& n : *it) model_names.push_back(n.is_string() ? n.get<std::string>() : n.dump());
        }
        if (auto it = j.find("status_names"); it != j.end()) {
          if (it->is_array()) {
            for (const auto& n : *it) status_names.push_back(n.is_string() ? n.get<std::string>() : n.dump());
          } else if (it->is_object()) {
            for (auto n = it->begin(); n != it->end(); ++n) {
              char* stop = nullptr;
              const long code = std::strtol(n.key().c_str(), &stop, 10);
              if (*stop || code < 0 || code > 255) continue;
              if (status_names.size() <= size_t(code)) status_names.resize(size_t(code) + 1);
              status_names[size_t(code)] = n->is_string() ? n->get<std::string>() : n->dump();
            }
          }
        }
      } else {
        fit_html += "<p class=note>" + HtmlEscape(report.string()) + ": not valid JSON.</p>\n";
      }
    } else {
      fit_html += "<p class=note>No fit summary: " + HtmlEscape(report.string()) + " is absent.</p>\n";
    }
    std::vector<std::string> channel_names;
    auto codes = ReadExrChannels(status, &channel_names);
    if (codes.ok()) {
      // One categorical map per channel the fit wrote: its status, the model each texel ended
      // with, and its material cluster (older FIT folders lack the last two: skipped).
      struct Map {
        std::string channel, png, title;
        std::vector<std::string> names;
      };
      std::vector<std::string> cluster_names;
      const std::vector<Map> maps = {
          {"status", "status.png", "Fit status per texel", status_names},
          {"model", "model.png", "Model per texel (what its parameters are)", model_names},
          {"material_cluster", "clusters.png", "Material cluster per texel", cluster_names}};
      for (const Map& map : maps) {
        int channel = -1;
        for (size_t k = 0; k < channel_names.size(); ++k) {
          if (channel_names[k] == map.channel || (map.channel == "status" && channel_names[k] == "Y")) {
            channel = int(k);
          }
        }
        if (channel < 0) continue;
        Image one(codes->width, codes->height, 1);
        Image valid(codes->width, codes->height, 1);
        for (size_t p = 0; p < one.PixelCount(); ++p) {
          const float v = codes->data[p * codes->channels + size_t(channel)];
          one.data[p] = v;
          valid.data[p] = std::isfinite(v) && v >= 0 ? 1.0f : 0.0f;
        }
        REFLCAP_RETURN_IF_ERROR(
            WritePng(out_dir / map.png, ComposeCategoricalMap(one, &valid, map.names)));
        fit_html += "<h3>" + map.title + "</h3><p>" + HtmlEscape(status.string()) + " channel " +
                    map.channel +
                    " in atlas layout; black = no texel (negative or non-finite code).</p>"
                    "<img src=\"" + map.png + "\" alt=\"" + map.title + "\">\n";
      }
    } else {
      fit_html += "<p class=note>No status map: " + HtmlEscape(codes.status().message()) + "</p>\n";
    }
  }
  if (!options.samples_dir.empty()) {
    const fs::path coverage = options.samples_dir / "coverage.png";
    if (fs::is_regular_file(coverage, ec)) {
      fs::copy_file(coverage, out_dir / "coverage.png", fs::copy_options::overwrite_existing, ec);
      if (ec) return InternalError(coverage.string(), ": cannot copy: ", ec.message());
      samples_html = "<p>" + HtmlEscape(coverage.string()) +
                     " (samples per texel, from the resampler):</p>"
                     "<img src=\"coverage.png\" alt=\"sample coverage map\">\n";
    } else {
      samples_html = "<p class=note>No coverage map: " + HtmlEscape(coverage.string()) +
                     " is absent.</p>\n";
    }
  }

  const double total_s = SecondsSince(start);
  Json timings = {{"score_s", score_s}, {"figures_s", figures_s}, {"total_s", total_s}};
  std::string render_timings;  // table rows
  if (auto text = ReadTextFile(renders_dir / "render_report.json"); text.ok()) {
    const Json j = Json::parse(*text, nullptr, false);
    if (j.is_object() && j.contains("timings") && j["timings"].is_object()) {
      timings["render"] = j["timings"];
      const std::string device = j.value("backend", "?") + ", " + j.value("device", "?");
      for (auto it = j["timings"].begin(); it != j["timings"].end(); ++it) {
        if (!it->is_number()) continue;
        render_timings += "<tr><td>render (" + HtmlEscape(device) + "): " + HtmlEscape(it.key()) +
                          "</td><td>" + Fixed(it->get<double>(), 2) + "</td></tr>\n";
      }
    }
  }
  Json metrics = {{"capture", capture.json_path.string()},
                  {"renders", renders_dir.string()},
                  {"split", render::SplitSelectionName(options.split)},
                  {"definitions", Definitions(options)},
                  {"figures", {{"count", figures},
                               {"cap", options.max_figures},
                               {"error_scale_fraction_of_peak", error_scale}}},
                  {"images", images},
                  {"overall", overall},
                  {"timings", timings}};
  REFLCAP_RETURN_IF_ERROR(WriteTextFileAtomic(out_dir / "metrics.json", metrics.dump(2) + "\n"));

  // report.html
  std::ostringstream html;
  html << "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
       << "<title>reflcap validation: " << HtmlEscape(capture.json_path.string()) << "</title>\n"
       << "<style>body{font-family:sans-serif;margin:2em;max-width:80em}"
          "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #bbb;"
          "padding:2px 8px;text-align:right}th{background:#eee}td:first-child{text-align:left}"
          "img{max-width:100%;image-rendering:pixelated}.note{color:#a60}</style>\n"
       << "</head>\n<body>\n<h1>Validation renders</h1>\n"
       << "<p>Capture <code>" << HtmlEscape(capture.json_path.string()) << "</code>, renders <code>"
       << HtmlEscape(renders_dir.string()) << "</code>, split <b>"
       << render::SplitSelectionName(options.split) << "</b>: " << entries.size() << " images, "
       << size_t(raw.pixels) << " evaluated pixels.</p>\n";
  html << "<h2>Summary</h2>\n<table><tr><th></th><th>PSNR (dB)</th><th>PSNR-L (dB)</th>"
          "<th>rel. RMSE</th><th>SSIM</th></tr>\n<tr><td>raw, pooled</td>"
       << MetricCells(raw) << "</tr>\n<tr><td>LS-scaled (Stanford-ORB), pooled</td>"
       << MetricCells(scaled) << "</tr>\n<tr><td>raw, mean over images</td><td>"
       << Fixed(scored ? std::optional<double>(mean_psnr / double(scored)) : std::nullopt, 2)
       << "</td><td>"
       << Fixed(scored_l ? std::optional<double>(mean_psnr_l / double(scored_l)) : std::nullopt, 2)
       << "</td><td>"
       << Fixed(scored ? std::optional<double>(mean_rel / double(scored)) : std::nullopt, 4)
       << "</td><td>"
       << Fixed(scored ? std::optional<double>(mean_ssim / double(scored)) : std::nullopt, 4)
       << "</td></tr>\n</table>\n<p>PSNR-L: Stanford-ORB's LDR PSNR (both images divided by the "
          "photograph's 99th percentile, clipped to [0, 1], sRGB-encoded). Worst-pixel share of "
          "the pooled squared error: worst 0.1 % of pixels "
       << Share(worst_share[0]) << ", worst 1 % " << Share(worst_share[1]) << ".</p>\n";
  if (noise) {
    html << "<p>Noise bound (PSNR a perfect re-render scores under the capture's noise model, "
            "photon &sigma; "
         << noise->photon_sigma_at_1 << " at 1, read &sigma; " << noise->read_sigma << "): <b>"
         << Fixed(raw.NoiseBoundDb(), 2) << " dB</b>; the pooled PSNR is "
         << Fixed(raw.PsnrDb() && raw.NoiseBoundDb()
                      ? std::optional<double>(*raw.PsnrDb() - *raw.NoiseBoundDb())
                      : std::nullopt,
                  2)
         << " dB from it.</p>\n";
  } else {
    html << "<p class=note>No noise model in the capture (ground_truth.noise): no noise bound.</p>\n";
  }
  html << "<h2>Where the error is</h2>\n";
  if (all_regions) {
    html << "<table><tr><th>region</th><th>pixels</th><th>share of pixels</th>"
            "<th>share of squared error</th><th>PSNR (dB)</th><th>PSNR-L (dB)</th>"
            "<th>rel. RMSE</th></tr>\n";
    for (int k = 0; k < kRegionCount; ++k) {
      const ErrorSums& r = regions[k];
      html << "<tr><td>" << RegionName(k) << "</td><td>" << size_t(r.pixels) << "</td><td>"
           << Fixed(raw.pixels > 0 ? std::optional<double>(100 * r.pixels / raw.pixels)
                                   : std::nullopt, 1)
           << "%</td><td>"
           << Fixed(raw.sse_over_peak2 > 0
                        ? std::optional<double>(100 * r.sse_over_peak2 / raw.sse_over_peak2)
                        : std::nullopt, 1)
           << "%</td><td>" << Fixed(r.PsnrDb(), 2) << "</td><td>" << Fixed(r.PsnrLDb(), 2)
           << "</td><td>" << Fixed(r.RelRmse(), 4)
           << "</td></tr>\n";
    }
    html << "</table>\n<p>shadow_edge: within " << options.score.shadow_edge_px
         << " px of a cast-shadow boundary; high_curvature: scale-free curvature &gt; "
         << options.score.high_curvature << " (1 on a sphere); grazing: cos &theta;<sub>i</sub> or "
            "cos &theta;<sub>o</sub> &lt; "
         << options.score.grazing_cos
         << "; elsewhere: none of these. The first three may overlap.</p>\n";
  } else {
    html << "<p class=note>Some renders have no aux buffers: no region breakdown.</p>\n";
  }
  html << "<h2>Per image</h2>\n<table><tr><th>file</th><th>camera</th><th>light</th>"
          "<th>turntable (&deg;)</th><th>pixels</th><th>PSNR (dB)</th><th>PSNR-L (dB)</th>"
          "<th>rel. RMSE</th><th>SSIM</th><th>scaled PSNR</th><th>scaled PSNR-L</th>"
          "<th>scaled rel. RMSE</th><th>scaled SSIM</th><th>worst 0.1 % share</th>"
       << (noise ? "<th>noise bound (dB)</th>" : "") << "</tr>\n";
  for (const Entry& e : entries) {
    const CaptureImage& image = capture.images[e.index];
    html << "<tr><td>" << (e.figure ? "<a href=\"#" + HtmlEscape(e.key) + "\">" : "")
         << HtmlEscape(image.file) << (e.figure ? "</a>" : "") << "</td><td>"
         << HtmlEscape(capture.cameras[image.camera].id) << "</td><td>"
         << HtmlEscape(capture.lights[image.light].id) << "</td><td>" << image.turntable_deg
         << "</td><td>" << size_t(e.score.raw.pixels) << "</td>" << MetricCells(e.score.raw)
         << MetricCells(e.score.scaled) << "<td>" << Share(e.score.worst_share[0]) << "</td>";
    if (noise) html << "<td>" << Fixed(e.score.raw.NoiseBoundDb(), 2) << "</td>";
    html << "</tr>\n";
  }
  html << "</table>\n<h2>Worst pixels</h2>\n";
  if (worst_pixels.empty()) {
    html << "<p class=note>No evaluated pixel has an error.</p>\n";
  } else {
    html << "<p>The " << worst_pixels.size() << " evaluated pixels of largest error e = "
            "&Sigma;<sub>RGB</sub> (r &minus; p)&sup2; relative to their image's peak&sup2;, over "
            "all images; x = column, y = row (0 = top).</p>\n<table><tr><th>image</th><th>x</th>"
            "<th>y</th><th>photograph RGB</th><th>render RGB</th><th>e</th>"
            "<th>share of squared error</th><th>regions</th></tr>\n";
    for (const ListedPixel& w : worst_pixels) {
      const Entry& e = entries[w.entry];
      const WorstPixel& px = w.pixel;
      html << "<tr><td>" << (e.figure ? "<a href=\"#" + HtmlEscape(e.key) + "\">" : "")
           << HtmlEscape(capture.images[e.index].file) << (e.figure ? "</a>" : "") << "</td><td>"
           << px.x << "</td><td>" << px.y << "</td><td>" << RgbText(px.photo) << "</td><td>"
           << RgbText(px.render) << "</td><td>" << Fixed(px.error, 5) << "</td><td>"
           << Share(raw.sse_over_peak2 > 0
                        ? std::optional<double>(px.error_over_peak2 / raw.sse_over_peak2)
                        : std::nullopt)
           << "</td><td>" << (e.score.has_regions ? RegionList(px.region_bits) : "&ndash;")
           << "</td></tr>\n";
    }
    html << "</table>\n";
  }
  html << "<h2>Figures</h2>\n<p>Photograph | re-render | error |r &minus; p| / peak "
          "(mean over RGB; colour bar in % of the photograph's peak, "
       << FormatPercent(error_scale) << " at the top; grey = not evaluated). Tone map: x/(1+x) "
          "after dividing by the photograph's mean over the evaluated pixels, then gamma 1/2.2, "
          "the same for both images. "
       << figures << " of " << entries.size() << " images (at most " << options.max_figures
       << ", evenly spaced).</p>\n";
  for (const Entry& e : entries) {
    if (!e.figure) continue;
    html << "<h3 id=\"" << HtmlEscape(e.key) << "\">" << HtmlEscape(capture.images[e.index].file)
         << "</h3>\n<img src=\"figures/" << HtmlEscape(e.key) << ".png\" alt=\"comparison\">\n";
    if (e.has_aux) {
      html << "<br><img src=\"figures/" << HtmlEscape(e.key)
           << "_regions.png\" alt=\"regions\">\n";
    }
  }
  html << "<h2>Fit</h2>\n"
       << (options.fit_dir.empty() ? "<p class=note>No fit folder given (--fit FIT).</p>\n" : fit_html)
       << "<h2>Sample coverage</h2>\n"
       << (options.samples_dir.empty()
               ? "<p class=note>No sample store given (--samples SAMPLES).</p>\n"
               : samples_html)
       << "<h2>Timings</h2>\n<table><tr><th>stage</th><th>seconds</th></tr>\n"
       << "<tr><td>load and score</td><td>" << Fixed(score_s, 2) << "</td></tr>\n"
       << "<tr><td>figures</td><td>" << Fixed(figures_s, 2) << "</td></tr>\n"
       << "<tr><td>validate total</td><td>" << Fixed(total_s, 2) << "</td></tr>\n"
       << render_timings << "</table>\n";
  html << "<p>Definitions: see metrics.json <code>definitions</code> and README.md "
          "(reflcap validate).</p>\n</body>\n</html>\n";
  REFLCAP_RETURN_IF_ERROR(WriteTextFileAtomic(out_dir / "report.html", html.str()));

  ValidateSummary summary;
  summary.images = entries.size();
  summary.pixels = size_t(raw.pixels);
  summary.figures = figures;
  summary.psnr_db = raw.PsnrDb();
  summary.rel_rmse = raw.RelRmse();
  summary.ssim = raw.Ssim();
  summary.scaled_psnr_db = scaled.PsnrDb();
  summary.scaled_rel_rmse = scaled.RelRmse();
  summary.scaled_ssim = scaled.Ssim();
  summary.psnr_l_db = raw.PsnrLDb();
  summary.scaled_psnr_l_db = scaled.PsnrLDb();
  summary.worst_0_1pct_error_share = worst_share[0];
  summary.worst_1pct_error_share = worst_share[1];
  if (noise) summary.noise_bound_psnr_db = raw.NoiseBoundDb();
  summary.seconds = SecondsSince(start);
  return summary;
}

}  // namespace reflcap::validate
