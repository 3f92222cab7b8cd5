// The `reflcap scan` pipeline and its outputs (see scan_pipeline.h).
#include "acquire/scan/scan_pipeline.h"

#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>

#include <nlohmann/json.hpp>

#include "acquire/scan/compare.h"
#include "engine/capture/capture.h"
#include "engine/core/atomic_file.h"
#include "engine/core/log.h"
#include "engine/core/parallel.h"
#include "engine/core/progress.h"
#include "engine/image/png_io.h"
#include "engine/mesh/mesh_io.h"
#include "engine/mesh/ray_scene.h"
#include "engine/mesh/texel_atlas.h"

namespace reflcap::scan {
namespace fs = std::filesystem;
using Json = nlohmann::json;

namespace {

// A reference point counts as seen when a measured point lies within this many point spacings
// (one camera pixel's footprint is ~1 spacing; 2 allows for the sampling between pixels).
constexpr double kSeenSpacings = 2.0;
// Turntables of the scan and a capture agree when axes differ by < 1e-6 rad and points by < 1 µm
// (the files' rounding), else their object frames are different.
constexpr double kSameAxis = 1e-6;
constexpr double kSamePointM = 1e-6;

double Seconds(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

std::string AngleTag(double deg) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%03d", int(std::lround(deg)));
  return buf;
}

double Mm(double m) { return std::round(m * 1e6) / 1e3; }  // metres -> mm, 3 decimals

Json StatsJson(const DistanceStats& s) {
  return Json{{"samples", s.samples},         {"median_mm", Mm(s.median_m)},
              {"p90_mm", Mm(s.p90_m)},        {"p95_mm", Mm(s.p95_m)},
              {"p99_mm", Mm(s.p99_m)},        {"max_mm", Mm(s.max_m)},
              {"mean_mm", Mm(s.mean_m)},      {"fraction_over_1mm", s.fraction_over_1mm}};
}

Status WritePly(const fs::path& path, const ViewCloud& c) {
  return WriteFileAtomic(path, [&](const fs::path& tmp) -> Status {
    std::ofstream out(tmp, std::ios::binary);
    out << "ply\nformat binary_little_endian 1.0\ncomment reflcap scan: object frame, metres; "
           "turntable " << c.turntable_deg << " deg\nelement vertex " << c.points.size()
        << "\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\n"
           "property float nz\nproperty float confidence\nproperty float sigma_m\nend_header\n";
    for (size_t i = 0; i < c.points.size(); ++i) {
      const float rec[8] = {c.points[i].x(),  c.points[i].y(),  c.points[i].z(), c.normals[i].x(),
                            c.normals[i].y(), c.normals[i].z(), c.confidence[i], c.sigma_m[i]};
      out.write(reinterpret_cast<const char*>(rec), sizeof(rec));
    }
    out.close();
    if (!out) return InternalError(path.string(), ": write failed");
    return OkStatus();
  });
}

Status WriteDecodePng(const fs::path& path, const DecodedView& v) {
  Image im(v.width, v.height, 3, 0.0f);
  for (size_t i = 0; i < v.outcome.size(); ++i) {
    float rgb[3] = {0, 0, 0};
    switch (PixelOutcome(v.outcome[i])) {
      case PixelOutcome::kDecoded: {
        const float g = 0.35f + 0.65f * std::clamp(v.contrast[i] * 2.0f, 0.0f, 1.0f);
        rgb[0] = rgb[1] = rgb[2] = g;
        break;
      }
      case PixelOutcome::kShadow: break;
      case PixelOutcome::kLowContrast: rgb[2] = 1; break;
      case PixelOutcome::kLowModulation: rgb[1] = rgb[2] = 1; break;
      case PixelOutcome::kOutOfRange: rgb[0] = rgb[2] = 1; break;
      case PixelOutcome::kInconsistent: rgb[0] = 1; break;
      case PixelOutcome::kNoisy: rgb[0] = rgb[1] = 1; break;
    }
    for (int c = 0; c < 3; ++c) im.data[i * 3 + c] = rgb[c];
  }
  return WritePng(path, im);
}

// Shaded render of the mesh through the scan camera with the object at turntable 0.
StatusOr<Image> RenderPreview(const TriangleMesh& mesh, const ScanSpec& spec) {
  REFLCAP_ASSIGN_OR_RETURN(auto scene, RayScene::Create(mesh));
  const Camera& cam = spec.camera;
  const Rigid3 object_from_cam = spec.turntable.WorldFromObject(0).Inverse() * cam.cam_from_world.Inverse();
  Image im(cam.width, cam.height, 3, 0.0f);
  ParallelFor(0, cam.height, 8, [&](int64_t y0, int64_t y1, int) {
    for (int64_t y = y0; y < y1; ++y) {
      for (int x = 0; x < cam.width; ++x) {
        Vec3d o, d;
        cam.PixelRay(Vec2d(x, double(y)), &o, &d);
        const Vec3f origin = (object_from_cam * o).cast<float>();
        const Vec3f dir = (object_from_cam.rotation * d).cast<float>();
        const RayHit hit = scene->Intersect(origin, dir, 0.0f, 1e3f);
        if (!hit.hit) continue;
        const Vec3f n = mesh.GeometricNormal(hit.triangle);
        const float shade = 0.15f + 0.85f * std::max(0.0f, -n.dot(dir.normalized()));
        // Back faces (inside of a trimmed rim) in a warm tint so holes are visible.
        const bool back = n.dot(dir) > 0;
        float* px = im.pixel(x, int(y));
        px[0] = back ? 0.6f : shade;
        px[1] = back ? 0.3f : shade;
        px[2] = back ? 0.2f : shade;
      }
    }
  });
  return im;
}

Image AtlasImage(const TexelAtlas& atlas) {
  Image im(atlas.width, atlas.height, 3, 0.0f);
  for (size_t t = 0; t < atlas.TexelCount(); ++t) {
    int x, y;
    atlas.PixelOf(t, &x, &y);
    const Vec3f& n = atlas.geometric_normal[t];
    for (int c = 0; c < 3; ++c) im.at(x, y, c) = 0.5f + 0.5f * n[c];
  }
  return im;
}

// capture.json of `capture_arg` with its mesh replaced by `mesh_file` (a file of out_dir), written
// into out_dir together with a symbolic link to every other entry of the capture's folder
// (images/, masks/, textures), so that every relative path of the capture resolves as before and
// stays relative. Image paths are deliberately not made absolute: stages that write one output per
// image (render) place it at <output>/<image file>, which an absolute path would turn into the
// photograph itself.
Status WriteDerivedCapture(const ScanSpec& spec, const std::string& capture_arg, const fs::path& out_dir,
                           const std::string& mesh_file) {
  REFLCAP_ASSIGN_OR_RETURN(Capture capture, ReadCapture(capture_arg));
  const std::string name = capture.json_path.string();
  if (!capture.turntable) {
    return InvalidArgumentError(name, ": turntable: missing, but the scan's object frame is defined by "
                                "the scan's turntable");
  }
  if ((capture.turntable->axis - spec.turntable.axis).norm() > kSameAxis ||
      (capture.turntable->point - spec.turntable.point).norm() > kSamePointM) {
    return InvalidArgumentError(name, ": turntable: axis/point differ from ", spec.json_path.string(),
                                " turntable: the scanned mesh would be in another object frame");
  }
  if (capture.normal_map) {
    return InvalidArgumentError(name, ": normal_map: a normal-map capture has no mesh to replace");
  }
  for (size_t i = 0; i < capture.images.size(); ++i) {
    const fs::path file(capture.images[i].file);
    if (file.is_absolute() || *file.begin() == "..") {
      return InvalidArgumentError(name, ": images[", i, "].file: \"", capture.images[i].file,
                                  "\" leaves the capture's folder; --capture needs paths inside it");
    }
  }
  std::error_code ec;
  const fs::path folder = fs::absolute(capture.Folder()).lexically_normal();
  for (const auto& entry : fs::directory_iterator(folder, ec)) {
    const fs::path entry_name = entry.path().filename();
    if (entry_name == "capture.json" || entry_name == fs::path(capture.mesh).filename() ||
        fs::exists(out_dir / entry_name)) {
      continue;
    }
    fs::create_symlink(entry.path(), out_dir / entry_name, ec);
    if (ec) return InternalError((out_dir / entry_name).string(), ": cannot link to ", entry.path().string(),
                                 ": ", ec.message());
  }
  if (ec) return InternalError(folder.string(), ": cannot list: ", ec.message());
  capture.mesh = mesh_file;
  capture.json_path = out_dir / "capture.json";
  return WriteCapture(capture, capture.json_path);
}

}  // namespace

Status ScanOptions::Validate() const {
  REFLCAP_RETURN_IF_ERROR(decode.Validate());
  REFLCAP_RETURN_IF_ERROR(triangulate.Validate());
  REFLCAP_RETURN_IF_ERROR(merge.Validate());
  REFLCAP_RETURN_IF_ERROR(atlas.Validate());
  if (distance_samples < 1000 || distance_samples > 100000000) {
    return InvalidArgumentError("distance samples must be in [1000, 1e8], got ", distance_samples);
  }
  return OkStatus();
}

Status WriteGltf(const fs::path& path, const TriangleMesh& mesh) {
  // One vertex per corner (seams split UVs and normals): simple and exact.
  const size_t n = mesh.triangles.size() * 3;
  std::vector<float> pos, nrm, uv;
  pos.reserve(n * 3);
  nrm.reserve(n * 3);
  uv.reserve(n * 2);
  Vec3f lo = Vec3f::Constant(std::numeric_limits<float>::max()), hi = -lo;
  for (size_t t = 0; t < mesh.triangles.size(); ++t) {
    for (int k = 0; k < 3; ++k) {
      const Vec3f& p = mesh.positions[mesh.triangles[t][k]];
      lo = lo.cwiseMin(p);
      hi = hi.cwiseMax(p);
      pos.insert(pos.end(), {p.x(), p.y(), p.z()});
      const Vec3f nn = t < mesh.corner_normals.size() ? mesh.corner_normals[t][k] : mesh.GeometricNormal(t);
      nrm.insert(nrm.end(), {nn.x(), nn.y(), nn.z()});
      const Vec2f u = t < mesh.corner_uvs.size() ? mesh.corner_uvs[t][k] : Vec2f::Zero();
      uv.insert(uv.end(), {u.x(), 1.0f - u.y()});
    }
  }
  std::string bytes;
  auto append = [&](const std::vector<float>& v) {
    bytes.append(reinterpret_cast<const char*>(v.data()), v.size() * sizeof(float));
  };
  append(pos);
  append(nrm);
  append(uv);
  static const char* kB64 = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string b64;
  b64.reserve((bytes.size() + 2) / 3 * 4);
  for (size_t i = 0; i < bytes.size(); i += 3) {
    uint32_t v = uint32_t(uint8_t(bytes[i])) << 16;
    if (i + 1 < bytes.size()) v |= uint32_t(uint8_t(bytes[i + 1])) << 8;
    if (i + 2 < bytes.size()) v |= uint32_t(uint8_t(bytes[i + 2]));
    b64 += kB64[(v >> 18) & 63];
    b64 += kB64[(v >> 12) & 63];
    b64 += i + 1 < bytes.size() ? kB64[(v >> 6) & 63] : '=';
    b64 += i + 2 < bytes.size() ? kB64[v & 63] : '=';
  }
  const size_t pos_bytes = pos.size() * 4, nrm_bytes = nrm.size() * 4, uv_bytes = uv.size() * 4;
  Json gltf;
  gltf["asset"] = {{"version", "2.0"}, {"generator", "reflcap scan"}};
  gltf["scene"] = 0;
  gltf["scenes"] = Json::array({Json{{"nodes", Json::array({0})}}});
  gltf["nodes"] = Json::array({Json{{"mesh", 0}, {"name", "scan"}}});
  Json attributes = {{"POSITION", 0}, {"NORMAL", 1}, {"TEXCOORD_0", 2}};
  gltf["meshes"] = Json::array({Json{{"primitives", Json::array({Json{{"attributes", attributes}, {"mode", 4}}})}}});
  gltf["buffers"] = Json::array(
      {Json{{"byteLength", bytes.size()}, {"uri", "data:application/octet-stream;base64," + b64}}});
  Json views = Json::array();
  size_t offset = 0;
  for (size_t length : {pos_bytes, nrm_bytes, uv_bytes}) {
    views.push_back(Json{{"buffer", 0}, {"byteOffset", offset}, {"byteLength", length}, {"target", 34962}});
    offset += length;
  }
  gltf["bufferViews"] = views;
  Json accessors = Json::array();
  accessors.push_back(Json{{"bufferView", 0}, {"componentType", 5126}, {"count", n}, {"type", "VEC3"},
                           {"min", {lo.x(), lo.y(), lo.z()}}, {"max", {hi.x(), hi.y(), hi.z()}}});
  accessors.push_back(Json{{"bufferView", 1}, {"componentType", 5126}, {"count", n}, {"type", "VEC3"}});
  accessors.push_back(Json{{"bufferView", 2}, {"componentType", 5126}, {"count", n}, {"type", "VEC2"}});
  gltf["accessors"] = accessors;
  return WriteTextFileAtomic(path, gltf.dump() + "\n");
}

StatusOr<ScanSummary> RunScanPipeline(const ScanSpec& spec, const fs::path& out_dir,
                                      const ScanOptions& options) {
  REFLCAP_RETURN_IF_ERROR(options.Validate());
  const auto start = std::chrono::steady_clock::now();
  ScanSummary summary;
  Json report;
  report["format"] = "reflcap_scan_report/1";
  report["scan"] = spec.json_path.string();
  report["frame"] = "object (= world at turntable 0; capture/1), metres in files, mm in this report";

  // Decode and triangulate, one angle at a time (its 90 photographs are ~110 MB as floats).
  std::vector<ViewCloud> clouds;
  Json angles = Json::array();
  int64_t lit_total = 0, decoded_total = 0;
  double decode_s = 0;
  {
    Progress progress("scan: decoding and triangulating", int64_t(spec.angles.size()));
    for (size_t a = 0; a < spec.angles.size(); ++a) {
      const AngleImages& angle = spec.angles[a];
      const auto t0 = std::chrono::steady_clock::now();
      REFLCAP_ASSIGN_OR_RETURN(AnglePhotos photos,
                               LoadAnglePhotos(angle, spec.camera.width, spec.camera.height));
      auto decoded = DecodeAngle(photos, spec.projector.width, spec.projector.height, options.decode);
      if (!decoded.ok()) return decoded.status().WithContext(angle.white);
      const DecodedView& view = *decoded;
      const int64_t pixels = int64_t(view.outcome.size());
      const int64_t lit = pixels - view.counts[int(PixelOutcome::kShadow)];
      if (lit == 0) {
        return FailedPreconditionError(
            angle.white, ": the projector lights nothing at turntable ", angle.turntable_deg,
            " deg (white - black < ", options.decode.min_contrast, " at every pixel; check the "
            "white/black photographs and camera.width/height)");
      }
      if (view.Decoded() == 0) {
        return FailedPreconditionError(angle.white, ": no pixel decodes at turntable ",
                                       angle.turntable_deg, " deg (", lit, " lit pixels; the Gray "
                                       "codes and phase sequences disagree everywhere)");
      }
      REFLCAP_ASSIGN_OR_RETURN(
          ViewCloud cloud,
          TriangulateView(view, spec.camera, spec.projector, spec.ProjectorFromCamera(),
                          spec.ObjectFromCamera(a), options.triangulate));
      cloud.turntable_deg = angle.turntable_deg;
      if (cloud.points.empty()) {
        return FailedPreconditionError(angle.white, ": no point triangulates at turntable ",
                                       angle.turntable_deg, " deg (", view.Decoded(),
                                       " decoded pixels, all off the epipolar lines: check "
                                       "projector.proj_from_world and the intrinsics)");
      }
      const std::string tag = AngleTag(angle.turntable_deg);
      REFLCAP_RETURN_IF_ERROR(WriteDecodePng(out_dir / ("decode_" + tag + ".png"), view));
      if (options.write_clouds) REFLCAP_RETURN_IF_ERROR(WritePly(out_dir / ("points_" + tag + ".ply"), cloud));
      Json outcomes;
      for (int o = 0; o < kPixelOutcomeCount; ++o) outcomes[PixelOutcomeName(PixelOutcome(o))] = view.counts[o];
      angles.push_back({{"turntable_deg", angle.turntable_deg},
                        {"pixels", pixels},
                        {"lit_pixels", lit},
                        {"decoded_pixels", view.Decoded()},
                        {"decode_coverage", view.Coverage()},
                        {"outcomes", outcomes},
                        {"points", int64_t(cloud.points.size())},
                        {"rejected", {{"epipolar", cloud.rejected_epipolar},
                                      {"behind_device", cloud.rejected_behind},
                                      {"no_normal", cloud.rejected_no_normal},
                                      {"grazing", cloud.rejected_grazing}}},
                        {"median_epipolar_px", cloud.median_epipolar_px},
                        {"median_depth_sigma_mm", Mm(cloud.median_sigma_m)},
                        {"seconds", Seconds(t0)}});
      lit_total += lit;
      decoded_total += view.Decoded();
      summary.points += int64_t(cloud.points.size());
      clouds.push_back(std::move(cloud));
      progress.Advance();
    }
    decode_s = progress.ElapsedSeconds();
  }
  summary.coverage = lit_total > 0 ? double(decoded_total) / double(lit_total) : 0;

  // Registration.
  auto t0 = std::chrono::steady_clock::now();
  REFLCAP_ASSIGN_OR_RETURN(std::vector<ViewRegistration> reg, RegisterViews(&clouds, options.merge));
  const double register_s = Seconds(t0);
  for (size_t a = 0; a < reg.size(); ++a) {
    angles[a]["registration"] = {{"overlap_points", reg[a].residual_points},
                                 {"residual_median_mm", Mm(reg[a].residual_median_m)},
                                 {"residual_p90_mm", Mm(reg[a].residual_p90_m)},
                                 {"icp_applied", reg[a].icp_applied},
                                 {"icp_rotation_deg", reg[a].icp_rotation_deg},
                                 {"icp_translation_mm", Mm(reg[a].icp_translation_m)},
                                 {"residual_median_after_mm", Mm(reg[a].residual_median_after_m)}};
  }
  report["angles"] = angles;
  report["decode_coverage"] = summary.coverage;
  report["points"] = summary.points;

  // Surface.
  SurfaceStats surface;
  REFLCAP_ASSIGN_OR_RETURN(TriangleMesh mesh, ReconstructSurface(clouds, options.merge, &surface));
  report["surface"] = {{"method", "screened Poisson (Open3D 0.16), trimmed, quadric decimation, "
                                  "vertices projected onto the points"},
                       {"input_points", surface.input_points},
                       {"point_spacing_mm", Mm(surface.point_spacing_m)},
                       {"poisson_depth", surface.poisson_depth},
                       {"poisson_triangles", surface.poisson_triangles},
                       {"trim_distance_mm", Mm(surface.trim_distance_m)},
                       {"trimmed_triangles", surface.trimmed_triangles},
                       {"removed_components", surface.removed_components},
                       {"triangles", surface.final_triangles},
                       {"vertices", surface.final_vertices},
                       {"boundary_edges", surface.boundary_edges},
                       {"non_manifold_edges", surface.non_manifold_edges},
                       {"projection_median_shift_mm", Mm(surface.refine_median_shift_m)},
                       {"normal_radius_mm", Mm(surface.normal_radius_m)},
                       {"seconds", {{"poisson", surface.poisson_s}, {"trim", surface.trim_s},
                                    {"decimate", surface.simplify_s}, {"project", surface.refine_s}}}};
  summary.triangles = surface.final_triangles;

  // UV atlas, and reflcap's texel atlas on it.
  UvAtlasStats atlas_stats;
  REFLCAP_LOG(kInfo) << "scan: UV atlas of " << mesh.triangles.size() << " triangles at "
                     << options.atlas.resolution << "^2";
  REFLCAP_RETURN_IF_ERROR(ComputeUvAtlas(&mesh, options.atlas, &atlas_stats));
  REFLCAP_ASSIGN_OR_RETURN(TexelAtlas texels,
                           BuildTexelAtlas(mesh, options.atlas.resolution, options.atlas.resolution));
  summary.area_use = atlas_stats.area_use;
  summary.texel_use = double(texels.TexelCount()) / (double(texels.width) * texels.height);
  summary.uv_overlap_pixels = atlas_stats.overlap_pixels;
  report["atlas"] = {{"resolution", options.atlas.resolution},
                     {"gutter_texels", options.atlas.gutter_texels},
                     {"charts", atlas_stats.charts},
                     {"charts_split_for_overlap", atlas_stats.split_charts},
                     {"area_use", atlas_stats.area_use},
                     {"texel_use", summary.texel_use},
                     {"texels", int64_t(texels.TexelCount())},
                     {"overlap_pixels", atlas_stats.overlap_pixels},
                     {"overlap_check_resolution", kOverlapCheckResolution},
                     {"max_stretch", atlas_stats.max_stretch},
                     {"texels_per_mm", atlas_stats.scale_texels_per_m / 1000.0},
                     {"seconds", atlas_stats.seconds}};

  // Outputs.
  REFLCAP_RETURN_IF_ERROR(WriteObj(out_dir / "mesh.obj", mesh));
  REFLCAP_RETURN_IF_ERROR(WriteGltf(out_dir / "mesh.gltf", mesh));
  REFLCAP_ASSIGN_OR_RETURN(Image preview, RenderPreview(mesh, spec));
  REFLCAP_RETURN_IF_ERROR(WritePng(out_dir / "preview.png", preview));
  REFLCAP_RETURN_IF_ERROR(WritePng(out_dir / "atlas.png", AtlasImage(texels)));

  // Reference comparison.
  t0 = std::chrono::steady_clock::now();
  std::optional<fs::path> reference;
  if (options.reference == "none") {
  } else if (!options.reference.empty()) {
    reference = options.reference;
  } else {
    reference = spec.reference_mesh;
  }
  if (reference) {
    REFLCAP_LOG(kInfo) << "scan: distances to " << reference->string();
    auto ref = LoadMesh(*reference);
    if (!ref.ok()) return ref.status().WithContext("reference mesh");
    std::vector<Vec3f> measured;
    for (const ViewCloud& c : clouds) measured.insert(measured.end(), c.points.begin(), c.points.end());
    const double seen_limit = kSeenSpacings * surface.point_spacing_m;
    // Accuracy over the surface a view saw: scan samples near a measured point (the rest is
    // Poisson's fill of small unseen gaps, reported as its share of the area).
    const std::vector<Vec3f> all_scan_samples = SampleSurface(mesh, options.distance_samples, 1);
    const std::vector<double> scan_to_points = DistanceToPoints(measured, all_scan_samples);
    std::vector<Vec3f> scan_samples;
    for (size_t i = 0; i < all_scan_samples.size(); ++i) {
      if (scan_to_points[i] <= seen_limit) scan_samples.push_back(all_scan_samples[i]);
    }
    REFLCAP_ASSIGN_OR_RETURN(std::vector<double> acc, DistanceToMesh(*ref, scan_samples));
    REFLCAP_ASSIGN_OR_RETURN(std::vector<double> acc_all, DistanceToMesh(*ref, all_scan_samples));
    const std::vector<Vec3f> ref_samples = SampleSurface(*ref, options.distance_samples, 2);
    const std::vector<double> to_points = DistanceToPoints(measured, ref_samples);
    std::vector<Vec3f> seen;
    for (size_t i = 0; i < ref_samples.size(); ++i) {
      if (to_points[i] <= seen_limit) seen.push_back(ref_samples[i]);
    }
    REFLCAP_ASSIGN_OR_RETURN(std::vector<double> comp, DistanceToMesh(mesh, seen));
    const DistanceStats a = Summarise(acc), c = Summarise(comp);
    report["reference"] = {{"mesh", reference->string()},
                           {"accuracy_scan_to_reference", StatsJson(a)},
                           {"accuracy_whole_scan_to_reference", StatsJson(Summarise(acc_all))},
                           {"seen_fraction_of_scan", all_scan_samples.empty() ? 0.0
                                : double(scan_samples.size()) / double(all_scan_samples.size())},
                           {"completeness_seen_reference_to_scan", StatsJson(c)},
                           {"seen_fraction_of_reference", double(seen.size()) / double(ref_samples.size())},
                           {"seen_definition", StrCat("points (of the scan or the reference) within ",
                                                      Mm(seen_limit), " mm of a measured point")},
                           {"seconds", Seconds(t0)}};
    summary.has_reference = true;
    summary.accuracy_median_m = a.median_m;
    summary.accuracy_p95_m = a.p95_m;
    summary.completeness_p95_m = c.p95_m;
    summary.completeness_over_1mm = c.fraction_over_1mm;
  }

  if (!options.capture.empty()) {
    REFLCAP_RETURN_IF_ERROR(WriteDerivedCapture(spec, options.capture, out_dir, "mesh.obj"));
    report["capture"] = {{"source", options.capture}, {"written", "capture.json"}};
  }
  summary.seconds = Seconds(start);
  report["seconds"] = {{"decode_triangulate", decode_s}, {"register", register_s}, {"total", summary.seconds}};
  Json outputs = {"mesh.obj", "mesh.gltf", "preview.png", "atlas.png", "decode_AAA.png", "scan_report.json"};
  if (options.write_clouds) outputs.push_back("points_AAA.ply");
  if (!options.capture.empty()) outputs.push_back("capture.json");
  report["outputs"] = outputs;
  REFLCAP_RETURN_IF_ERROR(WriteTextFileAtomic(out_dir / "scan_report.json", report.dump(1) + "\n"));
  return summary;
}

}  // namespace reflcap::scan
