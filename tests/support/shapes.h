#pragma once
// Procedural meshes for tests: an axis-aligned grid plane and a UV sphere, with UVs and exact
// analytic normals at the vertices.
#include "engine/mesh/mesh.h"

namespace reflcap::testing {

// Plane z = `z` spanning [-sx/2, sx/2] x [-sy/2, sy/2], nx x ny quads, normal +z,
// uv = ((x + sx/2)/sx, (y + sy/2)/sy).
TriangleMesh MakeGridPlane(float sx, float sy, int nx, int ny, float z = 0);

// Sphere of `radius` about `center`: `segments` around (φ), `rings` from pole to pole (θ);
// triangle fans at the poles; uv = (φ / 2π, 1 - θ / π).
TriangleMesh MakeUvSphere(float radius, int segments, int rings, const Vec3f& center = Vec3f::Zero());

// Appends `b` to `a` (indices shifted).
void AppendMesh(const TriangleMesh& b, TriangleMesh* a);

}  // namespace reflcap::testing
