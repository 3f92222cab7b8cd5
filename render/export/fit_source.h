#pragma once
// What `reflcap export` and `reflcap view` start from: a FIT folder (what `reflcap fit` writes,
// or any folder holding params.exr, such as a synthetic capture's gt/) traced back to the capture
// whose mesh and texel atlas its parameter maps are laid out on.
//
// The capture is, in this order: `capture_override` when given; the capture named by the sample
// store the fit was made from (FIT/fit_report.json "samples" → store.json "capture"; when a path
// recorded there no longer exists — e.g. it was a staging folder of `reflcap run` or `demo` —
// FIT/../samples and FIT/../../capture/capture.json, the layout those verbs write); FIT/../
// capture.json (a capture's gt/ folder). Otherwise NotFound, asking for --capture.
#include <filesystem>
#include <memory>
#include <string>

#include "engine/capture/capture.h"
#include "engine/core/status.h"
#include "render/reference/render_capture.h"

namespace reflcap::render {

// capture.json of the capture FIT belongs to (see above). Errors name the file and field read.
StatusOr<std::filesystem::path> FindFitCapture(const std::filesystem::path& fit,
                                               const std::filesystem::path& capture_override);

struct LoadedFit {
  std::filesystem::path params;        // the params.exr read
  std::filesystem::path capture_json;  // the capture it was traced to
  std::unique_ptr<Capture> capture;
  std::unique_ptr<FittedCapture> fitted;  // mesh, atlas and maps (fitted->capture = capture)
};

// Loads FIT (a folder holding params.exr, or that file) with its capture's mesh and atlas.
// FailedPrecondition when the capture is a normal-map capture (no mesh to export or view: the
// message says so and names `purpose`, e.g. "glTF export"); errors of FindFitCapture,
// ReadCapture and LoadFittedCapture otherwise.
StatusOr<LoadedFit> LoadFitWithMesh(const std::filesystem::path& fit,
                                    const std::filesystem::path& capture_override,
                                    const std::string& purpose);

}  // namespace reflcap::render
