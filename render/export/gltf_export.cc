// glTF 2.0 (.glb) export of a fit (gltf_export.h). The GLB is assembled by hand — a JSON chunk
// and a BIN chunk (glTF 2.0 spec, "Binary glTF Layout") — rather than through tinygltf's writer,
// so every byte goes to a temporary file that is renamed into place only when complete.
#include "render/export/gltf_export.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <fstream>
#include <map>
#include <tuple>
#include <unistd.h>

#include <nlohmann/json.hpp>

#include "engine/core/atomic_file.h"
#include "engine/core/log.h"
#include "engine/core/parallel.h"
#include "engine/image/exr_io.h"
#include "engine/image/png_io.h"
#include "engine/image/srgb.h"
#include "engine/texel/brdf_maps.h"
#include "render/export/metal_rough.h"

namespace reflcap::render {
namespace fs = std::filesystem;
using Json = nlohmann::json;
namespace {

constexpr uint32_t kGlbMagic = 0x46546C67;      // "glTF"
constexpr uint32_t kChunkJson = 0x4E4F534A;     // "JSON"
constexpr uint32_t kChunkBin = 0x004E4942;      // "BIN\0"
constexpr int kComponentFloat = 5126;
constexpr int kComponentUint = 5125;
constexpr int kTargetArrayBuffer = 34962;
constexpr int kTargetElementArrayBuffer = 34963;
constexpr int kFilterNearest = 9728;
constexpr int kWrapClampToEdge = 33071;
// GLB's length fields are uint32: a file must stay below 4 GiB.
constexpr uint64_t kMaxGlbBytes = 0xFFFFFFFFull;
// Unit tangents shorter than this after removing their normal component (within 0.06° of the
// normal) are replaced by any unit vector orthogonal to the normal (a degenerate UV chart there).
constexpr float kMinTangentLength = 1e-3f;

double Seconds(std::chrono::steady_clock::time_point since) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - since).count();
}

// sRGB encoding of a linear value, clamped to [0, 1] (base colours from rho_d may exceed 1).
float ClampedSrgb(float x) { return LinearToSrgb(std::clamp(x, 0.0f, 1.0f)); }

// The binary buffer under construction: views appended 4-byte aligned (float accessors need it).
struct BinBuilder {
  std::string bytes;
  Json views = Json::array();
  int AddView(const void* data, size_t size, int target) {
    while (bytes.size() % 4 != 0) bytes.push_back('\0');
    Json view = {{"buffer", 0}, {"byteOffset", bytes.size()}, {"byteLength", size}};
    if (target != 0) view["target"] = target;
    bytes.append(static_cast<const char*>(data), size);
    views.push_back(view);
    return int(views.size()) - 1;
  }
};

uint32_t FloatBits(float f) {
  uint32_t u;
  std::memcpy(&u, &f, sizeof u);
  return u;
}

// dP/du of triangle t times twice its UV area, as the texel atlas computes it (texel_atlas.cc):
// the tangent direction reflcap's BRDF frames follow. Zero for a degenerate UV triangle.
Vec3d WeightedFaceTangent(const TriangleMesh& mesh, size_t t) {
  const auto& tri = mesh.triangles[t];
  const auto& uv = mesh.corner_uvs[t];
  const Vec3d p0 = mesh.positions[tri[0]].cast<double>();
  const Vec3d e1 = mesh.positions[tri[1]].cast<double>() - p0;
  const Vec3d e2 = mesh.positions[tri[2]].cast<double>() - p0;
  const Vec2d d1 = (uv[1] - uv[0]).cast<double>();
  const Vec2d d2 = (uv[2] - uv[0]).cast<double>();
  const double det = d1.x() * d2.y() - d1.y() * d2.x();
  if (det == 0.0 || !std::isfinite(det)) return Vec3d::Zero();
  const Vec3d tangent = (e1 * d2.y() - e2 * d1.y()) * (det > 0.0 ? 1.0 : -1.0);
  return tangent.allFinite() ? tangent : Vec3d::Zero();
}

struct GltfVertices {
  std::vector<float> position, normal, tangent, uv;  // 3, 3, 4, 2 floats per vertex
  std::vector<uint32_t> indices;
  Vec3f min = Vec3f::Constant(std::numeric_limits<float>::max());
  Vec3f max = Vec3f::Constant(-std::numeric_limits<float>::max());
  size_t Count() const { return position.size() / 3; }
};

