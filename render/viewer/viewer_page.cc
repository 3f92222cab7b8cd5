// The relightable viewer page (viewer_page.h). The page template, its script and three.js are
// embedded into the binary at build time with the assembler's .incbin (paths from CMake), so the
// page reflcap writes never depends on files beside the executable.
#include "render/viewer/viewer_page.h"

#include <algorithm>
#include <cmath>
#include <string_view>
#include <unistd.h>

#include <nlohmann/json.hpp>

#include "engine/core/atomic_file.h"
#include "engine/core/html.h"
#include "engine/image/image_io.h"
#include "engine/image/png_io.h"

// REFLCAP_EMBED(name, "path"): name_begin .. name_end are the file's bytes.
#define REFLCAP_EMBED(name, path)                                                   \
  asm(".section .rodata\n.global " #name "_begin\n.balign 16\n" #name "_begin:\n" \
      ".incbin \"" path "\"\n.global " #name "_end\n" #name "_end:\n.byte 0\n.previous\n"); \
  extern "C" const char name##_begin[];                                              \
  extern "C" const char name##_end[];

REFLCAP_EMBED(reflcap_viewer_page_html, REFLCAP_VIEWER_PAGE_HTML)
REFLCAP_EMBED(reflcap_viewer_js, REFLCAP_VIEWER_JS)
#ifdef REFLCAP_THREE_JS
REFLCAP_EMBED(reflcap_three_js, REFLCAP_THREE_JS)
#endif

namespace reflcap::render {
namespace fs = std::filesystem;
using Json = nlohmann::json;
namespace {

// The page's shader declares one sampler per lobe parameter; WebGL2 guarantees 16 fragment
// texture units: rho, tangent and 4 per lobe fit for kMaxLobes = 3.
[[maybe_unused]] constexpr int kMaxViewerLobes = 3;
// Quantile of the photograph that maps to display white.
constexpr double kDisplayQuantile = 0.99;

[[maybe_unused]] std::string_view Embedded(const char* begin, const char* end) {
  return std::string_view(begin, size_t(end - begin));
}

[[maybe_unused]] std::string Base64(const void* data, size_t size) {
  static const char kAlphabet[] =
      "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  const auto* b = static_cast<const unsigned char*>(data);
  std::string out;
  out.reserve((size + 2) / 3 * 4);
  size_t i = 0;
  for (; i + 2 < size; i += 3) {
    const uint32_t v = (uint32_t(b[i]) << 16) | (uint32_t(b[i + 1]) << 8) | b[i + 2];
    for (int s = 18; s >= 0; s -= 6) out.push_back(kAlphabet[(v >> s) & 63]);
  }
  if (i < size) {
    uint32_t v = uint32_t(b[i]) << 16;
    if (i + 1 < size) v |= uint32_t(b[i + 1]) << 8;
    out.push_back(kAlphabet[(v >> 18) & 63]);
    out.push_back(kAlphabet[(v >> 12) & 63]);
    out.push_back(i + 1 < size ? kAlphabet[(v >> 6) & 63] : '=');
    out.push_back('=');
  }
  return out;
}

[[maybe_unused]] std::string Base64(const std::vector<float>& v) { return Base64(v.data(), 4 * v.size()); }

[[maybe_unused]] std::string Replace(std::string text, const std::string& marker,
                                     std::string_view with) {
  const size_t at = text.find(marker);
  REFLCAP_CHECK(at != std::string::npos) << "page template lacks " << marker;
  text.replace(at, marker.size(), with.data(), with.size());
  return text;
}

[[maybe_unused]] Json Vec(const Vec3d& v) { return Json::array({v.x(), v.y(), v.z()}); }

}  // namespace

bool ViewerHasThreeJs() {
#ifdef REFLCAP_THREE_JS
  return true;
#else
  return false;
#endif
}

Status ViewerOptions::Validate() const {
  if (views < 1 || views > 1000) return InvalidArgumentError("views must be in [1, 1000], got ", views);
  if (max_texture_size < 1 || max_texture_size > 65536) {
    return InvalidArgumentError("max_texture_size must be in [1, 65536], got ", max_texture_size);
  }
  return OkStatus();
}

float DisplayValue(float value, float scale) {
  const float x = std::clamp(value * scale, 0.0f, 1.0f);  // NaN-free: clamp of a finite product
  return x <= 0.0031308f ? 12.92f * x : 1.055f * std::pow(x, 1.0f / 2.4f) - 0.055f;
}

float DisplayScaleOf(const Image& photo) {
  std::vector<float> values;
  for (float v : photo.data) {
    if (v > 0 && std::isfinite(v)) values.push_back(v);
  }
  if (values.empty()) return 1.0f;  // an all-black photograph: any scale shows it
  const size_t k = std::min(values.size() - 1, size_t(kDisplayQuantile * double(values.size())));
  std::nth_element(values.begin(), values.begin() + long(k), values.end());
  return 1.0f / values[k];
}

StatusOr<ViewerSummary> WriteViewerPage(const FittedCapture& fitted, const fs::path& out_dir,
                                        const ViewerOptions& options) {
  REFLCAP_RETURN_IF_ERROR(options.Validate());
#ifndef REFLCAP_THREE_JS
  return UnavailableError("this reflcap was built without three.js (render/viewer/node_modules "
                          "was missing at configure time): run .ci/install-deps, then cmake "
                          "and rebuild");
#else
  const Capture& capture = *fitted.capture;
  if (fitted.normal_map) {
    return FailedPreconditionError(capture.json_path.string(), ": normal_map: the viewer needs a "
                                   "mesh capture; a normal-map capture has no mesh to show");
  }
  const TexelAtlas& atlas = fitted.atlas;
  const BrdfMaps& maps = fitted.maps;
  const TriangleMesh& mesh = fitted.mesh;
  if (atlas.width > options.max_texture_size || atlas.height > options.max_texture_size) {
    return InvalidArgumentError("params.exr: size: the atlas is ", atlas.width, "x", atlas.height,
                                ", above the WebGL texture limit of ", options.max_texture_size);
  }
  if (maps.num_lobes > kMaxViewerLobes) {
    return InvalidArgumentError("params.exr: ", maps.num_lobes, " lobes; the viewer shows at most ",
                                kMaxViewerLobes);
  }
  // Held-out pinhole views, evenly spaced.
  std::vector<size_t> holdout;
  for (size_t i = 0; i < capture.images.size(); ++i) {
    const CaptureImage& image = capture.images[i];
    if (image.split == Split::kHoldout &&
        capture.cameras[size_t(image.camera)].model == CameraModel::kPinhole) {
      holdout.push_back(i);
    }
  }
  if (holdout.empty()) {
    return FailedPreconditionError(capture.json_path.string(), ": images: no holdout photograph "
                                   "with a pinhole camera to show beside the re-render");
  }
  ViewerSummary summary;
  const size_t count = std::min(holdout.size(), size_t(options.views));
  for (size_t k = 0; k < count; ++k) summary.images.push_back(holdout[k * holdout.size() / count]);
  summary.texels = atlas.TexelCount();
  summary.triangles = mesh.TriangleCount();

  // Mesh as corners.
  std::vector<float> position, normal, uv;
  position.reserve(9 * mesh.TriangleCount());
  normal.reserve(9 * mesh.TriangleCount());
  uv.reserve(6 * mesh.TriangleCount());
  for (size_t t = 0; t < mesh.TriangleCount(); ++t) {
    for (int c = 0; c < 3; ++c) {
      const Vec3f& p = mesh.positions[mesh.triangles[t][c]];
      const Vec3f& n = mesh.corner_normals[t][c];
      const Vec2f& q = mesh.corner_uvs[t][c];
      position.insert(position.end(), {p.x(), p.y(), p.z()});
      normal.insert(normal.end(), {n.x(), n.y(), n.z()});
      uv.insert(uv.end(), {q.x(), q.y()});
    }
  }
  const Eigen::AlignedBox3f box = mesh.Bounds();
  const Vec3f centre = box.center();
  const Vec3d up = capture.turntable ? capture.turntable->axis.normalized() : Vec3d::UnitZ();

  // Atlas textures (RGBA float): rho_d + texel flag, tangent, per lobe Cx, Cy, Cz, n.
  const size_t pixels = size_t(atlas.width) * size_t(atlas.height);
  std::vector<float> rho(4 * pixels, 0.0f), tangent(4 * pixels, 0.0f);
  std::vector<std::vector<float>> lobes(size_t(4 * maps.num_lobes),
                                        std::vector<float>(4 * pixels, 0.0f));
  auto finite = [](float v) { return std::isfinite(v) ? v : 0.0f; };  // no NaN reaches the page
  for (size_t t = 0; t < atlas.TexelCount(); ++t) {
    const size_t p = atlas.pixel_of_texel[t];
    const brdf::BrdfParams& b = maps.texels[t];
    for (int c = 0; c < 3; ++c) {
      rho[4 * p + c] = finite(b.rho_d[c]);
      tangent[4 * p + c] = atlas.tangent[t][c];
      for (int k = 0; k < maps.num_lobes; ++k) {
        const brdf::LobeParams& l = b.lobes[k][c];
        lobes[4 * k][4 * p + c] = finite(l.cx);
        lobes[4 * k + 1][4 * p + c] = finite(l.cy);
        lobes[4 * k + 2][4 * p + c] = finite(l.cz);
        lobes[4 * k + 3][4 * p + c] = std::isfinite(l.n) ? l.n : float(brdf::kMinExponent);
      }
    }
    rho[4 * p + 3] = 1;
  }
  Json lobe_json = Json::array();
  for (const auto& l : lobes) lobe_json.push_back(Base64(l));

  Json views = Json::array(), views_file = Json::array();
  const fs::path png_scratch = out_dir / StrCat(".photo-", ::getpid(), ".png");
  for (size_t index : summary.images) {
    const CaptureImage& image = capture.images[index];
    const Camera& cam = capture.cameras[size_t(image.camera)];
    const Light& light = capture.lights[size_t(image.light)];
    const Rigid3 world_from_object = capture.WorldFromObject(image);
    const Rigid3 object_from_world = world_from_object.Inverse();
    const Rigid3 cam_from_object = cam.cam_from_world * world_from_object;
    auto photo = ReadImageRgb(capture.Resolve(image.file));
    if (!photo.ok()) return photo.status();
    const float scale = DisplayScaleOf(*photo);
    Image shown(photo->width, photo->height, 3);
    for (size_t i = 0; i < shown.data.size(); ++i) shown.data[i] = DisplayValue(photo->data[i], scale);
    REFLCAP_RETURN_IF_ERROR(WritePng(png_scratch, shown));
    auto png = ReadTextFile(png_scratch);
    std::error_code ec;
    fs::remove(png_scratch, ec);
    if (!png.ok()) return png.status();
    const Mat4d m = cam_from_object.ToMatrix();
    Json matrix = Json::array();
    for (int r = 0; r < 4; ++r) {
      for (int c = 0; c < 4; ++c) matrix.push_back(m(r, c));
    }
    Json light_json = {{"id", light.id}, {"intensity", Vec(light.intensity)}};
    if (light.type == LightType::kPoint) {
      light_json["type"] = "point";
      light_json["position"] = Vec(object_from_world * light.position);
    } else {
      light_json["type"] = "directional";
      light_json["direction"] = Vec(object_from_world.rotation * light.direction);
    }
    views.push_back({{"file", image.file},
                     {"camera", cam.id},
                     {"turntableDeg", image.turntable_deg},
                     {"width", cam.width},
                     {"height", cam.height},
                     {"intrinsics", {cam.K(0, 0), cam.K(1, 1), cam.K(0, 2), cam.K(1, 2)}},
                     {"camFromObject", matrix},
                     {"light", light_json},
                     {"exposure", image.exposure_s},
                     {"displayScale", scale},
                     {"photo", Base64(png->data(), png->size())}});
    views_file.push_back({{"image", index},
                          {"file", image.file},
                          {"width", cam.width},
                          {"height", cam.height},
                          {"display_scale", scale},
                          {"distortion", cam.HasDistortion()}});
    summary.display_scales.push_back(scale);
  }
  const Json data = {
      {"mesh",
       {{"position", Base64(position)},
        {"normal", Base64(normal)},
        {"uv", Base64(uv)},
        {"centre", {centre.x(), centre.y(), centre.z()}},
        {"up", Vec(up)}}},
      {"atlas",
       {{"width", atlas.width},
        {"height", atlas.height},
        {"numLobes", maps.num_lobes},
        {"rho", Base64(rho)},
        {"tangent", Base64(tangent)},
        {"lobes", lobe_json}}},
      {"views", views},
  };
  std::string page(Embedded(reflcap_viewer_page_html_begin, reflcap_viewer_page_html_end));
  page = Replace(page, "/*REFLCAP_TITLE*/",
                 HtmlEscape(capture.json_path.parent_path().filename().string()));
  // "</" inside a script element would end it (a file or id holding "</script>"); "<\/" is the
  // same JSON string.
  std::string data_text = data.dump();
  for (size_t at = data_text.find("</"); at != std::string::npos; at = data_text.find("</", at)) {
    data_text.replace(at, 2, "<\\/");
  }
  // Markers are replaced from the last to the first, so inserted text is never searched.
  page = Replace(page, "/*REFLCAP_VIEWER*/",
                 Embedded(reflcap_viewer_js_begin, reflcap_viewer_js_end));
  page = Replace(page, "/*REFLCAP_DATA*/", "window.REFLCAP_DATA = " + data_text + ";");
  page = Replace(page, "/*REFLCAP_THREE*/", Embedded(reflcap_three_js_begin, reflcap_three_js_end));
  REFLCAP_RETURN_IF_ERROR(WriteTextFileAtomic(out_dir / "index.html", page));
  summary.page_bytes = page.size();
  const Json views_json = {{"format", "reflcap-viewer/1"},
                           {"capture", capture.json_path.string()},
                           {"page", "index.html"},
                           {"test_url", "index.html?test=K (K = position in views)"},
                           {"views", views_file}};
  REFLCAP_RETURN_IF_ERROR(WriteTextFileAtomic(out_dir / "views.json", views_json.dump(2) + "\n"));
  return summary;
#endif
}

}  // namespace reflcap::render
