// Mesh loading and saving: Wavefront OBJ (own parser) and glTF 2.0 (tinygltf), both reduced to
// one TriangleMesh with shared positions and per-corner UVs and normals.
//
// OBJ: the whole file is read into memory and parsed line by line with std::from_chars, which
// is several times faster than iostream extraction and locale independent, so meshes of a few
// million triangles load in seconds. Indices are resolved as they are read (OBJ requires an
// element to be defined before it is referenced, which is also what makes negative, relative
// indices well defined), polygons are fan-triangulated.
//
// glTF: tinygltf (compiled separately into TinyGLTF::TinyGLTF) parses the file and decodes
// buffers; we walk the node hierarchy of the default scene, bake each node's world matrix into
// the positions (normals by its inverse transpose) and flip v, since glTF puts the UV origin at
// the top-left of the texture while reflcap uses the OBJ convention (v = 0 at the bottom).
//
// Both loaders end in FinalizeMesh, which drops degenerate triangles (repeated vertex,
// non-finite coordinates, zero area relative to the mesh size), compacts the positions, and
// fills in missing or zero-length normals, so every consumer sees the guarantees of mesh.h.
#include "engine/mesh/mesh_io.h"

#include <tiny_gltf.h>

#include <algorithm>
#include <array>
#include <cctype>
#include <charconv>
#include <cmath>
#include <cstring>
#include <fstream>
#include <exception>
#include <limits>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "engine/core/atomic_file.h"
#include "engine/core/log.h"

namespace reflcap {
namespace fs = std::filesystem;

namespace {

// A triangle is dropped as zero-area when |cross(e1, e2)| (twice its area) is at most this times
// the squared bounding-box diagonal: that is a triangle whose edges are ~1e-6 of the mesh size,
// i.e. within a few float ulps of the coordinates, where the normal is dominated by rounding.
constexpr double kRelativeDegenerateArea = 1e-12;

// What the loaders produce before cleaning: corner normals may be absent (has_normal bit clear).
struct RawMesh {
  std::vector<Vec3f> positions;
  std::vector<std::array<uint32_t, 3>> triangles;
  std::vector<std::array<Vec2f, 3>> corner_uvs;
  std::vector<std::array<Vec3f, 3>> corner_normals;
  std::vector<uint8_t> has_normal;  // bit c set when corner c of the triangle came with a normal
};

bool IsFinite(const Vec3f& p) {
  return std::isfinite(p.x()) && std::isfinite(p.y()) && std::isfinite(p.z());
}
bool IsFinite(const Vec2f& p) { return std::isfinite(p.x()) && std::isfinite(p.y()); }

Vec3d Cross(const std::vector<Vec3f>& positions, const std::array<uint32_t, 3>& tri) {
  const Vec3d p0 = positions[tri[0]].cast<double>();
  return (positions[tri[1]].cast<double>() - p0).cross(positions[tri[2]].cast<double>() - p0);
}

// Writes the unit vector along `n` to *out; false (out untouched) when n is zero or not finite.
bool NormalizeTo(const Vec3d& n, Vec3f* out) {
  const double length = n.norm();
  if (!(length > 0.0) || !std::isfinite(length)) return false;
  *out = (n / length).cast<float>();
  return true;
}

// Drops degenerate triangles, compacts positions (keeping their order) and completes normals.
StatusOr<TriangleMesh> FinalizeMesh(const fs::path& path, RawMesh raw, MeshLoadStats* stats) {
  const size_t read = raw.triangles.size();

  // Scale of the mesh: bounding box of the finite corners of all triangles.
  Eigen::AlignedBox3d box;
  for (const auto& tri : raw.triangles) {
    for (uint32_t i : tri) {
      if (IsFinite(raw.positions[i])) box.extend(raw.positions[i].cast<double>());
    }
  }
  const double diagonal_sq = box.isEmpty() ? 0.0 : box.diagonal().squaredNorm();
  const double min_cross = kRelativeDegenerateArea * diagonal_sq;

  size_t kept = 0;
  for (size_t t = 0; t < read; ++t) {
    const auto& tri = raw.triangles[t];
    const bool repeated = tri[0] == tri[1] || tri[1] == tri[2] || tri[0] == tri[2];
    bool finite = true;
    for (int c = 0; c < 3; ++c) {
      finite = finite && IsFinite(raw.positions[tri[c]]) && IsFinite(raw.corner_uvs[t][c]);
    }
    if (repeated || !finite || !(Cross(raw.positions, tri).norm() > min_cross)) continue;
    if (kept != t) {
      raw.triangles[kept] = tri;
      raw.corner_uvs[kept] = raw.corner_uvs[t];
      raw.corner_normals[kept] = raw.corner_normals[t];
      raw.has_normal[kept] = raw.has_normal[t];
    }
    ++kept;
  }
  const size_t skipped = read - kept;
  if (stats) {
    stats->faces_read = read;
    stats->triangles_kept = kept;
    stats->degenerate_skipped = skipped;
    stats->normals_computed = false;
  }
  if (kept == 0) {
    return InvalidArgumentError(path.string(), ": mesh has no usable triangles (", read, " read, ",
                                skipped, " degenerate)");
  }
  if (skipped > 0) {
    REFLCAP_LOG(kWarning) << path.string() << ": skipped " << skipped << " degenerate faces";
  }
  raw.triangles.resize(kept);
  raw.corner_uvs.resize(kept);
  raw.corner_normals.resize(kept);
  raw.has_normal.resize(kept);

  // Compact positions to the referenced ones, in their original order.
  constexpr uint32_t kUnused = std::numeric_limits<uint32_t>::max();
  std::vector<uint32_t> remap(raw.positions.size(), kUnused);
  for (const auto& tri : raw.triangles) {
    for (uint32_t i : tri) remap[i] = 0;
  }
  TriangleMesh mesh;
  for (size_t i = 0; i < raw.positions.size(); ++i) {
    if (remap[i] == kUnused) continue;
    remap[i] = uint32_t(mesh.positions.size());
    mesh.positions.push_back(raw.positions[i]);
  }
  for (auto& tri : raw.triangles) {
    for (uint32_t& i : tri) i = remap[i];
  }
  mesh.triangles = std::move(raw.triangles);
  mesh.corner_uvs = std::move(raw.corner_uvs);

  // Smooth normals (area weighted: the unnormalised cross product is twice the area times the
  // unit normal) for corners that came without one.
  bool any_missing = false;
  for (uint8_t bits : raw.has_normal) any_missing = any_missing || bits != 0b111;
  std::vector<Vec3d> smooth;
  if (any_missing) {
    smooth.assign(mesh.positions.size(), Vec3d::Zero());
    for (const auto& tri : mesh.triangles) {
      const Vec3d cross = Cross(mesh.positions, tri);
      for (uint32_t i : tri) smooth[i] += cross;
    }
    if (stats) stats->normals_computed = true;
  }
  mesh.corner_normals = std::move(raw.corner_normals);
  for (size_t t = 0; t < kept; ++t) {
    Vec3f geometric = Vec3f::UnitZ();
    NormalizeTo(Cross(mesh.positions, mesh.triangles[t]), &geometric);  // non-zero: area checked
    for (int c = 0; c < 3; ++c) {
      Vec3f& n = mesh.corner_normals[t][c];
      const bool given = (raw.has_normal[t] >> c) & 1;
      const Vec3d source = given ? n.cast<double>() : smooth[mesh.triangles[t][c]];
      // Zero-length or non-finite normals (given, or smooth sums that cancel out) fall back to
      // the geometric normal of the face.
      if (!NormalizeTo(source, &n)) n = geometric;
    }
  }
  return mesh;
}

// Reads a whole file into memory (one allocation; ReadTextFile's stream copy doubles the peak).
StatusOr<std::string> ReadFile(const fs::path& path) {
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) return NotFoundError(path.string(), ": no such file");
  std::ifstream in(path, std::ios::binary);
  if (!in) return NotFoundError(path.string(), ": cannot open file");
  in.seekg(0, std::ios::end);
  const std::streamoff size = in.tellg();
  if (size < 0) return DataLossError(path.string(), ": cannot determine file size");
  in.seekg(0, std::ios::beg);
  std::string contents(size_t(size), '\0');
  in.read(contents.data(), size);
  if (in.gcount() != size) return DataLossError(path.string(), ": read failed");
  return contents;
}

std::string LowerExtension(const fs::path& path) {
  std::string ext = path.extension().string();
  for (char& c : ext) c = char(std::tolower(static_cast<unsigned char>(c)));
  return ext;
}

// ---- OBJ ----------------------------------------------------------------------------------------

class ObjParser {
 public:
  explicit ObjParser(const fs::path& path) : path_(path) {}

