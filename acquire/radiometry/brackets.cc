// brackets/1 reader and validator (see brackets.h). The rig (cameras, lights, turntable) is parsed
// by the capture/1 parser itself, so both formats accept and reject exactly the same rig; the
// photos and the ground-truth block are checked here, each message naming the file and field.
#include "acquire/radiometry/brackets.h"

#include <algorithm>
#include <cmath>
#include <set>

#include <nlohmann/json.hpp>

#include "engine/core/atomic_file.h"
#include "engine/image/png_io.h"

namespace reflcap::radiometry {
namespace fs = std::filesystem;
using Json = nlohmann::json;

namespace {

// An 8-bit PNG decodes to byte/255 exactly (png_io.h); a 16-bit one to value/65535, which lies
// off that grid for all but 1 in 257 values. 1e-3 code units is far above float rounding
// (255 * 2^-24) and far below the 1/257 code offset of a 16-bit value.
constexpr double kEightBitGridTolerance = 1e-3;

class Fields {
 public:
  explicit Fields(std::string file) : file_(std::move(file)) {}
  Status Error(const std::string& field, const std::string& what) const {
    return InvalidArgumentError(file_, ": ", field, ": ", what);
  }
  StatusOr<const Json*> Required(const Json& object, const std::string& at,
                                 const std::string& key) const {
    auto it = object.find(key);
    if (it == object.end()) return Error(at.empty() ? key : at + "." + key, "missing");
    return &*it;
  }
  StatusOr<std::string> String(const Json& value, const std::string& field) const {
    if (!value.is_string()) return Error(field, "must be a string");
    std::string s = value.get<std::string>();
    if (s.empty()) return Error(field, "must not be empty");
    return s;
  }
  StatusOr<double> Number(const Json& value, const std::string& field) const {
    if (!value.is_number()) return Error(field, "must be a number");
    const double v = value.get<double>();
    if (!std::isfinite(v)) return Error(field, "must be finite");
    return v;
  }

