#include "engine/capture/json_fields.h"

#include <cstdlib>
#include <cstring>

namespace reflcap::jsonio {
namespace {

// JSON has no literal for infinity: a number too large for a double (1e999) is how a non-finite
// value reaches a file, and nlohmann rejects it without naming the field. Such tokens are
// replaced by a marker string before parsing, so that the field reader reports them by field.
constexpr char kNonFiniteMarkerJson[] = "\\u0001non-finite:";  // as written into the JSON text
constexpr char kNonFiniteMarker[] = "\x01non-finite:";           // as the parsed string holds it

std::string MarkNonFiniteNumbers(const std::string& text) {
  std::string out;
  out.reserve(text.size());
  bool in_string = false;
  for (size_t i = 0; i < text.size(); ++i) {
    const char c = text[i];
    if (in_string) {
      out += c;
      if (c == '\\' && i + 1 < text.size()) {
        out += text[++i];
      } else if (c == '"') {
        in_string = false;
      }
      continue;
    }
    if (c == '"') {
      in_string = true;
      out += c;
      continue;
    }
    if (c == '-' || (c >= '0' && c <= '9')) {
      size_t end = i + 1;
      while (end < text.size() && std::strchr("0123456789+-.eE", text[end]) != nullptr) ++end;
      const std::string token = text.substr(i, end - i);
      const double v = std::strtod(token.c_str(), nullptr);
      out += std::isfinite(v) ? token : StrCat("\"", kNonFiniteMarkerJson, token, "\"");
      i = end - 1;
      continue;
    }
    out += c;
  }
  return out;
}

bool IsNonFinite(const Json& value) {
  return value.is_string() && value.get<std::string>().rfind(kNonFiniteMarker, 0) == 0;
}

std::string NonFiniteToken(const Json& value) {
  return value.get<std::string>().substr(sizeof(kNonFiniteMarker) - 1);
}

}  // namespace

StatusOr<Json> ParseJsonObject(const std::string& text, const std::string& file) {
  Json root;
  try {
    root = Json::parse(MarkNonFiniteNumbers(text));
  } catch (const Json::parse_error& e) {
    // nlohmann reports a byte offset; turn it into line:column.
    size_t line = 1, column = 1;
    for (size_t i = 0; i < e.byte && i < text.size(); ++i) {
      if (text[i] == '\n') {
        ++line;
        column = 1;
      } else {
        ++column;
      }
    }
    std::string what = e.what();
    const size_t cut = what.find("syntax error");
    if (cut != std::string::npos) what = what.substr(cut);
    return InvalidArgumentError(file, ":", line, ":", column, ": JSON ", what);
  } catch (const std::exception& e) {
    return InvalidArgumentError(file, ": JSON error: ", e.what());
  }
  if (!root.is_object()) return InvalidArgumentError(file, ": (root): must be a JSON object");
  return root;
}

StatusOr<const Json*> FieldReader::Required(const Json& object, const std::string& parent,
                                            const std::string& key) const {
  if (!object.is_object()) return Error(parent.empty() ? "(root)" : parent, "must be an object");
  auto it = object.find(key);
  if (it == object.end()) return Error(Join(parent, key), "missing");
  return &*it;
}

const Json* FieldReader::Optional(const Json& object, const std::string& key) {
  if (!object.is_object()) return nullptr;
  auto it = object.find(key);
  return it == object.end() ? nullptr : &*it;
}

StatusOr<int> FieldReader::FormatMinorVersion(const Json& root, const std::string& name,
                                              const std::string& kind) const {
  REFLCAP_ASSIGN_OR_RETURN(const Json* f, Required(root, "", "format"));
  REFLCAP_ASSIGN_OR_RETURN(std::string format, String(*f, "format"));
  const std::string prefix = name + "/";
  if (format.rfind(prefix, 0) != 0) {
    return Error("format", StrCat("\"", format, "\" is not ", kind, " (expected \"", name, "/1\")"));
  }
  const std::string version = format.substr(prefix.size());
  const size_t dot = version.find('.');
  const std::string major = version.substr(0, dot);
  const auto digits = [](const std::string& t) {
    // More than 6 digits is no version anyone wrote, and would overflow stoi.
    return !t.empty() && t.size() <= 6 && t.find_first_not_of("0123456789") == std::string::npos;
  };
  if (!digits(major)) return Error("format", StrCat("malformed version \"", format, "\""));
  if (major != "1") {
    return Error("format", StrCat("unsupported major version ", major, " (this reflcap reads ", name,
                                  "/1)"));
  }
  if (dot == std::string::npos) return 0;
  const std::string minor = version.substr(dot + 1);
  if (!digits(minor)) return Error("format", StrCat("malformed version \"", format, "\""));
  return std::stoi(minor);
}

StatusOr<double> FieldReader::Number(const Json& value, const std::string& field) const {
  if (IsNonFinite(value)) return Error(field, StrCat("must be finite (got ", NonFiniteToken(value), ")"));
  if (!value.is_number()) return Error(field, "must be a number");
  const double v = value.get<double>();
  // nlohmann parses 1e999 as inf; a finite value is all a calibration file can mean.
  if (!std::isfinite(v)) return Error(field, "must be finite");
  return v;
}

StatusOr<double> FieldReader::PositiveNumber(const Json& value, const std::string& field) const {
  REFLCAP_ASSIGN_OR_RETURN(double v, Number(value, field));
  if (!(v > 0)) return Error(field, StrCat("must be positive (got ", v, ")"));
  return v;
}

StatusOr<int> FieldReader::PositiveInt(const Json& value, const std::string& field) const {
  // Image sizes: beyond 2^20 pixels a side is no camera's.
  if (!value.is_number_integer() || value.get<int64_t>() <= 0 ||
      value.get<int64_t>() > (1 << 20)) {
    return Error(field, "must be a positive integer");
  }
  return static_cast<int>(value.get<int64_t>());
}

StatusOr<std::string> FieldReader::String(const Json& value, const std::string& field) const {
  if (!value.is_string()) return Error(field, "must be a string");
  std::string s = value.get<std::string>();
  if (s.empty()) return Error(field, "must not be empty");
  return s;
}

StatusOr<std::vector<double>> FieldReader::Numbers(const Json& value,
                                                   const std::string& field) const {
  if (!value.is_array()) return Error(field, "must be an array of numbers");
  std::vector<double> out;
  for (size_t i = 0; i < value.size(); ++i) {
    REFLCAP_ASSIGN_OR_RETURN(double v, Number(value[i], Index(field, i)));
    out.push_back(v);
  }
  return out;
}

StatusOr<Vec3d> FieldReader::Vector3(const Json& value, const std::string& field) const {
  if (!value.is_array() || value.size() != 3) return Error(field, "must be an array of 3 numbers");
  Vec3d v;
  for (int i = 0; i < 3; ++i) {
    if (IsNonFinite(value[i])) {
      return Error(field, StrCat("component ", i, " is not finite (", NonFiniteToken(value[i]), ")"));
    }
    if (!value[i].is_number()) return Error(field, "must be an array of 3 numbers");
    v[i] = value[i].get<double>();
    if (!std::isfinite(v[i])) return Error(field, StrCat("component ", i, " is not finite"));
  }
  return v;
}

StatusOr<Vec3d> FieldReader::UnitVector3(const Json& value, const std::string& field) const {
  REFLCAP_ASSIGN_OR_RETURN(Vec3d v, Vector3(value, field));
  if (std::abs(v.norm() - 1) > kUnitTolerance) {
    return Error(field, StrCat("must be a unit vector (length is ", v.norm(), ")"));
  }
  return v.normalized();
}

StatusOr<std::array<int, 2>> FieldReader::IntPair(const Json& value,
                                                  const std::string& field) const {
  if (!value.is_array() || value.size() != 2) {
    return Error(field, "must be an array of 2 positive integers");
  }
  std::array<int, 2> out{};
  for (int i = 0; i < 2; ++i) {
    // Square and corner counts: no printable board has 10,000 squares along a side.
    if (!value[i].is_number_integer() || value[i].get<int64_t>() <= 0 ||
        value[i].get<int64_t>() > 10000) {
      return Error(field, "must be an array of 2 positive integers");
    }
    out[i] = int(value[i].get<int64_t>());
  }
  return out;
}

StatusOr<Eigen::MatrixXd> FieldReader::Matrix(const Json& value, int rows, int cols,
                                              const std::string& field) const {
  const std::string shape = StrCat("must be a ", rows, "x", cols, " array of numbers (rows)");
  if (!value.is_array() || int(value.size()) != rows) return Error(field, shape);
  Eigen::MatrixXd m(rows, cols);
  for (int r = 0; r < rows; ++r) {
    if (!value[r].is_array() || int(value[r].size()) != cols) return Error(field, shape);
    for (int c = 0; c < cols; ++c) {
      if (IsNonFinite(value[r][c])) {
        return Error(field, StrCat("element [", r, "][", c, "] is not finite (",
                                   NonFiniteToken(value[r][c]), ")"));
      }
      if (!value[r][c].is_number()) return Error(field, shape);
      m(r, c) = value[r][c].get<double>();
      if (!std::isfinite(m(r, c))) {
        return Error(field, StrCat("element [", r, "][", c, "] is not finite"));
      }
    }
  }
  return m;
}

StatusOr<Mat4d> FieldReader::RigidMatrix(const Json& value, const std::string& field) const {
  REFLCAP_ASSIGN_OR_RETURN(Eigen::MatrixXd m, Matrix(value, 4, 4, field));
  if (m.row(3).transpose() != Eigen::Vector4d(0, 0, 0, 1)) {
    return Error(field, "last row must be [0,0,0,1]");
  }
  const Mat3d r = m.topLeftCorner<3, 3>();
  if ((r.transpose() * r - Mat3d::Identity()).cwiseAbs().maxCoeff() > kRotationTolerance ||
      std::abs(r.determinant() - 1) > kRotationTolerance) {
    return Error(field, "rotation part is not a proper rotation (RᵀR ≠ I or det ≠ 1)");
  }
  return Mat4d(m);
}

StatusOr<Mat3d> FieldReader::CameraMatrix(const Json& value, const std::string& field) const {
  REFLCAP_ASSIGN_OR_RETURN(Eigen::MatrixXd m, Matrix(value, 3, 3, field));
  if (m(1, 0) != 0 || m(2, 0) != 0 || m(2, 1) != 0 || m(2, 2) != 1) {
    return Error(field, "must have the form [[fx,0,cx],[0,fy,cy],[0,0,1]]");
  }
  if (m(0, 1) != 0) return Error(field, "skew must be 0 (the calibration model has none)");
  if (!(m(0, 0) > 0) || !(m(1, 1) > 0)) return Error(field, "focal lengths fx and fy must be positive");
  return Mat3d(m);
}

StatusOr<std::array<double, 5>> FieldReader::Distortion(const Json& value,
                                                        const std::string& field) const {
  if (!value.is_array() || (value.size() != 4 && value.size() != 5)) {
    return Error(field, "must be [k1,k2,p1,p2] or [k1,k2,p1,p2,k3]");
  }
  std::array<double, 5> d{};
  for (size_t i = 0; i < value.size(); ++i) {
    REFLCAP_ASSIGN_OR_RETURN(d[i], Number(value[i], Index(field, i)));
  }
  return d;
}

Json MatrixJson(const Eigen::MatrixXd& m) {
  Json rows = Json::array();
  for (int r = 0; r < m.rows(); ++r) {
    Json row = Json::array();
    for (int c = 0; c < m.cols(); ++c) row.push_back(m(r, c));
    rows.push_back(row);
  }
  return rows;
}

Json VectorJson(const Eigen::VectorXd& v) {
  Json out = Json::array();
  for (int i = 0; i < v.size(); ++i) out.push_back(v[i]);
  return out;
}

}  // namespace reflcap::jsonio
