#pragma once
// Mesh loading: Wavefront OBJ (v/vt/vn, polygons fan-triangulated) and glTF 2.0 (.gltf/.glb via
// tinygltf). A mesh without UVs is rejected (FailedPrecondition, "has no UV coordinates").
// Missing normals are computed (area-weighted, smooth across shared positions). Zero-area and
// degenerate faces are skipped; `stats` (optional) receives the counts, and a warning is logged.
// Every error message starts with the file path (OBJ syntax errors with "path:line: ").
#include <filesystem>

#include "engine/core/status.h"
#include "engine/mesh/mesh.h"

namespace reflcap {

struct MeshLoadStats {
  size_t faces_read = 0;          // triangles read (after fan triangulation of OBJ polygons)
  size_t triangles_kept = 0;      // = faces_read - degenerate_skipped
  size_t degenerate_skipped = 0;  // zero area, repeated vertex, or non-finite coordinates
  bool normals_computed = false;  // some corners had no normal and got the smooth one
};

// Dispatches on the extension (case-insensitive): .obj, .gltf, .glb; else InvalidArgument.
StatusOr<TriangleMesh> LoadMesh(const std::filesystem::path& path, MeshLoadStats* stats = nullptr);

// OBJ: v, vt, vn and f (v, v/vt, v//vn, v/vt/vn; negative indices count back from the last
// element read so far); other statements are ignored. Errors: NotFound (no file), DataLoss
// ("path:line: ..." for malformed numbers, faces and out-of-range indices), FailedPrecondition
// (faces without vt), InvalidArgument (no triangle left). Positions keep their file order, minus
// the ones no kept triangle uses.
StatusOr<TriangleMesh> LoadObj(const std::filesystem::path& path, MeshLoadStats* stats = nullptr);

// glTF 2.0 (.gltf with embedded or external buffers, or .glb; told apart by the "glTF" magic):
// every TRIANGLES primitive reachable from the default scene (or scene 0, or all root nodes when
// there is no scene), with node world matrices applied (normals by the inverse transpose, winding
// kept counter-clockwise under mirroring) and v flipped to the OBJ convention (v = 1 - v_gltf).
// Other primitive modes are ignored with a warning. Errors: NotFound, DataLoss (tinygltf's error,
// bad accessors or indices), InvalidArgument (sparse accessors, no triangle left),
// FailedPrecondition (a primitive without TEXCOORD_0).
StatusOr<TriangleMesh> LoadGltf(const std::filesystem::path& path, MeshLoadStats* stats = nullptr);

// Writes OBJ with v/vt/vn (per-corner uv and normal; exact repeats around a vertex written once),
// numbers with 9 significant digits (floats round-trip exactly), atomically. InvalidArgument
// when the per-corner arrays do not match the triangles or an index is out of range.
Status WriteObj(const std::filesystem::path& path, const TriangleMesh& mesh);

}  // namespace reflcap
