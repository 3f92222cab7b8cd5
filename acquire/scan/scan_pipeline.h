#pragma once
// `reflcap scan`: structured-light photographs -> one textured-ready mesh (the seed paper's
// section 3.4.1). Per turntable angle: load the photographs, decode (decode.h), triangulate
// (triangulate.h); then register the views (merge.h, turntable pose, optional ICP), reconstruct
// the surface (screened Poisson, trimmed, decimated, projected onto the points), unwrap it
// (uv_atlas.h), check that reflcap's texel atlas builds on it, and write:
//   mesh.obj, mesh.gltf        the mesh in the object frame (= world at turntable 0), with UVs
//   points_AAA.ply             per-angle clouds: position, normal, confidence, sigma (object frame)
//   decode_AAA.png             per-pixel outcome (decoded grey by confidence, colours = reasons)
//   preview.png, atlas.png     a shaded render from the scan camera, the UV layout
//   scan_report.json           counts, coverage, residuals, surface and atlas stats, distances
//                              to the reference mesh, timings
//   capture.json (--capture)   a copy of a capture/1 whose mesh is this scan, with links to the
//                              capture's images/, masks/ ... so its relative paths still resolve
#include <filesystem>
#include <optional>
#include <string>

#include "acquire/scan/decode.h"
#include "acquire/scan/merge.h"
#include "acquire/scan/scan_spec.h"
#include "acquire/scan/triangulate.h"
#include "acquire/scan/uv_atlas.h"
#include "engine/core/status.h"

namespace reflcap::scan {

struct ScanOptions {
  DecodeOptions decode;
  TriangulateOptions triangulate;
  MergeOptions merge;
  UvAtlasOptions atlas;
  // Reference mesh for the distance report: empty = scan.json's "mesh" when present; "none" =
  // no comparison.
  std::string reference;
  // A capture/1 (folder or capture.json) whose mesh the scan replaces: capture.json is written
  // beside the mesh with "mesh": "mesh.obj", and every other entry of the capture's folder
  // (images/, masks/, ...) is linked (symbolic link) into the output so the capture's relative
  // paths resolve unchanged. Its turntable must equal the scan's (else the object frames differ:
  // InvalidArgument), and its image paths must stay inside its folder.
  std::string capture;
  bool write_clouds = true;  // points_AAA.ply
  // Samples for the distance statistics (accuracy and completeness each). >= 1000.
  int64_t distance_samples = 200000;
  Status Validate() const;
};

struct ScanSummary {
  int64_t points = 0;
  int64_t triangles = 0;
  double coverage = 0;              // decoded / lit pixels over all angles
  double area_use = 0, texel_use = 0;
  int64_t uv_overlap_pixels = 0;
  bool has_reference = false;
  double accuracy_median_m = 0, accuracy_p95_m = 0;
  double completeness_p95_m = 0, completeness_over_1mm = 0;
  double seconds = 0;
};

// Runs the whole scan and writes into `out_dir` (an existing, empty staging folder: the caller
// commits it). Errors: those of the inputs (named by file and field), FailedPrecondition when an
// angle decodes nothing ("projector lights nothing") or no surface can be built.
StatusOr<ScanSummary> RunScanPipeline(const ScanSpec& spec, const std::filesystem::path& out_dir,
                                      const ScanOptions& options);

// Writes `mesh` as glTF 2.0 (one buffer embedded as a data URI; POSITION, NORMAL, TEXCOORD_0 with
// v flipped to glTF's top-left origin), atomically.
Status WriteGltf(const std::filesystem::path& path, const TriangleMesh& mesh);

}  // namespace reflcap::scan