  StatusOr<TriangleMesh> Parse(std::string_view text, MeshLoadStats* stats) {
    const char* p = text.data();
    const char* const end = p + text.size();
    while (p < end) {
      ++line_;
      const char* eol = static_cast<const char*>(std::memchr(p, '\n', size_t(end - p)));
      if (!eol) eol = end;
      const char* line_end = eol;
      if (line_end > p && line_end[-1] == '\r') --line_end;
      REFLCAP_RETURN_IF_ERROR(ParseLine(p, line_end));
      p = eol + 1;
    }
    if (raw_.triangles.empty() && faces_without_uv_ == 0) {
      return InvalidArgumentError(path_.string(), ": mesh has no faces");
    }
    if (faces_without_uv_ > 0) {
      if (faces_with_uv_ == 0) {
        return FailedPreconditionError(path_.string(),
                                       ": mesh has no UV coordinates (texel atlas needs them)");
      }
      return FailedPreconditionError(path_.string(), ":", first_line_without_uv_, ": face has no",
                                     " UV coordinates (texel atlas needs them on every face; ",
                                     faces_without_uv_, " faces lack them)");
    }
    return FinalizeMesh(path_, std::move(raw_), stats);
  }

 private:
  struct Corner {
    uint32_t v = 0;
    int64_t vt = -1;
    int64_t vn = -1;
  };

  template <typename... Args>
  Status Error(const Args&... args) const {
    return DataLossError(path_.string(), ":", line_, ": ", args...);
  }

  static bool IsSpace(char c) { return c == ' ' || c == '\t'; }
  static const char* SkipSpace(const char* p, const char* end) {
    while (p < end && IsSpace(*p)) ++p;
    return p;
  }

