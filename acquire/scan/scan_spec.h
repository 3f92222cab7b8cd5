#pragma once
// ScanSpec: a structured-light scan on disk (format structured_light/1, `scan.json`): one camera
// and one projector (pinhole, OpenCV frames, world z up, metres), the turntable, the list of
// turntable angles, and per angle one photograph of each projected pattern:
//   white, black                         full-on / full-off projector,
//   gray_<col|row>_b<b>[_inv]             Gray code bit b (b = 0 the most significant) and inverse,
//   phase_<col|row>_p<P>_k<k>             sinusoid of period P projector pixels, shift 2πk/K.
// The object frame is the world at turntable 0 (capture/1), so a scanned mesh can stand in for a
// capture's mesh when both name the same turntable. LoadScanSpec validates every field and the
// header of every image; errors name the file and the field (exit 2 in the CLI).
#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "engine/camera/camera.h"
#include "engine/core/status.h"
#include "engine/geometry/rigid3.h"

namespace reflcap::scan {

// One axis (projector columns or rows) of the coded patterns.
struct AxisPatterns {
  int bits = 0;                                   // Gray code bits = ceil(log2(projector extent))
  std::vector<std::string> gray;                  // per bit (MSB first): image file of the pattern
  std::vector<std::string> gray_inverse;          // per bit: image file of the inverse
  // Phase-shift sequences by period (projector pixels, ascending): image files per shift k.
  std::map<int, std::vector<std::string>> phase;
};

// The photographs of one turntable angle (paths resolved against the scan folder).
struct AngleImages {
  double turntable_deg = 0;
  std::string white, black;
  AxisPatterns col, row;
};

struct ScanSpec {
  std::filesystem::path json_path;     // the scan.json read
  Camera camera;                       // cam_from_world
  Camera projector;                    // cam_from_world holds proj_from_world
  Turntable turntable;
  std::vector<AngleImages> angles;     // in turntable_angles_deg order
  std::optional<std::filesystem::path> reference_mesh;  // "mesh" (ground truth), when given

  // object_from_cam at angle index a: the turntable pose composed with the camera pose.
  Rigid3 ObjectFromCamera(size_t a) const;
  Rigid3 ObjectFromProjector(size_t a) const;
  // proj_from_cam, fixed over angles.
  Rigid3 ProjectorFromCamera() const {
    return projector.cam_from_world * camera.cam_from_world.Inverse();
  }
};

// Reads and validates scan.json: format, camera, projector, turntable, turntable_angles_deg
// (distinct, finite), images (each naming a file, one of the listed angles, and a pattern name of
// the forms above; every angle has white, black, every Gray bit of both axes with its inverse, and
// at least one phase period per axis with >= 3 shifts, the same set at every angle). With
// `check_images`, every image exists and its PNG header matches the camera's size. Errors:
// NotFound / DataLoss / InvalidArgument, the message naming "<file>: <field>: <what>".
StatusOr<ScanSpec> LoadScanSpec(const std::filesystem::path& json_path, bool check_images = true);

// Number of Gray code bits for a projector extent of `pixels`: ceil(log2(pixels)), at least 1.
int GrayBitsFor(int pixels);

}  // namespace reflcap::scan
