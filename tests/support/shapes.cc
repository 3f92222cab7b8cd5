#include "tests/support/shapes.h"

#include <cmath>

namespace reflcap::testing {

TriangleMesh MakeGridPlane(float sx, float sy, int nx, int ny, float z) {
  TriangleMesh mesh;
  for (int j = 0; j <= ny; ++j) {
    for (int i = 0; i <= nx; ++i) {
      mesh.positions.emplace_back(sx * (float(i) / nx - 0.5f), sy * (float(j) / ny - 0.5f), z);
    }
  }
  auto id = [&](int i, int j) { return uint32_t(j * (nx + 1) + i); };
  auto uv = [&](int i, int j) { return Vec2f(float(i) / nx, float(j) / ny); };
  const Vec3f up = Vec3f::UnitZ();
  for (int j = 0; j < ny; ++j) {
    for (int i = 0; i < nx; ++i) {
      mesh.triangles.push_back({id(i, j), id(i + 1, j), id(i + 1, j + 1)});
      mesh.corner_uvs.push_back({uv(i, j), uv(i + 1, j), uv(i + 1, j + 1)});
      mesh.triangles.push_back({id(i, j), id(i + 1, j + 1), id(i, j + 1)});
      mesh.corner_uvs.push_back({uv(i, j), uv(i + 1, j + 1), uv(i, j + 1)});
      mesh.corner_normals.push_back({up, up, up});
      mesh.corner_normals.push_back({up, up, up});
    }
  }
  return mesh;
}

TriangleMesh MakeUvSphere(float radius, int segments, int rings, const Vec3f& center) {
  TriangleMesh mesh;
  const double kTwoPi = 2 * kPi;
  // Grid of (segments + 1) x (rings + 1) vertices; the pole rows are kept (one per segment) so
  // every triangle has its own UV at the pole.
  auto dir = [&](int i, int j) {
    const double phi = kTwoPi * i / segments, theta = kPi * j / rings;
    return Vec3d(std::sin(theta) * std::cos(phi), std::sin(theta) * std::sin(phi), std::cos(theta));
  };
  for (int j = 0; j <= rings; ++j) {
    for (int i = 0; i <= segments; ++i) {
      mesh.positions.push_back(center + (radius * dir(i, j)).cast<float>());
    }
  }
  auto id = [&](int i, int j) { return uint32_t(j * (segments + 1) + i); };
  auto uv = [&](int i, int j) { return Vec2f(float(i) / segments, 1.0f - float(j) / rings); };
  auto nrm = [&](int i, int j) -> Vec3f { return dir(i, j).cast<float>(); };
  for (int j = 0; j < rings; ++j) {
    for (int i = 0; i < segments; ++i) {
      // Quad (i,j)-(i+1,j+1), counter-clockwise seen from outside; skip the collapsed pole edge.
      if (j > 0) {
        mesh.triangles.push_back({id(i, j), id(i, j + 1), id(i + 1, j)});
        mesh.corner_uvs.push_back({uv(i, j), uv(i, j + 1), uv(i + 1, j)});
        mesh.corner_normals.push_back({nrm(i, j), nrm(i, j + 1), nrm(i + 1, j)});
      }
      if (j < rings - 1) {
        mesh.triangles.push_back({id(i + 1, j), id(i, j + 1), id(i + 1, j + 1)});
        mesh.corner_uvs.push_back({uv(i + 1, j), uv(i, j + 1), uv(i + 1, j + 1)});
        mesh.corner_normals.push_back({nrm(i + 1, j), nrm(i, j + 1), nrm(i + 1, j + 1)});
      }
    }
  }
  return mesh;
}

void AppendMesh(const TriangleMesh& b, TriangleMesh* a) {
  const uint32_t base = uint32_t(a->positions.size());
  a->positions.insert(a->positions.end(), b.positions.begin(), b.positions.end());
  for (auto tri : b.triangles) a->triangles.push_back({tri[0] + base, tri[1] + base, tri[2] + base});
  a->corner_uvs.insert(a->corner_uvs.end(), b.corner_uvs.begin(), b.corner_uvs.end());
  a->corner_normals.insert(a->corner_normals.end(), b.corner_normals.begin(),
                           b.corner_normals.end());
}

}  // namespace reflcap::testing