  Status ParseLine(const char* p, const char* end) {
    p = SkipSpace(p, end);
    if (p == end || *p == '#') return OkStatus();
    const char* word_end = p;
    while (word_end < end && !IsSpace(*word_end)) ++word_end;
    const std::string_view word(p, size_t(word_end - p));
    p = word_end;
    if (word == "v") {
      Vec3f v;
      for (int i = 0; i < 3; ++i) REFLCAP_RETURN_IF_ERROR(ParseFloat(&p, end, "v", &v[i]));
      raw_.positions.push_back(v);  // optional w or vertex colours after x y z are ignored
    } else if (word == "vt") {
      Vec2f vt(0.0f, 0.0f);
      REFLCAP_RETURN_IF_ERROR(ParseFloat(&p, end, "vt", &vt[0]));
      if (SkipSpace(p, end) < end) {  // v is optional in OBJ (1D textures); w is ignored
        REFLCAP_RETURN_IF_ERROR(ParseFloat(&p, end, "vt", &vt[1]));
      }
      uvs_.push_back(vt);
    } else if (word == "vn") {
      Vec3f vn;
      for (int i = 0; i < 3; ++i) REFLCAP_RETURN_IF_ERROR(ParseFloat(&p, end, "vn", &vn[i]));
      normals_.push_back(vn);
    } else if (word == "f") {
      return ParseFace(p, end);
    }
    // Other statements (o, g, s, usemtl, mtllib, l, p, curves...) carry nothing we use.
    return OkStatus();
  }

  Status ParseFloat(const char** p, const char* end, const char* what, float* out) const {
    const char* q = SkipSpace(*p, end);
    if (q < end && *q == '+') ++q;  // from_chars rejects a leading '+'; some writers emit it
    const auto [next, ec] = std::from_chars(q, end, *out);
    // Out of float range: keep it as infinity, so the faces using it are dropped as non-finite.
    if (ec == std::errc::result_out_of_range) *out = std::numeric_limits<float>::infinity();
    if ((ec != std::errc() && ec != std::errc::result_out_of_range) ||
        (next < end && !IsSpace(*next))) {
      const char* token_end = q;
      while (token_end < end && !IsSpace(*token_end)) ++token_end;
      return Error("bad number '", std::string_view(q, size_t(token_end - q)), "' in '", what,
                   "' statement");
    }
    *p = next;
    return OkStatus();
  }

  // Resolves a 1-based (or negative, relative) OBJ index against `count` elements.
  Status Resolve(int64_t index, size_t count, const char* what, const char* plural,
                 int64_t* out) const {
    const int64_t resolved = index > 0 ? index - 1 : int64_t(count) + index;
    if (index == 0 || resolved < 0 || resolved >= int64_t(count)) {
      return Error("face ", what, "index ", index, " out of range (", count, " ", plural, ")");
    }
    *out = resolved;
    return OkStatus();
  }

  Status ParseIndex(const char** p, const char* end, int64_t* out) const {
    const char* q = *p;
    if (q < end && *q == '+') ++q;
    const auto [next, ec] = std::from_chars(q, end, *out);
    if (ec != std::errc()) {
      const char* token_end = q;
      while (token_end < end && !IsSpace(*token_end)) ++token_end;
      return Error("bad face corner '", std::string_view(*p, size_t(token_end - *p)), "'");
    }
    *p = next;
    return OkStatus();
  }

  Status ParseFace(const char* p, const char* end) {
    corners_.clear();
    bool has_uv = true;
    bool has_normal = true;
    while ((p = SkipSpace(p, end)) < end) {
      const char* token = p;
      Corner corner;
      int64_t index = 0;
      int64_t resolved = 0;
      REFLCAP_RETURN_IF_ERROR(ParseIndex(&p, end, &index));
      REFLCAP_RETURN_IF_ERROR(Resolve(index, raw_.positions.size(), "", "vertices", &resolved));
      corner.v = uint32_t(resolved);
      if (p < end && *p == '/') {
        ++p;
        if (p < end && *p != '/') {  // v/vt or v/vt/vn
          REFLCAP_RETURN_IF_ERROR(ParseIndex(&p, end, &index));
          REFLCAP_RETURN_IF_ERROR(Resolve(index, uvs_.size(), "uv ", "uvs", &corner.vt));
        }
        if (p < end && *p == '/') {  // v//vn or v/vt/vn
          ++p;
          REFLCAP_RETURN_IF_ERROR(ParseIndex(&p, end, &index));
          REFLCAP_RETURN_IF_ERROR(
              Resolve(index, normals_.size(), "normal ", "normals", &corner.vn));
        }
      }
      if (p < end && !IsSpace(*p)) {
        const char* token_end = p;
        while (token_end < end && !IsSpace(*token_end)) ++token_end;
        return Error("bad face corner '", std::string_view(token, size_t(token_end - token)), "'");
      }
      has_uv = has_uv && corner.vt >= 0;
      has_normal = has_normal && corner.vn >= 0;
      corners_.push_back(corner);
    }
    if (corners_.size() < 3) {
      return Error("face with ", corners_.size(), " corners (at least 3 needed)");
    }
    if (!has_uv) {
      if (faces_without_uv_++ == 0) first_line_without_uv_ = line_;
      return OkStatus();
    }
    ++faces_with_uv_;
    // Fan triangulation (c0, ci, ci+1): exact for convex polygons, which is what exporters write.
    for (size_t i = 1; i + 1 < corners_.size(); ++i) {
      const Corner* c[3] = {&corners_[0], &corners_[i], &corners_[i + 1]};
      std::array<uint32_t, 3> tri;
      std::array<Vec2f, 3> uv;
      std::array<Vec3f, 3> normal;
      uint8_t normal_bits = 0;
      for (int k = 0; k < 3; ++k) {
        tri[k] = c[k]->v;
        uv[k] = uvs_[size_t(c[k]->vt)];
        if (c[k]->vn >= 0) {
          normal[k] = normals_[size_t(c[k]->vn)];
          normal_bits |= uint8_t(1u << k);
        } else {
          normal[k] = Vec3f::Zero();
        }
      }
      raw_.triangles.push_back(tri);
      raw_.corner_uvs.push_back(uv);
      raw_.corner_normals.push_back(normal);
      raw_.has_normal.push_back(normal_bits);
    }
    return OkStatus();
  }

