// Synthetic capture generator (see synth.h).
#include "acquire/synth/synth.h"

#include <algorithm>
#include <chrono>
#include <iterator>
#include <cmath>
#include <cstdio>
#include <map>
#include <memory>
#include <mutex>
#include <random>

#include <nlohmann/json.hpp>

#include "engine/brdf/lafortune.h"
#include "engine/capture/capture.h"
#include "engine/core/log.h"
#include "engine/core/parallel.h"
#include "engine/core/progress.h"
#include "engine/core/worker_pool.h"
#include "engine/image/exr_io.h"
#include "engine/image/png_io.h"
#include "engine/mesh/mesh_io.h"
#include "engine/mesh/ray_scene.h"
#include "engine/mesh/texel_atlas.h"
#include "engine/texel/brdf_maps.h"
#include "render/reference/reference_renderer.h"

namespace reflcap::synth {
namespace fs = std::filesystem;
using Json = nlohmann::json;

namespace {

constexpr double kObjectRadius = 0.1;          // metres, before relief
constexpr double kCameraDistance = 0.8;        // metres from the object centre (as suzanne's rig)
constexpr double kLightDistance = 1.0;         // metres from the object centre
constexpr double kLightIntensity = 2.0;        // W/sr per channel: lit matte texels ≈ 0.1–0.4
constexpr double kImageFill = 0.75;            // object diameter / image width
// UV gutter between charts, as a fraction of a chart cell: >= 1 atlas pixel at the smallest
// preset resolution, so no texel straddles two charts.
constexpr double kChartGutter = 0.025;

struct Preset {
  const char* name;
  int64_t texels;
  int image_size;
  int cameras, lights, steps;
  int face_resolution;  // quads per cube-face edge
};

constexpr Preset kPresets[] = {
    {"small", 20000, 192, 3, 8, 12, 40},
    {"medium", 150000, 384, 4, 8, 12, 96},
    {"million", 1000000, 1024, 4, 6, 12, 160},
};

// ---- Object ----------------------------------------------------------------------------------

struct ReliefFeature {
  Vec3d centre;       // unit direction
  double amplitude;   // relative radius change at the centre
  double width_rad;   // Gaussian width in angle
};

std::vector<ReliefFeature> MakeRelief(uint64_t seed) {
  std::mt19937_64 rng(seed * 7919 + 17);
  std::normal_distribution<double> g;
  auto random_dir = [&] { return Vec3d(g(rng), g(rng), g(rng)).normalized(); };
  std::vector<ReliefFeature> features;
  for (int i = 0; i < 4; ++i) features.push_back({random_dir(), 0.30, 0.22});   // bumps
  for (int i = 0; i < 3; ++i) features.push_back({random_dir(), -0.22, 0.20});  // dimples
  return features;
}

double Relief(const std::vector<ReliefFeature>& features, const Vec3d& d) {
  double r = 1;
  for (const auto& f : features) {
    const double angle = std::acos(std::clamp(d.dot(f.centre), -1.0, 1.0));
    r += f.amplitude * std::exp(-0.5 * (angle / f.width_rad) * (angle / f.width_rad));
  }
  // A groove around the equator of a tilted axis, and a fine ripple.
  const double tilted = d.dot(Vec3d(0.3, 0.2, 1).normalized());
  r -= 0.07 * std::exp(-0.5 * (tilted / 0.05) * (tilted / 0.05));
  r += 0.015 * std::sin(9 * d.x()) * std::sin(7 * d.y() + 1) * std::sin(8 * d.z() + 2);
  return r;
}

// Cube face f: outward axis and in-plane axes with u x v = axis (counter-clockwise from outside).
void FaceAxes(int f, Vec3d* axis, Vec3d* u, Vec3d* v) {
  static const int kAxes[6][3][3] = {
      {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}},    {{-1, 0, 0}, {0, -1, 0}, {0, 0, 1}},
      {{0, 1, 0}, {-1, 0, 0}, {0, 0, 1}},   {{0, -1, 0}, {1, 0, 0}, {0, 0, 1}},
      {{0, 0, 1}, {1, 0, 0}, {0, 1, 0}},    {{0, 0, -1}, {1, 0, 0}, {0, -1, 0}}};
  *axis = Vec3d(kAxes[f][0][0], kAxes[f][0][1], kAxes[f][0][2]);
  *u = Vec3d(kAxes[f][1][0], kAxes[f][1][1], kAxes[f][1][2]);
  *v = Vec3d(kAxes[f][2][0], kAxes[f][2][1], kAxes[f][2][2]);
}

// Equal-angle warp of the cube face coordinate; exact at the face border so seams weld bitwise.
double Warp(int i, int n) {
  if (i == 0) return -1;
  if (i == n) return 1;
  return std::tan((2.0 * i / n - 1) * kPi / 4);
}

}  // namespace

