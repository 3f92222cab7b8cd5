#pragma once
// The relightable viewer page of `reflcap view FIT --out DIR`: one self-contained HTML file
// (DIR/index.html: three.js, bundled into reflcap at build time from render/viewer/node_modules,
// the page script render/viewer/viewer.js and the data, all inline; no network, opens from
// file://) that shades the fit's mesh with the Lambert + Lafortune BRDF per texel in WebGL2, and
// DIR/views.json describing the held-out views it carries.
//
// Data in the page: the mesh as triangle corners (object-frame positions, shading normals, UVs);
// the parameter maps and the texel tangents as float RGBA textures in atlas layout (rho_d + a
// texel flag; per lobe Cx, Cy, Cz, n); per held-out view the camera (intrinsics, cam_from_object
// = cam_from_world · world_from_object at the photograph's turntable angle), the light in the
// object frame, the exposure, a display scale (1 / the photograph's 99th percentile over its
// non-zero values, so display = sRGB(clamp(pixel · scale))) and the photograph tone-mapped the
// same way as a PNG. `index.html?test=K` shows only the re-render of view K at its camera's
// pixel size in the top-left corner (for screenshots).
#include <cstdint>
#include <filesystem>
#include <vector>

#include "engine/core/status.h"
#include "engine/image/image.h"
#include "render/reference/render_capture.h"

namespace reflcap::render {

// True when this build bundled three.js (render/viewer/node_modules was installed at configure
// time: .ci/install-deps); otherwise WriteViewerPage returns Unavailable.
bool ViewerHasThreeJs();

struct ViewerOptions {
  // Held-out photographs carried (evenly spaced over the holdout split; all when fewer), >= 1.
  int views = 4;
  // Largest atlas side accepted: WebGL2 float textures (16384, the largest MAX_TEXTURE_SIZE
  // devices report).
  int max_texture_size = 16384;
  Status Validate() const;
};

struct ViewerSummary {
  std::vector<size_t> images;  // capture image indices of the views, in page order
  std::vector<double> display_scales;
  uint64_t page_bytes = 0;
  size_t texels = 0, triangles = 0;
};

// Display mapping shared by the page and its tests: sRGB(clamp(value · scale, 0, 1)) in [0, 1].
float DisplayValue(float value, float scale);
// The display scale of a photograph: 1 / its 99th percentile over pixels with a positive
// channel, all channels (1 for an all-black photograph).
float DisplayScaleOf(const Image& photo);

// Writes DIR/index.html and DIR/views.json into `out_dir` (an existing folder; the CLI stages
// it). Unavailable: three.js was not bundled. FailedPrecondition: a normal-map capture, no
// holdout photograph with a pinhole camera. InvalidArgument: an atlas above max_texture_size or
// more lobes than the page supports. Errors reading photographs name the file.
StatusOr<ViewerSummary> WriteViewerPage(const FittedCapture& fitted,
                                        const std::filesystem::path& out_dir,
                                        const ViewerOptions& options);

}  // namespace reflcap::render