  const fs::path& path_;
  size_t line_ = 0;
  RawMesh raw_;
  std::vector<Vec2f> uvs_;
  std::vector<Vec3f> normals_;
  std::vector<Corner> corners_;  // scratch for the current face
  size_t faces_with_uv_ = 0;
  size_t faces_without_uv_ = 0;
  size_t first_line_without_uv_ = 0;
};

// ---- glTF ---------------------------------------------------------------------------------------

// Images are never needed (we only read geometry); skipping them also keeps a missing or
// unsupported texture from failing the load.
bool SkipImage(tinygltf::Image*, const int, std::string*, std::string*, int, int,
               const unsigned char*, int, void*) {
  return true;
}

Mat4d NodeLocalMatrix(const tinygltf::Node& node) {
  Mat4d m = Mat4d::Identity();
  if (node.matrix.size() == 16) {
    for (int c = 0; c < 4; ++c) {
      for (int r = 0; r < 4; ++r) m(r, c) = node.matrix[size_t(c) * 4 + r];  // column-major
    }
    return m;
  }
  // local = T * R * S (glTF 2.0, section 5.25).
  if (node.scale.size() == 3) {
    m.topLeftCorner<3, 3>() = Vec3d(node.scale[0], node.scale[1], node.scale[2]).asDiagonal();
  }
  if (node.rotation.size() == 4) {  // glTF stores (x, y, z, w)
    const Eigen::Quaterniond q(node.rotation[3], node.rotation[0], node.rotation[1],
                               node.rotation[2]);
    m.topLeftCorner<3, 3>() = q.normalized().toRotationMatrix() * m.topLeftCorner<3, 3>();
  }
  if (node.translation.size() == 3) {
    m.topRightCorner<3, 1>() = Vec3d(node.translation[0], node.translation[1], node.translation[2]);
  }
  return m;
}

class GltfReader {
 public:
  GltfReader(const fs::path& path, const tinygltf::Model& model) : path_(path), model_(model) {}

  StatusOr<TriangleMesh> Read(MeshLoadStats* stats) {
    std::vector<int> roots;
    if (!model_.scenes.empty()) {
      const int scene = model_.defaultScene >= 0 ? model_.defaultScene : 0;
      if (scene >= int(model_.scenes.size())) {
        return DataLossError(path_.string(), ": default scene ", scene, " does not exist");
      }
      roots = model_.scenes[size_t(scene)].nodes;
    } else {
      // No scene: every node that is nobody's child is a root.
      std::vector<bool> is_child(model_.nodes.size(), false);
      for (const auto& node : model_.nodes) {
        for (int child : node.children) {
          if (child >= 0 && child < int(is_child.size())) is_child[size_t(child)] = true;
        }
      }
      for (size_t i = 0; i < model_.nodes.size(); ++i) {
        if (!is_child[i]) roots.push_back(int(i));
      }
    }
    visited_.assign(model_.nodes.size(), false);
    for (int root : roots) REFLCAP_RETURN_IF_ERROR(VisitNode(root, Mat4d::Identity()));

    if (primitives_without_uv_ > 0) {
      if (primitives_with_uv_ == 0) {
        return FailedPreconditionError(path_.string(),
                                       ": mesh has no UV coordinates (texel atlas needs them)");
      }
      return FailedPreconditionError(path_.string(), ": ", first_without_uv_,
                                     " has no UV coordinates (texel atlas needs them on every "
                                     "primitive)");
    }
    if (skipped_primitives_ > 0) {
      REFLCAP_LOG(kWarning) << path_.string() << ": ignored " << skipped_primitives_
                            << " primitives that are not triangle lists";
    }
    return FinalizeMesh(path_, std::move(raw_), stats);
  }