TriangleMesh MakeReliefObject(int n, uint64_t seed) {
  const std::vector<ReliefFeature> features = MakeRelief(seed);
  // Lowest point rests on z = 0: the centre is lifted by the relief radius straight down.
  const double lift = kObjectRadius * Relief(features, -Vec3d::UnitZ());
  TriangleMesh mesh;
  std::map<std::array<float, 3>, uint32_t> weld;  // exact-position welding across face seams
  const double cell = 1.0 / 3.0;
  for (int f = 0; f < 6; ++f) {
    Vec3d axis, u, v;
    FaceAxes(f, &axis, &u, &v);
    const double cu = (f % 3) * cell, cv = (f / 3) * cell;
    std::vector<uint32_t> ids((n + 1) * (n + 1));
    std::vector<Vec2f> uvs((n + 1) * (n + 1));
    for (int j = 0; j <= n; ++j) {
      for (int i = 0; i <= n; ++i) {
        const Vec3d d = (axis + Warp(i, n) * u + Warp(j, n) * v).normalized();
        const Vec3d p = kObjectRadius * Relief(features, d) * d + Vec3d(0, 0, lift);
        const Vec3f pf = p.cast<float>();
        auto [it, inserted] = weld.try_emplace({pf.x(), pf.y(), pf.z()}, uint32_t(mesh.positions.size()));
        if (inserted) mesh.positions.push_back(pf);
        ids[j * (n + 1) + i] = it->second;
        const double s = kChartGutter + (1 - 2 * kChartGutter) * double(i) / n;
        const double t = kChartGutter + (1 - 2 * kChartGutter) * double(j) / n;
        uvs[j * (n + 1) + i] = Vec2f(float(cu + cell * s), float(cv + cell * t));
      }
    }
    for (int j = 0; j < n; ++j) {
      for (int i = 0; i < n; ++i) {
        const int a = j * (n + 1) + i, b = a + 1, c = a + n + 2, d = a + n + 1;
        // Alternate the diagonal so the tessellation has no preferred direction.
        if ((i + j) % 2 == 0) {
          mesh.triangles.push_back({ids[a], ids[b], ids[c]});
          mesh.corner_uvs.push_back({uvs[a], uvs[b], uvs[c]});
          mesh.triangles.push_back({ids[a], ids[c], ids[d]});
          mesh.corner_uvs.push_back({uvs[a], uvs[c], uvs[d]});
        } else {
          mesh.triangles.push_back({ids[a], ids[b], ids[d]});
          mesh.corner_uvs.push_back({uvs[a], uvs[b], uvs[d]});
          mesh.triangles.push_back({ids[b], ids[c], ids[d]});
          mesh.corner_uvs.push_back({uvs[b], uvs[c], uvs[d]});
        }
      }
    }
  }
  // Smooth normals: area-weighted face normals accumulated on welded vertices.
  std::vector<Vec3f> normals(mesh.positions.size(), Vec3f::Zero());
  for (const auto& tri : mesh.triangles) {
    const Vec3f w = (mesh.positions[tri[1]] - mesh.positions[tri[0]])
                        .cross(mesh.positions[tri[2]] - mesh.positions[tri[0]]);
    for (uint32_t id : tri) normals[id] += w;
  }
  for (auto& nrm : normals) nrm.normalize();
  for (const auto& tri : mesh.triangles) {
    mesh.corner_normals.push_back({normals[tri[0]], normals[tri[1]], normals[tri[2]]});
  }
  return mesh;
}

