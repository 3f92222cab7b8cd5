#include "calib/report_json.h"

#include <filesystem>

namespace reflcap::calib::internal {
namespace {

Json Vec(const Vec3d& v) { return Json::array({v.x(), v.y(), v.z()}); }

Json IntrinsicsJson(const IntrinsicParams& p) {
  Json j = Json::object();
  for (int k = 0; k < kIntrinsicCount; ++k) j[IntrinsicName(k)] = p[k];
  return j;
}

Json StatJson(const RmsStat& s) { return {{"rms_px", s.rms_px}, {"max_px", s.max_px}, {"corners", s.corners}}; }

Json ModelJson(const CalibFile& file, const RigModel& m) {
  Json cams = Json::array();
  for (size_t c = 0; c < m.cam_from_world.size(); ++c) {
    cams.push_back({{"id", file.cameras[c].id},
                    {"cam_from_world", MatrixJson(m.cam_from_world[c].ToMatrix())},
                    {"centre_world", Vec(m.cam_from_world[c].Inverse().translation)},
                    {"intrinsics", IntrinsicsJson(m.intrinsics[c])}});
  }
  return {{"cameras", cams},
          {"axis", Vec(m.axis)},
          {"point", Vec(m.point)},
          {"world_from_box_at_0", MatrixJson(m.world_from_box0.ToMatrix())},
          {"angle_offsets_deg", Json(m.angle_offset_deg)}};
}

}  // namespace

Json TruthJson(const TruthComparison& c, const CalibFile& file) {
  Json cams = Json::array();
  for (size_t i = 0; i < c.camera_rotation_deg.size(); ++i) {
    Json j = {{"id", file.cameras[i].id},
              {"rotation_deg", c.camera_rotation_deg[i]},
              {"centre_mm", c.camera_centre_mm[i]},
              {"axis_deg", c.axis_deg_per_camera[i]},
              {"point_mm", c.point_mm_per_camera[i]}};
    if (i < c.intrinsics_error.size()) j["intrinsics_error"] = IntrinsicsJson(c.intrinsics_error[i]);
    cams.push_back(j);
  }
  return {{"definition",
           "gauge-free (calib/1 README): axis and axis point in camera 0's frame, and in each camera's "
           "(max_*) (point: distance from the true point to the estimated axis, in the plane through it "
           "perpendicular to the true axis); cameras: cam_i_from_cam0 (rotation angle, centre "
           "distance); cuboid: cam_from_box of every photo; intrinsics: estimate - truth"},
          {"axis_deg", c.axis_deg},
          {"point_mm", c.point_mm},
          {"max_axis_deg", c.max_axis_deg},
          {"max_point_mm", c.max_point_mm},
          {"max_camera_rotation_deg", c.max_camera_rotation_deg},
          {"max_camera_centre_mm", c.max_camera_centre_mm},
          {"cameras", cams},
          {"cam_from_box", {{"rotation_median_deg", c.box_rotation_median_deg},
                            {"rotation_max_deg", c.box_rotation_max_deg},
                            {"translation_median_mm", c.box_translation_median_mm},
                            {"translation_max_mm", c.box_translation_max_mm}}}};
}

Json CalibrationJson(const CalibFile& file, const TurntableResult& r, const TurntableOptions& options,
                     const std::string& intrinsics_note, const std::string& report_path) {
  Json j = Json::object();
  j["format"] = "reflcap-rig/1";
  j["source"] = std::filesystem::absolute(file.json_path).lexically_normal().string();
  j["world"] = StrCat("turntable frame: origin where the axis meets the cuboid's bottom face (the plate's top), z "
                      "along the axis (the turntable turns counter-clockwise seen from +z), x towards camera \"",
                      file.cameras[0].id, "\"; the object frame is this world at turntable angle 0");
  j["intrinsics"] = intrinsics_note;
  j["model"] = {{"angle_offsets", options.angle_offsets},
                {"refine_intrinsics", options.refine_intrinsics},
                {"intrinsics_estimated", options.refine_intrinsics ? options.intrinsics_model.ToString() : "none"},
                {"board_photos", !r.board_views.empty()},
                {"min_cos", options.min_cos},
                {"loss", StrCat("Huber, scale ", options.loss_scale_px, " px")}};
  j["reprojection"] = StatJson(r.total);
  j["reprojection"]["residual_sigma_px"] = r.residual_sigma_px;
  if (r.board_total.corners > 0) j["reprojection"]["board_photos"] = StatJson(r.board_total);
  Json sig = Json::object();
  sig["gauge"] = StrCat("camera \"", file.cameras[0].id, "\" fixed: other cameras' sigmas are relative to it; "
                        "rotations about each camera's own axes; centres along camera 0's axes");
  Json cams = Json::array();
  for (size_t c = 0; c < file.cameras.size(); ++c) {
    Json cj = {{"id", file.cameras[c].id},
               {"rotation_deg", Vec(r.sigma.camera_rotation_deg[c])},
               {"centre_mm", Vec(r.sigma.camera_centre_mm[c])}};
    if (options.refine_intrinsics) cj["intrinsics"] = IntrinsicsJson(r.sigma.intrinsics[c]);
    cams.push_back(cj);
  }
  sig["cameras"] = cams;
  sig["axis_deg"] = r.sigma.axis_deg;
  sig["point_mm"] = r.sigma.point_mm;
  sig["cuboid_rotation_deg"] = Vec(r.sigma.box_rotation_deg);
  sig["cuboid_translation_mm"] = Vec(r.sigma.box_translation_mm);
  if (options.angle_offsets) sig["angle_offsets_deg"] = Json(r.sigma.angle_offset_deg);
  j["sigma"] = sig;
  j["cuboid_world_from_box_at_0"] = MatrixJson(r.rig.world_from_box0.ToMatrix());
  if (options.angle_offsets) j["angle_offsets_deg"] = Json(r.rig.angle_offset_deg);
  j["baseline"] = {{"method",
                    "the seed's averaged per-angle poses: per camera, the cuboid's pose at every angle by PnP, "
                    "the axis as the mean rotation axis of all pose pairs, the axis point by least squares "
                    "on their screw motions, the cameras from their own turntable frames"},
                   {"reprojection", StatJson(r.baseline_total)},
                   {"axis", Vec(r.baseline.axis)},
                   {"point", Vec(r.baseline.point)}};
  if (r.truth) {
    j["ground_truth_comparison"] = TruthJson(*r.truth, file);
    j["baseline"]["ground_truth_comparison"] = TruthJson(*r.baseline_truth, file);
  }
  j["timing_s"] = {{"detect", r.detect_s}, {"solve", r.solve_s}};
  if (!report_path.empty()) j["report"] = report_path;
  return j;
}

Json TurntableReportJson(const CalibFile& file, const TurntableResult& r, const TurntableOptions& options,
                         const std::string& intrinsics_note) {
  Json j = CalibrationJson(file, r, options, intrinsics_note, "");
  j["rig"] = ModelJson(file, r.rig);
  j["rig_camera0_gauge"] = ModelJson(file, r.rig_cam0);
  j["baseline"]["rig"] = ModelJson(file, r.baseline);
  Json per_camera = Json::array();
  for (size_t c = 0; c < r.per_camera.size(); ++c) {
    per_camera.push_back({{"id", file.cameras[c].id},
                          {"adjusted", StatJson(r.per_camera[c])},
                          {"baseline", StatJson(r.baseline_per_camera[c])}});
  }
  j["per_camera"] = per_camera;
  Json per_angle = Json::array();
  for (size_t a = 0; a < r.per_angle.size(); ++a) {
    Json aj = StatJson(r.per_angle[a]);
    aj["turntable_deg"] = file.angles_deg[a];
    per_angle.push_back(aj);
  }
  j["per_angle"] = per_angle;
  Json per_face = Json::array();
  for (size_t f = 0; f < r.per_face.size(); ++f) {
    Json fj = StatJson(r.per_face[f]);
    fj["face"] = file.faces[f].name;
    per_face.push_back(fj);
  }
  j["per_face"] = per_face;
  Json views = Json::array();
  for (const FaceView& v : r.views) {
    Json vj = {{"photo", file.images[v.image].file},
               {"camera", file.cameras[file.images[v.image].camera].id},
               {"turntable_deg", file.images[v.image].turntable_deg},
               {"face", file.faces[v.face].name},
               {"found_by", v.found_by},
               {"cos", v.cos_view},
               {"status", v.status}};
    if (v.used) {
      vj["rms_px"] = v.rms_px;
      vj["max_px"] = v.max_px;
      vj["baseline_rms_px"] = v.baseline_rms_px;
      vj["corners_used"] = v.corners_used;
      vj["corners_rejected"] = v.corners_rejected;
    }
    // Per corner: detected x, y (pixels) and the adjusted residual dx, dy (projected - detected);
    // null for a corner not used.
    Json corners = Json::array();
    for (size_t k = 0; k < v.corners.size(); ++k) {
      if (v.used && v.valid[k]) {
        corners.push_back({v.corners[k].x(), v.corners[k].y(), v.residuals[k].x(), v.residuals[k].y()});
      } else {
        corners.push_back(nullptr);
      }
    }
    vj["corners"] = corners;
    views.push_back(vj);
  }
  j["face_views"] = views;
  Json photos = Json::array();
  for (const ImageResult& im : r.images) {
    photos.push_back({{"file", im.file},
                      {"camera", file.cameras[im.camera].id},
                      {"turntable_deg", file.angles_deg[im.angle]},
                      {"status", im.status},
                      {"refused", Json(im.refused)}});
  }
  j["photos"] = photos;
  if (!r.board_views.empty()) {
    Json boards = Json::array();
    for (const BoardViewResult& v : r.board_views) {
      Json bj = {{"file", v.file}, {"camera", file.cameras[v.camera].id}, {"status", v.status}};
      if (v.used) {
        bj["rms_px"] = v.rms_px;
        bj["max_px"] = v.max_px;
        bj["corners_used"] = v.corners_used;
        bj["corners_rejected"] = v.corners_rejected;
      }
      boards.push_back(bj);
    }
    j["board_photos"] = boards;
  }
  j["adjustment"] = {{"parameters", r.parameters},
                     {"iterations", r.iterations},
                     {"rejection_rounds", r.rejection_rounds}};
  return j;
}

}  // namespace reflcap::calib::internal
