#pragma once
// TriangleMesh: an indexed triangle mesh in the object frame (metres) with per-corner UVs and
// per-corner shading normals. Positions are shared (Embree needs one vertex buffer); UVs and
// normals are per corner because OBJ/glTF seams split them. Loaders guarantee: every triangle has
// three distinct, finite vertices of non-zero area (degenerate faces are dropped and counted).
#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "engine/math/types.h"

namespace reflcap {

struct TriangleMesh {
  std::vector<Vec3f> positions;                      // object frame, metres
  std::vector<std::array<uint32_t, 3>> triangles;    // indices into positions, counter-clockwise
  std::vector<std::array<Vec2f, 3>> corner_uvs;      // one per triangle corner; OBJ convention:
                                                     // v = 0 is the bottom of the texture
  std::vector<std::array<Vec3f, 3>> corner_normals;  // unit shading normals per corner

  size_t TriangleCount() const { return triangles.size(); }
  // Unit geometric normal of triangle t (right-hand rule over its corners).
  Vec3f GeometricNormal(size_t t) const {
    const auto& tri = triangles[t];
    return (positions[tri[1]] - positions[tri[0]])
        .cross(positions[tri[2]] - positions[tri[0]])
        .normalized();
  }
  // Axis-aligned bounds of the positions.
  Eigen::AlignedBox3f Bounds() const {
    Eigen::AlignedBox3f box;
    for (const auto& p : positions) box.extend(p);
    return box;
  }
};

}  // namespace reflcap
