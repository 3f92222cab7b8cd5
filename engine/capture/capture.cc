// capture/1 reader, validator and writer. Parsing uses the shared field reader
// (engine/capture/json_fields.h), which carries the file name and the JSON path
// ("images[3].exposure_s") so that every message names both; writing uses nlohmann::json.
// Validation is complete and eager: the first problem found is returned.
#include "engine/capture/capture.h"

#include <cctype>
#include <cmath>
#include <cstring>
#include <set>

#include <nlohmann/json.hpp>

#include "engine/capture/json_fields.h"
#include "engine/core/atomic_file.h"
#include "engine/image/image_io.h"
#include "engine/image/png_io.h"
#include "engine/image/exr_io.h"
#include "engine/mesh/mesh_io.h"

namespace reflcap {
namespace fs = std::filesystem;
// Reading: the field reader's (insertion-ordered) JSON; writing: nlohmann::json (sorted keys).
using Json = jsonio::Json;
using OutJson = nlohmann::json;

namespace {

// Rotation matrices: |RᵀR - I| and |det R - 1| below this (a file's >= 6 significant digits,
// 3x3 products).
constexpr double kRotationTolerance = 1e-4;
// |fx fy| below this (pixels²) makes K numerically singular.
constexpr double kMinFocalProduct = 1e-12;

using jsonio::FieldReader;

// "capture/1" -> minor 0, "capture/1.2" -> minor 2; anything else is an error naming `format`.
StatusOr<int> ParseFormat(const FieldReader& r, const Json& root) {
  return r.FormatMinorVersion(root, "capture", "a capture format");
}

StatusOr<Camera> ParseCamera(const FieldReader& r, const Json& j, const std::string& at) {
  if (!j.is_object()) return r.Error(at, "must be an object");
  Camera cam;
  REFLCAP_ASSIGN_OR_RETURN(const Json* id, r.Required(j, at, "id"));
  REFLCAP_ASSIGN_OR_RETURN(cam.id, r.String(*id, at + ".id"));
  REFLCAP_ASSIGN_OR_RETURN(const Json* w, r.Required(j, at, "width"));
  REFLCAP_ASSIGN_OR_RETURN(cam.width, r.PositiveInt(*w, at + ".width"));
  REFLCAP_ASSIGN_OR_RETURN(const Json* h, r.Required(j, at, "height"));
  REFLCAP_ASSIGN_OR_RETURN(cam.height, r.PositiveInt(*h, at + ".height"));
  std::string model = "pinhole";
  if (auto it = j.find("model"); it != j.end()) {
    REFLCAP_ASSIGN_OR_RETURN(model, r.String(*it, at + ".model"));
  }
  if (model == "pinhole") {
    cam.model = CameraModel::kPinhole;
    REFLCAP_ASSIGN_OR_RETURN(const Json* k, r.Required(j, at, "K"));
    REFLCAP_ASSIGN_OR_RETURN(cam.K, (r.Matrix(*k, 3, 3, at + ".K")));
    if (cam.K(1, 0) != 0 || cam.K(2, 0) != 0 || cam.K(2, 1) != 0 || cam.K(2, 2) != 1) {
      return r.Error(at + ".K", "must have the form [[fx,s,cx],[0,fy,cy],[0,0,1]]");
    }
    if (std::abs(cam.K(0, 0) * cam.K(1, 1)) < kMinFocalProduct) {
      return r.Error(at + ".K", StrCat("not invertible (fx*fy = ", cam.K(0, 0) * cam.K(1, 1), ")"));
    }
    if (cam.K(0, 0) < 0 || cam.K(1, 1) < 0) {
      return r.Error(at + ".K", "focal lengths fx and fy must be positive");
    }
  } else if (model == "orthographic") {
    cam.model = CameraModel::kOrthographic;
    if (auto it = j.find("pixel_size_m"); it != j.end()) {
      REFLCAP_ASSIGN_OR_RETURN(cam.pixel_size_m, r.Number(*it, at + ".pixel_size_m"));
      if (cam.pixel_size_m <= 0) return r.Error(at + ".pixel_size_m", "must be positive");
    }
  } else {
    return r.Error(at + ".model", StrCat("unknown camera model \"", model,
                                         "\" (expected \"pinhole\" or \"orthographic\")"));
  }
  if (auto it = j.find("dist"); it != j.end()) {
    const Json& d = *it;
    if (!d.is_array() || (d.size() != 4 && d.size() != 5)) {
      return r.Error(at + ".dist", "must be [k1,k2,p1,p2] or [k1,k2,p1,p2,k3]");
    }
    for (size_t i = 0; i < d.size(); ++i) {
      REFLCAP_ASSIGN_OR_RETURN(cam.dist[i], r.Number(d[i], StrCat(at, ".dist[", i, "]")));
    }
    if (cam.model == CameraModel::kOrthographic && cam.HasDistortion()) {
      return r.Error(at + ".dist", "orthographic cameras take no distortion");
    }
  }
  if (auto it = j.find("pixel_filter"); it != j.end()) {
    REFLCAP_ASSIGN_OR_RETURN(const std::string filter, r.String(*it, at + ".pixel_filter"));
    if (filter == "area") {
      cam.pixel_filter = PixelFilter::kArea;
    } else if (filter == "point") {
      cam.pixel_filter = PixelFilter::kPoint;
    } else {
      return r.Error(at + ".pixel_filter", StrCat("unknown pixel filter \"", filter,
                                                  "\" (expected \"area\" or \"point\")"));
    }
  }
  REFLCAP_ASSIGN_OR_RETURN(const Json* m, r.Required(j, at, "cam_from_world"));
  REFLCAP_ASSIGN_OR_RETURN(Mat4d mat, (r.Matrix(*m, 4, 4, at + ".cam_from_world")));
  if ((mat.row(3) - Eigen::RowVector4d(0, 0, 0, 1)).cwiseAbs().maxCoeff() > 0) {
    return r.Error(at + ".cam_from_world", "last row must be [0,0,0,1]");
  }
  cam.cam_from_world = Rigid3::FromMatrix(mat);
  const Mat3d& rot = cam.cam_from_world.rotation;
  if ((rot.transpose() * rot - Mat3d::Identity()).cwiseAbs().maxCoeff() > kRotationTolerance ||
      std::abs(rot.determinant() - 1) > kRotationTolerance) {
    return r.Error(at + ".cam_from_world", "rotation part is not a proper rotation (RᵀR ≠ I or det ≠ 1)");
  }
  // Re-orthonormalise the rotation so rounding in the file does not accumulate downstream.
  Eigen::JacobiSVD<Mat3d> svd(rot, Eigen::ComputeFullU | Eigen::ComputeFullV);
  cam.cam_from_world.rotation = svd.matrixU() * svd.matrixV().transpose();
  return cam;
}

StatusOr<Light> ParseLight(const FieldReader& r, const Json& j, const std::string& at) {
  if (!j.is_object()) return r.Error(at, "must be an object");
  Light light;
  REFLCAP_ASSIGN_OR_RETURN(const Json* id, r.Required(j, at, "id"));
  REFLCAP_ASSIGN_OR_RETURN(light.id, r.String(*id, at + ".id"));
  REFLCAP_ASSIGN_OR_RETURN(const Json* type, r.Required(j, at, "type"));
  REFLCAP_ASSIGN_OR_RETURN(std::string type_name, r.String(*type, at + ".type"));
  if (type_name == "point") {
    light.type = LightType::kPoint;
    REFLCAP_ASSIGN_OR_RETURN(const Json* p, r.Required(j, at, "position"));
    REFLCAP_ASSIGN_OR_RETURN(light.position, r.Vector3(*p, at + ".position"));
  } else if (type_name == "directional") {
    light.type = LightType::kDirectional;
    REFLCAP_ASSIGN_OR_RETURN(const Json* d, r.Required(j, at, "direction"));
    REFLCAP_ASSIGN_OR_RETURN(light.direction, r.UnitVector3(*d, at + ".direction"));
  } else {
    return r.Error(at + ".type", StrCat("unknown light type \"", type_name,
                                        "\" (expected \"point\" or \"directional\")"));
  }
  REFLCAP_ASSIGN_OR_RETURN(const Json* intensity, r.Required(j, at, "intensity"));
  REFLCAP_ASSIGN_OR_RETURN(light.intensity, r.Vector3(*intensity, at + ".intensity"));
  if (light.intensity.minCoeff() < 0) return r.Error(at + ".intensity", "must not be negative");
  return light;
}

// True when `name` ends in ".exr" (any case): a variance image must be a float OpenEXR file (an
// 8-bit PNG cannot hold variances spanning the many decades of an HDR photograph).
bool HasExrExtension(const std::string& name) {
  std::string ext = fs::path(name).extension().string();
  for (char& c : ext) c = char(std::tolower(static_cast<unsigned char>(c)));
  return ext == ".exr";
}

StatusOr<CaptureImage> ParseImage(const FieldReader& r, const Json& j, const std::string& at,
                                  const Capture& capture) {
  if (!j.is_object()) return r.Error(at, "must be an object");
  CaptureImage image;
  REFLCAP_ASSIGN_OR_RETURN(const Json* file, r.Required(j, at, "file"));
  REFLCAP_ASSIGN_OR_RETURN(image.file, r.String(*file, at + ".file"));
  REFLCAP_ASSIGN_OR_RETURN(const Json* cam, r.Required(j, at, "camera"));
  REFLCAP_ASSIGN_OR_RETURN(std::string cam_id, r.String(*cam, at + ".camera"));
  image.camera = capture.FindCamera(cam_id);
  if (image.camera < 0) return r.Error(at + ".camera", StrCat("unknown camera id \"", cam_id, "\""));
  REFLCAP_ASSIGN_OR_RETURN(const Json* light, r.Required(j, at, "light"));
  REFLCAP_ASSIGN_OR_RETURN(std::string light_id, r.String(*light, at + ".light"));
  image.light = capture.FindLight(light_id);
  if (image.light < 0) return r.Error(at + ".light", StrCat("unknown light id \"", light_id, "\""));
  if (auto it = j.find("turntable_deg"); it != j.end()) {
    REFLCAP_ASSIGN_OR_RETURN(image.turntable_deg, r.Number(*it, at + ".turntable_deg"));
  }
  if (auto it = j.find("exposure_s"); it != j.end()) {
    REFLCAP_ASSIGN_OR_RETURN(image.exposure_s, r.Number(*it, at + ".exposure_s"));
    if (image.exposure_s <= 0) {
      return r.Error(at + ".exposure_s", StrCat("must be positive (got ", image.exposure_s, ")"));
    }
  }
  std::string split = "train";
  if (auto it = j.find("split"); it != j.end()) {
    REFLCAP_ASSIGN_OR_RETURN(split, r.String(*it, at + ".split"));
  }
  if (split == "train") {
    image.split = Split::kTrain;
  } else if (split == "holdout") {
    image.split = Split::kHoldout;
  } else {
    return r.Error(at + ".split", StrCat("unknown split \"", split, "\" (expected \"train\" or \"holdout\")"));
  }
  if (auto it = j.find("saturation"); it != j.end()) {
    REFLCAP_ASSIGN_OR_RETURN(image.saturation, r.Number(*it, at + ".saturation"));
    if (image.saturation < 0) return r.Error(at + ".saturation", "must not be negative");
  }
  if (auto it = j.find("variance"); it != j.end()) {
    REFLCAP_ASSIGN_OR_RETURN(image.variance, r.String(*it, at + ".variance"));
    if (!HasExrExtension(image.variance)) {
      return r.Error(at + ".variance",
                     StrCat("\"", image.variance, "\" must name an OpenEXR file (.exr): float "
                            "RGB, the variance of each pixel value"));
    }
    if (image.variance == image.file) {
      return r.Error(at + ".variance", StrCat("\"", image.variance, "\" is the photograph itself"));
    }
  }
  return image;
}

// "B, G, R" (or "none").
std::string JoinChannelNames(const std::vector<std::string>& names) {
  if (names.empty()) return "none";
  std::string out;
  for (const std::string& n : names) out += (out.empty() ? "" : ", ") + n;
  return out;
}

Status CheckUniqueIds(const FieldReader& r, const std::vector<std::string>& ids,
                      const std::string& array) {
  std::set<std::string> seen;
  for (size_t i = 0; i < ids.size(); ++i) {
    if (!seen.insert(ids[i]).second) {
      return r.Error(StrCat(array, "[", i, "].id"), StrCat("duplicate id \"", ids[i], "\""));
    }
  }
  return OkStatus();
}

}  // namespace

const char* SplitName(Split split) { return split == Split::kTrain ? "train" : "holdout"; }

Rigid3 Capture::WorldFromObject(const CaptureImage& image) const {
  return turntable ? turntable->WorldFromObject(image.turntable_deg) : Rigid3();
}

int Capture::FindCamera(const std::string& id) const {
  for (size_t i = 0; i < cameras.size(); ++i) {
    if (cameras[i].id == id) return int(i);
  }
  return -1;
}

int Capture::FindLight(const std::string& id) const {
  for (size_t i = 0; i < lights.size(); ++i) {
    if (lights[i].id == id) return int(i);
  }
  return -1;
}

size_t Capture::CountSplit(Split split) const {
  size_t n = 0;
  for (const auto& image : images) n += image.split == split;
  return n;
}

namespace {

StatusOr<Capture> ParseCaptureDocument(const std::string& text, const fs::path& name, bool rig) {
  const std::string file = name.string();
  FieldReader r(file);
  REFLCAP_ASSIGN_OR_RETURN(Json root, jsonio::ParseJsonObject(text, file));
  if (!root.is_object()) return r.Error("(root)", "must be a JSON object");

  Capture capture;
  capture.json_path = name;
  REFLCAP_ASSIGN_OR_RETURN(capture.minor_version, ParseFormat(r, root));

  REFLCAP_ASSIGN_OR_RETURN(const Json* cameras, r.Required(root, "", "cameras"));
  if (!cameras->is_array() || cameras->empty()) return r.Error("cameras", "must be a non-empty array");
  std::vector<std::string> ids;
  for (size_t i = 0; i < cameras->size(); ++i) {
    REFLCAP_ASSIGN_OR_RETURN(Camera cam, ParseCamera(r, (*cameras)[i], StrCat("cameras[", i, "]")));
    ids.push_back(cam.id);
    capture.cameras.push_back(std::move(cam));
  }
  REFLCAP_RETURN_IF_ERROR(CheckUniqueIds(r, ids, "cameras"));

  // A rig (what `reflcap calibrate turntable` writes without --capture) may lack the lights, the
  // geometry and the images; whatever it has is checked as in a capture.
  const bool no_lights = rig && !root.contains("lights");
  const Json no_list = Json::array();
  const Json* lights = &no_list;
  if (!rig && !root.contains("lights") && root.contains("calibration")) {
    return r.Error("lights", "missing: this is a rig skeleton (reflcap calibrate turntable); add "
                             "lights, a mesh or normal map and images, or calibrate with --capture");
  }
  if (!no_lights) {
    REFLCAP_ASSIGN_OR_RETURN(lights, r.Required(root, "", "lights"));
    if (!lights->is_array() || lights->empty()) return r.Error("lights", "must be a non-empty array");
  }
  ids.clear();
  for (size_t i = 0; i < lights->size(); ++i) {
    REFLCAP_ASSIGN_OR_RETURN(Light light, ParseLight(r, (*lights)[i], StrCat("lights[", i, "]")));
    ids.push_back(light.id);
    capture.lights.push_back(std::move(light));
  }
  REFLCAP_RETURN_IF_ERROR(CheckUniqueIds(r, ids, "lights"));

  const bool has_mesh = root.contains("mesh");
  const bool has_normal_map = root.contains("normal_map");
  if (has_mesh == has_normal_map && !(rig && !has_mesh)) {
    return r.Error(has_mesh ? "mesh" : "(root)",
                   "exactly one of \"mesh\" and \"normal_map\" must be given");
  }
  if (has_mesh) {
    REFLCAP_ASSIGN_OR_RETURN(capture.mesh, r.String(root["mesh"], "mesh"));
  } else if (has_normal_map) {
    const Json& nm = root["normal_map"];
    if (!nm.is_object()) return r.Error("normal_map", "must be an object");
    NormalMapGeometry g;
    REFLCAP_ASSIGN_OR_RETURN(const Json* cam, r.Required(nm, "normal_map", "camera"));
    REFLCAP_ASSIGN_OR_RETURN(std::string cam_id, r.String(*cam, "normal_map.camera"));
    g.camera = capture.FindCamera(cam_id);
    if (g.camera < 0) return r.Error("normal_map.camera", StrCat("unknown camera id \"", cam_id, "\""));
    REFLCAP_ASSIGN_OR_RETURN(const Json* normals, r.Required(nm, "normal_map", "normals"));
    REFLCAP_ASSIGN_OR_RETURN(g.normals, r.String(*normals, "normal_map.normals"));
    REFLCAP_ASSIGN_OR_RETURN(const Json* mask, r.Required(nm, "normal_map", "mask"));
    REFLCAP_ASSIGN_OR_RETURN(g.mask, r.String(*mask, "normal_map.mask"));
    capture.normal_map = g;
  }

  if (auto it = root.find("turntable"); it != root.end() && !it->is_null()) {
    if (!it->is_object()) return r.Error("turntable", "must be an object");
    Turntable t;
    REFLCAP_ASSIGN_OR_RETURN(const Json* axis, r.Required(*it, "turntable", "axis"));
    REFLCAP_ASSIGN_OR_RETURN(t.axis, r.UnitVector3(*axis, "turntable.axis"));
    REFLCAP_ASSIGN_OR_RETURN(const Json* point, r.Required(*it, "turntable", "point"));
    REFLCAP_ASSIGN_OR_RETURN(t.point, r.Vector3(*point, "turntable.point"));
    capture.turntable = t;
  }

  const Json* images = &no_list;
  if (!(rig && !root.contains("images"))) {
    REFLCAP_ASSIGN_OR_RETURN(images, r.Required(root, "", "images"));
    if (!images->is_array()) return r.Error("images", "must be an array");
    if (images->empty()) return r.Error("images", "the image list is empty");
  }
  for (size_t i = 0; i < images->size(); ++i) {
    const std::string at = StrCat("images[", i, "]");
    REFLCAP_ASSIGN_OR_RETURN(CaptureImage image, ParseImage(r, (*images)[i], at, capture));
    if (!capture.turntable && image.turntable_deg != 0) {
      return r.Error(at + ".turntable_deg", "non-zero angle but the capture has no turntable");
    }
    capture.images.push_back(std::move(image));
  }

  if (auto it = root.find("ground_truth"); it != root.end()) capture.ground_truth_json = it->dump();
  return capture;
}

StatusOr<std::string> ReadCaptureText(const fs::path& json_path, fs::path* file) {
  std::error_code ec;
  *file = fs::is_directory(json_path, ec) ? json_path / "capture.json" : json_path;
  auto text = ReadTextFile(*file);
  if (!text.ok()) return NotFoundError(file->string(), ": cannot open capture file");
  return text;
}

}  // namespace

StatusOr<Capture> ParseCapture(const std::string& text, const fs::path& name) {
  return ParseCaptureDocument(text, name, /*rig=*/false);
}

StatusOr<Capture> ReadRig(const fs::path& json_path) {
  fs::path file;
  REFLCAP_ASSIGN_OR_RETURN(std::string text, ReadCaptureText(json_path, &file));
  return ParseCaptureDocument(text, file, /*rig=*/true);
}

StatusOr<Capture> ReadCapture(const fs::path& json_path) {
  fs::path file;
  REFLCAP_ASSIGN_OR_RETURN(std::string text, ReadCaptureText(json_path, &file));
  return ParseCapture(text, file);
}

Status ValidateCaptureFiles(const Capture& capture, CaptureFilesReport* report,
                            const std::vector<bool>* images) {
  const std::string file = capture.json_path.string();
  auto field_error = [&](const std::string& field, const Status& cause) {
    return Status(cause.code(), StrCat(file, ": ", field, ": ", cause.message()));
  };
  CaptureFilesReport local;
  CaptureFilesReport& out = report ? *report : local;
  if (!capture.mesh.empty()) {
    MeshLoadStats stats;
    auto mesh = LoadMesh(capture.Resolve(capture.mesh), &stats);
    if (!mesh.ok()) return field_error("mesh", mesh.status());
    out.mesh_vertices = mesh->positions.size();
    out.mesh_triangles = mesh->triangles.size();
    out.mesh_degenerate_skipped = stats.degenerate_skipped;
    out.mesh = std::make_shared<const TriangleMesh>(std::move(*mesh));
  } else {
    const NormalMapGeometry& g = *capture.normal_map;
    const Camera& cam = capture.cameras[g.camera];
    auto normals = ReadExrInfo(capture.Resolve(g.normals));
    if (!normals.ok()) return field_error("normal_map.normals", normals.status());
    if (normals->width != cam.width || normals->height != cam.height) {
      return InvalidArgumentError(file, ": normal_map.normals: ", g.normals, " is ", normals->width,
                                  "x", normals->height, " but camera \"", cam.id, "\" is ",
                                  cam.width, "x", cam.height);
    }
    auto mask = ReadPng(capture.Resolve(g.mask));
    if (!mask.ok()) return field_error("normal_map.mask", mask.status());
    if (mask->width != cam.width || mask->height != cam.height) {
      return InvalidArgumentError(file, ": normal_map.mask: ", g.mask, " is ", mask->width, "x",
                                  mask->height, " but camera \"", cam.id, "\" is ", cam.width,
                                  "x", cam.height);
    }
    size_t count = 0;
    for (size_t p = 0; p < mask->PixelCount(); ++p) count += mask->data[p * mask->channels] > 0;
    out.normal_map_texels = count;
  }
  for (size_t i = 0; i < capture.images.size(); ++i) {
    if (images != nullptr && (i >= images->size() || !(*images)[i])) continue;
    const CaptureImage& image = capture.images[i];
    const std::string field = StrCat("images[", i, "].file");
    auto info = ReadImageInfo(capture.Resolve(image.file));
    if (!info.ok()) return field_error(field, info.status());
    const Camera& cam = capture.cameras[image.camera];
    if (info->width != cam.width || info->height != cam.height) {
      return InvalidArgumentError(file, ": ", field, ": ", image.file, " is ", info->width, "x",
                                  info->height, " but camera \"", cam.id, "\" is ", cam.width,
                                  "x", cam.height);
    }
    ++out.images_checked;
    if (!image.variance.empty()) {
      const std::string vfield = StrCat("images[", i, "].variance");
      auto vinfo = ReadExrInfo(capture.Resolve(image.variance));
      if (!vinfo.ok()) return field_error(vfield, vinfo.status());
      if (vinfo->width != cam.width || vinfo->height != cam.height) {
        return InvalidArgumentError(file, ": ", vfield, ": ", image.variance, " is ", vinfo->width,
                                    "x", vinfo->height, " but camera \"", cam.id, "\" is ",
                                    cam.width, "x", cam.height, " (the photograph's size)");
      }
      // OpenEXR lists channels sorted by name.
      if (vinfo->channel_names != std::vector<std::string>{"B", "G", "R"}) {
        return InvalidArgumentError(file, ": ", vfield, ": ", image.variance, " has ",
                                    vinfo->channels,
                                    vinfo->channels == 1 ? " channel" : " channels", " (",
                                    JoinChannelNames(vinfo->channel_names),
                                    "); a variance image has exactly R, G and B, one per channel "
                                    "of the photograph");
      }
      ++out.variance_images_checked;
    }
  }
  return OkStatus();
}

Status CheckVarianceImage(const Capture& capture, size_t index, const Image& variance) {
  const std::string file = capture.json_path.string();
  if (index >= capture.images.size()) {
    return InvalidArgumentError(file, ": image index ", index, " out of range");
  }
  const CaptureImage& image = capture.images[index];
  const Camera& cam = capture.cameras[image.camera];
  const std::string field = StrCat(file, ": images[", index, "].variance: ", image.variance);
  if (variance.width != cam.width || variance.height != cam.height || variance.channels != 3) {
    return InvalidArgumentError(field, " is ", variance.width, "x", variance.height, "x",
                                variance.channels, ", expected ", cam.width, "x", cam.height,
                                " RGB (camera \"", cam.id, "\")");
  }
  size_t bad = 0, first = 0;
  for (size_t k = 0; k < variance.data.size(); ++k) {
    const float v = variance.data[k];
    // !(v >= 0) also catches NaN.
    if (!(v >= 0) || !std::isfinite(v)) {
      if (bad++ == 0) first = k;
    }
  }
  if (bad > 0) {
    const size_t pixel = first / 3;
    const float v = variance.data[first];
    const char* what = std::isnan(v) ? "NaN" : !std::isfinite(v) ? "infinite" : "negative";
    return InvalidArgumentError(field, ": pixel (", pixel % size_t(variance.width), ", ",
                                pixel / size_t(variance.width), ") channel ", "RGB"[first % 3],
                                " is ", what, " (", v,
                                "); every variance must be finite and >= 0 (", bad,
                                bad == 1 ? " bad value)" : " bad values)");
  }
  return OkStatus();
}

StatusOr<Image> ReadVarianceImage(const Capture& capture, size_t index) {
  const std::string file = capture.json_path.string();
  if (index >= capture.images.size()) {
    return InvalidArgumentError(file, ": image index ", index, " out of range");
  }
  const CaptureImage& image = capture.images[index];
  if (image.variance.empty()) {
    return InvalidArgumentError(file, ": images[", index, "].variance: not given");
  }
  auto variance = ReadExrRgb(capture.Resolve(image.variance));
  if (!variance.ok()) {
    return Status(variance.status().code(), StrCat(file, ": images[", index, "].variance: ",
                                                   variance.status().message()));
  }
  REFLCAP_RETURN_IF_ERROR(CheckVarianceImage(capture, index, *variance));
  return std::move(*variance);
}

namespace {
OutJson MatrixJson(const Eigen::MatrixXd& m) {
  OutJson rows = OutJson::array();
  for (int r = 0; r < m.rows(); ++r) {
    OutJson row = OutJson::array();
    for (int c = 0; c < m.cols(); ++c) row.push_back(m(r, c));
    rows.push_back(row);
  }
  return rows;
}
OutJson VecJson(const Vec3d& v) { return OutJson::array({v.x(), v.y(), v.z()}); }
}  // namespace

std::string CaptureToJson(const Capture& capture) {
  OutJson root = OutJson::object();
  root["format"] = capture.minor_version ? StrCat("capture/1.", capture.minor_version) : "capture/1";
  if (capture.normal_map) {
    const auto& g = *capture.normal_map;
    root["normal_map"] = {{"camera", capture.cameras[g.camera].id},
                          {"normals", g.normals},
                          {"mask", g.mask}};
  } else {
    root["mesh"] = capture.mesh;
  }
  OutJson cameras = OutJson::array();
  for (const Camera& cam : capture.cameras) {
    OutJson j = {{"id", cam.id}, {"width", cam.width}, {"height", cam.height}};
    if (cam.model == CameraModel::kOrthographic) {
      j["model"] = "orthographic";
      if (cam.pixel_size_m > 0) j["pixel_size_m"] = cam.pixel_size_m;
    } else {
      j["K"] = MatrixJson(cam.K);
      j["dist"] = OutJson(std::vector<double>(cam.dist.begin(), cam.dist.end()));
    }
    j["cam_from_world"] = MatrixJson(cam.cam_from_world.ToMatrix());
    // Written only when not the default, so area-filtered captures keep their files unchanged.
    if (cam.pixel_filter != PixelFilter::kArea) {
      j["pixel_filter"] = PixelFilterName(cam.pixel_filter);
    }
    cameras.push_back(j);
  }
  root["cameras"] = cameras;
  OutJson lights = OutJson::array();
  for (const Light& light : capture.lights) {
    OutJson j = {{"id", light.id}};
    if (light.type == LightType::kPoint) {
      j["type"] = "point";
      j["position"] = VecJson(light.position);
    } else {
      j["type"] = "directional";
      j["direction"] = VecJson(light.direction);
    }
    j["intensity"] = VecJson(light.intensity);
    lights.push_back(j);
  }
  root["lights"] = lights;
  if (capture.turntable) {
    root["turntable"] = {{"axis", VecJson(capture.turntable->axis)},
                         {"point", VecJson(capture.turntable->point)}};
  }
  OutJson images = OutJson::array();
  for (const CaptureImage& image : capture.images) {
    OutJson j = {{"file", image.file},
              {"camera", capture.cameras[image.camera].id},
              {"light", capture.lights[image.light].id},
              {"turntable_deg", image.turntable_deg},
              {"exposure_s", image.exposure_s},
              {"split", SplitName(image.split)}};
    if (image.saturation > 0) j["saturation"] = image.saturation;
    if (!image.variance.empty()) j["variance"] = image.variance;
    images.push_back(j);
  }
  root["images"] = images;
  if (!capture.ground_truth_json.empty()) root["ground_truth"] = OutJson::parse(capture.ground_truth_json);
  return root.dump(2) + "\n";
}

Status WriteCapture(const Capture& capture, const fs::path& json_path) {
  return WriteTextFileAtomic(json_path, CaptureToJson(capture));
}

}  // namespace reflcap