 private:
  Status VisitNode(int index, const Mat4d& parent) {
    if (index < 0 || index >= int(model_.nodes.size())) {
      return DataLossError(path_.string(), ": node index ", index, " out of range (",
                           model_.nodes.size(), " nodes)");
    }
    if (visited_[size_t(index)]) {
      return DataLossError(path_.string(), ": node ", index,
                           " is reached twice (cycle or shared child in the node hierarchy)");
    }
    visited_[size_t(index)] = true;
    const tinygltf::Node& node = model_.nodes[size_t(index)];
    const Mat4d world = parent * NodeLocalMatrix(node);
    if (node.mesh >= 0) {
      if (node.mesh >= int(model_.meshes.size())) {
        return DataLossError(path_.string(), ": node ", index, " refers to mesh ", node.mesh,
                             " of ", model_.meshes.size());
      }
      const tinygltf::Mesh& mesh = model_.meshes[size_t(node.mesh)];
      for (size_t p = 0; p < mesh.primitives.size(); ++p) {
        REFLCAP_RETURN_IF_ERROR(AddPrimitive(mesh, node.mesh, p, world));
      }
    }
    for (int child : node.children) REFLCAP_RETURN_IF_ERROR(VisitNode(child, world));
    return OkStatus();
  }

  // Reads accessor `index` as `components` floats per element (integer components are
  // normalised when the accessor says so, as glTF allows for quantised UVs and normals).
  Status ReadFloats(int index, int components, const std::string& what,
                    std::vector<float>* out) const {
    const tinygltf::Accessor* accessor = nullptr;
    const unsigned char* data = nullptr;
    size_t stride = 0;
    REFLCAP_RETURN_IF_ERROR(Locate(index, what, &accessor, &data, &stride));
    if (tinygltf::GetNumComponentsInType(uint32_t(accessor->type)) != components) {
      return DataLossError(path_.string(), ": ", what, ": expected ", components,
                           " components per element");
    }
    out->resize(accessor->count * size_t(components));
    for (size_t i = 0; i < accessor->count; ++i) {
      const unsigned char* element = data + i * stride;
      for (int c = 0; c < components; ++c) {
        (*out)[i * size_t(components) + size_t(c)] =
            ReadComponent(element, accessor->componentType, c, accessor->normalized);
      }
    }
    return OkStatus();
  }

  static float ReadComponent(const unsigned char* element, int type, int c, bool normalized) {
    auto load = [&](auto zero) {
      decltype(zero) value;
      std::memcpy(&value, element + size_t(c) * sizeof(value), sizeof(value));
      return value;
    };
    // Normalised integers per glTF 2.0 section 3.11 (signed: max(v / MAX, -1)).
    switch (type) {
      case TINYGLTF_COMPONENT_TYPE_FLOAT:
        return load(float{});
      case TINYGLTF_COMPONENT_TYPE_DOUBLE:
        return float(load(double{}));
      case TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE:
        return normalized ? load(uint8_t{}) / 255.0f : float(load(uint8_t{}));
      case TINYGLTF_COMPONENT_TYPE_BYTE:
        return normalized ? std::max(load(int8_t{}) / 127.0f, -1.0f) : float(load(int8_t{}));
      case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT:
        return normalized ? load(uint16_t{}) / 65535.0f : float(load(uint16_t{}));
      case TINYGLTF_COMPONENT_TYPE_SHORT:
        return normalized ? std::max(load(int16_t{}) / 32767.0f, -1.0f) : float(load(int16_t{}));
      case TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT:
        return float(load(uint32_t{}));
      case TINYGLTF_COMPONENT_TYPE_INT:
        return float(load(int32_t{}));
      default:
        return std::numeric_limits<float>::quiet_NaN();  // rejected in Locate
    }
  }

  Status ReadIndices(int index, const std::string& what, std::vector<uint32_t>* out) const {
    const tinygltf::Accessor* accessor = nullptr;
    const unsigned char* data = nullptr;
    size_t stride = 0;
    REFLCAP_RETURN_IF_ERROR(Locate(index, what, &accessor, &data, &stride));
    if (accessor->type != TINYGLTF_TYPE_SCALAR) {
      return DataLossError(path_.string(), ": ", what, ": indices must be scalars");
    }
    out->resize(accessor->count);
    for (size_t i = 0; i < accessor->count; ++i) {
      const unsigned char* element = data + i * stride;
      switch (accessor->componentType) {
        case TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE:
          (*out)[i] = *element;
          break;
        case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT: {
          uint16_t v;
          std::memcpy(&v, element, sizeof(v));
          (*out)[i] = v;
          break;
        }
        case TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT: {
          uint32_t v;
          std::memcpy(&v, element, sizeof(v));
          (*out)[i] = v;
          break;
        }
        default:
          return DataLossError(path_.string(), ": ", what,
                               ": index component type must be u8, u16 or u32 (got ",
                               accessor->componentType, ")");
      }
    }
    return OkStatus();
  }