namespace {

// ---- Materials -------------------------------------------------------------------------------

enum Material { kMatte, kGlossy, kSharp, kAnisotropic, kTextured, kMetallic, kMaterialCount };
const char* const* kMaterialNames = kSynthMaterialNames;

// The material ids options.materials names (all of them when it is empty); names are checked by
// SynthOptions::Validate.
std::vector<int> SelectedMaterials(const std::vector<std::string>& names) {
  std::vector<int> ids;
  for (int m = 0; m < kMaterialCount; ++m) {
    if (names.empty() || std::find(names.begin(), names.end(), kMaterialNames[m]) != names.end()) {
      ids.push_back(m);
    }
  }
  return ids;
}

// Normalised-Phong-like peak for a lobe of specular albedo ks: ks (n + 2) / (2π).
double Peak(double ks, double n) { return ks * (n + 2) / (2 * kPi); }

brdf::BrdfParams MaterialParams(int material, const Vec3d& p_in_object) {
  brdf::BrdfParams p;
  p.num_lobes = 1;
  // `anisotropy` a: Cx = -c a, Cy = -c / a (brdf::MirrorLobe); 1 = isotropic.
  auto set = [&](Vec3d rho, Vec3d ks, double n, double anisotropy = 1) {
    for (int c = 0; c < 3; ++c) {
      p.rho_d[c] = float(rho[c]);
      p.lobes[0][c] = ks[c] > 0 ? brdf::MirrorLobe(Peak(ks[c], n), n, anisotropy)
                                : brdf::LobeParams{0, 0, 0, 1};
    }
  };
  switch (material) {
    case kMatte: set({0.60, 0.55, 0.50}, {0, 0, 0}, 1); break;
    case kGlossy: set({0.25, 0.35, 0.60}, {0.35, 0.35, 0.35}, 25); break;
    case kSharp: set({0.50, 0.15, 0.10}, {0.5, 0.5, 0.5}, 250); break;
    case kAnisotropic: set({0.30, 0.50, 0.30}, {0.3, 0.3, 0.3}, 40, 0.985); break;
    case kTextured: {
      // Stripes in object space between two colours, soft-edged so the map is not aliased.
      const double s = 0.5 + 0.5 * std::tanh(6 * std::sin(p_in_object.x() * 90 + p_in_object.z() * 60));
      const Vec3d a(0.70, 0.45, 0.15), b(0.15, 0.30, 0.55);
      set(a + s * (b - a), {0.1, 0.1, 0.1}, 10);
      break;
    }
    default: set({0.05, 0.04, 0.02}, {0.9, 0.7, 0.35}, 80); break;  // kMetallic
  }
  return p;
}

// ---- Rig -------------------------------------------------------------------------------------

Camera ArcCamera(const std::string& id, double elevation_deg, const Vec3d& target, int size,
                 double focal_px) {
  Camera cam;
  cam.id = id;
  cam.width = cam.height = size;
  cam.K << focal_px, 0, 0.5 * (size - 1), 0, focal_px, 0.5 * (size - 1), 0, 0, 1;
  const double el = DegToRad(elevation_deg);
  const Vec3d eye = target + kCameraDistance * Vec3d(std::cos(el), 0, std::sin(el));
  cam.cam_from_world = CamFromWorldLookAt(eye, target);
  return cam;
}

double Spread(int i, int count, double lo, double hi) {
  return count == 1 ? 0.5 * (lo + hi) : lo + (hi - lo) * i / (count - 1);
}

}  // namespace

const char* const kSynthMaterialNames[6] = {"matte", "glossy", "sharp_highlight", "anisotropic",
                                            "coloured_texture", "coloured_lobe"};

Status SynthOptions::Validate() const {
  for (const std::string& name : materials) {
    if (std::find(std::begin(kSynthMaterialNames), std::end(kSynthMaterialNames), name) ==
        std::end(kSynthMaterialNames)) {
      return InvalidArgumentError("--materials: unknown material \"", name,
                                  "\" (matte, glossy, sharp_highlight, anisotropic, "
                                  "coloured_texture, coloured_lobe)");
    }
  }
  bool known = false;
  for (const auto& p : kPresets) known |= preset == p.name;
  if (!known) return InvalidArgumentError("--preset: unknown preset \"", preset, "\" (small, medium, million)");
  if (!(noise >= 0 && noise <= 1)) return InvalidArgumentError("--noise: must be in [0, 1], got ", noise);
  if (!(saturation >= 0) || !std::isfinite(saturation)) return InvalidArgumentError("--saturation: must be >= 0");
  if (texels < 0 || texels > 50'000'000) return InvalidArgumentError("--texels: must be in [1, 5e7]");
  if (image_size < 0 || image_size > 8192) return InvalidArgumentError("--image-size: must be in [16, 8192]");
  if (image_size > 0 && image_size < 16) return InvalidArgumentError("--image-size: must be in [16, 8192]");
  if (cameras < 0 || cameras > 64) return InvalidArgumentError("--cameras: must be in [1, 64]");
  if (lights < 0 || lights > 256) return InvalidArgumentError("--lights: must be in [1, 256]");
  if (steps < 0 || steps > 360) return InvalidArgumentError("--steps: must be in [1, 360]");
  if (!(pixel_footprint >= 1 && pixel_footprint <= render::kMaxPixelFootprint)) {
    return InvalidArgumentError("--pixel-footprint: must be in [1, ", render::kMaxPixelFootprint,
                                "]");
  }
  render::RenderOptions render_options;
  render_options.supersampling = supersampling;
  render_options.pixel_footprint = pixel_footprint;
  return render_options.Validate();
}

