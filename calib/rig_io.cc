#include "calib/rig_io.h"

#include "engine/capture/json_fields.h"
#include "calib/report_json.h"

namespace reflcap::calib {
namespace fs = std::filesystem;
using jsonio::Json;

std::vector<Camera> RigCameras(const CalibFile& file, const TurntableResult& result) {
  std::vector<Camera> cameras;
  for (size_t c = 0; c < file.cameras.size(); ++c) {
    cameras.push_back(MakeCamera(file.cameras[c].id, file.cameras[c].width, file.cameras[c].height,
                                 result.rig.intrinsics[c], result.rig.cam_from_world[c]));
  }
  return cameras;
}

Turntable RigTurntable(const TurntableResult& result) {
  return Turntable{result.rig.axis.normalized(), result.rig.point};
}

std::string RigToJson(const CalibFile& file, const TurntableResult& result, const TurntableOptions& options,
                      const RigProvenance& provenance) {
  Json root = Json::object();
  root["format"] = "capture/1";
  root["description"] =
      "Rig calibrated by `reflcap calibrate turntable`: cameras and turntable (capture/1). A capture "
      "skeleton: add lights, images and the mesh (or pass --capture) to make it a capture.";
  Json cameras = Json::array();
  for (const Camera& cam : RigCameras(file, result)) {
    cameras.push_back({{"id", cam.id},
                       {"width", cam.width},
                       {"height", cam.height},
                       {"K", jsonio::MatrixJson(cam.K)},
                       {"dist", Json(std::vector<double>(cam.dist.begin(), cam.dist.end()))},
                       {"cam_from_world", jsonio::MatrixJson(cam.cam_from_world.ToMatrix())}});
  }
  root["cameras"] = cameras;
  const Turntable t = RigTurntable(result);
  root["turntable"] = {{"axis", jsonio::VectorJson(t.axis)}, {"point", jsonio::VectorJson(t.point)}};
  root["calibration"] = internal::CalibrationJson(file, result, options, provenance.intrinsics, provenance.report);
  return root.dump(2) + "\n";
}

Status CheckCaptureCameras(const Capture& capture, const CalibFile& file) {
  const std::string name = capture.json_path.string();
  for (size_t i = 0; i < capture.cameras.size(); ++i) {
    const Camera& cam = capture.cameras[i];
    const std::string field = StrCat("cameras[", i, "]");
    const int c = file.FindCamera(cam.id);
    if (c < 0) {
      return InvalidArgumentError(name, ": ", field, ".id: camera \"", cam.id, "\" is not in ",
                                  file.json_path.string(), ", so the calibration cannot place it");
    }
    if (cam.model != CameraModel::kPinhole) {
      return InvalidArgumentError(name, ": ", field, ".model: only pinhole cameras can be calibrated");
    }
    if (cam.width != file.cameras[c].width || cam.height != file.cameras[c].height) {
      return InvalidArgumentError(name, ": ", field, ": ", cam.width, "x", cam.height, " but the calibrated \"",
                                  cam.id, "\" is ", file.cameras[c].width, "x", file.cameras[c].height);
    }
  }
  return OkStatus();
}

StatusOr<std::string> MergeRigIntoCapture(const Capture& capture, const CalibFile& file,
                                          const TurntableResult& result, const TurntableOptions& options,
                                          const RigProvenance& provenance, const fs::path& out_dir) {
  Capture merged = capture;
  const std::vector<Camera> calibrated = RigCameras(file, result);
  REFLCAP_RETURN_IF_ERROR(CheckCaptureCameras(capture, file));
  for (Camera& cam : merged.cameras) {
    const Camera* match = nullptr;
    for (const Camera& c : calibrated) {
      if (c.id == cam.id) match = &c;
    }
    cam.K = match->K;
    cam.dist = match->dist;
    cam.cam_from_world = match->cam_from_world;
  }
  merged.turntable = RigTurntable(result);
  // Paths relative to the new capture.json's folder.
  const fs::path from = fs::absolute(out_dir).lexically_normal();
  auto rebase = [&](const std::string& relative) {
    if (relative.empty()) return relative;
    const fs::path target = fs::absolute(capture.Resolve(relative)).lexically_normal();
    const fs::path rel = target.lexically_relative(from);
    return (rel.empty() ? target : rel).generic_string();
  };
  merged.mesh = rebase(merged.mesh);
  if (merged.normal_map) {
    merged.normal_map->normals = rebase(merged.normal_map->normals);
    merged.normal_map->mask = rebase(merged.normal_map->mask);
  }
  for (CaptureImage& image : merged.images) image.file = rebase(image.file);
  Json root = Json::parse(CaptureToJson(merged));
  root["calibration"] = internal::CalibrationJson(file, result, options, provenance.intrinsics, provenance.report);
  return root.dump(2) + "\n";
}

}  // namespace reflcap::calib
