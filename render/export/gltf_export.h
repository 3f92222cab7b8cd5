#pragma once
// glTF 2.0 export of a fit (`reflcap export FIT --gltf OUT.glb`): one binary .glb holding the
// capture's mesh, a core metallic-roughness material approximating every texel's BRDF
// (metal_rough.h), and the raw Lambert + Lafortune parameters in the material extension
// REFLCAP_lafortune (schema: README.md, "reflcap export"); beside it OUT.lafortune.exr, the same
// parameters as a parameter-map EXR (a valid FIT params.exr) plus the per-texel approximation
// error channel `gltf.error`.
//
// GLB layout: positions (object frame, metres), NORMAL (unit shading normals), TANGENT (xyz: the
// tangent reflcap's atlas uses, dP/du accumulated over the corners sharing a position and UV,
// made orthogonal to the normal; w = +1: bitangent = normal × tangent, reflcap's right-handed
// frame), TEXCOORD_0 (u, 1 - v: glTF's v points down the image), uint32 indices; a vertex per
// distinct (position, UV, normal). Textures at the atlas size, NEAREST-sampled (one texel, one
// BRDF): baseColor (sRGB PNG), metallicRoughness (linear PNG: G roughness, B metallic). The node
// turns the capture's turntable axis (when it has one) to glTF's +Y up.
#include <cstdint>
#include <filesystem>
#include <string>

#include "engine/core/status.h"
#include "render/reference/render_capture.h"

namespace reflcap::render {

struct GltfExportOptions {
  // Largest atlas side written, pixels; larger atlases are refused (InvalidArgument naming
  // params.exr). 16384 is the largest MAX_TEXTURE_SIZE WebGL devices report; glTF itself has no
  // limit. Range [1, 65536].
  int max_texture_size = 16384;
  // Also write OUT.lafortune.exr beside the .glb.
  bool write_exr = true;
  // Replace existing output files (else an existing OUT.glb or its EXR is refused).
  bool overwrite = false;
  // Worker threads for the per-texel approximation (0: all).
  int threads = 0;
  Status Validate() const;
};

// Percentiles, mean and RMS over texels of the per-texel relative RMS error e of the
// metallic-roughness approximation (metal_rough.h).
struct ApproximationError {
  double median = 0, p90 = 0, p99 = 0, max = 0, mean = 0, rms = 0;
  size_t metallic_texels = 0;  // texels the fit called metallic (m > 0)
};

struct GltfExportSummary {
  size_t texels = 0, vertices = 0, triangles = 0;
  int width = 0, height = 0, num_lobes = 0;
  uint64_t glb_bytes = 0, exr_bytes = 0;
  std::filesystem::path glb, exr;
  ApproximationError error;
  double approximate_s = 0, write_s = 0;
};

// OUT.glb -> OUT.lafortune.exr (the name of the EXR beside a .glb).
std::filesystem::path LafortuneExrPathFor(const std::filesystem::path& glb);

// Writes `glb` (and its EXR) for a mesh capture's fit. Both files are written under temporary
// names and renamed only when both are complete; after an error neither exists (nor is an older
// one touched). InvalidArgument: a mesh without triangles, an atlas side above
// max_texture_size, a .glb over 4 GiB (GLB lengths are 32-bit); FailedPrecondition: the output
// exists (without overwrite) or `fitted` is a normal-map capture; Internal: write errors.
StatusOr<GltfExportSummary> ExportGltf(const FittedCapture& fitted,
                                       const std::filesystem::path& params_exr,
                                       const std::filesystem::path& glb,
                                       const GltfExportOptions& options);

}  // namespace reflcap::render
