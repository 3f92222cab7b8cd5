// Re-rendering a capture from a parameter map (see render_capture.h).
#include "render/reference/render_capture.h"

#include <chrono>
#include <set>

#include <nlohmann/json.hpp>

#include "engine/core/atomic_file.h"
#include "engine/core/log.h"
#include "engine/core/progress.h"
#include "engine/image/exr_io.h"
#include "engine/image/png_io.h"
#include "engine/mesh/mesh_io.h"

namespace reflcap::render {
namespace fs = std::filesystem;
using Json = nlohmann::json;

namespace {

double SecondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

}  // namespace

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

std::string ImageKey(const std::string& file) {
  fs::path p = fs::path(file).lexically_normal();
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
  return fs::path(file).lexically_normal().replace_extension(".exr").generic_string();
}
std::string MaskPathFor(const std::string& file) { return "masks/" + ImageKey(file) + ".png"; }
std::string AuxPathFor(const std::string& file) { return "aux/" + ImageKey(file) + ".exr"; }

StatusOr<std::unique_ptr<FittedCapture>> LoadFittedCapture(const Capture& capture,
                                                           const fs::path& params_exr) {
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
          ? RenderNormalMapImage(fitted.atlas, fitted.maps, camera, light, image.exposure_s, options)
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
  b.renderer = "CPU reference renderer (render/reference): direct light, Embree shadow rays, "
               "no interreflection";
  b.render = RenderCaptureImage;
  return b;
}

StatusOr<CaptureRenderSummary> RenderCapture(const Capture& capture, const fs::path& params_exr,
                                             const fs::path& out_dir,
                                             const CaptureRenderOptions& options) {
  return RenderCapture(capture, params_exr, out_dir, options, CpuCaptureRenderBackend());
}

StatusOr<CaptureRenderSummary> RenderCapture(const Capture& capture, const fs::path& params_exr,
                                             const fs::path& out_dir,
                                             const CaptureRenderOptions& options,
                                             const CaptureRenderBackend& backend) {
  REFLCAP_CHECK(backend.render) << "CaptureRenderBackend::render is empty";
  const auto start = std::chrono::steady_clock::now();
  RenderOptions render_options;
  render_options.supersampling = options.supersampling;
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

  CaptureRenderSummary summary;
  REFLCAP_ASSIGN_OR_RETURN(std::unique_ptr<FittedCapture> fitted,
                           LoadFittedCapture(capture, params_exr));
  summary.texels = fitted->atlas.TexelCount();
  summary.num_lobes = fitted->maps.num_lobes;
  if (backend.prepare) REFLCAP_RETURN_IF_ERROR(backend.prepare(*fitted));
  summary.load_s = SecondsSince(start);
  REFLCAP_LOG(kInfo) << "render: " << summary.texels << " texels ("
                     << (fitted->normal_map ? "normal map" : "mesh atlas") << " "
                     << fitted->atlas.width << "x" << fitted->atlas.height << "), "
                     << fitted->maps.num_lobes << " lobes; " << selected.size() << " images";

  Json images = Json::array();
  Progress progress("render", int64_t(selected.size()));
  for (size_t index : selected) {
    const CaptureImage& image = capture.images[index];
    const auto t0 = std::chrono::steady_clock::now();
    REFLCAP_ASSIGN_OR_RETURN(RenderResult r, backend.render(*fitted, index, render_options));
    const double render_s = SecondsSince(t0);
    summary.render_s += render_s;
    const auto t1 = std::chrono::steady_clock::now();
    const std::string render_file = RenderPathFor(image.file);
    const std::string mask_file = MaskPathFor(image.file);
    const std::string aux_file = AuxPathFor(image.file);
    for (const std::string& f : {render_file, mask_file, aux_file}) {
      std::error_code ec;
      fs::create_directories((out_dir / f).parent_path(), ec);
      if (ec) return InternalError((out_dir / f).parent_path().string(), ": cannot create: ", ec.message());
    }
    REFLCAP_RETURN_IF_ERROR(WriteExr(out_dir / render_file, r.pixels, ExrPixelType::kFloat));
    REFLCAP_RETURN_IF_ERROR(WritePng(out_dir / mask_file, r.mask));
    REFLCAP_RETURN_IF_ERROR(
        WriteExrChannels(out_dir / aux_file, r.aux, AuxChannelNames(), ExrPixelType::kFloat));
    summary.write_s += SecondsSince(t1);
    images.push_back({{"file", image.file},
                      {"render", render_file},
                      {"mask", mask_file},
                      {"aux", aux_file},
                      {"camera", capture.cameras[image.camera].id},
                      {"light", capture.lights[image.light].id},
                      {"turntable_deg", image.turntable_deg},
                      {"split", SplitName(image.split)},
                      {"render_s", render_s}});
    progress.Advance();
  }
  progress.Finish();
  summary.images = selected.size();
  summary.total_s = SecondsSince(start);

  Json report = {
      {"backend", backend.backend},
      {"device", backend.device},
      {"renderer", backend.renderer},
      {"capture", capture.json_path.string()},
      {"fit", params_exr.string()},
      {"split", SplitSelectionName(options.split)},
      {"geometry", fitted->normal_map ? "normal_map" : "mesh"},
      {"supersampling", fitted->normal_map ? 1 : options.supersampling},
      {"cast_shadows", fitted->normal_map ? false : options.cast_shadows},
      {"atlas", {{"width", fitted->atlas.width}, {"height", fitted->atlas.height},
                 {"texels", fitted->atlas.TexelCount()}}},
      {"num_lobes", fitted->maps.num_lobes},
      {"aux_channels",
       {{"cast_shadow", "1 where the point faces the light but the segment to it is blocked"},
        {"cos_theta_i", "shading normal . direction to the light (signed)"},
        {"cos_theta_o", "shading normal . direction to the camera (signed)"},
        {"curvature", "max turning rate of the shading normal x object size (1 on a sphere)"},
        {"mask", "1 where the ray through the pixel centre hits the object"}}},
      {"images", images},
      {"timings", {{"load_s", summary.load_s}, {"render_s", summary.render_s},
                   {"write_s", summary.write_s}, {"total_s", summary.total_s}}}};
  REFLCAP_RETURN_IF_ERROR(WriteTextFileAtomic(out_dir / "render_report.json", report.dump(2) + "\n"));
  return summary;
}

}  // namespace reflcap::render
