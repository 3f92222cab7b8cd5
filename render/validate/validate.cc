// `reflcap validate` as a library (see validate.h).
#include "render/validate/validate.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <future>
#include <limits>
#include <map>
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
#include "render/validate/pixel_texels.h"

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

// Fixed() without the HTML entity, for the text drawn into figures.
std::string PlainFixed(const std::optional<double>& v, int digits) {
  return v ? Fixed(v, digits) : "-";
}

// The legend of the shared error-map scale (REPORT/<this>), and its words (report, metrics.json).
constexpr char kColourBarPng[] = "error_scale.png";
constexpr char kColourMapText[] =
    "viridis (dark purple = 0, yellow = the scale; larger errors saturate at yellow; dark grey = "
    "not evaluated)";
constexpr char kMapErrorText[] =
    "|r - p| / peak, mean over RGB, per pixel (p photograph, r re-render, peak the photograph's "
    "maximum over its evaluated pixels)";

// The page's style: readable at any width, no external resource.
constexpr char kReportCss[] =
    "body{font-family:system-ui,-apple-system,'Segoe UI',sans-serif;margin:0 auto;"
    "padding:1em 2em 3em;max-width:1200px;color:#222;line-height:1.4}"
    "h1{font-size:1.5em;margin:.4em 0 .2em}h2{font-size:1.25em;border-bottom:2px solid #ddd;"
    "padding-bottom:.15em;margin-top:1.8em}h3{font-size:1.05em;margin:.6em 0 .3em}"
    ".meta,.small{color:#555;font-size:.88em}code{word-break:break-all}nav{margin:.5em 0;"
    "font-size:.92em}a{color:#1a5fb4}"
    ".cards{display:flex;flex-wrap:wrap;gap:10px;margin:.8em 0}.card{border:1px solid #ccc;"
    "border-radius:6px;padding:6px 12px;min-width:8.4em;background:#f7f7f7}"
    ".card .k{font-size:.82em;color:#555}.card .v{font-size:1.6em;font-weight:600}"
    ".card .s{font-size:.78em;color:#666}"
    ".cols{display:flex;flex-wrap:wrap;gap:2em}.cols>div{flex:1 1 24em}"
    "table{border-collapse:collapse;margin:.6em 0;font-size:.9em}td,th{border:1px solid #bbb;"
    "padding:2px 8px;text-align:right}th{background:#eee}td:first-child{text-align:left}"
    "table.kv td{text-align:left;vertical-align:top}"
    "img{max-width:100%;image-rendering:pixelated}figure{margin:.8em 0}"
    "figcaption{font-size:.88em;color:#333;margin-top:.2em}"
    ".pair{display:flex;gap:6px;align-items:flex-start}.pair a.cmp{flex:3.4}.pair a.reg{flex:1}"
    ".pair img{width:100%;display:block}.big .pair a.reg{flex:0 0 17%}"
    ".grid{display:grid;grid-template-columns:repeat(auto-fill,minmax(540px,1fr));gap:12px 20px}"
    ".wide{overflow-x:auto}"
    ".maps{display:grid;grid-template-columns:repeat(auto-fill,minmax(300px,1fr));gap:16px}"
    ".maps img{width:100%}.legend img{width:min(100%,640px)}.note{color:#a60}";

// One summary number: name, value, a line below.
std::string Card(const std::string& name, const std::string& value, const std::string& below) {
  return "<div class=card><div class=k>" + name + "</div><div class=v>" + value +
         "</div><div class=s>" + below + "</div></div>\n";
}

// "converged 93.1 %, max_iterations 6.9 % of 1234 texels" (largest first); for clusters, their
// number and the largest one's share. HTML.
std::string CountsText(const std::map<long, size_t>& counts, const std::vector<std::string>& names,
                       size_t texels, bool clusters) {
  if (texels == 0) return "no texel";
  std::vector<std::pair<long, size_t>> sorted(counts.begin(), counts.end());
  std::stable_sort(sorted.begin(), sorted.end(),
                   [](const auto& a, const auto& b) { return a.second > b.second; });
  const auto percent = [&](size_t n) { return Fixed(100.0 * double(n) / double(texels), 1) + " %"; };
  if (clusters) {
    return std::to_string(sorted.size()) + " cluster" + (sorted.size() == 1 ? "" : "s") +
           " over " + std::to_string(texels) + " texels (largest " +
           percent(sorted.front().second) + ")";
  }
  std::string out;
  for (const auto& [code, n] : sorted) {
    const std::string name = code >= 0 && size_t(code) < names.size() && !names[size_t(code)].empty()
                                 ? names[size_t(code)]
                                 : "code " + std::to_string(code);
    out += (out.empty() ? "" : ", ") + HtmlEscape(name) + " " + percent(n);
  }
  return out + " of " + std::to_string(texels) + " texels";
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
  size_t rank = 0;  // by error, 1 = worst (largest MSE / peak^2, i.e. lowest PSNR)
};

// The caption of an image's comparison figure on the page (HTML).
std::string FigureCaption(const Capture& capture, const Entry& e) {
  const CaptureImage& image = capture.images[e.index];
  char turntable[32];
  std::snprintf(turntable, sizeof turntable, "%g", image.turntable_deg);
  return "<b>#" + std::to_string(e.rank) + " " + HtmlEscape(image.file) + "</b> &middot; camera " +
         HtmlEscape(capture.cameras[image.camera].id) + ", light " +
         HtmlEscape(capture.lights[image.light].id) + ", turntable " + turntable +
         "&deg; &middot; PSNR " + Fixed(e.score.raw.PsnrDb(), 2) + " dB, PSNR-L " +
         Fixed(e.score.raw.PsnrLDb(), 2) + " dB, rel. RMSE " + Fixed(e.score.raw.RelRmse(), 4) +
         ", SSIM " + Fixed(e.score.raw.Ssim(), 4);
}

