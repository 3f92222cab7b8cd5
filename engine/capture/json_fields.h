#pragma once
// Field-by-field JSON reading for reflcap's file formats (capture/1, calib/1,
// reflcap-intrinsics/1): every error names the file and the JSON path of the field
// ("images[3].turntable_deg"). Non-finite numbers (1e999: JSON has no literal for infinity) are
// reported against their field, and syntax errors with line and column. For readers' .cc files
// only: public headers keep nlohmann out of their includes.
#include <array>
#include <cmath>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "engine/core/status.h"
#include "engine/math/types.h"

namespace reflcap::jsonio {

// Insertion-ordered, so that written files read in the order they are built.
using Json = nlohmann::ordered_json;

// Parses `text` (the contents of `file`) into a JSON object; syntax errors carry line and column.
StatusOr<Json> ParseJsonObject(const std::string& text, const std::string& file);

class FieldReader {
 public:
  explicit FieldReader(std::string file) : file_(std::move(file)) {}
  const std::string& file() const { return file_; }

  Status Error(const std::string& field, const std::string& what) const {
    return InvalidArgumentError(file_, ": ", field, ": ", what);
  }
  static std::string Join(const std::string& parent, const std::string& key) {
    return parent.empty() ? key : parent + "." + key;
  }
  static std::string Index(const std::string& array, size_t i) {
    return StrCat(array, "[", i, "]");
  }

  // A required member of `object` (which sits at JSON path `parent`).
  StatusOr<const Json*> Required(const Json& object, const std::string& parent,
                                 const std::string& key) const;
  // An optional member; nullptr when absent.
  static const Json* Optional(const Json& object, const std::string& key);

  // The minor version of root's "format" = "<name>/1[.N]" (0 for "<name>/1"); any other name,
  // major version or malformed version is an error naming the field. `kind` words the first
  // ("a capture format").
  StatusOr<int> FormatMinorVersion(const Json& root, const std::string& name,
                                   const std::string& kind) const;

  StatusOr<double> Number(const Json& value, const std::string& field) const;
  StatusOr<double> PositiveNumber(const Json& value, const std::string& field) const;
  StatusOr<int> PositiveInt(const Json& value, const std::string& field) const;
  StatusOr<std::string> String(const Json& value, const std::string& field) const;
  StatusOr<std::vector<double>> Numbers(const Json& value, const std::string& field) const;
  StatusOr<Vec3d> Vector3(const Json& value, const std::string& field) const;
  StatusOr<Vec3d> UnitVector3(const Json& value, const std::string& field) const;
  StatusOr<std::array<int, 2>> IntPair(const Json& value, const std::string& field) const;
  StatusOr<Eigen::MatrixXd> Matrix(const Json& value, int rows, int cols,
                                   const std::string& field) const;
  // A 4x4 rigid transform [[R t],[0 0 0 1]] with a proper rotation.
  StatusOr<Mat4d> RigidMatrix(const Json& value, const std::string& field) const;
  // Pinhole K [[fx,0,cx],[0,fy,cy],[0,0,1]] (zero skew), fx, fy > 0.
  StatusOr<Mat3d> CameraMatrix(const Json& value, const std::string& field) const;
  // OpenCV distortion [k1,k2,p1,p2] or [k1,k2,p1,p2,k3].
  StatusOr<std::array<double, 5>> Distortion(const Json& value, const std::string& field) const;

 private:
  std::string file_;
};

// Unit vectors in a file are written with >= 6 significant digits; 1e-4 accepts that rounding and
// rejects anything a user meant as non-unit (the capture/1 reader's tolerance).
constexpr double kUnitTolerance = 1e-4;
// Rotation matrices: |RᵀR - I| and |det R - 1| below this (same rounding argument).
constexpr double kRotationTolerance = 1e-4;

Json MatrixJson(const Eigen::MatrixXd& m);
Json VectorJson(const Eigen::VectorXd& v);

}  // namespace reflcap::jsonio
