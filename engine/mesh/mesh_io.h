#pragma once
// Mesh loading: Wavefront OBJ (v/vt/vn, polygons fan-triangulated) and glTF 2.0 (.gltf/.glb via
// tinygltf). A mesh without UVs is rejected (FailedPrecondition, "has no UV coordinates").
// Missing normals are computed (area-weighted, smooth across shared positions). Zero-area and
// degenerate faces are skipped; `stats` (optional) receives the counts, and a warning is logged.
#include <filesystem>

#include "engine/core/status.h"
#include "engine/mesh/mesh.h"

namespace reflcap {

struct MeshLoadStats {
  size_t faces_read = 0;
  size_t triangles_kept = 0;
  size_t degenerate_skipped = 0;  // zero area, repeated vertex, or non-finite coordinates
  bool normals_computed = false;
};

StatusOr<TriangleMesh> LoadMesh(const std::filesystem::path& path, MeshLoadStats* stats = nullptr);
StatusOr<TriangleMesh> LoadObj(const std::filesystem::path& path, MeshLoadStats* stats = nullptr);
StatusOr<TriangleMesh> LoadGltf(const std::filesystem::path& path, MeshLoadStats* stats = nullptr);

// Writes OBJ with v/vt/vn (per-corner uv and normal), atomically.
Status WriteObj(const std::filesystem::path& path, const TriangleMesh& mesh);

}  // namespace reflcap