// The comparison figure of an image and its region map beside it (when drawn), each a link to
// itself: the browser shows it at full size, no script needed (HTML).
std::string FigureImages(const Capture& capture, const Entry& e) {
  const std::string file = HtmlEscape(capture.images[e.index].file);
  const std::string png = "figures/" + HtmlEscape(e.key) + ".png";
  std::string out = "<div class=pair><a class=cmp href=\"" + png + "\"><img src=\"" + png +
                    "\" alt=\"photograph, re-render and error map of " + file + "\"></a>";
  if (e.has_aux) {
    const std::string regions = "figures/" + HtmlEscape(e.key) + "_regions.png";
    out += "<a class=reg href=\"" + regions + "\"><img src=\"" + regions +
           "\" alt=\"regions of " + file + "\"></a>";
  }
  return out + "</div>";
}

// metrics.json worst_pixels[].texel: null fields where unknown (no texel, no channel, no store).
Json TexelJson(const PixelTexel& t) {
  if (t.texel < 0) return {{"index", nullptr}};
  const auto code = [](int c) { return c >= 0 ? Json(c) : Json(nullptr); };
  const auto name = [](const std::string& n) { return n.empty() ? Json(nullptr) : Json(n); };
  Json j = {{"index", t.texel},
            {"model", code(t.model)},
            {"model_name", name(t.model_name)},
            {"status", code(t.status)},
            {"status_name", name(t.status_name)},
            {"material_cluster", code(t.cluster)},
            {"lobe_donor", std::isfinite(t.lobe_donor) ? Json(t.lobe_donor) : Json(nullptr)}};
  if (t.train_samples >= 0) {
    j["train_samples"] = t.train_samples;
    j["brightest_train"] = {t.brightest[0], t.brightest[1], t.brightest[2]};
  } else {
    j["train_samples"] = nullptr;
    j["brightest_train"] = nullptr;
  }
  return j;
}

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
      {"error_map",
       StrCat("figures' error maps: ", kMapErrorText, "; colour map ", kColourMapText,
              "; one scale for all maps (figures.error_scale): given, or the ",
              kMapErrorScaleQuantile, " quantile of this error over all evaluated pixels of all "
              "selected images (log histogram, ", kMapErrorBinsPerDecade, " bins per decade, the "
              "upper edge of the bin holding it) rounded up to 1, 2, 2.5 or 5 x 10^k")},
      {"error_rank", "images ranked by MSE / peak^2 (lowest PSNR first), 1 = worst; ties keep "
                     "image order; the worst (figures.worst_shown) always get figures"},
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

// An image's re-render as validation reads it: pixels, mask and aux buffers (aux empty, with
// `aux_problem` saying why, when the image has none).
struct Rendered {
  Image pixels;
  Image mask;
  std::optional<Image> aux;
  std::string aux_problem;
};

// Reads the re-render of `e` from its files in renders_dir.
StatusOr<Rendered> ReadRendered(const fs::path& renders_dir, const Entry& e) {
  Rendered r;
  REFLCAP_ASSIGN_OR_RETURN(r.pixels, ReadExrRgb(renders_dir / e.render));
  REFLCAP_ASSIGN_OR_RETURN(r.mask, ReadPng(renders_dir / e.mask));
  std::error_code ec;
  if (fs::is_regular_file(renders_dir / e.aux, ec)) {
    r.aux = ReadAux(renders_dir / e.aux, &r.aux_problem);
  } else {
    r.aux_problem = StrCat((renders_dir / e.aux).string(), ": missing");
  }
  return r;
}

// What the files of `result` hold once render writes them (RenderCapture: WriteExr, WritePng,
// WriteExrChannels): NaN as 0 and values beyond the float range clamped to it; the mask as its
// 8-bit PNG reads back (only whether it exceeds 0.5 is used: exactly when the value is >= 0.5).
Rendered AsWritten(const render::RenderResult& result) {
  auto finite = [](const Image& image) {
    Image out = image;
    constexpr float kMax = std::numeric_limits<float>::max();
    for (float& x : out.data) x = std::isnan(x) ? 0.0f : std::clamp(x, -kMax, kMax);
    return out;
  };
  Rendered r;
  r.pixels = finite(result.pixels);
  r.mask = Image(result.mask.width, result.mask.height, 1, 0.0f);
  for (size_t p = 0; p < r.mask.PixelCount(); ++p) {
    // WritePng: lround(clamp(x, 0, 1) * 255), a code >= 128 (read back > 0.5) iff x >= 0.5.
    r.mask.data[p] = result.mask.data[p * size_t(result.mask.channels)] >= 0.5f ? 1.0f : 0.0f;
  }
  if (result.aux.channels == int(render::AuxChannelNames().size())) {
    r.aux = finite(result.aux);
  } else {
    r.aux_problem = "the re-render has no aux buffers";
  }
  return r;
}

// Scores the photograph of `e` against its re-render `rendered` into e->score (figure data too
// when keep_figure_data); errors name the re-render by its file in renders_dir. *aux_problem
// receives why the image has no aux buffers (then it has no region breakdown), else stays empty.
Status ScoreEntry(const Capture& capture, const fs::path& renders_dir,
                  const ValidateOptions& options, const std::optional<NoiseModel>& noise,
                  bool keep_figure_data, const Rendered& rendered, Entry* entry,
                  std::string* aux_problem) {
  Entry& e = *entry;
  const CaptureImage& image = capture.images[e.index];
  REFLCAP_ASSIGN_OR_RETURN(Image photo, ReadImageRgb(capture.Resolve(image.file)));
  const Image& render = rendered.pixels;
  const Image& render_mask = rendered.mask;
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
  e.geometric_pixels = 0;
  for (float v : geometric.data) e.geometric_pixels += v > 0.5f;
  const Image* aux = rendered.aux ? &*rendered.aux : nullptr;
  std::string problem = rendered.aux_problem;
  if (aux != nullptr && (aux->width != photo.width || aux->height != photo.height)) {
    problem = StrCat((renders_dir / e.aux).string(), ": wrong size");
    aux = nullptr;
  }
  if (aux == nullptr) *aux_problem = problem;
  e.has_aux = aux != nullptr;
  size_t excluded = 0;
  const Image eval = EvaluationMask(geometric, photo, image.saturation,
                                    options.score.erode_px, &excluded);
  ScoreOptions score_options = options.score;
  score_options.keep_figure_data = keep_figure_data;
  e.score = ScoreImage(photo, render, eval, aux, noise, score_options);
  e.score.excluded_invalid = excluded;
  return OkStatus();
}