  // Finds accessor `index`'s first element and stride, checking every bound against its buffer.
  Status Locate(int index, const std::string& what, const tinygltf::Accessor** accessor_out,
                const unsigned char** data, size_t* stride) const {
    if (index < 0 || index >= int(model_.accessors.size())) {
      return DataLossError(path_.string(), ": ", what, ": accessor ", index, " out of range (",
                           model_.accessors.size(), " accessors)");
    }
    const tinygltf::Accessor& accessor = model_.accessors[size_t(index)];
    *accessor_out = &accessor;
    if (accessor.sparse.isSparse) {
      return InvalidArgumentError(path_.string(), ": ", what,
                                  ": sparse accessors are not supported");
    }
    if (accessor.bufferView < 0 || accessor.bufferView >= int(model_.bufferViews.size())) {
      return DataLossError(path_.string(), ": ", what, ": accessor ", index,
                           " has no valid bufferView");
    }
    const tinygltf::BufferView& view = model_.bufferViews[size_t(accessor.bufferView)];
    if (view.buffer < 0 || view.buffer >= int(model_.buffers.size())) {
      return DataLossError(path_.string(), ": ", what, ": bufferView ", accessor.bufferView,
                           " has no valid buffer");
    }
    const tinygltf::Buffer& buffer = model_.buffers[size_t(view.buffer)];
    const int component_size = tinygltf::GetComponentSizeInBytes(uint32_t(accessor.componentType));
    const int components = tinygltf::GetNumComponentsInType(uint32_t(accessor.type));
    const int byte_stride = accessor.ByteStride(view);
    if (component_size <= 0 || components <= 0 || byte_stride <= 0) {
      return DataLossError(path_.string(), ": ", what, ": accessor ", index,
                           " has an invalid component type, type or stride");
    }
    const size_t element_size = size_t(component_size) * size_t(components);
    const size_t begin = view.byteOffset + accessor.byteOffset;
    const size_t extent =
        accessor.count == 0 ? 0 : (accessor.count - 1) * size_t(byte_stride) + element_size;
    if (accessor.byteOffset + extent > view.byteLength ||
        view.byteOffset + view.byteLength > buffer.data.size()) {
      return DataLossError(path_.string(), ": ", what, ": accessor ", index,
                           " reaches past the end of its buffer");
    }
    *data = buffer.data.data() + begin;
    *stride = size_t(byte_stride);
    return OkStatus();
  }

  Status AddPrimitive(const tinygltf::Mesh& mesh, int mesh_index, size_t prim_index,
                      const Mat4d& world) {
    const tinygltf::Primitive& prim = mesh.primitives[prim_index];
    const int mode = prim.mode < 0 ? TINYGLTF_MODE_TRIANGLES : prim.mode;
    if (mode != TINYGLTF_MODE_TRIANGLES) {
      ++skipped_primitives_;
      return OkStatus();
    }
    const std::string where =
        StrCat("mesh ", mesh_index, " ('", mesh.name, "') primitive ", prim_index);
    const auto position_it = prim.attributes.find("POSITION");
    if (position_it == prim.attributes.end()) {
      return DataLossError(path_.string(), ": ", where, " has no POSITION attribute");
    }
    const auto uv_it = prim.attributes.find("TEXCOORD_0");
    if (uv_it == prim.attributes.end()) {
      if (primitives_without_uv_++ == 0) first_without_uv_ = where;
      return OkStatus();
    }
    ++primitives_with_uv_;
    std::vector<float> positions, uvs, normals;
    REFLCAP_RETURN_IF_ERROR(ReadFloats(position_it->second, 3, where + " POSITION", &positions));
    REFLCAP_RETURN_IF_ERROR(ReadFloats(uv_it->second, 2, where + " TEXCOORD_0", &uvs));
    const size_t vertex_count = positions.size() / 3;
    if (uvs.size() / 2 != vertex_count) {
      return DataLossError(path_.string(), ": ", where, ": TEXCOORD_0 has ", uvs.size() / 2,
                           " elements, POSITION ", vertex_count);
    }
    const auto normal_it = prim.attributes.find("NORMAL");
    const bool has_normals = normal_it != prim.attributes.end();
    if (has_normals) {
      REFLCAP_RETURN_IF_ERROR(ReadFloats(normal_it->second, 3, where + " NORMAL", &normals));
      if (normals.size() / 3 != vertex_count) {
        return DataLossError(path_.string(), ": ", where, ": NORMAL has ", normals.size() / 3,
                             " elements, POSITION ", vertex_count);
      }
    }
    std::vector<uint32_t> indices;
    if (prim.indices >= 0) {
      REFLCAP_RETURN_IF_ERROR(ReadIndices(prim.indices, where + " indices", &indices));
    } else {
      indices.resize(vertex_count);
      for (size_t i = 0; i < vertex_count; ++i) indices[i] = uint32_t(i);
    }
    if (indices.size() % 3 != 0) {
      return DataLossError(path_.string(), ": ", where, ": ", indices.size(),
                           " indices is not a multiple of 3");
    }
    for (uint32_t i : indices) {
      if (i >= vertex_count) {
        return DataLossError(path_.string(), ": ", where, ": index ", i, " out of range (",
                             vertex_count, " vertices)");
      }
    }
    if (raw_.positions.size() + vertex_count > std::numeric_limits<uint32_t>::max()) {
      return InvalidArgumentError(path_.string(), ": more than 2^32 vertices");
    }

    // Positions by the world matrix, normals by the inverse transpose of its linear part.
    const Mat3d linear = world.topLeftCorner<3, 3>();
    const Eigen::Vector3d translation = world.topRightCorner<3, 1>();
    const double det = linear.determinant();
    const Mat3d normal_matrix = det != 0.0 ? Mat3d(linear.inverse().transpose()) : Mat3d::Zero();
    const uint32_t base = uint32_t(raw_.positions.size());
    for (size_t i = 0; i < vertex_count; ++i) {
      const Vec3d p(positions[3 * i], positions[3 * i + 1], positions[3 * i + 2]);
      raw_.positions.push_back((linear * p + translation).cast<float>());
    }
    // A negative determinant mirrors the geometry and with it the winding (glTF 2.0 section
    // 3.7.4): swap two corners so that our triangles stay counter-clockwise.
    const bool mirrored = det < 0.0;
    for (size_t t = 0; t < indices.size(); t += 3) {
      std::array<uint32_t, 3> corner = {indices[t], indices[t + 1], indices[t + 2]};
      if (mirrored) std::swap(corner[1], corner[2]);
      std::array<uint32_t, 3> tri;
      std::array<Vec2f, 3> uv;
      std::array<Vec3f, 3> normal;
      for (int c = 0; c < 3; ++c) {
        const size_t i = corner[c];
        tri[c] = base + uint32_t(i);
        // glTF's UV origin is the top-left corner of the texture (v grows downwards); ours is
        // OBJ's bottom-left, hence v_obj = 1 - v_gltf.
        uv[c] = Vec2f(uvs[2 * i], 1.0f - uvs[2 * i + 1]);
        normal[c] = Vec3f::Zero();
        if (has_normals) {
          const Vec3d n(normals[3 * i], normals[3 * i + 1], normals[3 * i + 2]);
          normal[c] = (normal_matrix * n).cast<float>();
        }
      }
      raw_.triangles.push_back(tri);
      raw_.corner_uvs.push_back(uv);
      raw_.corner_normals.push_back(normal);
      raw_.has_normal.push_back(has_normals ? 0b111 : 0);
    }
    return OkStatus();
  }