GltfVertices BuildVertices(const TriangleMesh& mesh) {
  GltfVertices out;
  using Key = std::tuple<uint32_t, uint32_t, uint32_t, uint32_t, uint32_t, uint32_t>;
  std::map<Key, uint32_t> vertex_of;
  std::map<std::tuple<uint32_t, uint32_t, uint32_t>, Vec3d> tangent_sum;  // (position, u, v)
  for (size_t t = 0; t < mesh.TriangleCount(); ++t) {
    const Vec3d face = WeightedFaceTangent(mesh, t);
    for (int c = 0; c < 3; ++c) {
      const Vec2f& uv = mesh.corner_uvs[t][c];
      tangent_sum[{mesh.triangles[t][c], FloatBits(uv.x()), FloatBits(uv.y())}] += face;
    }
  }
  out.indices.reserve(3 * mesh.TriangleCount());
  for (size_t t = 0; t < mesh.TriangleCount(); ++t) {
    for (int c = 0; c < 3; ++c) {
      const uint32_t p = mesh.triangles[t][c];
      const Vec2f& uv = mesh.corner_uvs[t][c];
      const Vec3f& n = mesh.corner_normals[t][c];
      const Key key{p, FloatBits(uv.x()), FloatBits(uv.y()), FloatBits(n.x()), FloatBits(n.y()),
                    FloatBits(n.z())};
      auto [it, inserted] = vertex_of.emplace(key, uint32_t(out.Count()));
      if (inserted) {
        const Vec3f& x = mesh.positions[p];
        out.position.insert(out.position.end(), {x.x(), x.y(), x.z()});
        out.min = out.min.cwiseMin(x);
        out.max = out.max.cwiseMax(x);
        const Vec3f unit_n = n.normalized();
        out.normal.insert(out.normal.end(), {unit_n.x(), unit_n.y(), unit_n.z()});
        // The sum is scaled by UV areas (tiny): made unit in double before the float work.
        const Vec3d sum = tangent_sum[{p, FloatBits(uv.x()), FloatBits(uv.y())}];
        Vec3f tangent = sum.norm() > 0 ? Vec3f((sum / sum.norm()).cast<float>()) : Vec3f::Zero();
        tangent -= unit_n * unit_n.dot(tangent);
        if (!(tangent.norm() > kMinTangentLength)) tangent = unit_n.unitOrthogonal();
        tangent.normalize();
        out.tangent.insert(out.tangent.end(), {tangent.x(), tangent.y(), tangent.z(), 1.0f});
        out.uv.insert(out.uv.end(), {uv.x(), 1.0f - uv.y()});
      }
      out.indices.push_back(it->second);
    }
  }
  return out;
}

// PNG bytes of `image` (written to a temporary file beside `scratch` and read back).
StatusOr<std::string> EncodePng(const Image& image, const fs::path& scratch) {
  REFLCAP_RETURN_IF_ERROR(WritePng(scratch, image, 8));
  auto bytes = ReadTextFile(scratch);
  std::error_code ec;
  fs::remove(scratch, ec);
  return bytes;
}

// Rotation (x, y, z, w) taking unit `axis` to +Y.
std::array<double, 4> QuaternionToYUp(const Vec3d& axis) {
  const Eigen::Quaterniond q = Eigen::Quaterniond::FromTwoVectors(axis.normalized(), Vec3d::UnitY());
  return {q.x(), q.y(), q.z(), q.w()};
}

// Removes the files on destruction unless released (nothing half-written is left behind).
struct TempFiles {
  std::vector<fs::path> paths;
  ~TempFiles() {
    std::error_code ec;
    for (const fs::path& p : paths) fs::remove(p, ec);
  }
};

fs::path TempNameFor(const fs::path& path) {
  return path.parent_path() / StrCat(".", path.filename().string(), ".tmp-", ::getpid());
}

}  // namespace

Status GltfExportOptions::Validate() const {
  if (max_texture_size < 1 || max_texture_size > 65536) {
    return InvalidArgumentError("max_texture_size must be in [1, 65536], got ", max_texture_size);
  }
  if (threads < 0) return InvalidArgumentError("threads must be >= 0, got ", threads);
  return OkStatus();
}

fs::path LafortuneExrPathFor(const fs::path& glb) {
  fs::path exr = glb;
  exr.replace_extension(".lafortune.exr");
  return exr;
}

