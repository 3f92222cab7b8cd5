// calib/1 reader. Validation is eager and complete for what calibration uses: the first problem
// found is returned with the file and the JSON path of the field.
#include "calib/calib_file.h"

#include <algorithm>
#include <cmath>
#include <set>

#include "engine/capture/json_fields.h"
#include "engine/core/atomic_file.h"
#include "engine/image/image_io.h"

namespace reflcap::calib {
namespace fs = std::filesystem;
using jsonio::FieldReader;
using jsonio::Json;

namespace {

// Board geometry in the file is written to ~1e-9 m; listed corners must follow the corner rule to
// 1 µm (far below any detection error, far above float rounding of metre-sized numbers).
constexpr double kCornerRuleToleranceM = 1e-6;
// Two turntable readings closer than this (degrees) are the same angle (readings are written
// with >= 6 significant digits).
constexpr double kSameAngleDeg = 1e-6;

double WrapDeg(double deg) {
  double w = std::fmod(deg, 360.0);
  if (w < 0) w += 360.0;
  return w;
}

bool SameAngle(double a_deg, double b_deg) {
  const double d = WrapDeg(a_deg - b_deg);
  return std::min(d, 360.0 - d) < kSameAngleDeg;
}

StatusOr<int> ParseFormat(const FieldReader& r, const Json& root) {
  return r.FormatMinorVersion(root, "calib", "a calibration format");
}

StatusOr<CalibCamera> ParseCamera(const FieldReader& r, const Json& j, const std::string& at) {
  if (!j.is_object()) return r.Error(at, "must be an object");
  CalibCamera cam;
  REFLCAP_ASSIGN_OR_RETURN(const Json* id, r.Required(j, at, "id"));
  REFLCAP_ASSIGN_OR_RETURN(cam.id, r.String(*id, at + ".id"));
  REFLCAP_ASSIGN_OR_RETURN(const Json* w, r.Required(j, at, "width"));
  REFLCAP_ASSIGN_OR_RETURN(cam.width, r.PositiveInt(*w, at + ".width"));
  REFLCAP_ASSIGN_OR_RETURN(const Json* h, r.Required(j, at, "height"));
  REFLCAP_ASSIGN_OR_RETURN(cam.height, r.PositiveInt(*h, at + ".height"));
  if (const Json* k = FieldReader::Optional(j, "K")) {
    REFLCAP_ASSIGN_OR_RETURN(cam.K, r.CameraMatrix(*k, at + ".K"));
    cam.has_intrinsics = true;
    if (const Json* d = FieldReader::Optional(j, "dist")) {
      REFLCAP_ASSIGN_OR_RETURN(cam.dist, r.Distortion(*d, at + ".dist"));
    }
  } else if (FieldReader::Optional(j, "dist") != nullptr) {
    return r.Error(at + ".dist", "given without K");
  }
  return cam;
}

// Reads the fields a board shares between a cuboid face and the planar board.
Status ParseBoardGrid(const FieldReader& r, const Json& j, const std::string& at, BoardSpec* b) {
  REFLCAP_ASSIGN_OR_RETURN(const Json* sq, r.Required(j, at, "squares"));
  REFLCAP_ASSIGN_OR_RETURN(auto squares, r.IntPair(*sq, at + ".squares"));
  REFLCAP_ASSIGN_OR_RETURN(const Json* ic, r.Required(j, at, "inner_corners"));
  REFLCAP_ASSIGN_OR_RETURN(auto inner, r.IntPair(*ic, at + ".inner_corners"));
  if (inner[0] != squares[0] - 1 || inner[1] != squares[1] - 1) {
    return r.Error(at + ".inner_corners",
                   StrCat("must be squares - 1 = [", squares[0] - 1, ", ", squares[1] - 1, "] (got [",
                          inner[0], ", ", inner[1], "])"));
  }
  if (inner[0] < 2 || inner[1] < 2) {
    return r.Error(at + ".inner_corners", "a board needs at least 2x2 inner corners");
  }
  b->squares_x = squares[0];
  b->squares_y = squares[1];
  b->corners_x = inner[0];
  b->corners_y = inner[1];
  REFLCAP_ASSIGN_OR_RETURN(const Json* s, r.Required(j, at, "square_m"));
  REFLCAP_ASSIGN_OR_RETURN(b->square_m, r.PositiveNumber(*s, at + ".square_m"));
  return OkStatus();
}

// Optional listed corners must follow the corner rule.
Status CheckListedCorners(const FieldReader& r, const Json& j, const std::string& at,
                          const std::string& key, const BoardSpec& b) {
  const Json* list = FieldReader::Optional(j, key);
  if (list == nullptr) return OkStatus();
  const std::string field = at + "." + key;
  if (!list->is_array() || int(list->size()) != b.CornerCount()) {
    return r.Error(field, StrCat("must list ", b.CornerCount(), " corners (inner_corners ",
                                 b.corners_x, "x", b.corners_y, ")"));
  }
  for (int k = 0; k < b.CornerCount(); ++k) {
    REFLCAP_ASSIGN_OR_RETURN(Vec3d p, r.Vector3((*list)[k], FieldReader::Index(field, k)));
    if ((p - b.Corner(k)).norm() > kCornerRuleToleranceM) {
      return r.Error(FieldReader::Index(field, k),
                     StrCat("does not follow the corner rule (expected [", b.Corner(k).transpose(),
                            "], off by ", (p - b.Corner(k)).norm(), " m)"));
    }
  }
  return OkStatus();
}

StatusOr<BoardSpec> ParseFace(const FieldReader& r, const Json& j, const std::string& at) {
  if (!j.is_object()) return r.Error(at, "must be an object");
  BoardSpec b;
  b.field = at;
  REFLCAP_ASSIGN_OR_RETURN(const Json* name, r.Required(j, at, "name"));
  REFLCAP_ASSIGN_OR_RETURN(b.name, r.String(*name, at + ".name"));
  REFLCAP_RETURN_IF_ERROR(ParseBoardGrid(r, j, at, &b));
  REFLCAP_ASSIGN_OR_RETURN(const Json* n, r.Required(j, at, "normal"));
  REFLCAP_ASSIGN_OR_RETURN(b.normal, r.UnitVector3(*n, at + ".normal"));
  REFLCAP_ASSIGN_OR_RETURN(const Json* u, r.Required(j, at, "u_axis"));
  REFLCAP_ASSIGN_OR_RETURN(b.u_axis, r.UnitVector3(*u, at + ".u_axis"));
  REFLCAP_ASSIGN_OR_RETURN(const Json* v, r.Required(j, at, "v_axis"));
  REFLCAP_ASSIGN_OR_RETURN(b.v_axis, r.UnitVector3(*v, at + ".v_axis"));
  if (std::abs(b.u_axis.dot(b.v_axis)) > jsonio::kUnitTolerance) {
    return r.Error(at + ".v_axis", "must be perpendicular to u_axis");
  }
  // The corner rule: seen from outside u points right and v down, so u x v is the inward normal.
  if ((b.u_axis.cross(b.v_axis) + b.normal).norm() > 10 * jsonio::kUnitTolerance) {
    return r.Error(at + ".normal", "must equal -(u_axis x v_axis) (u right and v down seen from outside)");
  }
  REFLCAP_ASSIGN_OR_RETURN(const Json* o, r.Required(j, at, "first_inner_corner_box"));
  REFLCAP_ASSIGN_OR_RETURN(b.origin, r.Vector3(*o, at + ".first_inner_corner_box"));
  if (const Json* m = FieldReader::Optional(j, "board_margin_m")) {
    REFLCAP_ASSIGN_OR_RETURN(std::vector<double> margin, r.Numbers(*m, at + ".board_margin_m"));
    if (margin.size() != 2 || margin[0] < 0 || margin[1] < 0) {
      return r.Error(at + ".board_margin_m", "must be [along u, along v], metres, not negative");
    }
    b.margin_u_m = margin[0];
    b.margin_v_m = margin[1];
  }
  REFLCAP_RETURN_IF_ERROR(CheckListedCorners(r, j, at, "corners_box", b));
  return b;
}

StatusOr<BoardSpec> ParsePlanarBoard(const FieldReader& r, const Json& j, const std::string& at) {
  if (!j.is_object()) return r.Error(at, "must be an object");
  BoardSpec b;
  b.name = "intrinsics_board";
  b.field = at;
  REFLCAP_RETURN_IF_ERROR(ParseBoardGrid(r, j, at, &b));
  // Board frame: origin at inner corner (0, 0), x right, y down, z into the board.
  b.origin = Vec3d::Zero();
  b.u_axis = Vec3d::UnitX();
  b.v_axis = Vec3d::UnitY();
  b.normal = -Vec3d::UnitZ();
  if (const Json* m = FieldReader::Optional(j, "margin_m")) {
    REFLCAP_ASSIGN_OR_RETURN(double margin, r.Number(*m, at + ".margin_m"));
    if (margin < 0) return r.Error(at + ".margin_m", "must not be negative");
    b.margin_u_m = b.margin_v_m = margin;
  }
  REFLCAP_RETURN_IF_ERROR(CheckListedCorners(r, j, at, "corners_board", b));
  return b;
}

StatusOr<int> CameraIndex(const FieldReader& r, const Json& j, const std::string& at,
                          const CalibFile& file) {
  REFLCAP_ASSIGN_OR_RETURN(const Json* c, r.Required(j, at, "camera"));
  REFLCAP_ASSIGN_OR_RETURN(std::string id, r.String(*c, at + ".camera"));
  const int index = file.FindCamera(id);
  if (index < 0) return r.Error(at + ".camera", StrCat("unknown camera id \"", id, "\""));
  return index;
}

Status CheckTarget(const FieldReader& r, const Json& j, const std::string& at,
                   const std::string& expected) {
  const Json* t = FieldReader::Optional(j, "target");
  if (t == nullptr) return OkStatus();
  REFLCAP_ASSIGN_OR_RETURN(std::string target, r.String(*t, at + ".target"));
  if (target != expected) {
    return r.Error(at + ".target", StrCat("\"", target, "\" (expected \"", expected, "\")"));
  }
  return OkStatus();
}

StatusOr<CalibGroundTruth> ParseGroundTruth(const FieldReader& r, const Json& gt,
                                            const CalibFile& file) {
  const std::string at = "ground_truth";
  if (!gt.is_object()) return r.Error(at, "must be an object");
  CalibGroundTruth out;
  const Json* cfw = FieldReader::Optional(gt, "cam_from_world");
  const Json* tt = FieldReader::Optional(gt, "turntable");
  if (cfw != nullptr && tt != nullptr) {
    if (!cfw->is_object()) return r.Error(at + ".cam_from_world", "must be an object keyed by camera id");
    for (const CalibCamera& cam : file.cameras) {
      REFLCAP_ASSIGN_OR_RETURN(const Json* m, r.Required(*cfw, at + ".cam_from_world", cam.id));
      REFLCAP_ASSIGN_OR_RETURN(Mat4d t, r.RigidMatrix(*m, at + ".cam_from_world." + cam.id));
      out.cam_from_world.push_back(Rigid3::FromMatrix(t));
    }
    REFLCAP_ASSIGN_OR_RETURN(const Json* axis, r.Required(*tt, at + ".turntable", "axis"));
    REFLCAP_ASSIGN_OR_RETURN(out.axis, r.UnitVector3(*axis, at + ".turntable.axis"));
    REFLCAP_ASSIGN_OR_RETURN(const Json* point, r.Required(*tt, at + ".turntable", "point"));
    REFLCAP_ASSIGN_OR_RETURN(out.point, r.Vector3(*point, at + ".turntable.point"));
    out.has_extrinsics = true;
  }
  if (const Json* box = FieldReader::Optional(gt, "world_from_box_at_0")) {
    REFLCAP_ASSIGN_OR_RETURN(Mat4d t, r.RigidMatrix(*box, at + ".world_from_box_at_0"));
    out.world_from_box_at_0 = Rigid3::FromMatrix(t);
  }
  if (const Json* intr = FieldReader::Optional(gt, "intrinsics")) {
    if (!intr->is_object()) return r.Error(at + ".intrinsics", "must be an object keyed by camera id");
    for (const CalibCamera& cam : file.cameras) {
      const std::string field = at + ".intrinsics." + cam.id;
      REFLCAP_ASSIGN_OR_RETURN(const Json* c, r.Required(*intr, at + ".intrinsics", cam.id));
      REFLCAP_ASSIGN_OR_RETURN(const Json* k, r.Required(*c, field, "K"));
      REFLCAP_ASSIGN_OR_RETURN(Mat3d K, r.CameraMatrix(*k, field + ".K"));
      std::array<double, 5> dist{};
      if (const Json* d = FieldReader::Optional(*c, "dist")) {
        REFLCAP_ASSIGN_OR_RETURN(dist, r.Distortion(*d, field + ".dist"));
      }
      out.K.push_back(K);
      out.dist.push_back(dist);
    }
    out.has_intrinsics = true;
  }
  for (const auto& [key, target] : {std::pair<const char*, std::map<std::string, Rigid3>*>{
                                        "cam_from_box", &out.cam_from_box},
                                    {"intrinsics_cam_from_board", &out.cam_from_board}}) {
    const Json* per_image = FieldReader::Optional(gt, key);
    if (per_image == nullptr) continue;
    const std::string field = at + "." + key;
    if (!per_image->is_object()) return r.Error(field, "must be an object keyed by image file");
    for (auto it = per_image->begin(); it != per_image->end(); ++it) {
      REFLCAP_ASSIGN_OR_RETURN(Mat4d t, r.RigidMatrix(it.value(), field + "." + it.key()));
      (*target)[it.key()] = Rigid3::FromMatrix(t);
    }
  }
  return out;
}

}  // namespace

int CalibFile::FindCamera(const std::string& id) const {
  for (size_t i = 0; i < cameras.size(); ++i) {
    if (cameras[i].id == id) return int(i);
  }
  return -1;
}

StatusOr<CalibFile> ParseCalibFile(const std::string& text, const fs::path& name) {
  const FieldReader r(name.string());
  REFLCAP_ASSIGN_OR_RETURN(Json root, jsonio::ParseJsonObject(text, name.string()));
  CalibFile file;
  file.json_path = name;
  REFLCAP_ASSIGN_OR_RETURN(file.minor_version, ParseFormat(r, root));

  REFLCAP_ASSIGN_OR_RETURN(const Json* cameras, r.Required(root, "", "cameras"));
  if (!cameras->is_array() || cameras->empty()) return r.Error("cameras", "must be a non-empty array");
  for (size_t i = 0; i < cameras->size(); ++i) {
    const std::string at = FieldReader::Index("cameras", i);
    REFLCAP_ASSIGN_OR_RETURN(CalibCamera cam, ParseCamera(r, (*cameras)[i], at));
    if (file.FindCamera(cam.id) >= 0) return r.Error(at + ".id", StrCat("duplicate id \"", cam.id, "\""));
    file.cameras.push_back(std::move(cam));
  }

  if (const Json* tt = FieldReader::Optional(root, "turntable")) {
    REFLCAP_ASSIGN_OR_RETURN(const Json* angles, r.Required(*tt, "turntable", "angles_deg"));
    REFLCAP_ASSIGN_OR_RETURN(file.angles_deg, r.Numbers(*angles, "turntable.angles_deg"));
    for (size_t i = 0; i < file.angles_deg.size(); ++i) {
      for (size_t k = 0; k < i; ++k) {
        if (SameAngle(file.angles_deg[i], file.angles_deg[k])) {
          return r.Error(FieldReader::Index("turntable.angles_deg", i),
                         StrCat(file.angles_deg[i], " repeats angles_deg[", k, "] (", file.angles_deg[k],
                                ") modulo 360"));
        }
      }
    }
  }

  if (const Json* images = FieldReader::Optional(root, "images")) {
    if (!images->is_array()) return r.Error("images", "must be an array");
    for (size_t i = 0; i < images->size(); ++i) {
      const std::string at = FieldReader::Index("images", i);
      const Json& j = (*images)[i];
      if (!j.is_object()) return r.Error(at, "must be an object");
      CuboidImage image;
      REFLCAP_ASSIGN_OR_RETURN(const Json* f, r.Required(j, at, "file"));
      REFLCAP_ASSIGN_OR_RETURN(image.file, r.String(*f, at + ".file"));
      REFLCAP_ASSIGN_OR_RETURN(image.camera, CameraIndex(r, j, at, file));
      REFLCAP_RETURN_IF_ERROR(CheckTarget(r, j, at, "cuboid"));
      REFLCAP_ASSIGN_OR_RETURN(const Json* deg, r.Required(j, at, "turntable_deg"));
      REFLCAP_ASSIGN_OR_RETURN(image.turntable_deg, r.Number(*deg, at + ".turntable_deg"));
      image.angle = -1;
      for (size_t k = 0; k < file.angles_deg.size(); ++k) {
        if (SameAngle(image.turntable_deg, file.angles_deg[k])) image.angle = int(k);
      }
      if (image.angle < 0) {
        return r.Error(at + ".turntable_deg",
                       StrCat(image.turntable_deg, " is not one of turntable.angles_deg"));
      }
      for (size_t k = 0; k < file.images.size(); ++k) {
        if (file.images[k].camera == image.camera && file.images[k].angle == image.angle) {
          return r.Error(at, StrCat("camera \"", file.cameras[image.camera].id, "\" at ",
                                    image.turntable_deg, " deg was already photographed by images[", k,
                                    "] (", file.images[k].file, ")"));
        }
      }
      file.images.push_back(std::move(image));
    }
  }

  if (const Json* images = FieldReader::Optional(root, "intrinsics_images")) {
    if (!images->is_array()) return r.Error("intrinsics_images", "must be an array");
    std::set<std::string> seen;
    for (size_t i = 0; i < images->size(); ++i) {
      const std::string at = FieldReader::Index("intrinsics_images", i);
      const Json& j = (*images)[i];
      if (!j.is_object()) return r.Error(at, "must be an object");
      BoardImage image;
      REFLCAP_ASSIGN_OR_RETURN(const Json* f, r.Required(j, at, "file"));
      REFLCAP_ASSIGN_OR_RETURN(image.file, r.String(*f, at + ".file"));
      REFLCAP_ASSIGN_OR_RETURN(image.camera, CameraIndex(r, j, at, file));
      REFLCAP_RETURN_IF_ERROR(CheckTarget(r, j, at, "intrinsics_board"));
      if (!seen.insert(image.file).second) {
        return r.Error(at + ".file", StrCat("\"", image.file, "\" is listed twice"));
      }
      file.board_images.push_back(std::move(image));
    }
  }

  if (const Json* cuboid = FieldReader::Optional(root, "cuboid")) {
    REFLCAP_ASSIGN_OR_RETURN(const Json* faces, r.Required(*cuboid, "cuboid", "faces"));
    if (!faces->is_array() || faces->empty()) return r.Error("cuboid.faces", "must be a non-empty array");
    for (size_t i = 0; i < faces->size(); ++i) {
      const std::string at = FieldReader::Index("cuboid.faces", i);
      REFLCAP_ASSIGN_OR_RETURN(BoardSpec face, ParseFace(r, (*faces)[i], at));
      for (const BoardSpec& other : file.faces) {
        if (other.name == face.name) return r.Error(at + ".name", StrCat("duplicate face \"", face.name, "\""));
        const bool same_grid = std::minmax(other.corners_x, other.corners_y) ==
                               std::minmax(face.corners_x, face.corners_y);
        if (same_grid) {
          return r.Error(at + ".inner_corners",
                         StrCat(face.corners_x, "x", face.corners_y, " is also face \"", other.name,
                                "\"'s grid: a found board could not tell the faces apart"));
        }
      }
      file.faces.push_back(std::move(face));
    }
  }

  if (const Json* board = FieldReader::Optional(root, "intrinsics_board")) {
    REFLCAP_ASSIGN_OR_RETURN(BoardSpec b, ParsePlanarBoard(r, *board, "intrinsics_board"));
    file.board = std::move(b);
  }

  if (const Json* gt = FieldReader::Optional(root, "ground_truth")) {
    REFLCAP_ASSIGN_OR_RETURN(CalibGroundTruth g, ParseGroundTruth(r, *gt, file));
    file.ground_truth = std::move(g);
  }
  return file;
}

StatusOr<CalibFile> ReadCalibFile(const fs::path& json_path) {
  auto text = ReadTextFile(json_path);
  if (!text.ok()) return NotFoundError(json_path.string(), ": cannot open calibration file");
  return ParseCalibFile(*text, json_path);
}

namespace {

Status CheckPhoto(const CalibFile& file, const std::string& photo, int camera, const std::string& field) {
  auto info = ReadImageInfo(file.Resolve(photo));
  if (!info.ok()) return info.status().WithContext(StrCat(file.json_path.string(), ": ", field));
  const CalibCamera& cam = file.cameras[camera];
  if (info->width != cam.width || info->height != cam.height) {
    return InvalidArgumentError(file.json_path.string(), ": ", field, ": ", photo, " is ", info->width, "x",
                                info->height, " but camera \"", cam.id, "\" is ", cam.width, "x", cam.height);
  }
  return OkStatus();
}

}  // namespace

Status CheckCuboidPhotos(const CalibFile& file) {
  for (size_t i = 0; i < file.images.size(); ++i) {
    REFLCAP_RETURN_IF_ERROR(CheckPhoto(file, file.images[i].file, file.images[i].camera, StrCat("images[", i, "].file")));
  }
  return OkStatus();
}

Status CheckBoardPhotos(const CalibFile& file) {
  for (size_t i = 0; i < file.board_images.size(); ++i) {
    REFLCAP_RETURN_IF_ERROR(CheckPhoto(file, file.board_images[i].file, file.board_images[i].camera,
                                       StrCat("intrinsics_images[", i, "].file")));
  }
  return OkStatus();
}

Status CheckCuboidSession(const CalibFile& file) {
  const FieldReader r(file.json_path.string());
  if (file.faces.empty()) return r.Error("cuboid", "missing (calibrate turntable needs the cuboid's boards)");
  if (file.angles_deg.empty()) return r.Error("turntable.angles_deg", "missing or empty");
  if (file.images.empty()) return r.Error("images", "missing or empty (no photo of the cuboid)");
  std::set<int> angles;
  for (const CuboidImage& image : file.images) angles.insert(image.angle);
  if (angles.size() < 2) {
    return r.Error("images", StrCat("every photo was taken at turntable angle ",
                                    file.images.front().turntable_deg,
                                    ": the axis needs photos at two or more angles"));
  }
  return OkStatus();
}

Status CheckBoardSession(const CalibFile& file) {
  const FieldReader r(file.json_path.string());
  if (!file.board) return r.Error("intrinsics_board", "missing (calibrate intrinsics needs the board)");
  if (file.board_images.empty()) return r.Error("intrinsics_images", "missing or empty");
  return OkStatus();
}

}  // namespace reflcap::calib
