// structured_light/1 reader and validator (see scan_spec.h). Every error names the file and the
// JSON field (or the image file) so that `reflcap scan` can exit 2 with a message a user can act on.
#include "acquire/scan/scan_spec.h"

#include <algorithm>
#include <cmath>
#include <regex>
#include <set>

#include <nlohmann/json.hpp>

#include "engine/core/atomic_file.h"
#include "engine/image/png_io.h"

namespace reflcap::scan {
namespace fs = std::filesystem;
using Json = nlohmann::json;

namespace {

// A rotation read from a file with 6-7 significant digits is orthonormal to ~1e-6; 1e-4 accepts
// that rounding and rejects anything that is not a rotation.
constexpr double kRotationTolerance = 1e-4;
// Two turntable angles closer than this (degrees) are the same angle listed twice.
constexpr double kSameAngleDeg = 1e-6;

class Fields {
 public:
  explicit Fields(std::string file) : file_(std::move(file)) {}
  Status Error(const std::string& field, const std::string& what) const {
    return InvalidArgumentError(file_, ": ", field, ": ", what);
  }
  StatusOr<const Json*> Required(const Json& object, const std::string& field,
                                 const std::string& key) const {
    if (!object.is_object()) return Error(field, "must be an object");
    auto it = object.find(key);
    if (it == object.end()) return Error(field.empty() ? key : field + "." + key, "missing");
    return &*it;
  }
  StatusOr<double> Number(const Json& v, const std::string& field) const {
    if (!v.is_number()) return Error(field, "must be a number");
    const double d = v.get<double>();
    if (!std::isfinite(d)) return Error(field, "must be finite");
    return d;
  }
  StatusOr<int> PositiveInt(const Json& v, const std::string& field) const {
    if (!v.is_number_integer() || v.get<int64_t>() <= 0 || v.get<int64_t>() > (1 << 16)) {
      return Error(field, "must be a positive integer (at most 65536)");
    }
    return int(v.get<int64_t>());
  }
  StatusOr<std::string> String(const Json& v, const std::string& field) const {
    if (!v.is_string() || v.get<std::string>().empty()) return Error(field, "must be a non-empty string");
    return v.get<std::string>();
  }
  template <int R, int C>
  StatusOr<Eigen::Matrix<double, R, C>> Matrix(const Json& v, const std::string& field) const {
    const std::string shape = StrCat("must be a ", R, "x", C, " array of numbers (rows)");
    if (!v.is_array() || v.size() != R) return Error(field, shape);
    Eigen::Matrix<double, R, C> m;
    for (int r = 0; r < R; ++r) {
      if (!v[r].is_array() || v[r].size() != C) return Error(field, shape);
      for (int c = 0; c < C; ++c) {
        REFLCAP_ASSIGN_OR_RETURN(m(r, c), Number(v[r][c], StrCat(field, "[", r, "][", c, "]")));
      }
    }
    return m;
  }
  StatusOr<Vec3d> Vector3(const Json& v, const std::string& field) const {
    if (!v.is_array() || v.size() != 3) return Error(field, "must be an array of 3 numbers");
    Vec3d out;
    for (int i = 0; i < 3; ++i) {
      REFLCAP_ASSIGN_OR_RETURN(out[i], Number(v[i], StrCat(field, "[", i, "]")));
    }
    return out;
  }