StatusOr<GltfExportSummary> ExportGltf(const FittedCapture& fitted, const fs::path& params_exr,
                                       const fs::path& glb, const GltfExportOptions& options) {
  REFLCAP_RETURN_IF_ERROR(options.Validate());
  if (fitted.normal_map) {
    return FailedPreconditionError(params_exr.string(), ": a normal-map capture's fit has no mesh "
                                   "to export");
  }
  const TexelAtlas& atlas = fitted.atlas;
  const TriangleMesh& mesh = fitted.mesh;
  const BrdfMaps& maps = fitted.maps;
  if (mesh.TriangleCount() == 0) {
    return InvalidArgumentError(fitted.capture->json_path.string(), ": mesh: has no triangles");
  }
  if (atlas.width > options.max_texture_size || atlas.height > options.max_texture_size) {
    return InvalidArgumentError(params_exr.string(), ": size: the atlas is ", atlas.width, "x",
                                atlas.height, ", above the glTF texture limit of ",
                                options.max_texture_size, " pixels per side");
  }
  GltfExportSummary summary;
  summary.glb = glb;
  summary.exr = options.write_exr ? LafortuneExrPathFor(glb) : fs::path();
  for (const fs::path& out : {summary.glb, summary.exr}) {
    std::error_code ec;
    if (!out.empty() && fs::exists(out, ec) && !options.overwrite) {
      return FailedPreconditionError(out.string(), ": exists (use --overwrite to replace it)");
    }
  }
  const fs::path folder = glb.has_parent_path() ? glb.parent_path() : fs::path(".");
  {
    std::error_code ec;
    if (!fs::is_directory(folder, ec)) {
      return NotFoundError(folder.string(), ": the folder of ", glb.filename().string(),
                           " does not exist");
    }
  }
  summary.texels = atlas.TexelCount();
  summary.width = atlas.width;
  summary.height = atlas.height;
  summary.num_lobes = maps.num_lobes;
  summary.triangles = mesh.TriangleCount();

  // Metallic-roughness approximation per texel.
  auto start = std::chrono::steady_clock::now();
  const MetalRoughFitter fitter;
  std::vector<MetalRough> approx(atlas.TexelCount());
  ParallelFor(0, int64_t(approx.size()), 256, [&](int64_t b, int64_t e, int) {
    for (int64_t t = b; t < e; ++t) approx[size_t(t)] = fitter.Fit(maps.texels[size_t(t)]);
  }, options.threads);
  {
    std::vector<float> errors(approx.size());
    double sum = 0;
    for (size_t t = 0; t < approx.size(); ++t) {
      errors[t] = approx[t].error;
      sum += approx[t].error;
      if (approx[t].metallic > 0) ++summary.error.metallic_texels;
    }
    // RMS over texels of the per-texel relative error.
    double sum_sq = 0;
    for (float e : errors) sum_sq += double(e) * e;
    if (!errors.empty()) {
      std::sort(errors.begin(), errors.end());
      auto pct = [&](double q) {
        return double(errors[std::min(errors.size() - 1, size_t(q * double(errors.size())))]);
      };
      summary.error.median = pct(0.5);
      summary.error.p90 = pct(0.9);
      summary.error.p99 = pct(0.99);
      summary.error.max = errors.back();
      summary.error.mean = sum / double(errors.size());
      summary.error.rms = std::sqrt(sum_sq / double(errors.size()));
    }
  }
  summary.approximate_s = Seconds(start);
  start = std::chrono::steady_clock::now();

  // Textures and raw parameters in atlas layout.
  Image base(atlas.width, atlas.height, 3, 0.0f), metal_rough(atlas.width, atlas.height, 3, 0.0f);
  Image error_map(atlas.width, atlas.height, 1, 0.0f);
  for (size_t t = 0; t < atlas.TexelCount(); ++t) {
    int x, y;
    atlas.PixelOf(t, &x, &y);
    for (int c = 0; c < 3; ++c) base.at(x, y, c) = ClampedSrgb(approx[t].base_color[c]);
    metal_rough.at(x, y, 0) = 1;  // R: unused by the core material (occlusion would be 1)
    metal_rough.at(x, y, 1) = approx[t].roughness;
    metal_rough.at(x, y, 2) = approx[t].metallic;
    error_map.at(x, y) = approx[t].error;
  }
  Image params = BrdfMapsToImage(maps, atlas);
  const std::vector<std::string> channels = BrdfChannelNames(maps.num_lobes);
  for (float& v : params.data) {
    if (!std::isfinite(v)) v = 0;  // no NaN/Inf reaches the file (the EXR writer does the same)
  }
  const GltfVertices vertices = BuildVertices(mesh);
  summary.vertices = vertices.Count();

  TempFiles temps;
  const fs::path glb_tmp = TempNameFor(glb);
  temps.paths.push_back(glb_tmp);
  const fs::path png_scratch = folder / StrCat(".", glb.filename().string(), ".png-", ::getpid(), ".png");
  temps.paths.push_back(png_scratch);
  REFLCAP_ASSIGN_OR_RETURN(std::string base_png, EncodePng(base, png_scratch));
  REFLCAP_ASSIGN_OR_RETURN(std::string mr_png, EncodePng(metal_rough, png_scratch));

  BinBuilder bin;
  Json accessors = Json::array();
  auto add_accessor = [&](int view, int component, size_t count, const char* type) {
    accessors.push_back({{"bufferView", view}, {"componentType", component}, {"count", count},
                         {"type", type}});
    return int(accessors.size()) - 1;
  };
  const size_t nv = vertices.Count();
  const int pos = add_accessor(
      bin.AddView(vertices.position.data(), 4 * vertices.position.size(), kTargetArrayBuffer),
      kComponentFloat, nv, "VEC3");
  accessors[pos]["min"] = {vertices.min.x(), vertices.min.y(), vertices.min.z()};
  accessors[pos]["max"] = {vertices.max.x(), vertices.max.y(), vertices.max.z()};
  const int nrm = add_accessor(
      bin.AddView(vertices.normal.data(), 4 * vertices.normal.size(), kTargetArrayBuffer),
      kComponentFloat, nv, "VEC3");
  const int tan = add_accessor(
      bin.AddView(vertices.tangent.data(), 4 * vertices.tangent.size(), kTargetArrayBuffer),
      kComponentFloat, nv, "VEC4");
  const int tex = add_accessor(
      bin.AddView(vertices.uv.data(), 4 * vertices.uv.size(), kTargetArrayBuffer),
      kComponentFloat, nv, "VEC2");
  const int idx = add_accessor(bin.AddView(vertices.indices.data(), 4 * vertices.indices.size(),
                                           kTargetElementArrayBuffer),
                               kComponentUint, vertices.indices.size(), "SCALAR");
  const int base_view = bin.AddView(base_png.data(), base_png.size(), 0);
  const int mr_view = bin.AddView(mr_png.data(), mr_png.size(), 0);
  const int params_acc = add_accessor(bin.AddView(params.data.data(), 4 * params.data.size(), 0),
                                      kComponentFloat, params.data.size(), "SCALAR");
  while (bin.bytes.size() % 4 != 0) bin.bytes.push_back('\0');

  Json node = {{"mesh", 0}, {"name", "reflcap_object"}};
  if (fitted.capture->turntable) {
    const auto q = QuaternionToYUp(fitted.capture->turntable->axis);
    node["rotation"] = {q[0], q[1], q[2], q[3]};
  }
  Json lafortune = {
      {"version", 1},
      {"lobes", maps.num_lobes},
      {"width", atlas.width},
      {"height", atlas.height},
      {"channels", channels},
      {"parameters", params_acc},
      {"model", "f_c(wi, wo) = rho_d.c / pi + sum_k max(0, Cx_k.c wi_x wo_x + Cy_k.c wi_y wo_y + "
                "Cz_k.c wi_z wo_z)^n_k.c; wi, wo unit, away from the surface, in the frame "
                "(TANGENT.xyz, NORMAL x TANGENT.xyz, NORMAL); a lobe is 0 where its base <= 0"},
      {"layout", "row-major atlas pixels, row 0 = TEXCOORD_0 v = 0, pixel (x, y) covers u in "
                 "[x/width, (x+1)/width], v in [y/height, (y+1)/height]; channels interleaved "
                 "per pixel in the order of 'channels'; 0 where no texel"},
      {"metallicRoughnessError",
       {{"median", summary.error.median}, {"p90", summary.error.p90}, {"p99", summary.error.p99},
        {"max", summary.error.max}, {"rms", summary.error.rms}}},
  };
  if (options.write_exr) lafortune["exr"] = summary.exr.filename().string();
  Json gltf = {
      {"asset", {{"version", "2.0"}, {"generator", "reflcap export"}}},
      {"extensionsUsed", {"REFLCAP_lafortune"}},
      {"scene", 0},
      {"scenes", {{{"nodes", {0}}}}},
      {"nodes", {node}},
      {"meshes",
       {{{"name", "reflcap_object"},
         {"primitives",
          {{{"attributes", {{"POSITION", pos}, {"NORMAL", nrm}, {"TANGENT", tan},
                            {"TEXCOORD_0", tex}}},
            {"indices", idx},
            {"material", 0},
            {"mode", 4}}}}}}},
      {"materials",
       {{{"name", "reflcap_fit"},
         {"pbrMetallicRoughness",
          {{"baseColorTexture", {{"index", 0}}},
           {"metallicRoughnessTexture", {{"index", 1}}},
           {"metallicFactor", 1.0},
           {"roughnessFactor", 1.0}}},
         {"extensions", {{"REFLCAP_lafortune", lafortune}}}}}},
      {"samplers",
       {{{"magFilter", kFilterNearest}, {"minFilter", kFilterNearest},
         {"wrapS", kWrapClampToEdge}, {"wrapT", kWrapClampToEdge}}}},
      {"images",
       {{{"bufferView", base_view}, {"mimeType", "image/png"}, {"name", "baseColor"}},
        {{"bufferView", mr_view}, {"mimeType", "image/png"}, {"name", "metallicRoughness"}}}},
      {"textures", {{{"sampler", 0}, {"source", 0}}, {{"sampler", 0}, {"source", 1}}}},
      {"bufferViews", bin.views},
      {"accessors", accessors},
      {"buffers", {{{"byteLength", bin.bytes.size()}}}},
  };
  std::string json_text = gltf.dump();
  while (json_text.size() % 4 != 0) json_text.push_back(' ');
  const uint64_t total = 12 + 8 + uint64_t(json_text.size()) + 8 + uint64_t(bin.bytes.size());
  if (total > kMaxGlbBytes) {
    return InvalidArgumentError(params_exr.string(), ": the .glb would take ", total,
                                " bytes, above GLB's limit of 4 GiB (32-bit lengths); use a "
                                "smaller atlas");
  }
  {
    std::ofstream file(glb_tmp, std::ios::binary | std::ios::trunc);
    auto put32 = [&](uint32_t v) { file.write(reinterpret_cast<const char*>(&v), 4); };
    put32(kGlbMagic);
    put32(2);
    put32(uint32_t(total));
    put32(uint32_t(json_text.size()));
    put32(kChunkJson);
    file.write(json_text.data(), std::streamsize(json_text.size()));
    put32(uint32_t(bin.bytes.size()));
    put32(kChunkBin);
    file.write(bin.bytes.data(), std::streamsize(bin.bytes.size()));
    file.close();
    if (!file) return InternalError(glb_tmp.string(), ": write failed");
  }
  summary.glb_bytes = total;
  fs::path exr_tmp;
  if (options.write_exr) {
    exr_tmp = TempNameFor(summary.exr);
    exr_tmp.replace_extension(".exr");  // the EXR writer's own temporary sits beside it
    temps.paths.push_back(exr_tmp);
    Image with_error(atlas.width, atlas.height, params.channels + 1, 0.0f);
    for (size_t p = 0; p < params.PixelCount(); ++p) {
      std::copy_n(&params.data[p * params.channels], params.channels,
                  &with_error.data[p * with_error.channels]);
      with_error.data[p * with_error.channels + params.channels] = error_map.data[p];
    }
    std::vector<std::string> names = channels;
    names.push_back("gltf.error");
    REFLCAP_RETURN_IF_ERROR(WriteExrChannels(exr_tmp, with_error, names));
    std::error_code ec;
    summary.exr_bytes = fs::file_size(exr_tmp, ec);
    fs::rename(exr_tmp, summary.exr, ec);
    if (ec) return InternalError(summary.exr.string(), ": cannot rename into place: ", ec.message());
  }
  std::error_code ec;
  fs::rename(glb_tmp, glb, ec);
  if (ec) {
    if (options.write_exr) fs::remove(summary.exr, ec);
    return InternalError(glb.string(), ": cannot rename into place: ", ec.message());
  }
  summary.write_s = Seconds(start);
  return summary;
}

}  // namespace reflcap::render