// ScoreEntry on the re-render's files.
Status ScoreEntryFromFiles(const Capture& capture, const fs::path& renders_dir,
                           const ValidateOptions& options, const std::optional<NoiseModel>& noise,
                           bool keep_figure_data, Entry* entry, std::string* aux_problem) {
  REFLCAP_ASSIGN_OR_RETURN(Rendered rendered, ReadRendered(renders_dir, *entry));
  return ScoreEntry(capture, renders_dir, options, noise, keep_figure_data, rendered, entry,
                    aux_problem);
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

// What StreamingValidation holds between Start, Score and Finish.
struct StreamingValidation::State {
  State(const Capture& c, fs::path dir, ValidateOptions o)
      : capture(c), renders_dir(std::move(dir)), options(std::move(o)) {}
  const Capture& capture;
  const fs::path renders_dir;
  const ValidateOptions options;
  std::vector<Entry> entries;
  std::vector<int64_t> entry_of_image;  // capture image -> entries index, -1 when not selected
  std::optional<NoiseModel> noise;
  std::future<StatusOr<std::unique_ptr<FitTexels>>> fit_texels;
  size_t worst_shown = 0;
  // Per entry: scored (from memory), its status; written only by the thread scoring that entry.
  std::vector<char> scored;
  std::vector<Status> errors;
  std::atomic<size_t> missing_aux{0};
  std::mutex log_mutex;

  // ScoreEntry's aux problem, logged once per validation.
  void NoteAuxProblem(const std::string& problem) {
    if (problem.empty() || missing_aux++ != 0) return;
    std::lock_guard<std::mutex> lock(log_mutex);
    REFLCAP_LOG(kWarning) << problem << "; no region breakdown for such images";
  }
};

StreamingValidation::StreamingValidation(std::unique_ptr<State> state) : state_(std::move(state)) {}
StreamingValidation::~StreamingValidation() {
  // The fit look-up data may still be loading: wait for it before the capture it reads goes.
  if (state_ && state_->fit_texels.valid()) state_->fit_texels.wait();
}

StatusOr<std::unique_ptr<StreamingValidation>> StreamingValidation::Start(
    const Capture& capture, const fs::path& renders_dir, const ValidateOptions& options) {
  REFLCAP_RETURN_IF_ERROR(options.Validate());
  auto state = std::make_unique<State>(capture, renders_dir, options);
  state->entry_of_image.assign(capture.images.size(), -1);
  for (size_t i = 0; i < capture.images.size(); ++i) {
    const CaptureImage& image = capture.images[i];
    if (!render::IsSelected(options.split, image.split)) continue;
    Entry e;
    e.index = i;
    e.render = render::RenderPathFor(image.file);
    e.mask = render::MaskPathFor(image.file);
    e.aux = render::AuxPathFor(image.file);
    e.key = FlatKey(render::ImageKey(image.file));
    state->entry_of_image[i] = int64_t(state->entries.size());
    state->entries.push_back(std::move(e));
  }
  if (state->entries.empty()) {
    return FailedPreconditionError(capture.json_path.string(), ": no image in split \"",
                                   render::SplitSelectionName(options.split), "\"");
  }
  // Figures: the worst images (known after scoring; those not drawn yet are scored again for
  // their figure data, in Finish) and evenly spaced ones over the selection, at most the cap in
  // all.
  std::vector<Entry>& entries = state->entries;
  const size_t figure_cap = std::min(entries.size(), size_t(options.max_figures));
  state->worst_shown = std::min(figure_cap, size_t(kWorstImagesShown));
  const size_t spaced = figure_cap - state->worst_shown;
  for (size_t k = 0; k < spaced; ++k) entries[k * entries.size() / spaced].figure = true;
  state->noise = NoiseModelFromGroundTruth(capture.ground_truth_json);
  state->scored.assign(entries.size(), 0);
  state->errors.assign(entries.size(), OkStatus());
  // With the fit: what the worst pixels' texels are looked up in (mesh, atlas, status.exr, the
  // store) loads while the images are scored; its status map serves the fit figures too.
  if (!options.fit_dir.empty()) {
    const State* s = state.get();
    state->fit_texels = std::async(std::launch::async, [s] {
      return FitTexels::Load(s->capture, s->options.fit_dir, s->options.samples_dir);
    });
  }
  return std::unique_ptr<StreamingValidation>(new StreamingValidation(std::move(state)));
}

Status StreamingValidation::Score(size_t index, const render::RenderResult& result) {
  State& s = *state_;
  if (index >= s.entry_of_image.size() || s.entry_of_image[index] < 0) return OkStatus();
  const size_t k = size_t(s.entry_of_image[index]);
  Entry& e = s.entries[k];
  std::string problem;
  Status status = ScoreEntry(s.capture, s.renders_dir, s.options, s.noise, e.figure,
                             AsWritten(result), &e, &problem);
  s.NoteAuxProblem(problem);
  s.errors[k] = status;
  s.scored[k] = 1;
  return status;
}

StatusOr<ValidateSummary> RunValidation(const Capture& capture, const fs::path& renders_dir,
                                        const fs::path& out_dir, const ValidateOptions& options) {
  REFLCAP_ASSIGN_OR_RETURN(std::unique_ptr<StreamingValidation> validation,
                           StreamingValidation::Start(capture, renders_dir, options));
  return validation->Finish(out_dir);
}

StatusOr<ValidateSummary> StreamingValidation::Finish(const fs::path& out_dir) {
  State& st = *state_;
  const Capture& capture = st.capture;
  const fs::path& renders_dir = st.renders_dir;
  const ValidateOptions& options = st.options;
  std::vector<Entry>& entries = st.entries;
  const std::optional<NoiseModel>& noise = st.noise;
  const size_t worst_shown = st.worst_shown;
  const auto start = std::chrono::steady_clock::now();
  // The images not scored while they were rendered are read from their files.
  std::vector<size_t> from_files;
  for (size_t k = 0; k < entries.size(); ++k) {
    REFLCAP_RETURN_IF_ERROR(st.errors[k]);
    if (st.scored[k]) continue;
    from_files.push_back(k);
    const Entry& e = entries[k];
    for (const std::string& f : {e.render, e.mask}) {
      std::error_code ec;
      if (!fs::is_regular_file(renders_dir / f, ec)) {
        return NotFoundError((renders_dir / f).string(), ": missing (the re-render of ",
                             capture.images[e.index].file, "; run reflcap render with --split ",
                             render::SplitSelectionName(options.split), ")");
      }
    }
  }
  const size_t scored_while_rendering = entries.size() - from_files.size();
  Progress progress("validate", int64_t(from_files.size()));
  ParallelFor(0, int64_t(from_files.size()), 1, [&](int64_t b, int64_t e_end, int) {
    for (int64_t n = b; n < e_end; ++n) {
      const size_t k = from_files[size_t(n)];
      Entry& e = entries[k];
      std::string problem;
      st.errors[k] = ScoreEntryFromFiles(capture, renders_dir, options, noise, e.figure, &e,
                                         &problem);
      st.NoteAuxProblem(problem);
      progress.Advance();
    }
  }, options.threads);
  progress.Finish();
  for (const Status& s : st.errors) REFLCAP_RETURN_IF_ERROR(s);
  // Rank by error: MSE / peak^2 (what PSNR reads), largest first; ties keep image order.
  std::vector<size_t> by_error(entries.size());
  for (size_t n = 0; n < entries.size(); ++n) by_error[n] = n;
  auto mse = [&](size_t n) {
    const ErrorSums& r = entries[n].score.raw;
    return r.values > 0 ? r.sse_over_peak2 / r.values : -1.0;  // nothing evaluated: last
  };
  std::stable_sort(by_error.begin(), by_error.end(),
                   [&](size_t a, size_t b) { return mse(a) > mse(b); });
  for (size_t k = 0; k < by_error.size(); ++k) entries[by_error[k]].rank = k + 1;
  // The worst images get figures: score again those that were not drawn (same numbers, now with
  // the figure data).
  std::vector<size_t> rescore;
  for (size_t k = 0; k < worst_shown; ++k) {
    Entry& e = entries[by_error[k]];
    if (!e.figure) rescore.push_back(by_error[k]);
    e.figure = true;
  }
  std::vector<Status> rescore_errors(rescore.size());
  ParallelFor(0, int64_t(rescore.size()), 1, [&](int64_t b, int64_t end, int) {
    for (int64_t k = b; k < end; ++k) {
      Entry& e = entries[rescore[size_t(k)]];
      Entry again;
      again.index = e.index;
      again.render = e.render;
      again.mask = e.mask;
      again.aux = e.aux;
      std::string problem;
      rescore_errors[size_t(k)] =
          ScoreEntryFromFiles(capture, renders_dir, options, noise, true, &again, &problem);
      e.score.photo_tm = std::move(again.score.photo_tm);
      e.score.render_tm = std::move(again.score.render_tm);
      e.score.error = std::move(again.score.error);
      e.score.region_bits = std::move(again.score.region_bits);
    }
  }, options.threads);
  for (const Status& s : rescore_errors) REFLCAP_RETURN_IF_ERROR(s);
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
              {"error_rank", e.rank},
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
  // With the fit: the texel each worst pixel shows, its model, and its train samples.
  std::vector<PixelTexel> worst_texels;
  std::string worst_texels_note;
  StatusOr<std::unique_ptr<FitTexels>> loaded_fit = UnavailableError("no fit folder given");
  if (st.fit_texels.valid()) loaded_fit = st.fit_texels.get();
  if (!options.fit_dir.empty() && !worst_pixels.empty()) {
    std::vector<PixelQuery> queries;
    for (const ListedPixel& w : worst_pixels) {
      queries.push_back({entries[w.entry].index, w.pixel.x, w.pixel.y});
    }
    StatusOr<std::vector<PixelTexel>> looked_up =
        loaded_fit.ok() ? (*loaded_fit)->LookUp(queries)
                        : StatusOr<std::vector<PixelTexel>>(loaded_fit.status());
    if (looked_up.ok()) {
      worst_texels = std::move(looked_up).value();
    } else {
      // The table keeps its other columns; the reason is shown above it.
      worst_texels_note = looked_up.status().message();
      REFLCAP_LOG(kWarning) << "validate: worst pixels' texels: " << worst_texels_note;
    }
  }
  Json worst_json = Json::array();
  for (size_t listed = 0; listed < worst_pixels.size(); ++listed) {
    const ListedPixel& w = worst_pixels[listed];
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
         {"regions", e.score.has_regions ? region_names : Json(nullptr)},
         {"texel", worst_texels.empty() ? Json(nullptr) : TexelJson(worst_texels[listed])}});
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

  // Figures. One colour scale for every error map: the pooled quantile of the map error over all
  // evaluated pixels of all selected images (metrics.h), rounded up (NiceCeil), unless given.
  const auto figures_start = std::chrono::steady_clock::now();
  std::error_code ec;
  fs::create_directories(out_dir / "figures", ec);
  if (ec) return InternalError((out_dir / "figures").string(), ": cannot create: ", ec.message());
  MapErrorHistogram pooled_map_error;
  for (const Entry& e : entries) pooled_map_error.Merge(e.score.map_error);
  const std::optional<double> map_error_quantile =
      pooled_map_error.Quantile(kMapErrorScaleQuantile);
  const bool scale_given = options.error_scale > 0;
  const double error_scale =
      scale_given ? options.error_scale : NiceCeil(map_error_quantile.value_or(0));
  REFLCAP_RETURN_IF_ERROR(WritePng(
      out_dir / kColourBarPng,
      ComposeColourBar(error_scale, "ERROR = ABS(R - P) / PEAK, MEAN OVER RGB: ONE SCALE FOR ALL MAPS")));
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
                    image.file.c_str(), PlainFixed(e.score.raw.PsnrDb(), 2).c_str(),
                    PlainFixed(e.score.raw.RelRmse(), 4).c_str(),
                    PlainFixed(e.score.raw.Ssim(), 3).c_str());
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

  // Fit and sample sections: the summary's counts and speed, the maps, the report's fields.
  // maps_html: <figure>s for the maps grid; maps_note: text above it.
  std::string fit_summary_html, fit_fields_html, maps_html, maps_note, samples_html;
  Json fit_timings;                               // fit_report.json timings_s / timings
  std::optional<double> fits_per_second, texels_per_second;
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
        fit_fields_html += "<p>" + HtmlEscape(report.string()) + ":</p>\n"
                           "<table><tr><th>field</th><th>value</th></tr>\n";
        for (const auto& [k, v] : rows) {
          fit_fields_html +=
              "<tr><td>" + HtmlEscape(k) + "</td><td>" + HtmlEscape(v) + "</td></tr>\n";
        }
        fit_fields_html += "</table>\n";
        for (const char* key : {"timings_s", "timings"}) {
          if (auto it = j.find(key); it != j.end() && it->is_object() && fit_timings.is_null()) {
            fit_timings = *it;
          }
        }
        if (auto it = j.find("fits_per_second"); it != j.end() && it->is_number()) {
          fits_per_second = it->get<double>();
        }
        if (auto it = j.find("texels_per_second"); it != j.end() && it->is_number()) {
          texels_per_second = it->get<double>();
        }
        model_names = FitReportNames(j, "model_names");
        status_names = FitReportNames(j, "status_names");
      } else {
        fit_fields_html += "<p class=note>" + HtmlEscape(report.string()) + ": not valid JSON.</p>\n";
      }
    } else {
      fit_fields_html +=
          "<p class=note>No fit summary: " + HtmlEscape(report.string()) + " is absent.</p>\n";
    }
    // status.exr as the worst-pixel look-up read it, else read here.
    std::vector<std::string> channel_names;
    StatusOr<Image> codes = UnavailableError("not read");
    if (loaded_fit.ok()) {
      codes = (*loaded_fit)->status();
      channel_names = (*loaded_fit)->status_channels();
    } else {
      codes = ReadExrChannels(status, &channel_names, HardwareThreads());  // one large file
    }
    if (codes.ok()) {
      // One categorical map per channel the fit wrote: its status, the model each texel ended
      // with, and its material cluster (older FIT folders lack the last two: skipped).
      struct Map {
        std::string channel, png, title, summary;
        std::vector<std::string> names;
      };
      std::vector<std::string> cluster_names;
      const std::vector<Map> maps = {
          {"model", "model.png", "Model per texel (what its parameters are)", "models", model_names},
          {"material_cluster", "clusters.png", "Material cluster per texel", "clusters",
           cluster_names},
          {"status", "status.png", "Fit status per texel", "status", status_names}};
      maps_note += "<p>From <code>" + HtmlEscape(status.string()) +
                   "</code>, in atlas layout (one pixel per texel); each colour's code, name and "
                   "texel count are in the legend below its map; black = no texel (negative or "
                   "non-finite code).</p>\n";
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
        std::map<long, size_t> counts;
        size_t texels = 0;
        for (size_t p = 0; p < one.PixelCount(); ++p) {
          const float v = codes->data[p * codes->channels + size_t(channel)];
          one.data[p] = v;
          const bool ok = std::isfinite(v) && v >= 0;
          valid.data[p] = ok ? 1.0f : 0.0f;
          if (ok) ++counts[std::lround(v)], ++texels;
        }
        std::vector<std::string> names = map.names;
        // Clusters have no names: "cluster k" (when the codes are of a sane size).
        constexpr long kMaxNamedCluster = 1 << 16;
        if (map.channel == "material_cluster" && !counts.empty() &&
            counts.rbegin()->first < kMaxNamedCluster) {
          for (long k = 0; k <= counts.rbegin()->first; ++k) names.push_back("cluster " + std::to_string(k));
        }
        REFLCAP_RETURN_IF_ERROR(
            WritePng(out_dir / map.png, ComposeCategoricalMap(one, &valid, names)));
        maps_html += "<figure><figcaption><b>" + HtmlEscape(map.title) + "</b> (channel " +
                     HtmlEscape(map.channel) + ")</figcaption><img src=\"" + HtmlEscape(map.png) +
                     "\" alt=\"" + HtmlEscape(map.title) + "\"></figure>\n";
        fit_summary_html += "<tr><td>" + HtmlEscape(map.summary) + "</td><td>" +
                            CountsText(counts, map.names, texels, map.channel == "material_cluster") +
                            "</td></tr>\n";
      }
    } else {
      maps_note += "<p class=note>No status map: " + HtmlEscape(codes.status().message()) + "</p>\n";
    }
  }
  if (!options.samples_dir.empty()) {
    const fs::path coverage = options.samples_dir / "coverage.png";
    if (fs::is_regular_file(coverage, ec)) {
      fs::copy_file(coverage, out_dir / "coverage.png", fs::copy_options::overwrite_existing, ec);
      if (ec) return InternalError(coverage.string(), ": cannot copy: ", ec.message());
      samples_html = "<figure><figcaption><b>Sample coverage</b>: samples per texel, from the "
                     "resampler (<code>" + HtmlEscape(coverage.string()) + "</code>)</figcaption>"
                     "<img src=\"coverage.png\" alt=\"sample coverage map\"></figure>\n";
    } else {
      samples_html = "<p class=note>No coverage map: " + HtmlEscape(coverage.string()) +
                     " is absent.</p>\n";
    }
  }

  const double total_s = SecondsSince(start);
  Json timings = {{"score_s", score_s}, {"figures_s", figures_s}, {"total_s", total_s},
                  {"images_scored_while_rendering", scored_while_rendering}};
  std::string render_timings;  // table rows
  std::string render_speed;    // summary cell
  if (auto text = ReadTextFile(renders_dir / "render_report.json"); text.ok()) {
    const Json j = Json::parse(*text, nullptr, false);
    if (j.is_object() && j.contains("timings") && j["timings"].is_object()) {
      timings["render"] = j["timings"];
      const std::string device = j.value("backend", "?") + ", " + j.value("device", "?");
      for (auto it = j["timings"].begin(); it != j["timings"].end(); ++it) {
        if (!it->is_number()) continue;
        render_timings += "<tr><td>render (" + HtmlEscape(device) + "): " + HtmlEscape(it.key()) +
                          "</td><td>" + Fixed(it->get<double>(), 2) + "</td></tr>\n";
        render_speed += (render_speed.empty() ? "" : ", ") + HtmlEscape(it.key()) + " " +
                        Fixed(it->get<double>(), 2);
      }
      if (!render_speed.empty()) render_speed = HtmlEscape(device) + ": " + render_speed;
    }
  }
  Json worst_files = Json::array();
  for (size_t k = 0; k < worst_shown; ++k) worst_files.push_back(capture.images[entries[by_error[k]].index].file);
  Json metrics = {{"capture", capture.json_path.string()},
                  {"renders", renders_dir.string()},
                  {"split", render::SplitSelectionName(options.split)},
                  {"definitions", Definitions(options)},
                  {"figures", {{"count", figures},
                               {"cap", options.max_figures},
                               {"error_scale_fraction_of_peak", error_scale},
                               {"error_scale",
                                {{"fraction_of_peak", error_scale},
                                 {"source", scale_given ? "given (--error-scale)" : "automatic"},
                                 {"quantile", kMapErrorScaleQuantile},
                                 {"pooled_quantile_fraction_of_peak", OrNull(map_error_quantile)},
                                 {"legend", kColourBarPng},
                                 {"colour_map", kColourMapText},
                                 {"quantity", kMapErrorText}}},
                               {"worst_shown", worst_files}}},
                  {"images", images},
                  {"overall", overall},
                  {"timings", timings}};
  REFLCAP_RETURN_IF_ERROR(WriteTextFileAtomic(out_dir / "metrics.json", metrics.dump(2) + "\n"));

  // report.html: what a reader wants first (the numbers, the worst images, the maps), the tables
  // after. Every text from the inputs goes through HtmlEscape; paths as given.
  const std::string split_name = render::SplitSelectionName(options.split);
  std::ostringstream html;
  html << "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
       << "<title>reflcap validation: " << HtmlEscape(capture.json_path.string()) << "</title>\n"
       << "<style>" << kReportCss << "</style>\n"
       << "</head>\n<body>\n<h1>Validation: re-renders against " << HtmlEscape(split_name)
       << " photographs</h1>\n"
       << "<p class=meta>Capture <code>" << HtmlEscape(capture.json_path.string())
       << "</code> &middot; renders <code>" << HtmlEscape(renders_dir.string()) << "</code>";
  if (!options.fit_dir.empty()) html << " &middot; fit <code>" << HtmlEscape(options.fit_dir.string()) << "</code>";
  html << "</p>\n<nav><a href=\"#summary\">Summary</a> &middot; <a href=\"#worst\">Worst images</a>"
          " &middot; <a href=\"#figures\">More figures</a> &middot; <a href=\"#maps\">Fit maps</a>"
          " &middot; <a href=\"#tables\">Tables</a></nav>\n";

  // Summary.
  const std::optional<double> bound = noise ? raw.NoiseBoundDb() : std::nullopt;
  html << "<section id=\"summary\">\n<h2>Summary</h2>\n<div class=cards>\n"
       << Card("PSNR", Fixed(raw.PsnrDb(), 2) + " dB",
               "LS-scaled " + Fixed(scaled.PsnrDb(), 2) + " dB")
       << Card("PSNR-L", Fixed(raw.PsnrLDb(), 2) + " dB",
               "LS-scaled " + Fixed(scaled.PsnrLDb(), 2) + " dB")
       << Card("relative RMSE", Fixed(raw.RelRmse(), 4), "LS-scaled " + Fixed(scaled.RelRmse(), 4))
       << Card("SSIM", Fixed(raw.Ssim(), 4), "LS-scaled " + Fixed(scaled.Ssim(), 4));
  if (noise) {
    html << Card("noise bound", Fixed(bound, 2) + " dB",
                 "PSNR &minus; bound = " +
                     Fixed(raw.PsnrDb() && bound ? std::optional<double>(*raw.PsnrDb() - *bound)
                                                 : std::nullopt,
                           2) +
                     " dB");
  }
  html << Card("images compared", std::to_string(entries.size()),
               std::to_string(size_t(raw.pixels)) + " evaluated pixels")
       << "</div>\n<p class=small>Pooled over all evaluated pixels of the " << entries.size()
       << " " << HtmlEscape(split_name) << " images. PSNR relative to each photograph's peak; "
          "PSNR-L: Stanford-ORB's LDR PSNR; LS-scaled: the render scaled per channel by least "
          "squares first (removes a global exposure/albedo scale). ";
  if (noise) {
    html << "Noise bound: the PSNR a perfect re-render scores under the capture's noise model "
            "(photon &sigma; " << noise->photon_sigma_at_1 << " at 1, read &sigma; "
         << noise->read_sigma << ").";
  } else {
    html << "No noise model in the capture (ground_truth.noise): no noise bound.";
  }
  html << " Worst 0.1 % of pixels carry " << Share(worst_share[0])
       << " of the squared error, worst 1 % " << Share(worst_share[1]) << ".</p>\n";
  html << "<div class=cols>\n";
  if (!options.fit_dir.empty()) {
    html << "<div><h3>Fit</h3>\n"
         << (fit_summary_html.empty()
                 ? "<p class=note>No model/status map in the fit folder.</p>\n"
                 : "<table class=kv>\n" + fit_summary_html + "</table>\n")
         << "</div>\n";
  }
  html << "<div><h3>Speed</h3>\n<table class=kv>\n";
  if (!options.fit_dir.empty()) {
    std::string fit_cell;
    if (fit_timings.is_object()) {
      for (const char* key : {"total", "total_s"}) {
        if (auto it = fit_timings.find(key); it != fit_timings.end() && it->is_number()) {
          fit_cell = Fixed(it->get<double>(), 2) + " s total";
        }
      }
      if (auto it = fit_timings.find("fit"); it != fit_timings.end() && it->is_number()) {
        fit_cell += (fit_cell.empty() ? "" : ", ") + Fixed(it->get<double>(), 2) + " s fitting";
      }
    }
    if (fits_per_second) fit_cell += (fit_cell.empty() ? "" : ", ") + Fixed(fits_per_second, 0) + " fits/s";
    if (texels_per_second) {
      fit_cell += (fit_cell.empty() ? "" : ", ") + Fixed(texels_per_second, 0) + " texels/s";
    }
    html << "<tr><td>fit</td><td>" << (fit_cell.empty() ? "&ndash;" : fit_cell) << "</td></tr>\n";
  }
  html << "<tr><td>render</td><td>"
       << (render_speed.empty() ? "&ndash; (no render_report.json)" : render_speed + " s")
       << "</td></tr>\n<tr><td>validate</td><td>" << Fixed(total_s, 2) << " s ("
       << Fixed(score_s, 2) << " s scoring, " << Fixed(figures_s, 2)
       << " s figures)</td></tr>\n</table>\n</div>\n</div>\n</section>\n";

  // The error scale's legend, shown with the worst images and again with all figures.
  std::ostringstream legend;
  legend << "<div class=legend><img src=\"" << kColourBarPng << "\" alt=\"error colour scale: 0 to "
         << FormatPercent(error_scale) << " of the peak\"><p class=small>Error maps: "
         << kMapErrorText << ", colour map " << kColourMapText << ". <b>One scale for all error "
         << "maps on this page: 0 to " << FormatPercent(error_scale) << " of the peak</b> ("
         << (scale_given ? std::string("given with --error-scale")
                         : "the " + Fixed(100 * kMapErrorScaleQuantile, 0) +
                               "th percentile over all evaluated pixels of all images, " +
                               (map_error_quantile ? FormatPercent(*map_error_quantile) : "&ndash;") +
                               ", rounded up to 1, 2, 2.5 or 5 &times; 10<sup>k</sup>")
         << "). Photograph and re-render are tone-mapped alike: x/(1+x) after dividing by the "
            "photograph's mean over the evaluated pixels, then gamma 1/2.2.</p></div>\n";

  // Worst images, large.
  html << "<section id=\"worst\">\n<h2>Worst " << HtmlEscape(split_name) << " images</h2>\n";
  if (worst_shown == 0) {
    html << "<p class=note>No figures (--max-figures 0).</p>\n";
  } else {
    html << "<p>The " << worst_shown << " images of largest error (lowest PSNR) of "
         << entries.size() << ", worst first: photograph | re-render | error map.</p>\n"
         << legend.str();
    for (size_t k = 0; k < worst_shown; ++k) {
      const Entry& e = entries[by_error[k]];
      if (e.score.photo_tm.empty()) continue;
      html << "<figure class=big id=\"" << HtmlEscape(e.key) << "\">" << FigureImages(capture, e)
           << "<figcaption>" << FigureCaption(capture, e) << "</figcaption></figure>\n";
    }
  }
  html << "</section>\n";

  // The other figures, worst first, smaller.
  html << "<section id=\"figures\">\n<h2>More comparison figures</h2>\n<p>" << figures << " of "
       << entries.size() << " images have figures (at most " << options.max_figures << ": the "
       << worst_shown << " worst, above, and the rest evenly spaced over the images); here the "
       << (figures > worst_shown ? figures - worst_shown : 0)
       << " others, worst first, on the same colour scale (0 to " << FormatPercent(error_scale)
       << " of the peak), each beside its region labels where the renders have aux buffers "
          "(shadow edge red, high curvature blue, grazing yellow). Click an image for its full "
          "size.</p>\n<div class=grid>\n";
  for (size_t k = worst_shown; k < by_error.size(); ++k) {
    const Entry& e = entries[by_error[k]];
    if (!e.figure || e.score.photo_tm.empty()) continue;
    html << "<figure id=\"" << HtmlEscape(e.key) << "\">" << FigureImages(capture, e)
         << "<figcaption>" << FigureCaption(capture, e) << "</figcaption></figure>\n";
  }
  html << "</div>\n</section>\n";

  // Maps.
  html << "<section id=\"maps\">\n<h2>Fit maps</h2>\n"
       << (options.fit_dir.empty() ? "<p class=note>No fit folder given (--fit FIT).</p>\n"
                                   : maps_note)
       << (options.samples_dir.empty()
               ? "<p class=note>No sample store given (--samples SAMPLES): no coverage map.</p>\n"
               : "")
       << "<div class=maps>\n" << maps_html << samples_html << "</div>\n</section>\n";

  // Tables.
  html << "<section id=\"tables\">\n<h2>Metrics</h2>\n<table><tr><th></th><th>PSNR (dB)</th><th>PSNR-L (dB)</th>"
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
  html << "<h2>Per image</h2>\n<p>In capture order; rank 1 = the largest error (lowest PSNR).</p>\n"
          "<div class=wide><table><tr><th>file</th><th>rank</th><th>camera</th><th>light</th>"
          "<th>turntable (&deg;)</th><th>pixels</th><th>PSNR (dB)</th><th>PSNR-L (dB)</th>"
          "<th>rel. RMSE</th><th>SSIM</th><th>scaled PSNR</th><th>scaled PSNR-L</th>"
          "<th>scaled rel. RMSE</th><th>scaled SSIM</th><th>worst 0.1 % share</th>"
       << (noise ? "<th>noise bound (dB)</th>" : "") << "</tr>\n";
  for (const Entry& e : entries) {
    const CaptureImage& image = capture.images[e.index];
    html << "<tr><td>" << (e.figure ? "<a href=\"#" + HtmlEscape(e.key) + "\">" : "")
         << HtmlEscape(image.file) << (e.figure ? "</a>" : "") << "</td><td>" << e.rank
         << "</td><td>" << HtmlEscape(capture.cameras[image.camera].id) << "</td><td>"
         << HtmlEscape(capture.lights[image.light].id) << "</td><td>" << image.turntable_deg
         << "</td><td>" << size_t(e.score.raw.pixels) << "</td>" << MetricCells(e.score.raw)
         << MetricCells(e.score.scaled) << "<td>" << Share(e.score.worst_share[0]) << "</td>";
    if (noise) html << "<td>" << Fixed(e.score.raw.NoiseBoundDb(), 2) << "</td>";
    html << "</tr>\n";
  }
  html << "</table></div>\n<h2>Worst pixels</h2>\n";
  if (worst_pixels.empty()) {
    html << "<p class=note>No evaluated pixel has an error.</p>\n";
  } else {
    html << "<p>The " << worst_pixels.size() << " evaluated pixels of largest error e = "
            "&Sigma;<sub>RGB</sub> (r &minus; p)&sup2; relative to their image's peak&sup2;, over "
            "all images; x = column, y = row (0 = top).";
    if (!worst_texels.empty()) {
      html << " The texel each shows (the render's own lookup at the pixel centre), the model "
              "and fit status it ended with"
           << (options.samples_dir.empty() ? "" : ", and its train samples: how many, and the "
                                                  "brightest (a held-out pixel far above it shows "
                                                  "what no train photograph of the texel did)")
           << ".";
    } else if (!worst_texels_note.empty()) {
      html << " <span class=note>No texels: " << HtmlEscape(worst_texels_note) << "</span>";
    }
    html << "</p>\n<table><tr><th>image</th><th>x</th>"
            "<th>y</th><th>photograph RGB</th><th>render RGB</th><th>e</th>"
            "<th>share of squared error</th><th>regions</th>";
    if (!worst_texels.empty()) {
      html << "<th>texel</th><th>model</th><th>status</th>";
      if (!options.samples_dir.empty()) html << "<th>train samples</th><th>brightest train RGB</th>";
    }
    html << "</tr>\n";
    for (size_t listed = 0; listed < worst_pixels.size(); ++listed) {
      const ListedPixel& w = worst_pixels[listed];
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
           << "</td>";
      if (!worst_texels.empty()) {
        const PixelTexel& t = worst_texels[listed];
        const auto named = [](int code, const std::string& name) -> std::string {
          if (code < 0) return "&ndash;";
          return name.empty() ? std::to_string(code) : HtmlEscape(name);
        };
        html << "<td>" << (t.texel < 0 ? std::string("none") : std::to_string(t.texel))
             << "</td><td>" << named(t.model, t.model_name) << "</td><td>"
             << named(t.status, t.status_name) << "</td>";
        if (!options.samples_dir.empty()) {
          html << "<td>" << (t.train_samples < 0 ? std::string("&ndash;") : std::to_string(t.train_samples))
               << "</td><td>" << (t.train_samples < 0 ? std::string("&ndash;") : RgbText(t.brightest))
               << "</td>";
        }
      }
      html << "</tr>\n";
    }
    html << "</table>\n";
  }
  html << "<h2>Fit report</h2>\n"
       << (options.fit_dir.empty() ? "<p class=note>No fit folder given (--fit FIT).</p>\n"
                                   : fit_fields_html)
       << "<h2>Timings</h2>\n<table><tr><th>stage</th><th>seconds</th></tr>\n"
       << "<tr><td>load and score</td><td>" << Fixed(score_s, 2) << "</td></tr>\n"
       << "<tr><td>figures</td><td>" << Fixed(figures_s, 2) << "</td></tr>\n"
       << "<tr><td>validate total</td><td>" << Fixed(total_s, 2) << "</td></tr>\n"
       << render_timings << "</table>\n</section>\n";
  html << "<p class=small>Definitions: see metrics.json <code>definitions</code> and README.md "
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
