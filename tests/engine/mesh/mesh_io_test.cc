#include "engine/mesh/mesh_io.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <string>
#include <vector>

#include "tests/support/test_support.h"

namespace reflcap {
namespace {

using testing::ScratchDir;
using testing::WriteText;

// Loaded floats that went through text with at least 6 significant digits, or through a double
// transform and back to float: a few float ulps at magnitudes <= 10.
constexpr float kCoordinateTolerance = 1e-6f;
// Unit vectors normalised in float, or rotated in double then rounded: ~1 ulp of 1.0f each step.
constexpr float kUnitTolerance = 1e-6f;

::testing::AssertionResult Near(const Vec3f& actual, const Vec3f& expected, float tolerance) {
  if ((actual - expected).cwiseAbs().maxCoeff() <= tolerance) return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure()
         << "(" << actual.transpose() << ") vs expected (" << expected.transpose() << ")";
}

// v/vt/vn square z = 0, two triangles, all normals +z.
constexpr const char* kSquareObj =
    "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
    "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
    "vn 0 0 1\n";

TEST(LoadObj, ParsesVertexUvAndVertexUvNormalFaces) {
  ScratchDir dir;
  WriteText(dir / "m.obj", std::string(kSquareObj) + "f 1/1 2/2 3/3\nf 1/1/1 3/3/1 4/4/1\n");
  MeshLoadStats stats;
  StatusOr<TriangleMesh> mesh = LoadObj(dir / "m.obj", &stats);
  ASSERT_TRUE(mesh.ok()) << mesh.status().ToString();
  ASSERT_EQ(mesh->TriangleCount(), 2u);
  EXPECT_EQ(mesh->positions.size(), 4u);
  EXPECT_EQ(mesh->triangles[0], (std::array<uint32_t, 3>{0, 1, 2}));
  EXPECT_EQ(mesh->triangles[1], (std::array<uint32_t, 3>{0, 2, 3}));
  EXPECT_EQ(mesh->corner_uvs[0][1], Vec2f(1, 0));
  EXPECT_EQ(mesh->corner_uvs[1][2], Vec2f(0, 1));
  for (const auto& corners : mesh->corner_normals) {
    for (const Vec3f& n : corners) EXPECT_TRUE(Near(n, Vec3f(0, 0, 1), kUnitTolerance));
  }
  EXPECT_TRUE(stats.normals_computed);  // the first face has none
  EXPECT_EQ(stats.faces_read, 2u);
  EXPECT_EQ(stats.triangles_kept, 2u);
  EXPECT_EQ(stats.degenerate_skipped, 0u);
}

TEST(LoadObj, RejectsVertexOnlyAndVertexNormalFacesForLackOfUvs) {
  ScratchDir dir;
  for (const char* face : {"f 1 2 3\n", "f 1//1 2//1 3//1\n"}) {
    const auto path = dir / "no_uv.obj";
    WriteText(path, std::string(kSquareObj) + face);
    StatusOr<TriangleMesh> mesh = LoadObj(path);
    ASSERT_FALSE(mesh.ok()) << face;
    EXPECT_EQ(mesh.status().code(), StatusCode::kFailedPrecondition);
    EXPECT_EQ(mesh.status().message(),
              path.string() + ": mesh has no UV coordinates (texel atlas needs them)");
  }
}

TEST(LoadObj, RejectsMeshWhereSomeFacesLackUvs) {
  ScratchDir dir;
  const auto path = dir / "partial.obj";
  WriteText(path, std::string(kSquareObj) + "f 1/1 2/2 3/3\nf 1 3 4\n");
  StatusOr<TriangleMesh> mesh = LoadObj(path);
  ASSERT_FALSE(mesh.ok());
  EXPECT_EQ(mesh.status().code(), StatusCode::kFailedPrecondition);
  EXPECT_EQ(mesh.status().message().rfind(path.string() + ":11: face has no UV coordinates", 0), 0u)
      << mesh.status().message();
}

TEST(LoadObj, ResolvesNegativeIndicesRelativeToTheCurrentEnd) {
  ScratchDir dir;
  WriteText(dir / "neg.obj", std::string(kSquareObj) +
                                 "f -4/-4/-1 -3/-3/-1 -2/-2/-1\n"
                                 "v 5 5 5\n"  // shifts the relative vertex indices by one
                                 "f -5/-4/1 -3/-2/1 -2/-1/1\n");
  StatusOr<TriangleMesh> mesh = LoadObj(dir / "neg.obj");
  ASSERT_TRUE(mesh.ok()) << mesh.status().ToString();
  ASSERT_EQ(mesh->TriangleCount(), 2u);
  EXPECT_EQ(mesh->positions.size(), 4u);  // the unreferenced "v 5 5 5" is dropped
  EXPECT_EQ(mesh->triangles[0], (std::array<uint32_t, 3>{0, 1, 2}));
  EXPECT_EQ(mesh->triangles[1], (std::array<uint32_t, 3>{0, 2, 3}));
  EXPECT_EQ(mesh->corner_uvs[1][1], Vec2f(1, 1));
  EXPECT_EQ(mesh->corner_uvs[1][2], Vec2f(0, 1));
}

TEST(LoadObj, FanTriangulatesPolygons) {
  ScratchDir dir;
  WriteText(dir / "poly.obj",
            "v 0 0 0\nv 1 0 0\nv 2 1 0\nv 1 2 0\nv 0 1 0\n"
            "vt 0 0\nvt 0.5 0\nvt 1 0.5\nvt 0.5 1\nvt 0 0.5\n"
            "f 1/1 2/2 3/3 4/4\n"
            "f 1/1 2/2 3/3 4/4 5/5\n");
  MeshLoadStats stats;
  StatusOr<TriangleMesh> mesh = LoadObj(dir / "poly.obj", &stats);
  ASSERT_TRUE(mesh.ok()) << mesh.status().ToString();
  ASSERT_EQ(mesh->TriangleCount(), 5u);  // quad -> 2, pentagon -> 3
  EXPECT_EQ(stats.faces_read, 5u);
  const std::vector<std::array<uint32_t, 3>> expected = {
      {0, 1, 2}, {0, 2, 3}, {0, 1, 2}, {0, 2, 3}, {0, 3, 4}};
  EXPECT_EQ(mesh->triangles, expected);
  EXPECT_EQ(mesh->corner_uvs[4][2], Vec2f(0, 0.5f));
}

TEST(LoadObj, SkipsAndCountsDegenerateFaces) {
  ScratchDir dir;
  WriteText(dir / "degenerate.obj",
            "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 2 0 0\nv nan 0 0\nv 0.5 1e-9 0\n"
            "vt 0 0\nvt 1 0\nvt 1 1\n"
            "f 1/1 2/2 3/3\n"    // good
            "f 1/1 1/2 3/3\n"    // repeated vertex
            "f 1/1 2/2 4/3\n"    // collinear: zero area
            "f 1/1 5/2 3/3\n"    // non-finite coordinate
            "f 1/1 2/2 6/3\n");  // thin, but |cross| = 1e-9 > 1e-12 * diagonal^2: kept
  MeshLoadStats stats;
  StatusOr<TriangleMesh> mesh = LoadObj(dir / "degenerate.obj", &stats);
  ASSERT_TRUE(mesh.ok()) << mesh.status().ToString();
  EXPECT_EQ(stats.faces_read, 5u);
  EXPECT_EQ(stats.degenerate_skipped, 3u);
  EXPECT_EQ(stats.triangles_kept, 2u);
  EXPECT_EQ(mesh->TriangleCount(), 2u);
  for (const Vec3f& p : mesh->positions) EXPECT_TRUE(p.allFinite());
}

TEST(LoadObj, DropsTrianglesBelowTheRelativeAreaThreshold) {
  ScratchDir dir;
  // Bounding-box diagonal^2 = 2, so |cross| <= 2e-12 is degenerate; 1e-13 is, 1e-9 is not.
  WriteText(dir / "thin.obj",
            "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0.5 1e-13 0\nv 0.5 1e-9 0\n"
            "vt 0 0\nvt 1 0\nvt 1 1\n"
            "f 1/1 2/2 3/3\nf 1/1 2/2 4/3\nf 1/1 2/2 5/3\n");
  MeshLoadStats stats;
  StatusOr<TriangleMesh> mesh = LoadObj(dir / "thin.obj", &stats);
  ASSERT_TRUE(mesh.ok()) << mesh.status().ToString();
  EXPECT_EQ(stats.degenerate_skipped, 1u);
  EXPECT_EQ(mesh->TriangleCount(), 2u);
}

TEST(LoadObj, OutOfRangeIndexErrorNamesFileAndLine) {
  ScratchDir dir;
  const auto path = dir / "mesh.obj";
  WriteText(path, std::string(kSquareObj) + "f 1/1 2/2 3/3\nf 1/1 2/2 9/3\n");
  StatusOr<TriangleMesh> mesh = LoadObj(path);
  ASSERT_FALSE(mesh.ok());
  EXPECT_EQ(mesh.status().code(), StatusCode::kDataLoss);
  EXPECT_EQ(mesh.status().message(), path.string() + ":11: face index 9 out of range (4 vertices)");

  WriteText(path, std::string(kSquareObj) + "f 1/1 2/-7 3/3\n");
  mesh = LoadObj(path);
  ASSERT_FALSE(mesh.ok());
  EXPECT_EQ(mesh.status().message(), path.string() + ":10: face uv index -7 out of range (4 uvs)");

  WriteText(path, std::string(kSquareObj) + "f 0/1 2/2 3/3\n");
  mesh = LoadObj(path);
  ASSERT_FALSE(mesh.ok());
  EXPECT_EQ(mesh.status().message(), path.string() + ":10: face index 0 out of range (4 vertices)");
}

TEST(LoadObj, MalformedNumbersAndCornersNameFileAndLine) {
  ScratchDir dir;
  const auto path = dir / "bad.obj";
  WriteText(path, "v 0 0 0\nv 1 zero 0\n");
  StatusOr<TriangleMesh> mesh = LoadObj(path);
  ASSERT_FALSE(mesh.ok());
  EXPECT_EQ(mesh.status().code(), StatusCode::kDataLoss);
  EXPECT_EQ(mesh.status().message(), path.string() + ":2: bad number 'zero' in 'v' statement");

  WriteText(path, std::string(kSquareObj) + "f 1/1 2/2x 3/3\n");
  mesh = LoadObj(path);
  ASSERT_FALSE(mesh.ok());
  EXPECT_EQ(mesh.status().message(), path.string() + ":10: bad face corner '2/2x'");

  WriteText(path, std::string(kSquareObj) + "f 1/1 2/2\n");
  mesh = LoadObj(path);
  ASSERT_FALSE(mesh.ok());
  EXPECT_EQ(mesh.status().message(),
            path.string() + ":10: face with 2 corners (at least 3 needed)");
}

TEST(LoadObj, ComputesMissingNormalsSmoothAndAreaWeighted) {
  ScratchDir dir;
  // A roof: a large face in z = 0 and a small one folded up along the x axis.
  WriteText(dir / "roof.obj",
            "v 0 0 0\nv 1 0 0\nv 0 -2 0\nv 0 0.5 0.5\n"
            "vt 0 0\nvt 1 0\nvt 0 1\n"
            "f 1/1 3/3 2/2\n"
            "f 1/1 2/2 4/3\n");
  MeshLoadStats stats;
  StatusOr<TriangleMesh> mesh = LoadObj(dir / "roof.obj", &stats);
  ASSERT_TRUE(mesh.ok()) << mesh.status().ToString();
  EXPECT_TRUE(stats.normals_computed);
  // Face 0: cross((0,-2,0), (1,0,0)) = (0,0,2); face 1: cross((1,0,0), (0,.5,.5)) = (0,-.5,.5).
  const Vec3f shared = Vec3f(0.0f, -0.5f, 2.5f).normalized();
  EXPECT_TRUE(Near(mesh->corner_normals[0][0], shared, kUnitTolerance));          // vertex 1
  EXPECT_TRUE(Near(mesh->corner_normals[0][2], shared, kUnitTolerance));          // vertex 2
  EXPECT_TRUE(Near(mesh->corner_normals[1][1], shared, kUnitTolerance));          // vertex 2
  EXPECT_TRUE(Near(mesh->corner_normals[0][1], Vec3f(0, 0, 1), kUnitTolerance));  // vertex 3
  EXPECT_TRUE(Near(mesh->corner_normals[1][2], Vec3f(0, -1, 1).normalized(), kUnitTolerance));
}

TEST(LoadObj, NormalisesNormalsAndReplacesZeroLengthOnesByTheGeometricNormal) {
  ScratchDir dir;
  WriteText(dir / "n.obj", std::string(kSquareObj) +
                               "vn 0 0 0\nvn 0 3 4\n"
                               "f 1/1/2 2/2/3 3/3/1\n");
  MeshLoadStats stats;
  StatusOr<TriangleMesh> mesh = LoadObj(dir / "n.obj", &stats);
  ASSERT_TRUE(mesh.ok()) << mesh.status().ToString();
  EXPECT_FALSE(stats.normals_computed);
  EXPECT_TRUE(Near(mesh->corner_normals[0][0], Vec3f(0, 0, 1), kUnitTolerance));
  EXPECT_TRUE(Near(mesh->corner_normals[0][1], Vec3f(0, 0.6f, 0.8f), kUnitTolerance));
  EXPECT_TRUE(Near(mesh->corner_normals[0][2], Vec3f(0, 0, 1), kUnitTolerance));
}

TEST(LoadObj, IgnoresOtherStatementsCommentsAndCrlf) {
  ScratchDir dir;
  WriteText(dir / "misc.obj",
            "# exported\r\nmtllib m.mtl\r\no thing\r\ng group\r\ns 1\r\nusemtl stone\r\n"
            "v 0 0 0 1\r\nv +1 0 0\r\n  v 1 1 0 0.5 0.5 0.5\r\n\r\n"
            "vt 0 0 0\r\nvt 1 0\r\nvt 1 1\r\nl 1 2\r\n"
            "f 1/1 2/2 3/3 \r\n");
  StatusOr<TriangleMesh> mesh = LoadObj(dir / "misc.obj");
  ASSERT_TRUE(mesh.ok()) << mesh.status().ToString();
  ASSERT_EQ(mesh->TriangleCount(), 1u);
  EXPECT_EQ(mesh->positions[1], Vec3f(1, 0, 0));
  EXPECT_EQ(mesh->positions[2], Vec3f(1, 1, 0));
}

TEST(LoadObj, EmptyMeshIsInvalidArgument) {
  ScratchDir dir;
  WriteText(dir / "empty.obj", "v 0 0 0\nv 1 0 0\nvt 0 0\n");
  StatusOr<TriangleMesh> mesh = LoadObj(dir / "empty.obj");
  ASSERT_FALSE(mesh.ok());
  EXPECT_EQ(mesh.status().code(), StatusCode::kInvalidArgument);

  // Faces that are all degenerate leave nothing either.
  WriteText(dir / "flat.obj", "v 0 0 0\nv 1 0 0\nv 2 0 0\nvt 0 0\nf 1/1 2/1 3/1\n");
  mesh = LoadObj(dir / "flat.obj");
  ASSERT_FALSE(mesh.ok());
  EXPECT_EQ(mesh.status().code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(mesh.status().message().rfind((dir / "flat.obj").string() + ": ", 0), 0u);
}

TEST(LoadObj, MissingFileIsNotFound) {
  ScratchDir dir;
  StatusOr<TriangleMesh> mesh = LoadObj(dir / "absent.obj");
  ASSERT_FALSE(mesh.ok());
  EXPECT_EQ(mesh.status().code(), StatusCode::kNotFound);
  EXPECT_EQ(mesh.status().message().rfind((dir / "absent.obj").string(), 0), 0u);
}

TEST(WriteObj, RoundTripsThroughLoadObj) {
  TriangleMesh mesh;
  // Values that need all nine significant digits, and a seam (vertex 0 with two UVs).
  mesh.positions = {Vec3f(0.1f, 1.0f / 3.0f, -2.5e-7f), Vec3f(1.2345679f, 0, 1e6f),
                    Vec3f(0, 1.0000001f, 0.3f), Vec3f(-30, 20, 10)};
  mesh.triangles = {{0, 1, 2}, {0, 2, 3}};
  mesh.corner_uvs = {{Vec2f(0.1f, 0.2f), Vec2f(0.7f, 1.0f / 7.0f), Vec2f(0.9f, 0.95f)},
                     {Vec2f(0.3f, 0.2f), Vec2f(0.9f, 0.95f), Vec2f(0, 1)}};
  mesh.corner_normals = {{Vec3f(0, 0, 1), Vec3f(0.6f, 0, 0.8f), Vec3f(0, 0, 1)},
                         {Vec3f(0, 0, 1), Vec3f(0, 0, 1), Vec3f(0, -1, 0)}};
  ScratchDir dir;
  ASSERT_TRUE(WriteObj(dir / "out.obj", mesh).ok());
  StatusOr<TriangleMesh> loaded = LoadObj(dir / "out.obj");
  ASSERT_TRUE(loaded.ok()) << loaded.status().ToString();
  EXPECT_EQ(loaded->positions, mesh.positions);  // %.9g round-trips floats exactly
  EXPECT_EQ(loaded->triangles, mesh.triangles);
  EXPECT_EQ(loaded->corner_uvs, mesh.corner_uvs);
  for (size_t t = 0; t < mesh.TriangleCount(); ++t) {
    for (int c = 0; c < 3; ++c) {
      EXPECT_TRUE(Near(loaded->corner_normals[t][c], mesh.corner_normals[t][c], kUnitTolerance));
    }
  }
  // No temporary file is left beside the output.
  size_t files = 0;
  for (const auto& entry : std::filesystem::directory_iterator(dir.path())) {
    (void)entry;
    ++files;
  }
  EXPECT_EQ(files, 1u);
}

TEST(LoadMesh, DispatchesOnExtension) {
  ScratchDir dir;
  WriteText(dir / "m.OBJ", std::string(kSquareObj) + "f 1/1 2/2 3/3\n");
  StatusOr<TriangleMesh> mesh = LoadMesh(dir / "m.OBJ");
  ASSERT_TRUE(mesh.ok()) << mesh.status().ToString();
  EXPECT_EQ(mesh->TriangleCount(), 1u);
  StatusOr<TriangleMesh> ply = LoadMesh(dir / "m.ply");
  ASSERT_FALSE(ply.ok());
  EXPECT_EQ(ply.status().code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(ply.status().message().rfind((dir / "m.ply").string() + ": ", 0), 0u);
}

// ---- glTF ---------------------------------------------------------------------------------------

std::string Base64(const std::string& bytes) {
  static const char kAlphabet[] =
      "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  size_t i = 0;
  for (; i + 2 < bytes.size(); i += 3) {
    const uint32_t v =
        (uint8_t(bytes[i]) << 16) | (uint8_t(bytes[i + 1]) << 8) | uint8_t(bytes[i + 2]);
    for (int k = 3; k >= 0; --k) out += kAlphabet[(v >> (6 * k)) & 63];
  }
  if (i + 1 == bytes.size()) {
    const uint32_t v = uint8_t(bytes[i]) << 16;
    out += kAlphabet[(v >> 18) & 63];
    out += kAlphabet[(v >> 12) & 63];
    out += "==";
  } else if (i + 2 == bytes.size()) {
    const uint32_t v = (uint8_t(bytes[i]) << 16) | (uint8_t(bytes[i + 1]) << 8);
    out += kAlphabet[(v >> 18) & 63];
    out += kAlphabet[(v >> 12) & 63];
    out += kAlphabet[(v >> 6) & 63];
    out += '=';
  }
  return out;
}

// Builds one glTF buffer with one tightly packed bufferView per accessor.
class GltfBuilder {
 public:
  int AddFloats(const std::vector<float>& values, const char* type, int components) {
    return Add(values.data(), values.size() * sizeof(float), 5126, values.size() / components,
               type);
  }
  int AddIndices(const std::vector<uint32_t>& indices, int component_type) {
    std::string bytes;
    for (uint32_t i : indices) {
      if (component_type == 5121) bytes += char(uint8_t(i));
      if (component_type == 5123) bytes.append(reinterpret_cast<const char*>(&i), 2);
      if (component_type == 5125) bytes.append(reinterpret_cast<const char*>(&i), 4);
    }
    return Add(bytes.data(), bytes.size(), component_type, indices.size(), "SCALAR");
  }
  // `rest` holds "meshes", "nodes", "scenes"...; `uri` empty for a .glb's BIN chunk.
  std::string Json(const std::string& rest, bool embed) const {
    std::string json = "{\"asset\":{\"version\":\"2.0\"},\"buffers\":[{\"byteLength\":" +
                       std::to_string(bin_.size());
    if (embed) json += ",\"uri\":\"data:application/octet-stream;base64," + Base64(bin_) + "\"";
    json += "}],\"bufferViews\":[" + views_ + "],\"accessors\":[" + accessors_ + "]," + rest + "}";
    return json;
  }
  std::string Glb(const std::string& rest) const {
    std::string json = Json(rest, /*embed=*/false);
    while (json.size() % 4) json += ' ';
    std::string bin = bin_;
    while (bin.size() % 4) bin += '\0';
    std::string out;
    auto u32 = [&](uint32_t v) { out.append(reinterpret_cast<const char*>(&v), 4); };
    out += "glTF";
    u32(2);
    u32(uint32_t(12 + 8 + json.size() + 8 + bin.size()));
    u32(uint32_t(json.size()));
    out += "JSON";
    out += json;
    u32(uint32_t(bin.size()));
    out += std::string("BIN\0", 4);
    out += bin;
    return out;
  }

 private:
  int Add(const void* data, size_t size, int component_type, size_t count, const char* type) {
    while (bin_.size() % 4) bin_ += '\0';
    const size_t offset = bin_.size();
    bin_.append(static_cast<const char*>(data), size);
    if (count_ > 0) {
      views_ += ",";
      accessors_ += ",";
    }
    views_ += "{\"buffer\":0,\"byteOffset\":" + std::to_string(offset) +
              ",\"byteLength\":" + std::to_string(size) + "}";
    accessors_ += "{\"bufferView\":" + std::to_string(count_) +
                  ",\"componentType\":" + std::to_string(component_type) +
                  ",\"count\":" + std::to_string(count) + ",\"type\":\"" + type + "\"}";
    return count_++;
  }
  std::string bin_, views_, accessors_;
  int count_ = 0;
};

// The unit square in z = 0 with glTF UVs (v down): v_gltf = 1 - y.
const std::vector<float> kSquarePositions = {0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0};
const std::vector<float> kSquareGltfUvs = {0, 1, 1, 1, 1, 0, 0, 0};

TEST(LoadGltf, ReadsEmbeddedBufferAppliesNodeTranslationAndFlipsV) {
  GltfBuilder gltf;
  const int pos = gltf.AddFloats(kSquarePositions, "VEC3", 3);
  const int uv = gltf.AddFloats(kSquareGltfUvs, "VEC2", 2);
  const int idx = gltf.AddIndices({0, 1, 2, 0, 2, 3}, 5123);
  const std::string rest =
      "\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":" + std::to_string(pos) +
      ",\"TEXCOORD_0\":" + std::to_string(uv) + "},\"indices\":" + std::to_string(idx) +
      "}]}],\"nodes\":[{\"mesh\":0,\"translation\":[1,2,3]}],\"scenes\":[{\"nodes\":[0]}],"
      "\"scene\":0";
  ScratchDir dir;
  WriteText(dir / "square.gltf", gltf.Json(rest, /*embed=*/true));
  MeshLoadStats stats;
  StatusOr<TriangleMesh> mesh = LoadMesh(dir / "square.gltf", &stats);
  ASSERT_TRUE(mesh.ok()) << mesh.status().ToString();
  ASSERT_EQ(mesh->TriangleCount(), 2u);
  ASSERT_EQ(mesh->positions.size(), 4u);
  EXPECT_TRUE(stats.normals_computed);
  for (size_t i = 0; i < 4; ++i) {
    const Vec3f original(kSquarePositions[3 * i], kSquarePositions[3 * i + 1], 0);
    EXPECT_TRUE(Near(mesh->positions[i], original + Vec3f(1, 2, 3), kCoordinateTolerance));
  }
  for (size_t t = 0; t < 2; ++t) {
    for (int c = 0; c < 3; ++c) {
      const Vec3f& p = mesh->positions[mesh->triangles[t][c]];
      // OBJ convention after the flip: uv = (x, y) of the untransformed square.
      EXPECT_FLOAT_EQ(mesh->corner_uvs[t][c].x(), p.x() - 1.0f);
      EXPECT_FLOAT_EQ(mesh->corner_uvs[t][c].y(), p.y() - 2.0f);
      EXPECT_TRUE(Near(mesh->corner_normals[t][c], Vec3f(0, 0, 1), kUnitTolerance));
    }
    EXPECT_TRUE(Near(mesh->GeometricNormal(t), Vec3f(0, 0, 1), kUnitTolerance));
  }
}

TEST(LoadGltf, ComposesNodeHierarchyAndTransformsNormals) {
  GltfBuilder gltf;
  const int pos = gltf.AddFloats(kSquarePositions, "VEC3", 3);
  const int uv = gltf.AddFloats(kSquareGltfUvs, "VEC2", 2);
  const int nrm = gltf.AddFloats({0, 0, 1, 0, 0, 1, 0, 0, 1, 0, 0, 1}, "VEC3", 3);
  const int idx = gltf.AddIndices({0, 1, 2, 0, 2, 3}, 5125);
  // Parent: rotation of +90 degrees about x and scale 2; child: translation (0, 0, 1).
  const std::string rest =
      "\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":" + std::to_string(pos) +
      ",\"TEXCOORD_0\":" + std::to_string(uv) + ",\"NORMAL\":" + std::to_string(nrm) +
      "},\"indices\":" + std::to_string(idx) +
      "}]}],\"nodes\":[{\"children\":[1],\"rotation\":[0.70710678118654752,0,0,"
      "0.70710678118654752],\"scale\":[2,2,2]},{\"mesh\":0,\"translation\":[0,0,1]}],"
      "\"scenes\":[{\"nodes\":[0]}]";
  ScratchDir dir;
  WriteText(dir / "tree.gltf", gltf.Json(rest, /*embed=*/true));
  MeshLoadStats stats;
  StatusOr<TriangleMesh> mesh = LoadGltf(dir / "tree.gltf", &stats);
  ASSERT_TRUE(mesh.ok()) << mesh.status().ToString();
  EXPECT_FALSE(stats.normals_computed);
  ASSERT_EQ(mesh->positions.size(), 4u);
  for (size_t i = 0; i < 4; ++i) {
    // (x, y, 0) -> scale 2 of (x, y, 1) -> rotated: (2x, -2, 2y).
    const float x = kSquarePositions[3 * i], y = kSquarePositions[3 * i + 1];
    EXPECT_TRUE(Near(mesh->positions[i], Vec3f(2 * x, -2, 2 * y), kCoordinateTolerance));
  }
  for (size_t t = 0; t < mesh->TriangleCount(); ++t) {
    EXPECT_TRUE(Near(mesh->GeometricNormal(t), Vec3f(0, -1, 0), kUnitTolerance));
    for (int c = 0; c < 3; ++c) {
      EXPECT_TRUE(Near(mesh->corner_normals[t][c], Vec3f(0, -1, 0), kUnitTolerance));
    }
  }
}

TEST(LoadGltf, MirroringNodeKeepsWindingConsistentWithNormals) {
  GltfBuilder gltf;
  const int pos = gltf.AddFloats(kSquarePositions, "VEC3", 3);
  const int uv = gltf.AddFloats(kSquareGltfUvs, "VEC2", 2);
  const int nrm = gltf.AddFloats({0, 0, 1, 0, 0, 1, 0, 0, 1, 0, 0, 1}, "VEC3", 3);
  const int idx = gltf.AddIndices({0, 1, 2, 0, 2, 3}, 5123);
  const std::string rest =
      "\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":" + std::to_string(pos) +
      ",\"TEXCOORD_0\":" + std::to_string(uv) + ",\"NORMAL\":" + std::to_string(nrm) +
      "},\"indices\":" + std::to_string(idx) +
      "}]}],\"nodes\":[{\"mesh\":0,\"scale\":[-1,1,1]}],\"scenes\":[{\"nodes\":[0]}]";
  ScratchDir dir;
  WriteText(dir / "mirror.gltf", gltf.Json(rest, /*embed=*/true));
  StatusOr<TriangleMesh> mesh = LoadGltf(dir / "mirror.gltf");
  ASSERT_TRUE(mesh.ok()) << mesh.status().ToString();
  for (size_t t = 0; t < mesh->TriangleCount(); ++t) {
    EXPECT_TRUE(Near(mesh->GeometricNormal(t), Vec3f(0, 0, 1), kUnitTolerance));
    EXPECT_TRUE(Near(mesh->corner_normals[t][0], Vec3f(0, 0, 1), kUnitTolerance));
  }
}

TEST(LoadGltf, ReadsU8AndU32IndicesAndUnindexedPrimitivesIgnoringLines) {
  GltfBuilder gltf;
  const int pos = gltf.AddFloats(kSquarePositions, "VEC3", 3);
  const int uv = gltf.AddFloats(kSquareGltfUvs, "VEC2", 2);
  const int idx8 = gltf.AddIndices({0, 1, 2, 0, 2, 3}, 5121);
  const int idx32 = gltf.AddIndices({0, 1, 2}, 5125);
  const int soup_pos = gltf.AddFloats({0, 0, 1, 1, 0, 1, 1, 1, 1}, "VEC3", 3);
  const int soup_uv = gltf.AddFloats({0, 1, 1, 1, 1, 0}, "VEC2", 2);
  auto attrs = [](int p, int u) {
    return "\"attributes\":{\"POSITION\":" + std::to_string(p) +
           ",\"TEXCOORD_0\":" + std::to_string(u) + "}";
  };
  const std::string rest = "\"meshes\":[{\"primitives\":[{" + attrs(pos, uv) +
                           ",\"indices\":" + std::to_string(idx8) + "},{" + attrs(pos, uv) +
                           ",\"indices\":" + std::to_string(idx32) + "},{" +
                           attrs(soup_pos, soup_uv) + "},{" + attrs(pos, uv) + ",\"mode\":1}]}]," +
                           "\"nodes\":[{\"mesh\":0}],\"scenes\":[{\"nodes\":[0]}]";
  ScratchDir dir;
  WriteText(dir / "kinds.gltf", gltf.Json(rest, /*embed=*/true));
  MeshLoadStats stats;
  StatusOr<TriangleMesh> mesh = LoadGltf(dir / "kinds.gltf", &stats);
  ASSERT_TRUE(mesh.ok()) << mesh.status().ToString();
  EXPECT_EQ(mesh->TriangleCount(), 2u + 1u + 1u);
  EXPECT_EQ(stats.faces_read, 4u);
  // Each primitive has its own copy of its vertices; the u32 one leaves vertex 3 unreferenced.
  EXPECT_EQ(mesh->positions.size(), 4u + 3u + 3u);
  EXPECT_EQ(mesh->positions[mesh->triangles[3][2]], Vec3f(1, 1, 1));
  EXPECT_EQ(mesh->corner_uvs[3][2], Vec2f(1, 1));
}

TEST(LoadGltf, ReadsBinaryGlb) {
  GltfBuilder gltf;
  const int pos = gltf.AddFloats(kSquarePositions, "VEC3", 3);
  const int uv = gltf.AddFloats(kSquareGltfUvs, "VEC2", 2);
  const int idx = gltf.AddIndices({0, 1, 2, 0, 2, 3}, 5123);
  const std::string rest =
      "\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":" + std::to_string(pos) +
      ",\"TEXCOORD_0\":" + std::to_string(uv) + "},\"indices\":" + std::to_string(idx) +
      "}]}],\"nodes\":[{\"mesh\":0,\"translation\":[0,0,-1]}],\"scenes\":[{\"nodes\":[0]}]";
  ScratchDir dir;
  WriteText(dir / "square.glb", gltf.Glb(rest));
  StatusOr<TriangleMesh> mesh = LoadMesh(dir / "square.glb");
  ASSERT_TRUE(mesh.ok()) << mesh.status().ToString();
  ASSERT_EQ(mesh->TriangleCount(), 2u);
  EXPECT_TRUE(Near(mesh->positions[2], Vec3f(1, 1, -1), kCoordinateTolerance));
  EXPECT_EQ(mesh->corner_uvs[0][2], Vec2f(1, 1));
}

TEST(LoadGltf, RejectsPrimitivesWithoutTexcoords) {
  GltfBuilder gltf;
  const int pos = gltf.AddFloats(kSquarePositions, "VEC3", 3);
  const std::string rest =
      "\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":" + std::to_string(pos) +
      "}}]}],\"nodes\":[{\"mesh\":0}],\"scenes\":[{\"nodes\":[0]}]";
  ScratchDir dir;
  const auto path = dir / "no_uv.gltf";
  WriteText(path, gltf.Json(rest, /*embed=*/true));
  StatusOr<TriangleMesh> mesh = LoadGltf(path);
  ASSERT_FALSE(mesh.ok());
  EXPECT_EQ(mesh.status().code(), StatusCode::kFailedPrecondition);
  EXPECT_EQ(mesh.status().message(),
            path.string() + ": mesh has no UV coordinates (texel atlas needs them)");
}

TEST(LoadGltf, ParseErrorsNameTheFile) {
  ScratchDir dir;
  const auto path = dir / "broken.gltf";
  WriteText(path, "{ \"asset\": { \"version\": \"2.0\" }, \"meshes\": [ ");
  StatusOr<TriangleMesh> mesh = LoadGltf(path);
  ASSERT_FALSE(mesh.ok());
  EXPECT_EQ(mesh.status().code(), StatusCode::kDataLoss);
  EXPECT_EQ(mesh.status().message().rfind(path.string() + ": ", 0), 0u) << mesh.status().message();

  // An accessor that reaches past its buffer is caught by our bounds checks.
  GltfBuilder gltf;
  const int pos = gltf.AddFloats(kSquarePositions, "VEC3", 3);
  const int uv = gltf.AddFloats(kSquareGltfUvs, "VEC2", 2);
  const int idx = gltf.AddIndices({0, 1, 7}, 5123);
  const std::string rest =
      "\"meshes\":[{\"primitives\":[{\"attributes\":{\"POSITION\":" + std::to_string(pos) +
      ",\"TEXCOORD_0\":" + std::to_string(uv) + "},\"indices\":" + std::to_string(idx) +
      "}]}],\"nodes\":[{\"mesh\":0}],\"scenes\":[{\"nodes\":[0]}]";
  WriteText(path, gltf.Json(rest, /*embed=*/true));
  mesh = LoadGltf(path);
  ASSERT_FALSE(mesh.ok());
  EXPECT_EQ(mesh.status().code(), StatusCode::kDataLoss);
  EXPECT_NE(mesh.status().message().find("index 7 out of range (4 vertices)"), std::string::npos)
      << mesh.status().message();
}


// A malformed GLB (found by the gltf fuzzer: tests/fuzz/corpus/gltf/
// regress_tinygltf_throws_out_of_range.glb) on which tinygltf throws std::out_of_range from
// inside its parser: refused as DataLoss naming the file, not an abort.
TEST(LoadGltf, AParserExceptionIsDataLossNotAnAbort) {
  static const unsigned char kGlb[] = {
    0x67, 0x6c, 0x54, 0x46, 0x02, 0x00, 0x00, 0x00, 0xc0, 0x02, 0x00, 0x00, 0x60, 0x02, 0x00, 0x00,
    0x4a, 0x53, 0x4f, 0x4e, 0x7b, 0x22, 0x61, 0x73, 0x73, 0x65, 0x74, 0x22, 0x3a, 0x7b, 0x22, 0x76,
    0x65, 0x72, 0x73, 0x69, 0x6f, 0x6e, 0x22, 0x3a, 0x22, 0x32, 0x2e, 0x30, 0x22, 0x7d, 0x2c, 0x22,
    0x73, 0x63, 0x65, 0x6e, 0x65, 0x22, 0x3a, 0x30, 0x2c, 0x22, 0x73, 0x63, 0x65, 0x6e, 0x65, 0x73,
    0x22, 0x3a, 0x5b, 0x7b, 0x22, 0x6e, 0x6f, 0x64, 0x65, 0x73, 0x22, 0x3a, 0x5b, 0x30, 0x5d, 0x7d,
    0x5d, 0x2c, 0x22, 0x6e, 0x6f, 0x64, 0x65, 0x73, 0x22, 0x3a, 0x5b, 0x7b, 0x22, 0x6d, 0x65, 0x73,
    0x68, 0x22, 0x3a, 0x30, 0x2c, 0x22, 0x74, 0x72, 0x61, 0x6e, 0x73, 0x6c, 0x61, 0x74, 0x69, 0x6f,
    0x6e, 0x22, 0x3a, 0x5b, 0x30, 0x2c, 0x30, 0x2c, 0x31, 0x5d, 0x7d, 0x5d, 0x2c, 0x22, 0x6d, 0x65,
    0x73, 0x68, 0x65, 0x73, 0x22, 0x3a, 0x5b, 0x7b, 0x22, 0x70, 0x72, 0x69, 0x6d, 0x69, 0x74, 0x69,
    0x76, 0x65, 0x73, 0x22, 0x3a, 0x5b, 0x7b, 0x22, 0x61, 0x74, 0x74, 0x72, 0x69, 0x62, 0x75, 0x74,
    0x65, 0x73, 0x22, 0x3a, 0x7b, 0x22, 0x50, 0x4f, 0x53, 0x49, 0x54, 0x49, 0x4f, 0x4e, 0x22, 0x3a,
    0x30, 0x2c, 0x22, 0x54, 0x45, 0x58, 0x43, 0x4f, 0x4f, 0x52, 0x44, 0x5f, 0x30, 0x22, 0x3a, 0x31,
    0x7d, 0x2c, 0x22, 0x69, 0x6e, 0x64, 0x69, 0x63, 0x65, 0x73, 0x22, 0x3a, 0x32, 0x2c, 0x22, 0x6d,
    0x6f, 0x64, 0x65, 0x22, 0x3a, 0x34, 0x7d, 0x5d, 0x7d, 0x5d, 0x2c, 0x22, 0x62, 0x75, 0x66, 0x66,
    0x65, 0x72, 0x73, 0x22, 0x3a, 0x5b, 0x7b, 0x22, 0x62, 0x66, 0x66, 0x65, 0x72, 0x22, 0x3a, 0x30,
    0x2c, 0x22, 0x62, 0x79, 0x74, 0x65, 0x4f, 0x66, 0x66, 0x73, 0x65, 0x74, 0x22, 0x3a, 0x30, 0x2c,
    0x22, 0x62, 0x79, 0x74, 0x65, 0x4c, 0x65, 0x6e, 0x67, 0x74, 0x68, 0x22, 0x3a, 0x33, 0x36, 0x7d,
    0x2c, 0x7b, 0x22, 0x62, 0x75, 0x66, 0x65, 0x74, 0x22, 0x3a, 0x36, 0x30, 0x2c, 0x22, 0x62, 0x79,
    0x74, 0x65, 0x4c, 0x65, 0x6e, 0x67, 0x74, 0x68, 0x22, 0x3a, 0x30, 0x7d, 0x5d, 0x2c, 0x22, 0x61,
    0x63, 0x63, 0x65, 0x73, 0x73, 0x6f, 0x72, 0x73, 0x22, 0x3a, 0x5b, 0x7b, 0x22, 0x62, 0x75, 0x66,
    0x66, 0x65, 0x72, 0x56, 0x69, 0x65, 0x77, 0x22, 0x3a, 0x30, 0x2c, 0x22, 0x63, 0x6f, 0x6d, 0x70,
    0x6f, 0x6e, 0x65, 0x6e, 0x74, 0x54, 0x79, 0x70, 0x65, 0x22, 0x3a, 0x35, 0x31, 0x32, 0x35, 0x2c,
    0x22, 0x63, 0x6f, 0x75, 0x6e, 0x62, 0x79, 0x74, 0x65, 0x4c, 0x65, 0x6e, 0x67, 0x74, 0x68, 0x22,
    0x3a, 0x32, 0x34, 0x7d, 0x2c, 0x7b, 0x22, 0x62, 0x75, 0x66, 0x66, 0x65, 0x72, 0x22, 0x3a, 0x30,
    0x2c, 0x22, 0x62, 0x66, 0x73, 0x65, 0x74, 0x22, 0x3a, 0x33, 0x36, 0x2c, 0x22, 0x62, 0x79, 0x74,
    0x65, 0x4c, 0x65, 0x6e, 0x67, 0x74, 0x68, 0x22, 0x3a, 0x32, 0x34, 0x7d, 0x2c, 0x7b, 0x22, 0x62,
    0x75, 0x66, 0x66, 0x65, 0x72, 0x22, 0x3a, 0x30, 0x2c, 0x22, 0x62, 0x79, 0x74, 0x65, 0x4f, 0x66,
    0x66, 0x73, 0x65, 0x74, 0x22, 0x3a, 0x36, 0x30, 0x2c, 0x22, 0x62, 0x79, 0x74, 0x65, 0x4c, 0x65,
    0x6e, 0x67, 0x74, 0x68, 0x22, 0x3a, 0x36, 0x7d, 0x5d, 0x2c, 0x22, 0x61, 0x63, 0x63, 0x65, 0x73,
    0x73, 0x6f, 0x72, 0x73, 0x22, 0x3a, 0x5b, 0x7b, 0x22, 0x62, 0x75, 0x66, 0x66, 0x65, 0x72, 0x56,
    0x69, 0x65, 0x77, 0x22, 0x3a, 0x30, 0x2c, 0x22, 0x63, 0x6f, 0x6d, 0x70, 0x6f, 0x6e, 0x65, 0x6e,
    0x74, 0x54, 0x79, 0x70, 0x65, 0x22, 0x3a, 0x35, 0x31, 0x32, 0x35, 0x2c, 0x22, 0x63, 0x6f, 0x75,
    0x6e, 0x74, 0x22, 0x3a, 0x33, 0x2c, 0x22, 0x74, 0x79, 0x70, 0x65, 0x22, 0x3a, 0x22, 0x56, 0x45,
    0x43, 0x33, 0x22, 0x2c, 0x22, 0x6d, 0x69, 0x6e, 0x22, 0x3a, 0x5b, 0x30, 0x2c, 0x30, 0x2c, 0x30,
    0x5d, 0x2c, 0x22, 0x6d, 0x61, 0x78, 0x22, 0x3a, 0x5b, 0x31, 0x2c, 0x31, 0x2c, 0x30, 0x5d, 0x7d,
    0x2c, 0x7b, 0x22, 0x62, 0x75, 0x66, 0x66, 0x65, 0x72, 0x56, 0x69, 0x65, 0x77, 0x22, 0x3a, 0x31,
    0x2c, 0x22, 0x63, 0x6f, 0x6d, 0x70, 0x6f, 0x6e, 0x65, 0x6e, 0x74, 0x54, 0x79, 0x70, 0x65, 0x70,
    0x65, 0x22, 0x3a, 0x35, 0x31, 0x32, 0x33, 0x2c, 0x22, 0x63, 0x6f, 0x75, 0x6e, 0x74, 0x22, 0x3a,
    0x33, 0x2c, 0x22, 0x74, 0x79, 0x70, 0x65, 0x22, 0x3a, 0x22, 0x53, 0x43, 0x41, 0x4c, 0x41, 0x52,
    0x22, 0x7d, 0x5d, 0x7d, 0x44, 0x00, 0x00, 0x00, 0x42, 0x49, 0x4e, 0x00, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0xff, 0xff, 0xff, 0xfa, 0x00, 0x00, 0x00, 0x00, 0x80, 0x3f, 0x7e, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x80, 0x3f, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x2d, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x80, 0x3f, 0x00, 0x00, 0x00, 0x00,
    0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x80, 0x3f, 0x00, 0x00, 0x01, 0x00, 0x02, 0x00, 0x00, 0x00,
  };
  testing::ScratchDir dir;
  testing::WriteText(dir / "bad.glb", std::string(reinterpret_cast<const char*>(kGlb), sizeof kGlb));
  auto mesh = LoadMesh(dir / "bad.glb");
  ASSERT_FALSE(mesh.ok());
  EXPECT_EQ(mesh.status().code(), StatusCode::kDataLoss);
  EXPECT_NE(mesh.status().message().find("bad.glb"), std::string::npos) << mesh.status().message();
}

}  // namespace
}  // namespace reflcap