 private:
  std::string file_;
};

// A pinhole device of the scan: id, width, height, K, optional dist, and its pose under `pose_key`.
StatusOr<Camera> ParseDevice(const Fields& f, const Json& root, const std::string& key,
                             const std::string& pose_key) {
  REFLCAP_ASSIGN_OR_RETURN(const Json* j, f.Required(root, "", key));
  if (!j->is_object()) return f.Error(key, "must be an object");
  Camera cam;
  if (auto it = j->find("id"); it != j->end()) {
    REFLCAP_ASSIGN_OR_RETURN(cam.id, f.String(*it, key + ".id"));
  } else {
    cam.id = key;
  }
  REFLCAP_ASSIGN_OR_RETURN(const Json* w, f.Required(*j, key, "width"));
  REFLCAP_ASSIGN_OR_RETURN(cam.width, f.PositiveInt(*w, key + ".width"));
  REFLCAP_ASSIGN_OR_RETURN(const Json* h, f.Required(*j, key, "height"));
  REFLCAP_ASSIGN_OR_RETURN(cam.height, f.PositiveInt(*h, key + ".height"));
  REFLCAP_ASSIGN_OR_RETURN(const Json* k, f.Required(*j, key, "K"));
  REFLCAP_ASSIGN_OR_RETURN(cam.K, (f.Matrix<3, 3>(*k, key + ".K")));
  if (cam.K(1, 0) != 0 || cam.K(2, 0) != 0 || cam.K(2, 1) != 0 || cam.K(2, 2) != 1) {
    return f.Error(key + ".K", "must have the form [[fx,s,cx],[0,fy,cy],[0,0,1]]");
  }
  if (!(cam.K(0, 0) > 0) || !(cam.K(1, 1) > 0)) {
    return f.Error(key + ".K", "focal lengths fx and fy must be positive");
  }
  if (auto it = j->find("dist"); it != j->end()) {
    if (!it->is_array() || (it->size() != 4 && it->size() != 5)) {
      return f.Error(key + ".dist", "must be [k1,k2,p1,p2] or [k1,k2,p1,p2,k3]");
    }
    for (size_t i = 0; i < it->size(); ++i) {
      REFLCAP_ASSIGN_OR_RETURN(cam.dist[i], f.Number((*it)[i], StrCat(key, ".dist[", i, "]")));
    }
  }
  REFLCAP_ASSIGN_OR_RETURN(const Json* m, f.Required(*j, key, pose_key));
  const std::string at = key + "." + pose_key;
  REFLCAP_ASSIGN_OR_RETURN(Mat4d mat, (f.Matrix<4, 4>(*m, at)));
  if ((mat.row(3) - Eigen::RowVector4d(0, 0, 0, 1)).cwiseAbs().maxCoeff() > 0) {
    return f.Error(at, "last row must be [0,0,0,1]");
  }
  cam.cam_from_world = Rigid3::FromMatrix(mat);
  const Mat3d& rot = cam.cam_from_world.rotation;
  if ((rot.transpose() * rot - Mat3d::Identity()).cwiseAbs().maxCoeff() > kRotationTolerance ||
      std::abs(rot.determinant() - 1) > kRotationTolerance) {
    return f.Error(at, "rotation part is not a proper rotation (R^T R != I or det != 1)");
  }
  Eigen::JacobiSVD<Mat3d> svd(rot, Eigen::ComputeFullU | Eigen::ComputeFullV);
  cam.cam_from_world.rotation = svd.matrixU() * svd.matrixV().transpose();
  return cam;
}

// Which slot of an angle a pattern name fills. Returns false for an unknown name.
struct PatternSlot {
  enum Kind { kWhite, kBlack, kGray, kGrayInverse, kPhase } kind = kWhite;
  bool row = false;  // axis: columns (false) or rows (true)
  int bit = 0;       // Gray bit
  int period = 0;    // phase period, projector pixels
  int shift = 0;     // phase shift index k
};

bool ParsePatternName(const std::string& name, PatternSlot* slot) {
  static const std::regex kGray("gray_(col|row)_b([0-9]+)(_inv)?");
  static const std::regex kPhase("phase_(col|row)_p([0-9]+)_k([0-9]+)");
  std::smatch m;
  if (name == "white") {
    slot->kind = PatternSlot::kWhite;
  } else if (name == "black") {
    slot->kind = PatternSlot::kBlack;
  } else if (std::regex_match(name, m, kGray)) {
    slot->kind = m[3].matched ? PatternSlot::kGrayInverse : PatternSlot::kGray;
    slot->row = m[1] == "row";
    // A bit index has at most two digits (ceil(log2) of an int extent); longer digit runs made
    // std::stoi throw out_of_range and abort `reflcap scan` (found by tests/fuzz/scan_spec_fuzzer).
    if (m[2].length() > 2) return false;
    slot->bit = std::stoi(m[2]);
  } else if (std::regex_match(name, m, kPhase)) {
    slot->kind = PatternSlot::kPhase;
    slot->row = m[1] == "row";
    if (m[2].length() > 6 || m[3].length() > 3) return false;
    slot->period = std::stoi(m[2]);
    slot->shift = std::stoi(m[3]);
  } else {
    return false;
  }
  return true;
}

}  // namespace

int GrayBitsFor(int pixels) {
  int bits = 1;
  while ((1 << bits) < pixels) ++bits;
  return bits;
}

Rigid3 ScanSpec::ObjectFromCamera(size_t a) const {
  return turntable.WorldFromObject(angles[a].turntable_deg).Inverse() *
         camera.cam_from_world.Inverse();
}

Rigid3 ScanSpec::ObjectFromProjector(size_t a) const {
  return turntable.WorldFromObject(angles[a].turntable_deg).Inverse() *
         projector.cam_from_world.Inverse();
}

StatusOr<ScanSpec> LoadScanSpec(const fs::path& json_path, bool check_images) {
  auto text = ReadTextFile(json_path);
  if (!text.ok()) return NotFoundError(json_path.string(), ": cannot read the scan description");
  Json root;
  try {
    root = Json::parse(*text);
  } catch (const Json::parse_error& e) {
    return DataLossError(json_path.string(), ": JSON syntax error at byte ", e.byte, ": ", e.what());
  } catch (const Json::exception& e) {
    // Not only syntax: a number beyond a double's range (1e999) throws out_of_range.406, which
    // used to escape and abort `reflcap scan` (found by tests/cli/bad_input_corpus_test).
    return DataLossError(json_path.string(), ": ", e.what());
  }
  const Fields f(json_path.string());
  if (!root.is_object()) return f.Error("(root)", "must be a JSON object");
  ScanSpec spec;
  spec.json_path = json_path;
  const fs::path base = json_path.parent_path();

  REFLCAP_ASSIGN_OR_RETURN(const Json* format, f.Required(root, "", "format"));
  REFLCAP_ASSIGN_OR_RETURN(std::string fmt, f.String(*format, "format"));
  if (fmt != "structured_light/1" && fmt.rfind("structured_light/1.", 0) != 0) {
    return f.Error("format", StrCat("unsupported \"", fmt, "\" (expected \"structured_light/1\")"));
  }
  REFLCAP_ASSIGN_OR_RETURN(spec.camera, ParseDevice(f, root, "camera", "cam_from_world"));
  REFLCAP_ASSIGN_OR_RETURN(spec.projector, ParseDevice(f, root, "projector", "proj_from_world"));
  if ((spec.camera.CenterInWorld() - spec.projector.CenterInWorld()).norm() <= 0) {
    return f.Error("projector.proj_from_world", "the projector sits at the camera centre (no baseline)");
  }
  if (auto it = root.find("mesh"); it != root.end()) {
    REFLCAP_ASSIGN_OR_RETURN(std::string mesh, f.String(*it, "mesh"));
    spec.reference_mesh = base / mesh;
  }

  REFLCAP_ASSIGN_OR_RETURN(const Json* tt, f.Required(root, "", "turntable"));
  REFLCAP_ASSIGN_OR_RETURN(const Json* axis, f.Required(*tt, "turntable", "axis"));
  REFLCAP_ASSIGN_OR_RETURN(Vec3d axis_v, f.Vector3(*axis, "turntable.axis"));
  if (std::abs(axis_v.norm() - 1) > 1e-3) {  // a hand-written unit vector has >= 3 digits
    return f.Error("turntable.axis", StrCat("must be a unit vector (length ", axis_v.norm(), ")"));
  }
  spec.turntable.axis = axis_v.normalized();
  REFLCAP_ASSIGN_OR_RETURN(const Json* point, f.Required(*tt, "turntable", "point"));
  REFLCAP_ASSIGN_OR_RETURN(spec.turntable.point, f.Vector3(*point, "turntable.point"));

  REFLCAP_ASSIGN_OR_RETURN(const Json* angles, f.Required(root, "", "turntable_angles_deg"));
  if (!angles->is_array() || angles->empty()) {
    return f.Error("turntable_angles_deg", "must be a non-empty array of numbers");
  }
  for (size_t i = 0; i < angles->size(); ++i) {
    AngleImages a;
    REFLCAP_ASSIGN_OR_RETURN(a.turntable_deg,
                             f.Number((*angles)[i], StrCat("turntable_angles_deg[", i, "]")));
    for (const AngleImages& other : spec.angles) {
      if (std::abs(other.turntable_deg - a.turntable_deg) < kSameAngleDeg) {
        return f.Error(StrCat("turntable_angles_deg[", i, "]"),
                       StrCat(a.turntable_deg, " is listed twice"));
      }
    }
    spec.angles.push_back(a);
  }

  const int col_bits = GrayBitsFor(spec.projector.width);
  const int row_bits = GrayBitsFor(spec.projector.height);
  for (AngleImages& a : spec.angles) {
    a.col.bits = col_bits;
    a.row.bits = row_bits;
    a.col.gray.resize(col_bits);
    a.col.gray_inverse.resize(col_bits);
    a.row.gray.resize(row_bits);
    a.row.gray_inverse.resize(row_bits);
  }

  std::map<std::string, size_t> index_of_file;  // for messages naming images[i].file
  REFLCAP_ASSIGN_OR_RETURN(const Json* images, f.Required(root, "", "images"));
  if (!images->is_array() || images->empty()) return f.Error("images", "must be a non-empty array");
  for (size_t i = 0; i < images->size(); ++i) {
    const std::string at = StrCat("images[", i, "]");
    const Json& im = (*images)[i];
    REFLCAP_ASSIGN_OR_RETURN(const Json* file_j, f.Required(im, at, "file"));
    REFLCAP_ASSIGN_OR_RETURN(std::string file, f.String(*file_j, at + ".file"));
    REFLCAP_ASSIGN_OR_RETURN(const Json* deg_j, f.Required(im, at, "turntable_deg"));
    REFLCAP_ASSIGN_OR_RETURN(double deg, f.Number(*deg_j, at + ".turntable_deg"));
    REFLCAP_ASSIGN_OR_RETURN(const Json* pat_j, f.Required(im, at, "pattern"));
    REFLCAP_ASSIGN_OR_RETURN(std::string pattern, f.String(*pat_j, at + ".pattern"));
    AngleImages* angle = nullptr;
    for (AngleImages& a : spec.angles) {
      if (std::abs(a.turntable_deg - deg) < kSameAngleDeg) angle = &a;
    }
    if (angle == nullptr) {
      return f.Error(at + ".turntable_deg", StrCat(deg, " is not one of turntable_angles_deg"));
    }
    PatternSlot slot;
    if (!ParsePatternName(pattern, &slot)) {
      return f.Error(at + ".pattern",
                     StrCat("unknown pattern \"", pattern, "\" (expected white, black, "
                            "gray_<col|row>_b<b>[_inv] or phase_<col|row>_p<P>_k<k>)"));
    }
    const std::string path = (base / file).string();
    AxisPatterns& axis_p = slot.row ? angle->row : angle->col;
    std::string* target = nullptr;
    switch (slot.kind) {
      case PatternSlot::kWhite: target = &angle->white; break;
      case PatternSlot::kBlack: target = &angle->black; break;
      case PatternSlot::kGray:
      case PatternSlot::kGrayInverse: {
        if (slot.bit >= axis_p.bits) {
          return f.Error(at + ".pattern",
                         StrCat("\"", pattern, "\": bit ", slot.bit, " but a projector ",
                                slot.row ? "height" : "width", " of ",
                                slot.row ? spec.projector.height : spec.projector.width,
                                " px has ", axis_p.bits, " Gray bits (0..", axis_p.bits - 1, ")"));
        }
        auto& v = slot.kind == PatternSlot::kGray ? axis_p.gray : axis_p.gray_inverse;
        target = &v[slot.bit];
        break;
      }
      case PatternSlot::kPhase: {
        const int extent = slot.row ? spec.projector.height : spec.projector.width;
        if (slot.period < 2 || slot.period > extent) {
          return f.Error(at + ".pattern", StrCat("\"", pattern, "\": period ", slot.period,
                                                 " must be in [2, ", extent, "] projector pixels"));
        }
        auto& seq = axis_p.phase[slot.period];
        if (slot.shift >= int(seq.size())) seq.resize(slot.shift + 1);
        target = &seq[slot.shift];
        break;
      }
    }
    if (!target->empty()) {
      return f.Error(at + ".pattern", StrCat("\"", pattern, "\" appears twice at turntable ", deg,
                                             " deg"));
    }
    *target = path;
    index_of_file.emplace(path, i);
  }

  // Completeness: every angle has every pattern, and the same phase sequences.
  for (size_t ai = 0; ai < spec.angles.size(); ++ai) {
    const AngleImages& a = spec.angles[ai];
    const std::string where = StrCat("images (turntable ", a.turntable_deg, " deg)");
    if (a.white.empty()) return f.Error(where, "no \"white\" pattern");
    if (a.black.empty()) return f.Error(where, "no \"black\" pattern");
    for (const auto* axis_p : {&a.col, &a.row}) {
      const char* name = axis_p == &a.col ? "col" : "row";
      for (int b = 0; b < axis_p->bits; ++b) {
        if (axis_p->gray[b].empty()) return f.Error(where, StrCat("no \"gray_", name, "_b", b, "\""));
        if (axis_p->gray_inverse[b].empty()) {
          return f.Error(where, StrCat("no \"gray_", name, "_b", b, "_inv\" (per-pixel thresholds "
                                       "need the inverse patterns)"));
        }
      }
      if (axis_p->phase.empty()) {
        return f.Error(where, StrCat("no phase_", name, "_p<P>_k<k> sequence"));
      }
      for (const auto& [period, seq] : axis_p->phase) {
        if (seq.size() < 3) {
          return f.Error(where, StrCat("phase_", name, "_p", period, ": ", seq.size(),
                                       " shifts (at least 3 are needed)"));
        }
        for (size_t k = 0; k < seq.size(); ++k) {
          if (seq[k].empty()) {
            return f.Error(where, StrCat("no \"phase_", name, "_p", period, "_k", k, "\" (shifts k = 0..",
                                         seq.size() - 1, " must all be present)"));
          }
        }
        const auto& first = ai == 0 ? *axis_p : (axis_p == &a.col ? spec.angles[0].col : spec.angles[0].row);
        auto it = first.phase.find(period);
        if (it == first.phase.end() || it->second.size() != seq.size()) {
          return f.Error(where, StrCat("phase_", name, "_p", period, " differs from the sequences "
                                       "of turntable ", spec.angles[0].turntable_deg, " deg"));
        }
      }
      if (ai > 0) {
        const auto& first = axis_p == &a.col ? spec.angles[0].col : spec.angles[0].row;
        if (first.phase.size() != axis_p->phase.size()) {
          return f.Error(where, StrCat("phase_", name, " periods differ from those of turntable ",
                                       spec.angles[0].turntable_deg, " deg"));
        }
      }
    }
  }

  if (check_images) {
    for (const AngleImages& a : spec.angles) {
      std::vector<const std::string*> files = {&a.white, &a.black};
      for (const auto* axis_p : {&a.col, &a.row}) {
        for (const auto& s : axis_p->gray) files.push_back(&s);
        for (const auto& s : axis_p->gray_inverse) files.push_back(&s);
        for (const auto& [period, seq] : axis_p->phase) {
          for (const auto& s : seq) files.push_back(&s);
        }
      }
      for (const std::string* file : files) {
        const std::string field = StrCat(json_path.string(), ": images[", index_of_file[*file], "].file");
        auto info = ReadPngInfo(*file);
        if (!info.ok()) {
          if (info.status().code() == StatusCode::kNotFound) {
            return NotFoundError(field, ": ", *file, " is missing");
          }
          return info.status().WithContext(field);
        }
        if (info->width != spec.camera.width || info->height != spec.camera.height) {
          return InvalidArgumentError(field, ": ", *file, " is ", info->width, "x", info->height,
                                      ", camera.width x camera.height is ", spec.camera.width, "x",
                                      spec.camera.height);
        }
      }
    }
  }
  return spec;
}

}  // namespace reflcap::scan
