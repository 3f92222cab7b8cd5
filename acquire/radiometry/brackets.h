#pragma once
// brackets/1: exposure brackets of a capture's photographs, the input of `reflcap hdr`.
//
// A brackets.json holds the rig (cameras, lights, turntable: the fields and rules of capture/1,
// ../shared/data/CAPTURE_FORMAT.md) and a list of photos; each photo is one view (camera, light,
// turntable angle, split) photographed at several exposure times, one 8-bit PNG per exposure:
//   { "format": "brackets/1",
//     "source_capture": "../capture.json",          // optional: where the mesh (and masks) live
//     "cameras": [...], "lights": [...], "turntable": {...},
//     "photos": [ { "id": "0000", "subject": "object" | "colorchecker",
//                   "camera": "cam0", "light": "L0", "turntable_deg": 0 (null for a chart),
//                   "split": "train" | "holdout" | "calibration",
//                   "source_hdr": "...exr",           // optional ground truth: the linear photo
//                   "chart": "chart/chart.json",      // optional (colorchecker): declared geometry
//                   "exposures": [ {"file": "ldr/0000_e0.png", "exposure_s": 0.125}, ... ] } ],
//     "ground_truth": { "response": {"x_of_code": [256 numbers]}, "wb_gains": [r, g, b],
//                       "read_noise_sigma": s, "chart": {"photo_id", "hdr", "geometry"} } }
// Exposure lists must be strictly increasing (a repeated or out-of-order time is an error: it
// usually means a mislabelled file). Paths are relative to the brackets file's folder.
// ReadBrackets validates every field; every message names the file and the field, e.g.
//   "data/brackets.json: photos[3].exposures[2].exposure_s: must exceed the previous exposure
//    (0.5 s), got 0.5".
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "engine/capture/capture.h"
#include "engine/core/status.h"
#include "engine/math/types.h"

namespace reflcap::radiometry {

// A bracket longer than this is almost certainly a malformed file (cameras bracket 3-9 frames).
constexpr int kMaxExposuresPerPhoto = 16;

enum class Subject { kObject, kColorChecker };

struct BracketExposure {
  std::string file;       // 8-bit RGB PNG, relative to the brackets file's folder
  double exposure_s = 0;  // > 0
};

struct BracketPhoto {
  std::string id;          // unique, a file-name-safe token ([A-Za-z0-9_.-])
  Subject subject = Subject::kObject;
  int camera = 0;          // index into BracketSet::rig.cameras
  int light = 0;           // index into BracketSet::rig.lights
  double turntable_deg = 0;
  std::string split;       // "train", "holdout" or "calibration" (charts)
  std::string source_hdr;  // optional ground truth (linear photo), "" when absent
  std::string chart;       // optional declared chart geometry (colorchecker photos), "" when absent
  std::vector<BracketExposure> exposures;  // strictly increasing exposure_s, >= 2 entries
};

// What the file's optional ground_truth block says (used only to report accuracy).
struct BracketTruth {
  std::vector<double> x_of_code;          // 256 entries, or empty: the true inverse response
  std::optional<Vec3d> wb_gains;          // camera RGB = gains * true RGB
  std::optional<double> read_noise_sigma; // relative to the clipping level
  std::string chart_photo_id;             // ground_truth.chart.photo_id
  std::string chart_hdr;                  // ground_truth.chart.hdr (linear radiance of the chart)
  std::string chart_geometry;             // ground_truth.chart.geometry
};

struct BracketSet {
  std::filesystem::path json_path;
  // Cameras, lights and turntable (parsed by the capture/1 rules); rig.images is empty.
  Capture rig;
  std::string source_capture;  // relative path, "" when absent
  std::vector<BracketPhoto> photos;
  BracketTruth truth;

  std::filesystem::path Resolve(const std::string& relative) const {
    return json_path.parent_path() / relative;
  }
  // Index of the first colorchecker photo, -1 when there is none.
  int ChartPhoto() const;
  size_t CountSubject(Subject subject) const;
};

// Parses and validates brackets.json (fields only; no image is opened).
StatusOr<BracketSet> ReadBrackets(const std::filesystem::path& json_path);
// Parses brackets JSON text; `name` stands for the file in messages and resolves relative paths.
StatusOr<BracketSet> ParseBrackets(const std::string& text, const std::filesystem::path& name);

// One photo's exposures, read: codes[e] is the 8-bit RGB image of exposures[e] (values 0..255),
// all of the photo camera's size. Errors name the brackets file and the field
// ("photos[2].exposures[1].file: ... is 640x480, camera cam0 is 320x320"), and reject PNGs that are
// not 8-bit (values off the 1/255 grid).
struct BracketImages {
  int width = 0, height = 0;
  std::vector<std::vector<uint8_t>> codes;  // [exposure][(y * width + x) * 3 + c]
};
StatusOr<BracketImages> ReadBracketImages(const BracketSet& set, size_t photo_index);

}  // namespace reflcap::radiometry