 private:
  std::string file_;
};

bool IsFileNameSafe(const std::string& id) {
  if (id.empty() || id == "." || id == "..") return false;
  for (char c : id) {
    const bool ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
                    c == '_' || c == '-' || c == '.';
    if (!ok) return false;
  }
  return true;
}

// The rig through the capture/1 parser: a capture text holding the file's cameras, lights and
// turntable, a placeholder mesh and one placeholder image (capture/1 requires both).
StatusOr<Capture> ParseRig(const Json& root, const fs::path& name) {
  Json capture = {{"format", "capture/1"}, {"mesh", "(brackets: no mesh)"}};
  for (const char* key : {"cameras", "lights", "turntable"}) {
    if (root.contains(key)) capture[key] = root[key];
  }
  std::string camera_id = "?", light_id = "?";
  if (root.contains("cameras") && root["cameras"].is_array() && !root["cameras"].empty() &&
      root["cameras"][0].is_object() && root["cameras"][0].contains("id") &&
      root["cameras"][0]["id"].is_string()) {
    camera_id = root["cameras"][0]["id"].get<std::string>();
  }
  if (root.contains("lights") && root["lights"].is_array() && !root["lights"].empty() &&
      root["lights"][0].is_object() && root["lights"][0].contains("id") &&
      root["lights"][0]["id"].is_string()) {
    light_id = root["lights"][0]["id"].get<std::string>();
  }
  capture["images"] = Json::array({Json{{"file", "(placeholder)"},
                                        {"camera", camera_id},
                                        {"light", light_id},
                                        {"turntable_deg", 0.0},
                                        {"exposure_s", 1.0},
                                        {"split", "train"}}});
  REFLCAP_ASSIGN_OR_RETURN(Capture rig, ParseCapture(capture.dump(), name));
  rig.images.clear();
  rig.mesh.clear();
  return rig;
}

Status ParseTruth(const Fields& f, const Json& j, BracketTruth* truth) {
  if (!j.is_object()) return f.Error("ground_truth", "must be an object");
  if (auto r = j.find("response"); r != j.end() && r->is_object()) {
    if (auto x = r->find("x_of_code"); x != r->end()) {
      const std::string at = "ground_truth.response.x_of_code";
      if (!x->is_array() || x->size() != 256) return f.Error(at, "must be an array of 256 numbers");
      for (size_t k = 0; k < 256; ++k) {
        REFLCAP_ASSIGN_OR_RETURN(double v, f.Number((*x)[k], StrCat(at, "[", k, "]")));
        if (v < 0) return f.Error(StrCat(at, "[", k, "]"), "must not be negative");
        truth->x_of_code.push_back(v);
      }
    }
  }
  if (auto g = j.find("wb_gains"); g != j.end()) {
    if (!g->is_array() || g->size() != 3) return f.Error("ground_truth.wb_gains", "must be 3 numbers");
    Vec3d gains;
    for (int c = 0; c < 3; ++c) {
      REFLCAP_ASSIGN_OR_RETURN(gains[c], f.Number((*g)[c], StrCat("ground_truth.wb_gains[", c, "]")));
      if (!(gains[c] > 0)) return f.Error(StrCat("ground_truth.wb_gains[", c, "]"), "must be positive");
    }
    truth->wb_gains = gains;
  }
  if (auto s = j.find("read_noise_sigma"); s != j.end()) {
    REFLCAP_ASSIGN_OR_RETURN(double sigma, f.Number(*s, "ground_truth.read_noise_sigma"));
    if (sigma < 0) return f.Error("ground_truth.read_noise_sigma", "must not be negative");
    truth->read_noise_sigma = sigma;
  }
  if (auto c = j.find("chart"); c != j.end() && c->is_object()) {
    for (auto [key, out] : {std::pair<const char*, std::string*>{"photo_id", &truth->chart_photo_id},
                            {"hdr", &truth->chart_hdr},
                            {"geometry", &truth->chart_geometry}}) {
      if (auto it = c->find(key); it != c->end()) {
        REFLCAP_ASSIGN_OR_RETURN(*out, f.String(*it, StrCat("ground_truth.chart.", key)));
      }
    }
  }
  return OkStatus();
}

StatusOr<BracketPhoto> ParsePhoto(const Fields& f, const Json& j, const std::string& at,
                                  const Capture& rig) {
  if (!j.is_object()) return f.Error(at, "must be an object");
  BracketPhoto photo;
  REFLCAP_ASSIGN_OR_RETURN(const Json* id, f.Required(j, at, "id"));
  REFLCAP_ASSIGN_OR_RETURN(photo.id, f.String(*id, at + ".id"));
  if (!IsFileNameSafe(photo.id)) {
    return f.Error(at + ".id", StrCat("\"", photo.id,
                                      "\" must use only letters, digits, '_', '-' and '.' (it names "
                                      "the output image)"));
  }
  REFLCAP_ASSIGN_OR_RETURN(const Json* subject, f.Required(j, at, "subject"));
  REFLCAP_ASSIGN_OR_RETURN(std::string subject_name, f.String(*subject, at + ".subject"));
  if (subject_name == "object") {
    photo.subject = Subject::kObject;
  } else if (subject_name == "colorchecker") {
    photo.subject = Subject::kColorChecker;
  } else {
    return f.Error(at + ".subject", StrCat("unknown subject \"", subject_name,
                                           "\" (expected \"object\" or \"colorchecker\")"));
  }
  REFLCAP_ASSIGN_OR_RETURN(const Json* camera, f.Required(j, at, "camera"));
  REFLCAP_ASSIGN_OR_RETURN(std::string camera_id, f.String(*camera, at + ".camera"));
  photo.camera = rig.FindCamera(camera_id);
  if (photo.camera < 0) return f.Error(at + ".camera", StrCat("unknown camera id \"", camera_id, "\""));
  REFLCAP_ASSIGN_OR_RETURN(const Json* light, f.Required(j, at, "light"));
  REFLCAP_ASSIGN_OR_RETURN(std::string light_id, f.String(*light, at + ".light"));
  photo.light = rig.FindLight(light_id);
  if (photo.light < 0) return f.Error(at + ".light", StrCat("unknown light id \"", light_id, "\""));

  auto angle = j.find("turntable_deg");
  if (angle == j.end() || angle->is_null()) {
    if (photo.subject == Subject::kObject) {
      return f.Error(at + ".turntable_deg", "missing (an object photo needs its turntable angle)");
    }
  } else {
    REFLCAP_ASSIGN_OR_RETURN(photo.turntable_deg, f.Number(*angle, at + ".turntable_deg"));
    if (!rig.turntable && photo.turntable_deg != 0) {
      return f.Error(at + ".turntable_deg", "non-zero angle but the file has no turntable");
    }
  }
  REFLCAP_ASSIGN_OR_RETURN(const Json* split, f.Required(j, at, "split"));
  REFLCAP_ASSIGN_OR_RETURN(photo.split, f.String(*split, at + ".split"));
  if (photo.subject == Subject::kObject && photo.split != "train" && photo.split != "holdout") {
    return f.Error(at + ".split", StrCat("unknown split \"", photo.split,
                                         "\" for an object photo (expected \"train\" or \"holdout\")"));
  }
  if (auto s = j.find("source_hdr"); s != j.end() && !s->is_null()) {
    REFLCAP_ASSIGN_OR_RETURN(photo.source_hdr, f.String(*s, at + ".source_hdr"));
  }
  if (auto s = j.find("chart"); s != j.end() && !s->is_null()) {
    REFLCAP_ASSIGN_OR_RETURN(photo.chart, f.String(*s, at + ".chart"));
  }

  REFLCAP_ASSIGN_OR_RETURN(const Json* exposures, f.Required(j, at, "exposures"));
  if (!exposures->is_array()) return f.Error(at + ".exposures", "must be an array");
  if (exposures->size() < 2) {
    return f.Error(at + ".exposures", StrCat("needs at least 2 exposures (got ", exposures->size(), ")"));
  }
  if (exposures->size() > size_t(kMaxExposuresPerPhoto)) {
    return f.Error(at + ".exposures", StrCat("at most ", kMaxExposuresPerPhoto, " exposures (got ",
                                             exposures->size(), ")"));
  }
  for (size_t e = 0; e < exposures->size(); ++e) {
    const std::string ea = StrCat(at, ".exposures[", e, "]");
    const Json& ej = (*exposures)[e];
    if (!ej.is_object()) return f.Error(ea, "must be an object");
    BracketExposure exposure;
    REFLCAP_ASSIGN_OR_RETURN(const Json* file, f.Required(ej, ea, "file"));
    REFLCAP_ASSIGN_OR_RETURN(exposure.file, f.String(*file, ea + ".file"));
    REFLCAP_ASSIGN_OR_RETURN(const Json* t, f.Required(ej, ea, "exposure_s"));
    REFLCAP_ASSIGN_OR_RETURN(exposure.exposure_s, f.Number(*t, ea + ".exposure_s"));
    if (!(exposure.exposure_s > 0)) {
      return f.Error(ea + ".exposure_s", StrCat("must be positive (got ", exposure.exposure_s, ")"));
    }
    if (e > 0) {
      const double previous = photo.exposures.back().exposure_s;
      if (exposure.exposure_s == previous) {
        return f.Error(ea + ".exposure_s",
                       StrCat("duplicates the previous exposure (", previous,
                              " s): each exposure of a bracket must be distinct"));
      }
      if (exposure.exposure_s < previous) {
        return f.Error(ea + ".exposure_s",
                       StrCat("must exceed the previous exposure (", previous, " s), got ",
                              exposure.exposure_s, ": list a bracket's exposures in increasing order"));
      }
    }
    for (const BracketExposure& other : photo.exposures) {
      if (other.file == exposure.file) {
        return f.Error(ea + ".file", StrCat("\"", exposure.file, "\" is listed twice in this bracket"));
      }
    }
    photo.exposures.push_back(std::move(exposure));
  }
  return photo;
}

}  // namespace

int BracketSet::ChartPhoto() const {
  for (size_t i = 0; i < photos.size(); ++i) {
    if (photos[i].subject == Subject::kColorChecker) return int(i);
  }
  return -1;
}

size_t BracketSet::CountSubject(Subject subject) const {
  size_t n = 0;
  for (const BracketPhoto& p : photos) n += p.subject == subject;
  return n;
}

StatusOr<BracketSet> ParseBrackets(const std::string& text, const fs::path& name) {
  const Fields f(name.string());
  Json root = Json::parse(text, nullptr, false);
  if (root.is_discarded()) {
    try {
      root = Json::parse(text);
    } catch (const Json::exception& e) {
      return InvalidArgumentError(name.string(), ": JSON syntax error: ", e.what());
    }
  }
  if (!root.is_object()) return f.Error("(root)", "must be a JSON object");
  REFLCAP_ASSIGN_OR_RETURN(const Json* format, f.Required(root, "", "format"));
  REFLCAP_ASSIGN_OR_RETURN(std::string format_name, f.String(*format, "format"));
  if (format_name != "brackets/1" && format_name.rfind("brackets/1.", 0) != 0) {
    return f.Error("format", StrCat("\"", format_name, "\" is not brackets/1"));
  }
  BracketSet set;
  set.json_path = name;
  REFLCAP_ASSIGN_OR_RETURN(set.rig, ParseRig(root, name));
  set.rig.json_path = name;
  if (auto s = root.find("source_capture"); s != root.end() && !s->is_null()) {
    REFLCAP_ASSIGN_OR_RETURN(set.source_capture, f.String(*s, "source_capture"));
  }
  REFLCAP_ASSIGN_OR_RETURN(const Json* photos, f.Required(root, "", "photos"));
  if (!photos->is_array() || photos->empty()) return f.Error("photos", "must be a non-empty array");
  std::set<std::string> ids;
  for (size_t i = 0; i < photos->size(); ++i) {
    const std::string at = StrCat("photos[", i, "]");
    REFLCAP_ASSIGN_OR_RETURN(BracketPhoto photo, ParsePhoto(f, (*photos)[i], at, set.rig));
    if (!ids.insert(photo.id).second) {
      return f.Error(at + ".id", StrCat("duplicate photo id \"", photo.id, "\""));
    }
    set.photos.push_back(std::move(photo));
  }
  if (set.CountSubject(Subject::kObject) == 0) {
    return f.Error("photos", "no photo has subject \"object\": nothing to merge");
  }
  if (auto it = root.find("ground_truth"); it != root.end() && !it->is_null()) {
    REFLCAP_RETURN_IF_ERROR(ParseTruth(f, *it, &set.truth));
  }
  return set;
}

StatusOr<BracketSet> ReadBrackets(const fs::path& json_path) {
  std::error_code ec;
  if (fs::is_directory(json_path, ec)) return ReadBrackets(json_path / "brackets.json");
  auto text = ReadTextFile(json_path);
  if (!text.ok()) return NotFoundError(json_path.string(), ": cannot open brackets file");
  return ParseBrackets(*text, json_path);
}

StatusOr<BracketImages> ReadBracketImages(const BracketSet& set, size_t photo_index) {
  const BracketPhoto& photo = set.photos[photo_index];
  const Camera& camera = set.rig.cameras[size_t(photo.camera)];
  const std::string file = set.json_path.string();
  BracketImages out;
  out.width = camera.width;
  out.height = camera.height;
  for (size_t e = 0; e < photo.exposures.size(); ++e) {
    const std::string field = StrCat("photos[", photo_index, "].exposures[", e, "].file");
    const fs::path path = set.Resolve(photo.exposures[e].file);
    auto image = ReadPng(path);
    if (!image.ok()) {
      return Status(image.status().code(), StrCat(file, ": ", field, ": ", image.status().message()));
    }
    if (image->width != camera.width || image->height != camera.height) {
      return InvalidArgumentError(file, ": ", field, ": ", path.string(), " is ", image->width, "x",
                                  image->height, ", camera ", camera.id, " is ", camera.width, "x",
                                  camera.height, " (every exposure of a photo must match its camera)");
    }
    const int channels = image->channels;
    if (channels < 1 || channels > 4) {
      return InvalidArgumentError(file, ": ", field, ": ", path.string(), ": unexpected ", channels,
                                  " channels");
    }
    const size_t pixels = image->PixelCount();
    std::vector<uint8_t> codes(pixels * 3);
    for (size_t p = 0; p < pixels; ++p) {
      for (int c = 0; c < 3; ++c) {
        // Grey (+alpha) replicates to RGB; RGBA drops alpha.
        const int source = channels >= 3 ? c : 0;
        const double v = double(image->data[p * size_t(channels) + size_t(source)]) * 255.0;
        const double code = std::round(v);
        if (std::abs(v - code) > kEightBitGridTolerance) {
          return InvalidArgumentError(file, ": ", field, ": ", path.string(),
                                      " is not an 8-bit PNG (brackets must hold the camera's 8-bit "
                                      "codes)");
        }
        codes[p * 3 + size_t(c)] = uint8_t(std::clamp(code, 0.0, 255.0));
      }
    }
    out.codes.push_back(std::move(codes));
  }
  return out;
}

}  // namespace reflcap::radiometry
