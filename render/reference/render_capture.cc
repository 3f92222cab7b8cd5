// Re-rendering a capture from a parameter map (see render_capture.h).
#include "render/reference/render_capture.h"

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <memory>
#include <mutex>
#include <optional>
#include <set>

#include <nlohmann/json.hpp>

#include "engine/core/atomic_file.h"
#include "engine/core/log.h"
#include "engine/core/parallel.h"
#include "engine/core/progress.h"
#include "engine/image/exr_io.h"
#include "engine/image/image_io.h"
#include "engine/image/png_io.h"
#include "engine/image/ldr.h"
#include "engine/mesh/mesh_io.h"
#include "engine/core/worker_pool.h"
#include "engine/texel/sample_store.h"
#include "render/reference/evidence_photos.h"
#include "render/reference/point_spread.h"
#include "render/reference/stray_light.h"

namespace reflcap::render {
namespace fs = std::filesystem;
using Json = nlohmann::json;

namespace {

double SecondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

// Auto interreflection (CaptureRenderOptions::indirect): the evidence is read from up to this
// many train photographs, evenly spaced over the split (a dozen views and lights decide it; more
// only costs reading time).
constexpr int kIndirectEvidenceImages = 12;
// Fewer unlit pixels than this over those photographs decide nothing: the indirect light is
// then left out (nothing in the photographs asks for it).
constexpr size_t kMinIndirectEvidencePixels = 1000;
// The evidence's gather table has at most this many rays per texel: its estimate is noisier per
// texel but unbiased, and the decision sums over thousands of pixels; a capture that shows no
// interreflection (every synthetic one) then pays a quarter of the full table's rays.
constexpr int kIndirectEvidenceRays = 16;
// The indirect light is added when it removes at least this share of the squared error of the
// photographs' unlit pixels (which a direct-light render leaves black). A capture without
// interreflection (direct-light synthetic) gains nothing — adding light there only adds error —
// and a physical one gains most of it (suzanne: 0.6 with the 16-ray table). A quarter keeps a
// prediction that is right in kind but weak in level, and refuses one that is mostly noise.
constexpr double kMinIndirectErrorReduction = 0.25;
// Auto pixel model (MeasurePixelEvidence): train photographs rendered twice each (1 and 4 rays
// per pixel); 8 views and lights show every silhouette and texture edge many times over.
constexpr int kPixelEvidenceImages = 8;
// The evidence's box render: 2 x 2 stratified rays already average over the pixel (the
// difference to the point sample is what is measured; kAutoBoxSupersampling refines the average).
constexpr int kPixelEvidenceSupersampling = 2;
// The display-referred evidences' white, as PSNR-L's (render/validate/metrics.h kLdrWhitePercentile).
constexpr double kFootprintWhitePercentile = 0.99;

}  // namespace

StatusOr<IndirectMode> ParseIndirectMode(const std::string& text, const std::string& option) {
  if (text == "auto") return IndirectMode::kAuto;
  if (text == "on") return IndirectMode::kOn;
  if (text == "off") return IndirectMode::kOff;
  return InvalidArgumentError(option, ": \"", text, "\" is not one of auto, on, off");
}

StatusOr<int> ParseSupersampling(const std::string& text, const std::string& option) {
  if (text == "auto") return kAutoSupersampling;
  char* end = nullptr;
  errno = 0;
  const long n = std::strtol(text.c_str(), &end, 10);
  if (text.empty() || end == nullptr || *end != '\0' || errno != 0 || n < 1 ||
      n > kMaxSupersampling) {
    return InvalidArgumentError(option, ": \"", text, "\" is not auto or an integer in [1, ",
                                kMaxSupersampling, "]");
  }
  return int(n);
}

int AutoBoxSupersampling(double pixel_footprint) {
  // 1e-9: a footprint such as 1.25 x 4 = 5 exactly must not round up to 6.
  const double n = std::ceil(kAutoBoxSupersampling * pixel_footprint - 1e-9);
  return int(std::clamp(n, double(kAutoBoxSupersampling), double(kMaxSupersampling)));
}

StatusOr<double> ParsePixelFootprint(const std::string& text, const std::string& option) {
  if (text == "auto") return kAutoPixelFootprint;
  char* end = nullptr;
  errno = 0;
  const double w = std::strtod(text.c_str(), &end);
  if (text.empty() || end == nullptr || *end != '\0' || errno != 0 || !std::isfinite(w) ||
      w < 1 || w > kMaxPixelFootprint) {
    return InvalidArgumentError(option, ": \"", text, "\" is not auto or a width in pixels in [1, ",
                                kMaxPixelFootprint, "]");
  }
  return w;
}

StatusOr<HeightFieldChoice> ParseHeightFieldChoice(const std::string& text,
                                                   const std::string& option) {
  if (text == "auto") return HeightFieldChoice::kAuto;
  if (text == "ls") return HeightFieldChoice::kLeastSquares;
  if (text == "l1") return HeightFieldChoice::kL1;
  return InvalidArgumentError(option, ": \"", text, "\" is not one of auto, ls, l1");
}

const char* HeightFieldChoiceName(HeightFieldChoice choice) {
  switch (choice) {
    case HeightFieldChoice::kLeastSquares: return "ls";
    case HeightFieldChoice::kL1: return "l1";
    default: return "auto";
  }
}

HeightFieldEvidence MeasureHeightFieldEvidence(const FittedCapture& fitted,
                                               const HeightField& l1_field) {
  REFLCAP_CHECK(fitted.normal_map && fitted.height_field != nullptr);
  const Capture& capture = *fitted.capture;
  HeightFieldEvidence evidence;
  RenderOptions direct;
  direct.aux_buffers = true;
  EvidencePhotographs photos(capture, EvidenceImages(capture, kHeightFieldEvidenceImages));
  for (size_t k = 0; k < photos.size(); ++k) {
    const size_t index = photos.index(k);
    const CaptureImage& image = capture.images[index];
    const Camera& camera = capture.cameras[image.camera];
    const Light& light = capture.lights[image.light];
    StatusOr<RenderResult> ls = RenderNormalMapImage(fitted.atlas, fitted.maps, camera, light,
                                                     image.exposure_s, direct,
                                                     fitted.height_field.get());
    StatusOr<RenderResult> l1 =
        ls.ok() ? RenderNormalMapImage(fitted.atlas, fitted.maps, camera, light, image.exposure_s,
                                       direct, &l1_field)
                : ls;
    StatusOr<Image> read = photos.Take(k, l1.status(), "height-field evidence");
    if (!read.ok()) {
      ++evidence.skipped;
      continue;
    }
    for (int y = 0; y < camera.height; ++y) {
      for (int x = 0; x < camera.width; ++x) {
        if (!(ls->mask.at(x, y) > 0.5f)) continue;
        const float* p = read->pixel(x, y);
        if (!UsablePixel(p, image)) continue;
        ++evidence.pixels;
        // Only where the two fields' shadows differ: elsewhere the renders are the same.
        if ((ls->aux.at(x, y, kAuxCastShadow) > 0.5f) == (l1->aux.at(x, y, kAuxCastShadow) > 0.5f)) {
          continue;
        }
        ++evidence.pixels_differing;
        const float* a = ls->pixels.pixel(x, y);
        const float* b = l1->pixels.pixel(x, y);
        for (int c = 0; c < 3; ++c) {
          evidence.error_ls += (double(p[c]) - a[c]) * (double(p[c]) - a[c]);
          evidence.error_l1 += (double(p[c]) - b[c]) * (double(p[c]) - b[c]);
        }
      }
    }
    ++evidence.images;
  }
  evidence.reduction = evidence.error_ls > 0 ? 1 - evidence.error_l1 / evidence.error_ls : 0.0;
  evidence.l1 = evidence.pixels_differing >= kMinHeightFieldEvidencePixels &&
                evidence.reduction >= kMinHeightFieldErrorReduction;
  return evidence;
}

const char* IndirectModeName(IndirectMode mode) {
  switch (mode) {
    case IndirectMode::kAuto: return "auto";
    case IndirectMode::kOn: return "on";
    default: return "off";
  }
}

namespace {
// The interreflection leaving every texel under capture image `index`'s light and pose.
std::vector<Vec3f> IndirectTexelRadiance(const FittedCapture& fitted, const IndirectLight& indirect,
                                         size_t index, int bounces, bool cast_shadows) {
  const Capture& capture = *fitted.capture;
  const CaptureImage& image = capture.images[index];
  return indirect.TexelRadiance(*fitted.scene, fitted.atlas, fitted.maps,
                                capture.lights[image.light],
                                capture.WorldFromObject(image).Inverse(), bounces, cast_shadows);
}
}  // namespace

void AddIndirectLight(const FittedCapture& fitted, const IndirectLight& indirect, size_t index,
                      int bounces, bool cast_shadows, int supersampling, double pixel_footprint,
                      Image* pixels) {
  const std::vector<Vec3f> radiance =
      IndirectTexelRadiance(fitted, indirect, index, bounces, cast_shadows);
  AddTexelRadiancePixels(fitted, index, supersampling, pixel_footprint, radiance, pixels);
}

void AddTexelRadiancePixels(const FittedCapture& fitted, size_t index, int supersampling,
                            double pixel_footprint, const std::vector<Vec3f>& radiance,
                            Image* pixels) {
  const Capture& capture = *fitted.capture;
  const CaptureImage& image = capture.images[index];
  const Rigid3 world_from_object = capture.WorldFromObject(image);
  AddTexelRadiance(*fitted.scene, fitted.atlas, capture.cameras[image.camera], world_from_object,
                   image.exposure_s, supersampling, pixel_footprint, radiance, pixels);
}

namespace {
// `render`, or the CPU reference renderer when it is empty.
StatusOr<RenderResult> RenderEvidence(const FittedCapture& fitted, const EvidenceRender& render,
                                      size_t index, const RenderOptions& options) {
  return render ? render(index, options) : RenderCaptureImage(fitted, index, options);
}
}  // namespace

IndirectEvidence MeasureIndirectEvidence(const FittedCapture& fitted,
                                         const IndirectLight& indirect, int bounces,
                                         bool cast_shadows, int supersampling,
                                         const EvidenceRender& render) {
  const Capture& capture = *fitted.capture;
  REFLCAP_CHECK(!fitted.normal_map && fitted.scene != nullptr);
  IndirectEvidence evidence;
  double pq = 0, qq = 0, pp = 0;
  // Photographs that integrate over their pixels: the direct light and the prediction averaged
  // over each pixel too (2 x 2, as the pixel-model evidence), so that a pixel with lit surface
  // anywhere in it is not taken for unlit.
  const bool box = supersampling > 1;
  RenderOptions direct;
  direct.cast_shadows = cast_shadows;
  direct.aux_buffers = true;
  direct.supersampling = box ? kPixelEvidenceSupersampling : 1;
  EvidencePhotographs photos(capture, EvidenceImages(capture, kIndirectEvidenceImages));
  for (size_t k = 0; k < photos.size(); ++k) {
    const size_t index = photos.index(k);
    const CaptureImage& image = capture.images[index];
    const Camera& camera = capture.cameras[image.camera];
    StatusOr<RenderResult> rendered = RenderEvidence(fitted, render, index, direct);
    StatusOr<Image> read = photos.Take(k, rendered.status(), "interreflection evidence");
    if (!read.ok()) {
      ++evidence.skipped;
      continue;
    }
    const RenderResult& lit = *rendered;
    const Image& photo = *read;
    Image predicted(camera.width, camera.height, 3, 0.0f);
    AddIndirectLight(fitted, indirect, index, bounces, cast_shadows, direct.supersampling, 1.0,
                     &predicted);
    // A pixel whose 3x3 neighbourhood is object without direct light: away from silhouettes and
    // shadow edges, where the photograph's pixel filter mixes in lit surface or background.
    // Point pixels: the centre faces away from the light or is cast-shadowed (aux); box pixels:
    // no direct light reaches any of the pixel's samples (its averaged direct render is 0).
    auto unlit = [&](int x, int y) {
      const float* a = lit.aux.pixel(x, y);
      if (!(a[kAuxMask] > 0.5f)) return false;
      if (box) {
        const float* d = lit.pixels.pixel(x, y);
        return d[0] == 0 && d[1] == 0 && d[2] == 0;
      }
      return a[kAuxCosThetaI] <= 0 || a[kAuxCastShadow] > 0.5f;
    };
    for (int y = 1; y + 1 < camera.height; ++y) {
      for (int x = 1; x + 1 < camera.width; ++x) {
        bool ok = true;
        for (int dy = -1; dy <= 1 && ok; ++dy) {
          for (int dx = -1; dx <= 1 && ok; ++dx) ok = unlit(x + dx, y + dy);
        }
        if (!ok) continue;
        const float* p = photo.pixel(x, y);
        const float* q = predicted.pixel(x, y);
        if (!UsablePixel(p, image)) continue;
        ++evidence.pixels;
        for (int c = 0; c < 3; ++c) {
          pq += double(p[c]) * q[c];
          qq += double(q[c]) * q[c];
          pp += double(p[c]) * p[c];
        }
      }
    }
    ++evidence.images;
  }
  evidence.scale = qq > 0 ? pq / qq : 0.0;
  // Σ (p - q)² = pp - 2 pq + qq against Σ p² (the error of the direct-light render there).
  evidence.error_reduction = pp > 0 ? (2 * pq - qq) / pp : 0.0;
  evidence.shows = evidence.pixels >= kMinIndirectEvidencePixels &&
                   evidence.error_reduction >= kMinIndirectErrorReduction;
  return evidence;
}

namespace {

// 1 / the photograph's "white" for display-referred errors (PSNR-L's, engine/image/ldr.h): its
// 99th percentile over the channels of its lit, usable pixels; nullopt for a black photograph
// (nothing to see). A photograph lit only by values <= 0 (noise) scales by 1.
std::optional<double> DisplayInvWhite(const Image& photo, const CaptureImage& image) {
  std::vector<float> lit;
  for (int y = 0; y < photo.height; ++y) {
    for (int x = 0; x < photo.width; ++x) {
      const float* p = photo.pixel(x, y);
      if (!UsablePixel(p, image) || !(p[0] > 0 || p[1] > 0 || p[2] > 0)) continue;
      lit.insert(lit.end(), p, p + 3);
    }
  }
  const std::optional<float> white = NearestRankPercentile(&lit, kFootprintWhitePercentile);
  if (!white) return std::nullopt;
  return *white > 0 ? 1.0 / *white : 1.0;
}

}  // namespace

PixelEvidence MeasurePixelEvidence(const FittedCapture& fitted, bool cast_shadows,
                                   const EvidenceRender& render) {
  const Capture& capture = *fitted.capture;
  REFLCAP_CHECK(!fitted.normal_map && fitted.scene != nullptr);
  PixelEvidence evidence;
  RenderOptions point, box;
  point.cast_shadows = box.cast_shadows = cast_shadows;
  box.supersampling = kPixelEvidenceSupersampling;
  EvidencePhotographs photos(capture, EvidenceImages(capture, kPixelEvidenceImages));
  for (size_t k = 0; k < photos.size(); ++k) {
    const size_t index = photos.index(k);
    const CaptureImage& image = capture.images[index];
    const Camera& camera = capture.cameras[image.camera];
    StatusOr<RenderResult> at_centre = RenderEvidence(fitted, render, index, point);
    StatusOr<RenderResult> averaged =
        at_centre.ok() ? RenderEvidence(fitted, render, index, box) : at_centre.status();
    StatusOr<Image> read = photos.Take(k, averaged.status(), "pixel-model evidence");
    if (!read.ok()) {
      ++evidence.skipped;
      continue;
    }
    const Image& photo = *read;
    // Display-referred errors, as the footprint's evidence below: in linear values the few
    // highlight pixels whose level the fit misses outweigh every edge and texture border, where
    // the pixel model shows (render_capture.h kMinPixelErrorReduction).
    const std::optional<double> inv_white = DisplayInvWhite(photo, image);
    if (!inv_white) continue;  // a black photograph: nothing to compare
    for (int y = 0; y < camera.height; ++y) {
      for (int x = 0; x < camera.width; ++x) {
        const float* p = photo.pixel(x, y);
        const float* a = at_centre->pixels.pixel(x, y);
        const float* b = averaged->pixels.pixel(x, y);
        if (!UsablePixel(p, image)) continue;
        ++evidence.pixels;
        for (int c = 0; c < 3; ++c) {
          const double shown = LdrValue(p[c], *inv_white);
          const double da = shown - LdrValue(a[c], *inv_white);
          const double db = shown - LdrValue(b[c], *inv_white);
          evidence.error_point += da * da;
          evidence.error_box += db * db;
        }
      }
    }
    ++evidence.images;
  }
  evidence.reduction =
      evidence.error_point > 0 ? 1 - evidence.error_box / evidence.error_point : 0.0;
  evidence.box = evidence.images > 0 && evidence.reduction >= kMinPixelErrorReduction;
  return evidence;
}

FootprintEvidence MeasureFootprintEvidence(const FittedCapture& fitted, bool cast_shadows,
                                           int supersampling, const IndirectLight* indirect,
                                           int indirect_bounces, const EvidenceRender& render) {
  const Capture& capture = *fitted.capture;
  REFLCAP_CHECK(!fitted.normal_map && fitted.scene != nullptr && supersampling > 1);
  FootprintEvidence evidence;
  EvidencePhotographs photos(capture, EvidenceImages(capture, kPixelEvidenceImages));
  for (size_t k = 0; k < photos.size(); ++k) {
    const size_t index = photos.index(k);
    const CaptureImage& image = capture.images[index];
    const Camera& camera = capture.cameras[image.camera];
    std::vector<RenderResult> renders;
    Status status;
    // The interreflection's texel radiance depends on the light and pose only: once an image.
    const std::vector<Vec3f> bounced =
        indirect != nullptr
            ? IndirectTexelRadiance(fitted, *indirect, index, indirect_bounces, cast_shadows)
            : std::vector<Vec3f>();
    for (const double footprint : kPixelFootprintCandidates) {
      RenderOptions options;
      options.cast_shadows = cast_shadows;
      options.supersampling = supersampling;
      options.pixel_footprint = footprint;
      StatusOr<RenderResult> rendered = RenderEvidence(fitted, render, index, options);
      if (!rendered.ok()) {
        status = rendered.status();
        break;
      }
      if (indirect != nullptr) {
        AddTexelRadiancePixels(fitted, index, supersampling, footprint, bounced,
                               &rendered->pixels);
      }
      renders.push_back(std::move(*rendered));
    }
    StatusOr<Image> read = photos.Take(k, status, "pixel-footprint evidence");
    if (!read.ok()) {
      ++evidence.skipped;
      continue;
    }
    const Image& photo = *read;
    // Display-referred: both images over the photograph's 99th percentile (of its lit, usable
    // pixels' channels), clipped to [0, 1], sRGB-encoded. The footprint shows at edges; in linear
    // values the few highlight pixels whose level the fit misses outweigh every edge (suzanne's
    // train photographs: 1 px least error in linear values, while 1.5 px predicts its holdout
    // photographs better in every metric but HDR PSNR, which is level with it).
    const std::optional<double> display = DisplayInvWhite(photo, image);
    if (!display) continue;  // a black photograph: no edge to see
    const double inv_white = *display;
    for (int y = 0; y < camera.height; ++y) {
      for (int x = 0; x < camera.width; ++x) {
        const float* p = photo.pixel(x, y);
        if (!UsablePixel(p, image)) continue;
        ++evidence.pixels;
        float shown[3];  // the photograph's display values, once for every candidate
        for (int c = 0; c < 3; ++c) shown[c] = LdrValue(p[c], inv_white);
        for (size_t f = 0; f < renders.size(); ++f) {
          const float* q = renders[f].pixels.pixel(x, y);
          for (int c = 0; c < 3; ++c) {
            const double d = double(shown[c]) - LdrValue(q[c], inv_white);
            evidence.error[f] += d * d;
          }
        }
      }
    }
    ++evidence.images;
  }
  static_assert(kPixelFootprintCandidates[0] == 1.0, "error[0] is the pixel's own box");
  size_t best = 0;
  for (size_t f = 1; f < evidence.error.size(); ++f) {
    if (evidence.error[f] < evidence.error[best]) best = f;
  }
  evidence.reduction = evidence.error[0] > 0 ? 1 - evidence.error[best] / evidence.error[0] : 0.0;
  if (evidence.images > 0 && evidence.reduction >= kMinFootprintErrorReduction) {
    evidence.footprint = kPixelFootprintCandidates[best];
  }
  return evidence;
}

StatusOr<SplitSelection> ParseSplitSelection(const std::string& text, const std::string& option) {
  if (text == "holdout") return SplitSelection::kHoldout;
  if (text == "train") return SplitSelection::kTrain;
  if (text == "all") return SplitSelection::kAll;
  return InvalidArgumentError(option, ": \"", text, "\" is not one of holdout, train, all");
}

const char* SplitSelectionName(SplitSelection selection) {
  switch (selection) {
    case SplitSelection::kHoldout: return "holdout";
    case SplitSelection::kTrain: return "train";
    default: return "all";
  }
}

bool IsSelected(SplitSelection selection, Split split) {
  switch (selection) {
    case SplitSelection::kHoldout: return split == Split::kHoldout;
    case SplitSelection::kTrain: return split == Split::kTrain;
    default: return true;
  }
}

// The image file as a path inside a render folder: relative, without "..". A file given with an
// absolute path, or one outside the capture's folder, keeps only its name (under images/): a
// render folder's outputs must never land outside it — on the photographs themselves, say.
fs::path InsideName(const std::string& file) {
  fs::path p = fs::path(file).lexically_normal();
  bool escapes = p.has_root_path() || p.empty();
  for (const fs::path& part : p) escapes = escapes || part == "..";
  if (escapes) p = fs::path("images") / fs::path(file).filename();
  return p;
}

std::string ImageKey(const std::string& file) {
  fs::path p = InsideName(file);
  p.replace_extension();
  auto it = p.begin();
  if (it != p.end() && *it == "images" && std::next(it) != p.end()) {
    fs::path rest;
    for (++it; it != p.end(); ++it) rest /= *it;
    p = rest;
  }
  return p.generic_string();
}

std::string RenderPathFor(const std::string& file) {
  return InsideName(file).replace_extension(".exr").generic_string();
}
std::string MaskPathFor(const std::string& file) { return "masks/" + ImageKey(file) + ".png"; }
std::string AuxPathFor(const std::string& file) { return "aux/" + ImageKey(file) + ".exr"; }

StatusOr<std::unique_ptr<FittedCapture>> LoadFittedCapture(const Capture& capture,
                                                           const fs::path& params_exr,
                                                           bool height_field) {
  auto fitted = std::make_unique<FittedCapture>();
  fitted->capture = &capture;
  REFLCAP_ASSIGN_OR_RETURN(ImageInfo params_info, ReadExrInfo(params_exr));
  if (capture.normal_map) {
    fitted->normal_map = true;
    const NormalMapGeometry& g = *capture.normal_map;
    const Camera& cam = capture.cameras[g.camera];
    if (params_info.width != cam.width || params_info.height != cam.height) {
      return InvalidArgumentError(params_exr.string(), ": is ", params_info.width, "x",
                                  params_info.height, " but this normal-map capture's atlas is "
                                  "its camera \"", cam.id, "\" (", cam.width, "x", cam.height, ")");
    }
    REFLCAP_ASSIGN_OR_RETURN(Image normals, ReadExrRgb(capture.Resolve(g.normals)));
    REFLCAP_ASSIGN_OR_RETURN(Image mask, ReadPng(capture.Resolve(g.mask)));
    auto atlas = BuildNormalMapAtlas(normals, mask);
    if (!atlas.ok()) return atlas.status().WithContext(capture.json_path.string());
    fitted->atlas = std::move(atlas).value();
    if (height_field && cam.model != CameraModel::kOrthographic) {
      REFLCAP_LOG(kWarning) << capture.json_path.string() << ": normal_map: camera \"" << cam.id
                            << "\" is not orthographic: no height field, no cast shadows";
    } else if (height_field) {
      auto field = IntegrateNormalMap(fitted->atlas, cam);
      if (!field.ok()) {
        return field.status().WithContext(StrCat(capture.json_path.string(), ": normal_map"));
      }
      fitted->height_field = std::make_unique<HeightField>(std::move(field).value());
      REFLCAP_LOG(kInfo) << "height field: " << fitted->height_field->stats.ToString();
    }
  } else {
    REFLCAP_ASSIGN_OR_RETURN(fitted->mesh, LoadMesh(capture.Resolve(capture.mesh)));
    REFLCAP_ASSIGN_OR_RETURN(fitted->scene, RayScene::Create(fitted->mesh));
    auto atlas = BuildTexelAtlas(fitted->mesh, params_info.width, params_info.height);
    if (!atlas.ok()) return atlas.status().WithContext(params_exr.string());
    fitted->atlas = std::move(atlas).value();
  }
  REFLCAP_ASSIGN_OR_RETURN(fitted->maps, ReadBrdfMaps(params_exr, fitted->atlas));
  size_t bad = 0;
  for (brdf::BrdfParams& p : fitted->maps.texels) {
    if (brdf::IsFinite(p)) continue;
    ++bad;
    p = brdf::BrdfParams{};  // renders black, rather than NaN
  }
  if (bad) {
    REFLCAP_LOG(kWarning) << params_exr.string() << ": " << bad
                          << " texels have non-finite parameters; they render black";
  }
  return fitted;
}

StatusOr<RenderResult> RenderCaptureImage(const FittedCapture& fitted, size_t index,
                                          const RenderOptions& options) {
  const Capture& capture = *fitted.capture;
  REFLCAP_CHECK(index < capture.images.size());
  const CaptureImage& image = capture.images[index];
  const Camera& camera = capture.cameras[image.camera];
  const Light& light = capture.lights[image.light];
  StatusOr<RenderResult> result =
      fitted.normal_map
          ? RenderNormalMapImage(fitted.atlas, fitted.maps, camera, light, image.exposure_s, options,
                                 fitted.height_field.get())
          : RenderImage({fitted.scene.get(), &fitted.atlas, &fitted.maps}, camera, light,
                        capture.WorldFromObject(image), image.exposure_s, options);
  if (!result.ok()) {
    return result.status().WithContext(StrCat(capture.json_path.string(), ": images[", index, "]"));
  }
  return result;
}

CaptureRenderBackend CpuCaptureRenderBackend() {
  CaptureRenderBackend b;
  b.backend = "cpu";
  b.device = "cpu";
  b.renderer = "CPU reference renderer (render/reference): direct light, Embree shadow rays "
               "(interreflection, when on, is added on the CPU for every backend)";
  b.render = RenderCaptureImage;
  return b;
}

StatusOr<CaptureRenderSummary> RenderCapture(const Capture& capture, const fs::path& params_exr,
                                             const fs::path& out_dir,
                                             const CaptureRenderOptions& options) {
  return RenderCapture(capture, params_exr, out_dir, options, CpuCaptureRenderBackend());
}

Status CaptureRenderOptions::Validate() const {
  if (supersampling != kAutoSupersampling &&
      (supersampling < 1 || supersampling > kMaxSupersampling)) {
    return InvalidArgumentError("supersampling must be in [1, ", kMaxSupersampling,
                                "] or auto, got ", supersampling);
  }
  if (pixel_footprint != kAutoPixelFootprint &&
      !(pixel_footprint >= 1 && pixel_footprint <= kMaxPixelFootprint)) {
    return InvalidArgumentError("pixel footprint must be in [1, ", kMaxPixelFootprint,
                                "] px or auto, got ", pixel_footprint);
  }
  if (writers < 0 || writers > 256) {
    return InvalidArgumentError("writers must be in [0, 256], got ", writers);
  }
  if (indirect_bounces < 1 || indirect_bounces > kMaxIndirectBounces) {
    return InvalidArgumentError("indirect bounces must be in [1, ", kMaxIndirectBounces, "], got ",
                                indirect_bounces);
  }
  if (indirect_rays < 1 || indirect_rays > kMaxIndirectRays) {
    return InvalidArgumentError("indirect rays must be in [1, ", kMaxIndirectRays, "], got ",
                                indirect_rays);
  }
  if (psf_sigma_px != kAutoPsf && !(psf_sigma_px >= 0 && psf_sigma_px <= kMaxPsfSigmaPx)) {
    return InvalidArgumentError("point-spread sigma must be in [0, ", kMaxPsfSigmaPx,
                                "] px or auto, got ", psf_sigma_px);
  }
  return OkStatus();
}

// The gather table when the render adds interreflection (null otherwise), and what decided it for
// render_report.json `indirect`.
StatusOr<std::unique_ptr<IndirectLight>> PrepareIndirectLight(const FittedCapture& fitted,
                                                              const CaptureRenderOptions& options,
                                                              int supersampling,
                                                              const EvidenceRender& render,
                                                              const std::string& renderer,
                                                              Json* report) {
  *report = {{"mode", IndirectModeName(options.indirect)}, {"used", false}};
  REFLCAP_CHECK(!fitted.normal_map) << "normal-map captures: PrepareStrayLight";
  if (options.indirect == IndirectMode::kOff) return std::unique_ptr<IndirectLight>();
  if (options.indirect == IndirectMode::kAuto) {
    const auto start = std::chrono::steady_clock::now();
    REFLCAP_ASSIGN_OR_RETURN(
        IndirectLight coarse,
        IndirectLight::Build(*fitted.scene, fitted.atlas,
                             std::min(options.indirect_rays, kIndirectEvidenceRays)));
    const IndirectEvidence evidence =
        MeasureIndirectEvidence(fitted, coarse, options.indirect_bounces, options.cast_shadows,
                                supersampling, render);
    (*report)["evidence"] = {{"images", evidence.images},
                             {"renderer", renderer},
                             {"pixels", evidence.pixels},
                             {"skipped_images", evidence.skipped},
                             {"scale", evidence.scale},
                             {"error_reduction", evidence.error_reduction},
                             {"min_pixels", kMinIndirectEvidencePixels},
                             {"min_error_reduction", kMinIndirectErrorReduction},
                             {"rays_per_texel", coarse.rays()},
                             {"seconds", SecondsSince(start)}};
    REFLCAP_LOG(kInfo) << "render: interreflection " << (evidence.shows ? "on" : "off")
                       << " (auto: where no direct light reaches, it changes the train "
                          "photographs' squared error by "
                       << std::lround(-100 * evidence.error_reduction) << " %)";
    if (!evidence.shows) {
      (*report)["why_not"] = "the train photographs show no interreflection";
      return std::unique_ptr<IndirectLight>();
    }
  }
  const auto start = std::chrono::steady_clock::now();
  REFLCAP_ASSIGN_OR_RETURN(IndirectLight table,
                           IndirectLight::Build(*fitted.scene, fitted.atlas,
                                                options.indirect_rays));
  (*report)["table_s"] = SecondsSince(start);
  (*report)["used"] = true;
  (*report)["bounces"] = options.indirect_bounces;
  (*report)["rays_per_texel"] = options.indirect_rays;
  if (options.indirect == IndirectMode::kOn) {
    REFLCAP_LOG(kInfo) << "render: interreflection on (" << options.indirect_bounces
                       << " bounces, " << options.indirect_rays << " rays per texel)";
  }
  return std::make_unique<IndirectLight>(std::move(table));
}

// Normal-map captures' light from the room (stray_light.h) when the render adds it (null
// otherwise), and what decided it for render_report.json `indirect`.
std::unique_ptr<StrayLight> PrepareStrayLight(const FittedCapture& fitted,
                                              const CaptureRenderOptions& options, Json* report) {
  *report = {{"mode", IndirectModeName(options.indirect)},
             {"used", false},
             {"kind", "stray_light"}};
  if (options.indirect == IndirectMode::kOff) return nullptr;
  auto stray = std::make_unique<StrayLight>(EstimateStrayLight(fitted, options.cast_shadows));
  (*report)["evidence"] = {{"images", stray->images},
                           {"skipped_images", stray->skipped},
                           {"observations", stray->observations},
                           {"error_reduction", stray->error_reduction},
                           {"min_observations", kMinStrayEvidenceObservations},
                           {"min_error_reduction", kMinStrayErrorReduction},
                           {"seconds", stray->seconds}};
  REFLCAP_LOG(kInfo) << "render: stray light " << (stray->shows || options.indirect ==
                                                    IndirectMode::kOn ? "on" : "off")
                     << " (" << IndirectModeName(options.indirect)
                     << "; where no direct light reaches, it changes the held-out train "
                        "photographs' squared error by "
                     << std::lround(-100 * stray->error_reduction) << " %)";
  if (options.indirect == IndirectMode::kAuto && !stray->shows) {
    (*report)["why_not"] = "the train photographs show no light where the lamp does not reach";
    return nullptr;
  }
  (*report)["used"] = true;
  (*report)["observed_texels"] = stray->observed_texels;
  (*report)["modelled_texels"] = stray->modelled_texels;
  Json environment = Json::array();
  for (const auto& e : stray->environment) environment.push_back({e[0], e[1], e[2], e[3]});
  (*report)["environment"] = environment;
  return stray;
}

// Normal-map captures with a height field: integrates the L1 field unless options say least
// squares, keeps it in `fitted` when chosen (HeightFieldChoice), and says what decided it for
// render_report.json `height_field`.
Status ChooseHeightField(const CaptureRenderOptions& options, FittedCapture* fitted,
                         Json* report) {
  const Capture& capture = *fitted->capture;
  *report = {{"mode", HeightFieldChoiceName(options.height_field)}};
  if (options.height_field != HeightFieldChoice::kLeastSquares) {
    const auto start = std::chrono::steady_clock::now();
    HeightFieldOptions l1_options;
    l1_options.integration = HeightFieldIntegration::kL1;
    auto l1_field = IntegrateNormalMap(fitted->atlas, capture.cameras[capture.normal_map->camera],
                                       l1_options);
    if (!l1_field.ok()) {
      return l1_field.status().WithContext(StrCat(capture.json_path.string(), ": normal_map"));
    }
    bool l1 = options.height_field == HeightFieldChoice::kL1;
    if (options.height_field == HeightFieldChoice::kAuto) {
      const HeightFieldEvidence evidence = MeasureHeightFieldEvidence(*fitted, *l1_field);
      l1 = evidence.l1;
      (*report)["evidence"] = {{"images", evidence.images},
                               {"skipped_images", evidence.skipped},
                               {"pixels", evidence.pixels},
                               {"pixels_differing", evidence.pixels_differing},
                               {"min_pixels_differing", kMinHeightFieldEvidencePixels},
                               {"error_ls", evidence.error_ls},
                               {"error_l1", evidence.error_l1},
                               {"reduction", evidence.reduction},
                               {"min_reduction", kMinHeightFieldErrorReduction},
                               {"seconds", SecondsSince(start)}};
      REFLCAP_LOG(kInfo) << "render: height field " << (l1 ? "l1" : "ls")
                         << " (auto: where the L1 and least-squares shadows differ, "
                         << evidence.pixels_differing << " train pixels, L1 changes the "
                            "squared error by "
                         << std::lround(-100 * evidence.reduction) << " %)";
    }
    if (l1) fitted->height_field = std::make_unique<HeightField>(std::move(l1_field).value());
  }
  const HeightFieldStats& st = fitted->height_field->stats;
  (*report)["integration"] = HeightFieldIntegrationName(st.integration);
  if (st.integration == HeightFieldIntegration::kL1) {
    (*report)["l1"] = {{"epsilon_px", HeightFieldOptions{}.l1_epsilon_px},
                       {"reweights", st.reweights},
                       {"last_weight_change", st.weight_change},
                       {"discontinuities", st.discontinuities}};
  }
  return OkStatus();
}

// Normal-map captures: the point spread's σ (0 = sharp) from options or (auto) the train
// photographs, rendered with `stray` (may be null) as the render adds it; `report` for
// render_report.json `pixel_model.psf`.
double ChoosePointSpread(const FittedCapture& fitted, const CaptureRenderOptions& options,
                         const StrayLight* stray, Json* report) {
  *report = {{"mode", options.psf_sigma_px == kAutoPsf ? "auto" : "fixed"}};
  double sigma_px = options.psf_sigma_px;
  if (options.psf_sigma_px == kAutoPsf) {
    const auto start = std::chrono::steady_clock::now();
    const PsfEvidence evidence = MeasurePsfEvidence(fitted, options.cast_shadows, stray);
    sigma_px = evidence.sigma_px;
    Json errors = Json::object();
    for (size_t k = 0; k < kPsfCandidatesPx.size(); ++k) {
      errors[StrCat(kPsfCandidatesPx[k])] = evidence.error[k];
    }
    (*report)["evidence"] = {{"images", evidence.images},
                             {"skipped_images", evidence.skipped},
                             {"pixels", evidence.pixels},
                             {"error_sharp", evidence.error_sharp},
                             {"error_by_sigma_px", errors},
                             {"best_sigma_px", evidence.best_sigma_px},
                             {"reduction", evidence.reduction},
                             {"min_reduction", kMinPsfErrorReduction},
                             {"seconds", SecondsSince(start)}};
    REFLCAP_LOG(kInfo) << "render: point spread " << sigma_px << " px (auto: a "
                       << evidence.best_sigma_px << " px spread changes the train "
                       << "photographs' squared error by "
                       << std::lround(-100 * evidence.reduction) << " %)";
  }
  (*report)["sigma_px"] = sigma_px;
  return sigma_px;
}

StatusOr<CaptureRenderSummary> RenderCapture(const Capture& capture, const fs::path& params_exr,
                                             const fs::path& out_dir,
                                             const CaptureRenderOptions& options,
                                             const CaptureRenderBackend& backend) {
  REFLCAP_CHECK(backend.render || backend.render_many) << "CaptureRenderBackend renders nothing";
  const auto start = std::chrono::steady_clock::now();
  REFLCAP_RETURN_IF_ERROR(options.Validate());
  RenderOptions render_options;
  render_options.supersampling = std::max(options.supersampling, 1);  // auto: decided below
  render_options.cast_shadows = options.cast_shadows;
  render_options.aux_buffers = true;
  REFLCAP_RETURN_IF_ERROR(render_options.Validate());

  std::vector<size_t> selected;
  std::set<std::string> keys;
  for (size_t i = 0; i < capture.images.size(); ++i) {
    if (!IsSelected(options.split, capture.images[i].split)) continue;
    if (!keys.insert(ImageKey(capture.images[i].file)).second) {
      return InvalidArgumentError(capture.json_path.string(), ": images[", i, "].file: \"",
                                  capture.images[i].file, "\" has the same name without extension ",
                                  "as an earlier image; renders would collide");
    }
    selected.push_back(i);
  }
  if (selected.empty()) {
    return FailedPreconditionError(capture.json_path.string(), ": no image in split \"",
                                   SplitSelectionName(options.split), "\"");
  }
  const size_t selected_total = selected.size();
  if (options.shard.count > 1) {
    REFLCAP_ASSIGN_OR_RETURN(ItemRange range,
                             ShardRange(options.shard, uint32_t(selected.size()), "selected images"));
    selected = std::vector<size_t>(selected.begin() + range.begin, selected.begin() + range.end);
  }

  CaptureRenderSummary summary;
  REFLCAP_ASSIGN_OR_RETURN(std::unique_ptr<FittedCapture> fitted,
                           LoadFittedCapture(capture, params_exr,
                                             options.cast_shadows && options.height_shadows));
  summary.texels = fitted->atlas.TexelCount();
  // Normal-map captures: which integration casts the shadows (auto: the train photographs say).
  Json height_report;
  if (fitted->height_field != nullptr) {
    REFLCAP_RETURN_IF_ERROR(ChooseHeightField(options, fitted.get(), &height_report));
  }
  // The evidence for the auto settings: rendered by the backend when it renders it (a GPU; it
  // is prepared first), else by the CPU reference renderer.
  EvidenceRender evidence_render;
  std::string evidence_renderer = "cpu";
  const bool backend_evidence = backend.renders_evidence && (backend.render || backend.render_many);
  if (backend_evidence) {
    if (backend.prepare) REFLCAP_RETURN_IF_ERROR(backend.prepare(*fitted));
    evidence_renderer = backend.backend;
    const FittedCapture& f = *fitted;
    evidence_render = [&backend, &f](size_t index, const RenderOptions& o) -> StatusOr<RenderResult> {
      if (backend.render) return backend.render(f, index, o);
      StatusOr<RenderResult> out = InternalError("render_many delivered no image");
      REFLCAP_RETURN_IF_ERROR(backend.render_many(f, {index}, o, [&](size_t, RenderResult&& r) {
        out = std::move(r);
        return OkStatus();
      }));
      return out;
    };
  }
  // The pixel model: fixed, or (auto) what the train photographs show.
  Json pixel_report = {{"mode", options.supersampling == kAutoSupersampling ? "auto" : "fixed"}};
  if (fitted->normal_map) {
    render_options.supersampling = 1;
    pixel_report["why"] = "a normal map's pixel is its texel: shaded once, then spread by the "
                          "photographs' point spread (psf)";
  } else if (options.supersampling == kAutoSupersampling) {
    const auto pixel_start = std::chrono::steady_clock::now();
    const PixelEvidence evidence =
        MeasurePixelEvidence(*fitted, options.cast_shadows, evidence_render);
    render_options.supersampling = evidence.box ? kAutoBoxSupersampling : 1;
    pixel_report["evidence"] = {{"images", evidence.images},
                                {"renderer", evidence_renderer},
                                {"skipped_images", evidence.skipped},
                                {"pixels", evidence.pixels},
                                {"error_point", evidence.error_point},
                                {"error_box", evidence.error_box},
                                {"reduction", evidence.reduction},
                                {"min_reduction", kMinPixelErrorReduction},
                                {"seconds", SecondsSince(pixel_start)}};
    pixel_report["why"] = evidence.box ? "the train photographs integrate over their pixels"
                                       : "the train photographs are point samples";
    REFLCAP_LOG(kInfo) << "render: " << render_options.supersampling << "x"
                       << render_options.supersampling << " rays per pixel (auto: averaging over "
                       << "the pixel changes the train photographs' squared error by "
                       << std::lround(-100 * evidence.reduction) << " %)";
  }
  // Interreflection: the gather table, and (auto) whether the photographs show it.
  // For normal maps, the light of the room instead (no surface to bounce from).
  Json indirect_report;
  std::unique_ptr<IndirectLight> indirect;
  std::unique_ptr<StrayLight> stray;
  if (fitted->normal_map) {
    stray = PrepareStrayLight(*fitted, options, &indirect_report);
  } else {
    REFLCAP_ASSIGN_OR_RETURN(indirect,
                             PrepareIndirectLight(*fitted, options, render_options.supersampling,
                                                  evidence_render, evidence_renderer,
                                                  &indirect_report));
  }
  // The pixel's footprint: fixed, or (auto, with an auto box) what the train photographs show,
  // rendered with the interreflection when it is on.
  Json footprint_report = {{"mode", options.pixel_footprint == kAutoPixelFootprint ? "auto"
                                                                                    : "fixed"}};
  render_options.pixel_footprint =
      options.pixel_footprint == kAutoPixelFootprint ? 1.0 : options.pixel_footprint;
  if (fitted->normal_map) {
    render_options.pixel_footprint = 1;
  } else if (options.pixel_footprint == kAutoPixelFootprint &&
             options.supersampling == kAutoSupersampling && render_options.supersampling > 1) {
    const auto footprint_start = std::chrono::steady_clock::now();
    const FootprintEvidence evidence =
        MeasureFootprintEvidence(*fitted, options.cast_shadows, render_options.supersampling,
                                 indirect.get(), options.indirect_bounces, evidence_render);
    render_options.pixel_footprint = evidence.footprint;
    Json candidates = Json::array();
    for (size_t f = 0; f < kPixelFootprintCandidates.size(); ++f) {
      candidates.push_back({{"footprint", kPixelFootprintCandidates[f]},
                            {"error", evidence.error[f]}});
    }
    footprint_report["evidence"] = {{"images", evidence.images},
                                    {"renderer", evidence_renderer},
                                    {"skipped_images", evidence.skipped},
                                    {"pixels", evidence.pixels},
                                    {"candidates", candidates},
                                    {"reduction", evidence.reduction},
                                    {"min_reduction", kMinFootprintErrorReduction},
                                    {"seconds", SecondsSince(footprint_start)}};
    REFLCAP_LOG(kInfo) << "render: pixel footprint " << evidence.footprint
                       << " px (auto: the best of " << kPixelFootprintCandidates.size()
                       << " widths changes the train photographs' squared error by "
                       << std::lround(-100 * evidence.reduction) << " % against 1 px)";
  } else if (options.pixel_footprint == kAutoPixelFootprint) {
    footprint_report["why"] = render_options.supersampling > 1
                                  ? "the pixel model is fixed (--supersample N): the pixel itself"
                                  : "one ray per pixel: no footprint to spread over";
  }
  if (options.supersampling == kAutoSupersampling && render_options.supersampling > 1 &&
      render_options.pixel_footprint > 1) {
    render_options.supersampling = AutoBoxSupersampling(render_options.pixel_footprint);
    // The line above said the pixel model's N x N; the footprint's own N is what renders.
    REFLCAP_LOG(kInfo) << "render: " << render_options.supersampling << "x"
                       << render_options.supersampling << " rays per pixel over the "
                       << render_options.pixel_footprint
                       << " px footprint (auto: the 1 px box's density of rays)";
  }
  footprint_report["footprint_px"] = render_options.pixel_footprint;
  pixel_report["footprint"] = footprint_report;
  pixel_report["supersampling"] = render_options.supersampling;
  // Normal-map captures: the photographs' point spread (after the stray light, which the
  // evidence renders include).
  double psf_sigma_px = 0;
  if (fitted->normal_map) {
    Json psf;
    psf_sigma_px = ChoosePointSpread(*fitted, options, stray.get(), &psf);
    pixel_report["psf"] = psf;
  }
  summary.num_lobes = fitted->maps.num_lobes;
  if (backend.prepare && !backend_evidence) REFLCAP_RETURN_IF_ERROR(backend.prepare(*fitted));
  // Every output folder exists before the writers start (they run concurrently).
  std::set<fs::path> folders;
  for (size_t index : selected) {
    const std::string& file = capture.images[index].file;
    for (const std::string& f : {RenderPathFor(file), MaskPathFor(file), AuxPathFor(file)}) {
      folders.insert((out_dir / f).parent_path());
    }
  }
  for (const fs::path& folder : folders) {
    std::error_code ec;
    fs::create_directories(folder, ec);
    if (ec) return InternalError(folder.string(), ": cannot create: ", ec.message());
  }
  summary.load_s = SecondsSince(start);
  summary.writers = options.writers > 0 ? options.writers : HardwareThreads();
  REFLCAP_LOG(kInfo) << "render: " << summary.texels << " texels ("
                     << (fitted->normal_map ? "normal map" : "mesh atlas") << " "
                     << fitted->atlas.width << "x" << fitted->atlas.height << "), "
                     << fitted->maps.num_lobes << " lobes; " << selected.size() << " images, "
                     << summary.writers << " writer threads";

  // Rendered images go to the writers; at most a few wait for one (their memory is bounded).
  struct Timing {
    double render_s = 0, write_s = 0;
  };
  std::vector<Timing> timings(selected.size());
  std::mutex mutex;
  Status write_error = OkStatus();
  std::atomic<bool> stop{false};
  Progress progress("render", int64_t(selected.size()));
  const auto render_start = std::chrono::steady_clock::now();
  auto last_delivery = render_start;
  Status render_status = OkStatus();
  {
    WorkerPool writers(summary.writers, /*max_queued=*/2);
    auto write = [&](size_t k, const RenderResult& r) -> Status {
      const std::string& file = capture.images[selected[k]].file;
      REFLCAP_RETURN_IF_ERROR(
          WriteExr(out_dir / RenderPathFor(file), r.pixels, ExrPixelType::kFloat));
      REFLCAP_RETURN_IF_ERROR(WritePng(out_dir / MaskPathFor(file), r.mask));
      return WriteExrChannels(out_dir / AuxPathFor(file), r.aux, AuxChannelNames(),
                              ExrPixelType::kFloat);
    };
    auto deliver = [&](size_t k, RenderResult&& r) -> Status {
      {
        std::lock_guard<std::mutex> lock(mutex);
        if (!write_error.ok()) return write_error;
      }
      if (indirect != nullptr) {  // part of the image's render time
        AddIndirectLight(*fitted, *indirect, selected[k], options.indirect_bounces,
                         options.cast_shadows, render_options.supersampling,
                         render_options.pixel_footprint, &r.pixels);
      }
      if (stray != nullptr) AddStrayLight(*fitted, *stray, selected[k], &r.pixels);
      if (psf_sigma_px > 0) BlurWithinMask(r.mask, psf_sigma_px, &r.pixels);
      const auto now = std::chrono::steady_clock::now();
      timings[k].render_s = std::chrono::duration<double>(now - last_delivery).count();
      last_delivery = now;
      auto result = std::make_shared<RenderResult>(std::move(r));
      writers.Submit([&, k, result] {
        if (stop) return;
        const auto t0 = std::chrono::steady_clock::now();
        Status s = write(k, *result);
        timings[k].write_s = SecondsSince(t0);
        if (s.ok() && options.after_write) s = options.after_write(selected[k], *result);
        if (!s.ok()) {
          std::lock_guard<std::mutex> lock(mutex);
          if (write_error.ok()) write_error = s;
          stop = true;
          return;
        }
        progress.Advance();
      });
      return OkStatus();
    };
    if (backend.render_many) {
      render_status = backend.render_many(*fitted, selected, render_options, deliver);
    } else {
      for (size_t k = 0; k < selected.size() && render_status.ok(); ++k) {
        StatusOr<RenderResult> r = backend.render(*fitted, selected[k], render_options);
        render_status = r.ok() ? deliver(k, std::move(r).value()) : r.status();
      }
    }
    summary.render_s = std::chrono::duration<double>(last_delivery - render_start).count();
    if (!render_status.ok()) stop = true;  // queued images are not written
    writers.WaitIdle();
    summary.write_tail_s = SecondsSince(last_delivery);
  }
  // A write error reaches the renderer through `deliver`: report the write error itself.
  if (!write_error.ok()) return write_error;
  REFLCAP_RETURN_IF_ERROR(render_status);
  progress.Finish();
  summary.images = selected.size();
  Json images = Json::array();
  for (size_t k = 0; k < selected.size(); ++k) {
    const CaptureImage& image = capture.images[selected[k]];
    summary.write_s += timings[k].write_s;
    images.push_back({{"file", image.file},
                      {"render", RenderPathFor(image.file)},
                      {"mask", MaskPathFor(image.file)},
                      {"aux", AuxPathFor(image.file)},
                      {"camera", capture.cameras[image.camera].id},
                      {"light", capture.lights[image.light].id},
                      {"turntable_deg", image.turntable_deg},
                      {"split", SplitName(image.split)},
                      {"render_s", timings[k].render_s},
                      {"write_s", timings[k].write_s}});
  }
  summary.total_s = SecondsSince(start);

  Json report = {
      {"backend", backend.backend},
      {"device", backend.device},
      {"renderer", backend.renderer},
      {"capture", capture.json_path.string()},
      {"fit", params_exr.string()},
      {"split", SplitSelectionName(options.split)},
      {"geometry", fitted->normal_map ? "normal_map" : "mesh"},
      {"supersampling", render_options.supersampling},
      {"pixel_model", pixel_report},
      {"cast_shadows", fitted->normal_map ? fitted->height_field != nullptr : options.cast_shadows},
      {"atlas", {{"width", fitted->atlas.width}, {"height", fitted->atlas.height},
                 {"texels", fitted->atlas.TexelCount()}}},
      {"num_lobes", fitted->maps.num_lobes},
      {"indirect", indirect_report},
      {"aux_channels",
       {{"cast_shadow", "1 where the point faces the light but the segment to it is blocked"},
        {"cos_theta_i", "shading normal . direction to the light (signed)"},
        {"cos_theta_o", "shading normal . direction to the camera (signed)"},
        {"curvature", "max turning rate of the shading normal x object size (1 on a sphere)"},
        {"mask", "1 where the ray through the pixel centre hits the object"}}},
      {"images", images},
      {"writers", summary.writers},
      {"timings", {{"load_s", summary.load_s}, {"render_s", summary.render_s},
                   {"write_s", summary.write_s}, {"write_tail_s", summary.write_tail_s},
                   {"total_s", summary.total_s}}},
      {"timing_definitions",
       {{"load_s", "capture, mesh and fit loaded (and uploaded to the device)"},
        {"render_s", "from then until the last image was rendered"},
        {"write_s", "wall time spent writing files, summed over the writer threads (overlaps "
                     "rendering)"},
        {"write_tail_s", "from the last image rendered until every file was written (in reflcap "
                         "run, also scored for validation)"},
        {"images[].render_s", "time since the previous image was rendered (a batch's images "
                              "arrive together)"}}}};
  if (fitted->height_field != nullptr) {
    const HeightFieldStats& st = fitted->height_field->stats;
    report["height_field"] = {
        {"cast_shadows", "a pixel facing the light is black (aux cast_shadow 1) when its march "
                         "towards the light passes more than bias_px below the height field "
                         "integrated from the normal map"},
        {"texels", st.texels},
        {"components", st.components},
        {"clamped_gradients", st.clamped},
        {"backfacing_normals", st.backfacing},
        {"residual_rms_px", st.rms_residual_px},
        {"residual_max_px", st.max_residual_px},
        {"height_range_px", {st.min_height_px, st.max_height_px}},
        {"bias_px", kHeightFieldShadowBiasPx},
        {"integrate_s", st.seconds}};
    for (auto it = height_report.begin(); it != height_report.end(); ++it) {
      report["height_field"][it.key()] = it.value();
    }
  } else if (fitted->normal_map) {
    report["height_field"] = {
        {"cast_shadows", options.cast_shadows && options.height_shadows
                             ? "none: the camera is not orthographic"
                             : "none: off (--no-shadows or --no-height-shadows)"}};
  }
  if (options.shard.count > 1) {
    // What the merge checks the parts against each other with.
    const StatusOr<std::string> capture_text = ReadTextFile(capture.json_path);
    const StatusOr<std::string> fit_text = ReadTextFile(params_exr);
    report["shard"] = {
        {"index", options.shard.index},
        {"count", options.shard.count},
        {"selected_images", selected_total},
        {"first", selected.front()},
        {"identity",
         {{"capture_crc32", capture_text.ok() ? Crc32(capture_text->data(), capture_text->size()) : 0u},
          {"fit_crc32", fit_text.ok() ? Crc32(fit_text->data(), fit_text->size()) : 0u},
          {"backend", backend.backend},
          {"split", SplitSelectionName(options.split)},
          {"supersampling", options.supersampling},
          {"pixel_footprint", options.pixel_footprint},
          {"cast_shadows", options.cast_shadows},
          {"height_shadows", options.height_shadows},
          {"indirect", IndirectModeName(options.indirect)},
          {"indirect_bounces", options.indirect_bounces},
          {"indirect_rays", options.indirect_rays},
          {"psf_sigma_px", options.psf_sigma_px},
          {"height_field", HeightFieldChoiceName(options.height_field)}}}};
  }
  REFLCAP_RETURN_IF_ERROR(WriteTextFileAtomic(out_dir / "render_report.json", report.dump(2) + "\n"));
  return summary;
}

Status MergeRenderParts(const std::vector<fs::path>& parts, const fs::path& out_dir) {
  if (parts.empty()) return InvalidArgumentError("merge: no parts given");
  std::vector<Json> reports;
  for (const fs::path& part : parts) {
    const fs::path file = part / "render_report.json";
    REFLCAP_ASSIGN_OR_RETURN(std::string text, ReadTextFile(file));
    Json r = Json::parse(text, nullptr, false);
    if (!r.is_object() || !r.contains("shard") || !r["shard"].is_object() ||
        !r.contains("images") || !r["images"].is_array()) {
      return DataLossError(file.string(), ": shard/images: not a render part (render --shard I/N)");
    }
    reports.push_back(std::move(r));
  }
  const Json& first = reports.front()["shard"];
  const int count = first.value("count", 0);
  std::vector<int> shard_of_part;
  std::vector<std::string> files;
  for (size_t i = 0; i < reports.size(); ++i) {
    const Json& sh = reports[i]["shard"];
    const std::string file = (parts[i] / "render_report.json").string();
    const Json mine = sh.value("identity", Json::object()), theirs = first.value("identity", Json::object());
    if (mine != theirs) {
      std::string differs = "identity";
      for (auto it = theirs.begin(); it != theirs.end(); ++it) {
        if (!mine.contains(it.key()) || mine[it.key()] != it.value()) {
          differs = "identity." + it.key();
          break;
        }
      }
      return FailedPreconditionError(file, ": shard.", differs, " differs from ",
                                     (parts.front() / "render_report.json").string(),
                                     ": the parts are not of one render");
    }
    const int index = sh.value("index", -1);
    if (sh.value("count", 0) != count || sh.value("selected_images", 0) != first.value("selected_images", 0)) {
      return FailedPreconditionError(file, ": shard count differs from ",
                                     (parts.front() / "render_report.json").string());
    }
    if (index < 0 || index >= count) return DataLossError(file, ": shard.index: ", index, " not in [0, ", count, ")");
    shard_of_part.push_back(index);
    files.push_back(file);
  }
  REFLCAP_ASSIGN_OR_RETURN(const std::vector<int> of_shard,
                           PartOfEachShard(shard_of_part, count, files, "render"));
  // Every part's files, checked before any is copied; then one report in shard order.
  Json images = Json::array();
  Json merged = reports[size_t(of_shard[0])];
  double load_s = 0, render_s = 0, write_s = 0, total_s = 0;
  for (int s = 0; s < count; ++s) {
    const size_t i = size_t(of_shard[size_t(s)]);
    for (const Json& image : reports[i]["images"]) {
      for (const char* key : {"render", "mask", "aux"}) {
        const fs::path from = parts[i] / image.value(key, "");
        std::error_code ec;
        if (!fs::is_regular_file(from, ec)) {
          return NotFoundError(from.string(), ": missing (listed in ",
                               (parts[i] / "render_report.json").string(), ")");
        }
      }
      images.push_back(image);
    }
    const Json t = reports[i].value("timings", Json::object());
    load_s += t.value("load_s", 0.0);
    render_s += t.value("render_s", 0.0);
    write_s += t.value("write_s", 0.0);
    total_s += t.value("total_s", 0.0);
  }
  if (images.size() != first.value("selected_images", size_t{0})) {
    return DataLossError((parts.front() / "render_report.json").string(), ": the parts list ",
                         images.size(), " images, the render selected ",
                         first.value("selected_images", size_t{0}));
  }
  for (int s = 0; s < count; ++s) {
    const size_t i = size_t(of_shard[size_t(s)]);
    for (const Json& image : reports[i]["images"]) {
      for (const char* key : {"render", "mask", "aux"}) {
        const fs::path rel = image.value(key, "");
        std::error_code ec;
        fs::create_directories((out_dir / rel).parent_path(), ec);
        fs::copy_file(parts[i] / rel, out_dir / rel, fs::copy_options::overwrite_existing, ec);
        if (ec) return InternalError((out_dir / rel).string(), ": cannot copy: ", ec.message());
      }
    }
  }
  merged["images"] = images;
  merged.erase("shard");
  merged["timings"] = {{"load_s", load_s}, {"render_s", render_s}, {"write_s", write_s},
                       {"write_tail_s", 0.0}, {"total_s", total_s}};
  merged["shards"] = count;
  return WriteTextFileAtomic(out_dir / "render_report.json", merged.dump(2) + "\n");
}

}  // namespace reflcap::render
