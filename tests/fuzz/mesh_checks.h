#pragma once
// The invariants every successfully loaded TriangleMesh must satisfy, for the mesh fuzz targets:
// per-corner arrays as long as the triangle list, indices in range, every number finite (the
// loaders drop triangles with non-finite coordinates) and at least one triangle.
#include <cmath>

#include "engine/mesh/mesh.h"
#include "tests/fuzz/fuzz_util.h"

namespace reflcap::fuzz {

inline void CheckMesh(const TriangleMesh& mesh) {
  FUZZ_CHECK(mesh.TriangleCount() > 0);
  FUZZ_CHECK(mesh.corner_uvs.size() == mesh.triangles.size());
  FUZZ_CHECK(mesh.corner_normals.size() == mesh.triangles.size());
  for (const auto& p : mesh.positions) FUZZ_CHECK(p.allFinite());
  for (size_t t = 0; t < mesh.triangles.size(); ++t) {
    for (int c = 0; c < 3; ++c) {
      FUZZ_CHECK(mesh.triangles[t][c] < mesh.positions.size());
      FUZZ_CHECK(mesh.corner_uvs[t][c].allFinite());
      FUZZ_CHECK(mesh.corner_normals[t][c].allFinite());
    }
  }
}

}  // namespace reflcap::fuzz