  const fs::path& path_;
  const tinygltf::Model& model_;
  RawMesh raw_;
  std::vector<bool> visited_;
  size_t skipped_primitives_ = 0;
  size_t primitives_with_uv_ = 0;
  size_t primitives_without_uv_ = 0;
  std::string first_without_uv_;
};

std::string TrimTrailingNewlines(std::string s) {
  while (!s.empty() && (s.back() == '\n' || s.back() == '\r')) s.pop_back();
  return s;
}

// %.9g: nine significant digits print every float exactly (round trip through from_chars).
void AppendFloat(std::string* out, float value) {
  char buffer[32];
  const auto result =
      std::to_chars(buffer, buffer + sizeof(buffer), value, std::chars_format::general, 9);
  out->append(buffer, result.ptr);
}

void AppendUint(std::string* out, size_t value) {
  char buffer[24];
  const auto result = std::to_chars(buffer, buffer + sizeof(buffer), value);
  out->append(buffer, result.ptr);
}

// Bit pattern of a float, so that exact repeats (including -0 vs 0 and NaNs) compare exactly.
uint32_t Bits(float value) {
  uint32_t bits;
  std::memcpy(&bits, &value, sizeof(bits));
  return bits;
}

// Numbers the distinct values of one per-corner attribute, looking for repeats only among the
// corners that share a position (where they occur: the corners around a smooth vertex), which
// needs no hash table. Calls `emit(corner)` once per distinct value, in order of the new ids.
template <typename Key, typename Emit>
std::vector<uint32_t> NumberCornerValues(const std::vector<uint32_t>& start,
                                         std::vector<uint32_t>& corners, const Key& key,
                                         const Emit& emit) {
  std::vector<uint32_t> id(corners.size());
  uint32_t next = 0;
  for (size_t p = 0; p + 1 < start.size(); ++p) {
    uint32_t* first = corners.data() + start[p];
    uint32_t* last = corners.data() + start[p + 1];
    std::sort(first, last, [&](uint32_t a, uint32_t b) {
      const auto ka = key(a), kb = key(b);
      return ka != kb ? ka < kb : a < b;
    });
    for (uint32_t* c = first; c != last; ++c) {
      if (c == first || key(*c) != key(c[-1])) {
        emit(*c);
        ++next;
      }
      id[*c] = next - 1;
    }
  }
  return id;
}

}  // namespace

StatusOr<TriangleMesh> LoadObj(const fs::path& path, MeshLoadStats* stats) {
  REFLCAP_ASSIGN_OR_RETURN(const std::string text, ReadFile(path));
  ObjParser parser(path);
  return parser.Parse(text, stats);
}

