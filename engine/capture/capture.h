#pragma once
// Capture: the in-memory form of capture/1 (../shared/data/CAPTURE_FORMAT.md), the on-disk
// description of a reflectance capture — rig (cameras, lights, turntable), photographs with their
// split, and the object's geometry (a mesh, or a normal map seen by one camera).
//
// ReadCapture parses and validates every field of capture.json; ValidateCaptureFiles also opens
// the mesh and every image header. Every error names the file and the field, e.g.
//   "data/capture.json: cameras[1].K: not invertible (fx*fy = 0)".
// Extensions reflcap reads beyond the format text (optional; older readers ignore them):
//   cameras[].pixel_size_m   orthographic cameras: metres per pixel (needed to render a mesh);
//   images[].saturation      pixel value at and above which a pixel is clipped (0 or absent: none);
//   images[].variance        a float RGB OpenEXR file of the variance of every pixel value of the
//                            photograph (its units squared), e.g. from an HDR merge (`reflcap
//                            hdr`); the resampler weights samples by it instead of a noise model.
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "engine/camera/camera.h"
#include "engine/core/status.h"
#include "engine/geometry/rigid3.h"
#include "engine/image/image.h"
#include "engine/math/types.h"

namespace reflcap {

enum class LightType { kPoint, kDirectional };

struct Light {
  std::string id;
  LightType type = LightType::kPoint;
  Vec3d position = Vec3d::Zero();     // world frame, metres (point lights)
  Vec3d direction = Vec3d::UnitZ();   // unit, world frame, towards the light (directional)
  Vec3d intensity = Vec3d::Ones();    // radiant intensity per channel (point: W/sr; directional:
                                      // irradiance at normal incidence)
};

enum class Split { kTrain, kHoldout };
const char* SplitName(Split split);

struct CaptureImage {
  std::string file;        // relative to the capture's folder
  int camera = 0;          // index into Capture::cameras
  int light = 0;           // index into Capture::lights
  double turntable_deg = 0;
  double exposure_s = 1;   // pixel value = exposure_s * radiance
  Split split = Split::kTrain;
  double saturation = 0;   // pixel value at which the sensor clips; 0 = unknown / none
  std::string variance;    // relative to the capture's folder: float RGB EXR, the variance of
                           // each pixel value of `file` (its units squared); "" = none
};

struct NormalMapGeometry {
  int camera = 0;          // index into Capture::cameras
  std::string normals;     // EXR, unit normals in the world frame (R,G,B = x,y,z)
  std::string mask;        // PNG, non-zero = object
};

struct Capture {
  std::filesystem::path json_path;  // capture.json as given; resolves relative file names
  int minor_version = 0;            // "capture/1" or "capture/1.N"
  std::string mesh;                 // relative path; empty when normal_map is set
  std::optional<NormalMapGeometry> normal_map;
  std::vector<Camera> cameras;
  std::vector<Light> lights;
  std::optional<Turntable> turntable;  // absent for fixed-object captures
  std::vector<CaptureImage> images;
  std::string ground_truth_json;       // the optional block, verbatim (compact JSON); "" if absent

  std::filesystem::path Folder() const { return json_path.parent_path(); }
  std::filesystem::path Resolve(const std::string& relative) const { return Folder() / relative; }
  // Object pose for an image (identity without a turntable).
  Rigid3 WorldFromObject(const CaptureImage& image) const;
  int FindCamera(const std::string& id) const;  // -1 when absent
  int FindLight(const std::string& id) const;
  size_t CountSplit(Split split) const;
  // True for a rig skeleton (ReadRig): no lights, no geometry or no images.
  bool IsRig() const { return lights.empty() || images.empty() || (mesh.empty() && !normal_map); }
};

// Parses and validates capture.json (fields only; no other file is opened).
StatusOr<Capture> ReadCapture(const std::filesystem::path& json_path);
// Reads a rig: a capture/1 document that may lack the lights, the geometry (mesh or normal map)
// and the images — the skeleton `reflcap calibrate turntable` writes. Every field it has is
// checked as ReadCapture checks it. Capture::IsRig() tells a skeleton from a full capture.
StatusOr<Capture> ReadRig(const std::filesystem::path& json_path);
// Parses capture JSON text; `name` is used in messages in place of a file name.
StatusOr<Capture> ParseCapture(const std::string& text, const std::filesystem::path& name);

// What ValidateCaptureFiles found.
struct TriangleMesh;  // engine/mesh/mesh.h

struct CaptureFilesReport {
  size_t mesh_vertices = 0;
  size_t mesh_triangles = 0;
  size_t mesh_degenerate_skipped = 0;
  size_t normal_map_texels = 0;  // masked pixels of a normal-map capture
  size_t images_checked = 0;
  size_t variance_images_checked = 0;  // images[].variance headers checked
  // A mesh capture's mesh as it was loaded and checked, for a caller that uses it next
  // (resample: loading the million preset's 35 MB OBJ takes ~0.14 s).
  std::shared_ptr<const TriangleMesh> mesh;
};

// Opens the mesh (or normal map and mask) and the header of every image: each must exist, be
// readable, and have its camera's size; a variance image must also be an OpenEXR file with
// exactly the channels R, G and B. The first problem is returned, naming the file and field.
// With `images` (one flag per image), only the marked images are opened: a shard checks the
// photographs it reads and leaves the others to the shards that read them.
Status ValidateCaptureFiles(const Capture& capture, CaptureFilesReport* report,
                            const std::vector<bool>* images = nullptr);

// Reads capture.images[index].variance (which must be set) and checks it whole: an RGB image of
// the camera's size whose every value is finite and >= 0 (CheckVarianceImage). Errors name
// capture.json, the field and the file: NotFound / DataLoss from reading, InvalidArgument else.
StatusOr<Image> ReadVarianceImage(const Capture& capture, size_t index);
// The checks of ReadVarianceImage on an image already in memory: 3 channels, the camera's size,
// every value finite and >= 0 (the first bad value and the count of bad ones are named).
Status CheckVarianceImage(const Capture& capture, size_t index, const Image& variance);

// Writes capture.json (full double precision), atomically.
Status WriteCapture(const Capture& capture, const std::filesystem::path& json_path);
// The JSON text WriteCapture writes.
std::string CaptureToJson(const Capture& capture);

}  // namespace reflcap
