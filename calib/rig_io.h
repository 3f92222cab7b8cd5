#pragma once
// What `reflcap calibrate turntable` writes: RIG.json, a capture/1 document holding the calibrated
// rig — cameras (id, width, height, K, dist, cam_from_world) and the turntable (axis, point) — with
// the calibration's own numbers under the extension key "calibration" (capture/1 readers ignore
// unknown keys). Alone it is a skeleton (no lights, images or mesh yet); merged into an existing
// capture (MergeRigIntoCapture) it is a complete capture/1 that `reflcap info`/`resample` read.
//
// Frames: world = the turntable frame of calib/turntable.h (z along the axis, origin on the plate
// at the axis, x towards the first camera); capture/1's object frame is that world at turntable
// angle 0, so a mesh of the object must be expressed in it (a scan registered with this rig is).
#include <filesystem>
#include <string>

#include "calib/calib_file.h"
#include "calib/turntable.h"
#include "engine/capture/capture.h"
#include "engine/core/status.h"

namespace reflcap::calib {

// How the intrinsics in RIG.json came about (written into "calibration").
struct RigProvenance {
  std::string intrinsics;   // e.g. "given in calib.json", "INTRINSICS.json", "refined: f,cx,cy,k1,k2"
  std::string report;       // path of the report's index.html, relative to RIG.json
};

// The cameras and turntable of a calibration as capture/1 types (output gauge).
std::vector<Camera> RigCameras(const CalibFile& file, const TurntableResult& result);
Turntable RigTurntable(const TurntableResult& result);

// RIG.json text: the skeleton with the "calibration" block.
std::string RigToJson(const CalibFile& file, const TurntableResult& result, const TurntableOptions& options,
                      const RigProvenance& provenance);

// Every camera of `capture` must be one of the calibration's (same id, same size, pinhole): the
// check MergeRigIntoCapture makes, to run before a calibration that would be wasted.
Status CheckCaptureCameras(const Capture& capture, const CalibFile& file);

// `capture` with its cameras and turntable replaced by the calibration's: every camera of the
// capture must have been calibrated (same id, same size); relative paths are rewritten for a
// capture.json written into `out_dir`. The JSON text, with the "calibration" block added.
StatusOr<std::string> MergeRigIntoCapture(const Capture& capture, const CalibFile& file,
                                          const TurntableResult& result, const TurntableOptions& options,
                                          const RigProvenance& provenance,
                                          const std::filesystem::path& out_dir);

}  // namespace reflcap::calib