StatusOr<TriangleMesh> LoadGltf(const fs::path& path, MeshLoadStats* stats) {
  REFLCAP_ASSIGN_OR_RETURN(const std::string bytes, ReadFile(path));
  if (bytes.size() > std::numeric_limits<unsigned int>::max()) {
    return InvalidArgumentError(path.string(), ": glTF files over 4 GiB are not supported");
  }
  tinygltf::TinyGLTF loader;
  loader.SetImageLoader(&SkipImage, nullptr);
  tinygltf::Model model;
  std::string err, warn;
  const std::string base_dir = path.parent_path().string();
  // Binary glTF starts with the magic "glTF"; trust the content rather than the extension.
  const bool binary = bytes.size() >= 4 && bytes.compare(0, 4, "glTF") == 0;
  bool ok = false;
  // tinygltf indexes some arrays with at(): a malformed file can throw out of the parser (found
  // by the gltf fuzzer: an accessor naming a buffer view of a buffer list that is empty).
  try {
    ok = binary ? loader.LoadBinaryFromMemory(&model, &err, &warn,
                                              reinterpret_cast<const unsigned char*>(bytes.data()),
                                              unsigned(bytes.size()), base_dir)
                : loader.LoadASCIIFromString(&model, &err, &warn, bytes.data(),
                                             unsigned(bytes.size()), base_dir);
  } catch (const std::exception& e) {
    return DataLossError(path.string(), ": cannot parse glTF: malformed (", e.what(), ")");
  }
  if (!ok) {
    return DataLossError(path.string(),
                         ": cannot parse glTF: ", TrimTrailingNewlines(err.empty() ? warn : err));
  }
  if (!warn.empty()) {
    REFLCAP_LOG(kWarning) << path.string() << ": " << TrimTrailingNewlines(warn);
  }
  GltfReader reader(path, model);
  return reader.Read(stats);
}

StatusOr<TriangleMesh> LoadMesh(const fs::path& path, MeshLoadStats* stats) {
  const std::string ext = LowerExtension(path);
  if (ext == ".obj") return LoadObj(path, stats);
  if (ext == ".gltf" || ext == ".glb") return LoadGltf(path, stats);
  return InvalidArgumentError(path.string(), ": unknown mesh format '", ext,
                              "' (expected .obj, .gltf or .glb)");
}

Status WriteObj(const fs::path& path, const TriangleMesh& mesh) {
  const size_t count = mesh.triangles.size();
  if (mesh.corner_uvs.size() != count || mesh.corner_normals.size() != count) {
    return InvalidArgumentError(path.string(), ": mesh has ", count, " triangles but ",
                                mesh.corner_uvs.size(), " corner UV and ",
                                mesh.corner_normals.size(), " corner normal triples");
  }
  for (const auto& tri : mesh.triangles) {
    for (uint32_t i : tri) {
      if (i >= mesh.positions.size()) {
        return InvalidArgumentError(path.string(), ": triangle index ", i, " out of range (",
                                    mesh.positions.size(), " positions)");
      }
    }
  }
  std::string out;
  out.reserve(mesh.positions.size() * 40 + count * 120);
  out += "# reflcap mesh: ";
  AppendUint(&out, mesh.positions.size());
  out += " vertices, ";
  AppendUint(&out, count);
  out += " triangles\n";
  for (const Vec3f& p : mesh.positions) {
    out += "v ";
    AppendFloat(&out, p.x());
    out += ' ';
    AppendFloat(&out, p.y());
    out += ' ';
    AppendFloat(&out, p.z());
    out += '\n';
  }
  // Exact repeats of a UV or a normal among the corners of a vertex are written once.
  std::vector<uint32_t> start(mesh.positions.size() + 1, 0);
  for (const auto& tri : mesh.triangles) {
    for (uint32_t i : tri) ++start[i + 1];
  }
  for (size_t i = 1; i < start.size(); ++i) start[i] += start[i - 1];
  std::vector<uint32_t> corners(3 * count);
  {
    std::vector<uint32_t> cursor(start.begin(), start.end() - 1);
    for (size_t t = 0; t < count; ++t) {
      for (int c = 0; c < 3; ++c) corners[cursor[mesh.triangles[t][c]]++] = uint32_t(3 * t + c);
    }
  }
  const std::vector<uint32_t> corner_uv = NumberCornerValues(
      start, corners,
      [&](uint32_t c) {
        const Vec2f& uv = mesh.corner_uvs[c / 3][c % 3];
        return std::array<uint32_t, 2>{Bits(uv.x()), Bits(uv.y())};
      },
      [&](uint32_t c) {
        const Vec2f& uv = mesh.corner_uvs[c / 3][c % 3];
        out += "vt ";
        AppendFloat(&out, uv.x());
        out += ' ';
        AppendFloat(&out, uv.y());
        out += '\n';
      });
  const std::vector<uint32_t> corner_normal = NumberCornerValues(
      start, corners,
      [&](uint32_t c) {
        const Vec3f& n = mesh.corner_normals[c / 3][c % 3];
        return std::array<uint32_t, 3>{Bits(n.x()), Bits(n.y()), Bits(n.z())};
      },
      [&](uint32_t c) {
        const Vec3f& n = mesh.corner_normals[c / 3][c % 3];
        out += "vn ";
        AppendFloat(&out, n.x());
        out += ' ';
        AppendFloat(&out, n.y());
        out += ' ';
        AppendFloat(&out, n.z());
        out += '\n';
      });
  for (size_t t = 0; t < count; ++t) {
    out += 'f';
    for (int c = 0; c < 3; ++c) {
      out += ' ';
      AppendUint(&out, size_t(mesh.triangles[t][c]) + 1);
      out += '/';
      AppendUint(&out, size_t(corner_uv[3 * t + c]) + 1);
      out += '/';
      AppendUint(&out, size_t(corner_normal[3 * t + c]) + 1);
    }
    out += '\n';
  }
  return WriteTextFileAtomic(path, out);
}

}  // namespace reflcap