StatusOr<SynthSummary> WriteSyntheticCapture(const SynthOptions& options, const fs::path& out) {
  REFLCAP_RETURN_IF_ERROR(options.Validate());
  const auto start = std::chrono::steady_clock::now();
  Preset preset = kPresets[0];
  for (const auto& p : kPresets) {
    if (options.preset == p.name) preset = p;
  }
  const int64_t target_texels = options.texels ? options.texels : preset.texels;
  const int image_size = options.image_size ? options.image_size : preset.image_size;
  const int num_cameras = options.cameras ? options.cameras : preset.cameras;
  const int num_lights = options.lights ? options.lights : preset.lights;
  const int num_steps = options.steps ? options.steps : preset.steps;
  // Six charts of (1 - 2 gutter) / 3 of the atlas side each: resolution for the target count.
  const int atlas_res = std::max(
      8, int(std::ceil(3 * std::sqrt(double(target_texels) / 6) / (1 - 2 * kChartGutter))));

  const int face_res = preset.face_resolution;

  SynthSummary summary;
  std::error_code ec;
  fs::create_directories(out, ec);
  if (ec) return InternalError(out.string(), ": cannot create folder: ", ec.message());
  TriangleMesh mesh = MakeReliefObject(face_res, options.seed);
  summary.triangles = mesh.triangles.size();
  REFLCAP_RETURN_IF_ERROR(WriteObj(out / "mesh.obj", mesh));
  REFLCAP_ASSIGN_OR_RETURN(std::unique_ptr<RayScene> scene, RayScene::Create(mesh));
  REFLCAP_ASSIGN_OR_RETURN(TexelAtlas atlas, BuildTexelAtlas(mesh, atlas_res, atlas_res));
  summary.atlas_resolution = atlas_res;
  summary.texels = atlas.TexelCount();

  // Ground truth: materials by region (Voronoi cells of 12 seeded directions on the sphere).
  const Eigen::AlignedBox3f bounds = mesh.Bounds();
  const Vec3d centre = bounds.center().cast<double>();
  std::mt19937_64 rng(options.seed * 104729 + 3);
  std::normal_distribution<double> g;
  std::vector<Vec3d> sites;
  for (int i = 0; i < 2 * kMaterialCount; ++i) sites.push_back(Vec3d(g(rng), g(rng), g(rng)).normalized());
  BrdfMaps gt;
  gt.num_lobes = 1;
  gt.texels.resize(atlas.TexelCount());
  Image material_map(atlas.width, atlas.height, 1, 0.0f);
  std::vector<size_t> material_texels(kMaterialCount, 0);
  const std::vector<int> selected = SelectedMaterials(options.materials);
  for (size_t t = 0; t < atlas.TexelCount(); ++t) {
    const Vec3d p = atlas.position[t].cast<double>();
    const Vec3d d = (p - centre).normalized();
    int best = 0;
    for (int i = 1; i < int(sites.size()); ++i) {
      if (d.dot(sites[i]) > d.dot(sites[best])) best = i;
    }
    const int material = selected[size_t(best) % selected.size()];
    gt.texels[t] = MaterialParams(material, p);
    material_map.data[atlas.pixel_of_texel[t]] = float(material + 1);
    ++material_texels[material];
  }
  fs::create_directories(out / "gt");
  REFLCAP_RETURN_IF_ERROR(WriteBrdfMaps(out / "gt" / "params.exr", gt, atlas));
  REFLCAP_RETURN_IF_ERROR(WriteExr(out / "gt" / "material.exr", material_map));

  // Rig.
  Capture capture;
  capture.json_path = out / "capture.json";
  capture.mesh = "mesh.obj";
  capture.turntable = Turntable{};
  const double bound_radius = 0.5 * bounds.diagonal().norm() / std::sqrt(3.0) * 1.2;
  const double focal = 0.5 * kImageFill * image_size / std::tan(std::asin(
                           std::min(0.9, bound_radius / kCameraDistance)));
  std::vector<double> cam_elevations, light_elevations, light_azimuths;
  for (int c = 0; c < num_cameras; ++c) {
    cam_elevations.push_back(Spread(c, num_cameras, 10, 70));
    capture.cameras.push_back(ArcCamera(StrCat("cam", c), cam_elevations.back(), centre, image_size, focal));
    // One ray per pixel centre: each pixel is a point sample (camera.h); --supersample N
    // averages N x N rays over the pixel, an area filter.
    capture.cameras.back().pixel_filter =
        options.supersampling == 1 ? PixelFilter::kPoint : PixelFilter::kArea;
  }
  static const double kLightElevations[3] = {20, 50, 75};
  for (int l = 0; l < num_lights; ++l) {
    Light light;
    light.id = StrCat("L", l);
    const double el = DegToRad(kLightElevations[l % 3]);
    const double az = DegToRad(Spread(l, num_lights, -150, 150));
    light_elevations.push_back(kLightElevations[l % 3]);
    light_azimuths.push_back(RadToDeg(az));
    light.position = centre + kLightDistance * Vec3d(std::cos(el) * std::cos(az),
                                                     std::cos(el) * std::sin(az), std::sin(el));
    light.intensity = Vec3d::Constant(kLightIntensity);
    capture.lights.push_back(light);
  }
  std::vector<double> holdout_angles;
  for (int s = 0; s < num_steps; ++s) {
    const double angle = 360.0 * s / num_steps;
    const bool holdout_angle = num_steps >= 4 && s % 4 == 1;
    if (holdout_angle) holdout_angles.push_back(angle);
    for (int c = 0; c < num_cameras; ++c) {
      for (int l = 0; l < num_lights; ++l) {
        CaptureImage image;
        char name[32];
        std::snprintf(name, sizeof name, "images/%04zu.exr", capture.images.size());
        image.file = name;
        image.camera = c;
        image.light = l;
        image.turntable_deg = angle;
        image.exposure_s = 1;
        image.saturation = options.saturation;
        const bool holdout_light = num_lights >= 2 && l == num_lights - 1;
        image.split = holdout_angle || holdout_light ? Split::kHoldout : Split::kTrain;
        capture.images.push_back(image);
      }
    }
  }
  summary.images = capture.images.size();
  summary.train_images = capture.CountSplit(Split::kTrain);
  summary.holdout_images = capture.CountSplit(Split::kHoldout);

  // Photographs.
  fs::create_directories(out / "images");
  fs::create_directories(out / "masks");
  const render::ShadedScene shaded{scene.get(), &atlas, &gt};
  render::RenderOptions render_options;
  render_options.supersampling = options.supersampling;
  render_options.pixel_footprint = options.pixel_footprint;
  const double read_sigma = kReadNoiseRatio * options.noise;
  Progress progress("synth: rendering", int64_t(capture.images.size()));
  // Files are compressed and written by a pool while the next photographs render (a million-texel
  // preset's 288 ZIP-compressed float EXRs took most of its time on one thread); at most two wait
  // to start, so memory stays a few images per writer.
  std::mutex write_mutex;
  Status write_error = OkStatus();
  auto writers = std::make_unique<WorkerPool>(std::max(1, HardwareThreads()), /*max_queued=*/2);
  for (size_t i = 0; i < capture.images.size(); ++i) {
    const CaptureImage& image = capture.images[i];
    const Camera& cam = capture.cameras[image.camera];
    REFLCAP_ASSIGN_OR_RETURN(
        render::RenderResult r,
        render::RenderImage(shaded, cam, capture.lights[image.light],
                            capture.WorldFromObject(image), image.exposure_s, render_options));
    if (options.noise > 0) {
      // Rows get independent, reproducible streams: seed, image index and row.
      ParallelFor(0, cam.height, 16, [&](int64_t y0, int64_t y1, int) {
        for (int64_t y = y0; y < y1; ++y) {
          std::mt19937_64 row_rng((options.seed * 1000003 + i) * 65537 + uint64_t(y));
          std::normal_distribution<float> normal;
          float* row = r.pixels.pixel(0, int(y));
          for (int k = 0; k < cam.width * 3; ++k) {
            const double v = std::max(0.0f, row[k]);
            const double sigma = std::sqrt(options.noise * options.noise * v + read_sigma * read_sigma);
            row[k] = float(row[k] + sigma * normal(row_rng));
          }
        }
      });
    }
    if (options.saturation > 0) {
      for (float& v : r.pixels.data) v = std::min(v, float(options.saturation));
    }
    std::string mask_name;
    if (image.light == 0) {
      char name[64];
      std::snprintf(name, sizeof name, "masks/%s_%03d.png", cam.id.c_str(),
                    int(std::lround(image.turntable_deg)));
      mask_name = name;
    }
    auto result = std::make_shared<render::RenderResult>(std::move(r));
    writers->Submit([&, result, file = out / image.file, mask_name] {
      Status s = WriteExr(file, result->pixels, ExrPixelType::kFloat);
      if (s.ok() && !mask_name.empty()) s = WritePng(out / mask_name, result->mask);
      if (!s.ok()) {
        const std::lock_guard<std::mutex> lock(write_mutex);
        if (write_error.ok()) write_error = s;
      }
    });
    {
      const std::lock_guard<std::mutex> lock(write_mutex);
      if (!write_error.ok()) break;
    }
    progress.Advance();
  }
  writers.reset();  // waits for every queued write
  REFLCAP_RETURN_IF_ERROR(write_error);
  progress.Finish();

  Json materials = Json::array();
  for (int m = 0; m < kMaterialCount; ++m) {
    materials.push_back({{"id", m + 1}, {"name", kMaterialNames[m]}, {"texels", material_texels[m]}});
  }
  Json lights_json = Json::array();
  for (int l = 0; l < num_lights; ++l) {
    lights_json.push_back({{"id", capture.lights[l].id},
                           {"elevation_deg", light_elevations[l]},
                           {"azimuth_deg", light_azimuths[l]}});
  }
  Json truth = {
      {"note", "Synthetic capture rendered by reflcap's CPU reference renderer (direct light, cast "
               "shadows, no interreflection) from Lambert + Lafortune ground truth."},
      {"generator", {{"name", "reflcap synth"}, {"preset", preset.name}, {"seed", options.seed},
                     {"supersampling", options.supersampling},
                     {"pixel_footprint", options.pixel_footprint}}},
      {"brdf_convention", "f_c(wi, wo) = rho_d.c / pi + sum_k max(0, Cx wix wox + Cy wiy woy + "
                          "Cz wiz woz)^n in the texel tangent frame (z = shading normal, x = "
                          "tangent along +u)"},
      {"atlas", {{"width", atlas_res}, {"height", atlas_res}, {"texels", atlas.TexelCount()}}},
      {"params", {{"file", "gt/params.exr"}, {"num_lobes", 1},
                  {"channels", "rho_d.{R,G,B}, lobe0.{Cx,Cy,Cz,n}.{R,G,B} in atlas layout"}}},
      {"materials", {{"file", "gt/material.exr"},
                     {"encoding", "Y channel in atlas layout: material id, 0 = no texel"},
                     {"list", materials}}},
      {"noise", {{"model", "photon + read: std = sqrt(photon_sigma_at_1^2 * max(value, 0) + read_sigma^2)"},
                 {"photon_sigma_at_1", options.noise},
                 {"read_sigma", read_sigma},
                 {"saturation", options.saturation}}},
      {"masks", {{"files", "masks/{camera}_{turntable_deg:03d}.png; one per (camera, turntable angle)"},
                 {"encoding", "8-bit grey PNG, 255 = object, 0 = background"},
                 {"definition", "255 iff the camera ray through the pixel centre hits the mesh"}}},
      {"object", {{"kind", "relief cube-sphere (bumps, dimples, groove, ripple)"},
                  {"radius_m", kObjectRadius},
                  {"face_resolution", face_res},
                  {"triangles", mesh.triangles.size()},
                  {"bbox_min", {bounds.min().x(), bounds.min().y(), bounds.min().z()}},
                  {"bbox_max", {bounds.max().x(), bounds.max().y(), bounds.max().z()}}}},
      {"rig", {{"cam_elevations_deg", cam_elevations},
               {"cam_distance_m", kCameraDistance},
               {"light_distance_m", kLightDistance},
               {"lights", lights_json},
               {"steps", num_steps},
               {"holdout_angles_deg", holdout_angles},
               {"holdout_light", num_lights >= 2 ? capture.lights.back().id : ""},
               {"camera_target", {centre.x(), centre.y(), centre.z()}}}}};
  capture.ground_truth_json = truth.dump();
  REFLCAP_RETURN_IF_ERROR(WriteCapture(capture, capture.json_path));
  summary.seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return summary;
}

}  // namespace reflcap::synth
