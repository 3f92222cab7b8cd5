// Synthetic brackets/1 data (see synthetic_brackets.h).
#include "tests/acquire/radiometry/synthetic_brackets.h"

#include <cmath>
#include <fstream>

#include <nlohmann/json.hpp>

#include "acquire/radiometry/colour.h"
#include "engine/camera/camera.h"
#include "engine/image/exr_io.h"
#include "engine/image/png_io.h"
#include "tests/support/test_support.h"

namespace reflcap::radiometry::testing {
namespace fs = std::filesystem;
using Json = nlohmann::json;

namespace {

// The chart's black frame (brackets/1: albedo 0.010) and its margin around the patch grid.
constexpr double kFrameAlbedo = 0.010;
constexpr double kMarginM = 0.010;
constexpr int kSupersample = 4;
const Vec3d kLightPosition(0.30, 0.25, 0.70);
constexpr double kLightIntensity = 2.4;
constexpr double kChartDistanceM = 0.8;

struct Rng {
  uint64_t state;
  double Uniform() {
    uint64_t z = (state += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return double((z ^ (z >> 31)) >> 11) * (1.0 / 9007199254740992.0);
  }
  double Normal() {
    const double u1 = std::max(Uniform(), 1e-300), u2 = Uniform();
    return std::sqrt(-2 * std::log(u1)) * std::cos(2 * kPi * u2);
  }
};

Json MatrixJson(const Mat4d& m) {
  Json j = Json::array();
  for (int r = 0; r < 4; ++r) j.push_back({m(r, 0), m(r, 1), m(r, 2), m(r, 3)});
  return j;
}

Json CameraJson(const Camera& c) {
  Json K = Json::array();
  for (int r = 0; r < 3; ++r) K.push_back({c.K(r, 0), c.K(r, 1), c.K(r, 2)});
  return {{"id", c.id}, {"width", c.width}, {"height", c.height}, {"K", K},
          {"dist", {0, 0, 0, 0, 0}}, {"cam_from_world", MatrixJson(c.cam_from_world.ToMatrix())}};
}

// The LDR exposures of a linear photo through the synthetic camera.
std::vector<Image> Expose(const Image& radiance, const SyntheticBracketsOptions& o, Rng* rng) {
  std::vector<Image> out;
  for (double t : o.exposures) {
    Image ldr(radiance.width, radiance.height, 3);
    for (size_t i = 0; i < ldr.data.size(); ++i) {
      const int c = int(i % 3);
      const double raw = o.gains[c] * t * radiance.data[i] + o.read_sigma * rng->Normal();
      ldr.data[i] = float(std::lround(255 * o.response(std::clamp(raw, 0.0, 1.0))) / 255.0);
    }
    out.push_back(std::move(ldr));
  }
  return out;
}

double InverseResponse(const std::function<double(double)>& f, double y) {
  double lo = 0, hi = 1;
  for (int i = 0; i < 100; ++i) {
    const double mid = 0.5 * (lo + hi);
    (f(mid) < y ? lo : hi) = mid;
  }
  return 0.5 * (lo + hi);
}

}  // namespace

double LogLogisticResponse(double x) {
  const double a = 1.4, k = 0.3;
  const double s1 = 1 / (1 + std::pow(k, a));
  const double xa = std::pow(std::max(x, 0.0), a);
  return xa / (xa + std::pow(k, a)) / s1;
}

double RippledResponse(double x) {
  const double u = std::pow(std::max(x, 0.0), 1 / 2.2);
  return u * std::exp(0.02 * std::sin(3 * kPi * u));
}

SyntheticBrackets WriteSyntheticBrackets(const fs::path& dir, const SyntheticBracketsOptions& o) {
  SyntheticBrackets out;
  out.json = dir / "brackets.json";
  fs::create_directories(dir / "ldr");
  fs::create_directories(dir / "truth");
  fs::create_directories(dir / "source");
  fs::create_directories(dir / "chart");
  Rng rng{o.seed * 7919 + 13};
  for (int k = 0; k < 256; ++k) out.x_of_code.push_back(InverseResponse(o.response, k / 255.0));

  // Rig: cam0 photographs the object, cam1 the chart; one point light.
  Camera cam0;
  cam0.id = "cam0";
  cam0.width = cam0.height = o.object_size;
  cam0.K << 100, 0, 0.5 * (o.object_size - 1), 0, 100, 0.5 * (o.object_size - 1), 0, 0, 1;
  cam0.cam_from_world = CamFromWorldLookAt(Vec3d(0, -1, 0.2), Vec3d::Zero(), Vec3d::UnitZ());
  Camera cam1;
  cam1.id = "cam1";
  cam1.width = o.chart_width;
  cam1.height = o.chart_height;
  const double grid_w = 6 * 0.040 + 5 * 0.006, outer_w = grid_w + 2 * kMarginM;
  const double f = 0.85 * o.chart_width * kChartDistanceM / outer_w;
  cam1.K << f, 0, 0.5 * (o.chart_width - 1), 0, f, 0.5 * (o.chart_height - 1), 0, 0, 1;
  cam1.cam_from_world =
      CamFromWorldLookAt(Vec3d(0, 0, kChartDistanceM), Vec3d::Zero(), Vec3d::UnitY());
  const Mat3d tilt = AxisAngleRotation(Vec3d::UnitY(), DegToRad(o.chart_tilt_deg));
  const Mat3d roll = AxisAngleRotation(Vec3d::UnitZ(), DegToRad(o.chart_roll_deg));
  out.world_from_chart.rotation = tilt * roll;
  out.world_from_chart.translation = Vec3d::Zero();

  Json brackets = {{"format", "brackets/1"}, {"source_capture", "source/capture.json"}};
  brackets["cameras"] = Json::array({CameraJson(cam0), CameraJson(cam1)});
  brackets["lights"] = Json::array({Json{{"id", "L0"}, {"type", "point"},
                                         {"position", {kLightPosition.x(), kLightPosition.y(), kLightPosition.z()}},
                                         {"intensity", {kLightIntensity, kLightIntensity, kLightIntensity}}}});
  brackets["turntable"] = {{"axis", {0, 0, 1}}, {"point", {0, 0, 0}}};
  Json photos = Json::array();
  auto add_photo = [&](const std::string& id, const std::string& subject, const std::string& camera,
                       const Image& radiance) {
    const std::vector<Image> ldr = Expose(radiance, o, &rng);
    Json exposures = Json::array();
    for (size_t e = 0; e < ldr.size(); ++e) {
      const std::string file = "ldr/" + id + "_e" + std::to_string(e) + ".png";
      REFLCAP_CHECK(WritePng(dir / file, ldr[e]).ok());
      exposures.push_back({{"file", file}, {"exposure_s", o.exposures[e]}});
    }
    const std::string truth = "truth/" + id + ".exr";
    REFLCAP_CHECK(WriteExr(dir / truth, radiance).ok());
    Json p = {{"id", id}, {"subject", subject}, {"camera", camera}, {"light", "L0"},
              {"split", subject == "object" ? "train" : "calibration"}, {"source_hdr", truth},
              {"exposures", exposures}};
    p["turntable_deg"] = subject == "object" ? Json(0.0) : Json(nullptr);
    if (subject == "colorchecker") p["chart"] = "chart/chart.json";
    photos.push_back(p);
  };

  // Object photos: smooth random log-radiance fields over ~5 decades, a black corner and a
  // highlight clipped even at the shortest exposure.
  for (int i = 0; i < o.object_photos; ++i) {
    Image radiance(o.object_size, o.object_size, 3);
    double phase[3][4];
    for (auto& pc : phase) {
      for (double& v : pc) v = 2 * kPi * rng.Uniform();
    }
    for (int y = 0; y < o.object_size; ++y) {
      for (int x = 0; x < o.object_size; ++x) {
        const double u = double(x) / o.object_size, v = double(y) / o.object_size;
        const bool background = u + v < 0.15;
        // A highlight clipped at every exposure (g · t_min · L > 1 for every channel).
        const bool highlight = u > 0.9 && v > 0.9;
        for (int c = 0; c < 3; ++c) {
          const double field = 0.5 * (u + v) + 0.12 * std::sin(7 * u + phase[c][0]) +
                               0.12 * std::sin(9 * v + phase[c][1]) +
                               0.08 * std::sin(23 * (u - v) + phase[c][2]) +
                               0.05 * std::sin(41 * u + 37 * v + phase[c][3]);
          const double log_l = std::log(2e-4) + (std::log(12.0) - std::log(2e-4)) * std::clamp(field, 0.0, 1.0);
          radiance.at(x, y, c) = background ? 0.0f : highlight ? 20.0f : float(std::exp(log_l));
        }
      }
    }
    char id[16];
    std::snprintf(id, sizeof id, "p%02d", i);
    add_photo(id, "object", "cam0", radiance);
  }

  // The chart.
  ChartLayout layout;
  const Rigid3 chart_from_world = out.world_from_chart.Inverse();
  const Rigid3 world_from_cam = cam1.cam_from_world.Inverse();
  const Vec3d normal = out.world_from_chart.rotation.col(2);
  for (int i = 0; i < kChartPatches; ++i) {
    for (int k = 0; k < 4; ++k) {
      const Vec2d c = layout.PatchCorner(i, k);
      Vec2d px;
      cam1.Project(cam1.cam_from_world * (out.world_from_chart * Vec3d(c.x(), c.y(), 0)), &px);
      out.chart_corners[size_t(i)][size_t(k)] = px;
    }
  }
  if (o.chart) {
    Image radiance(cam1.width, cam1.height, 3);
    const double half_w = 0.5 * grid_w, half_h = 0.5 * (4 * 0.040 + 3 * 0.006);
    for (int y = 0; y < cam1.height; ++y) {
      for (int x = 0; x < cam1.width; ++x) {
        Vec3d sum = Vec3d::Zero();
        for (int sy = 0; sy < kSupersample; ++sy) {
          for (int sx = 0; sx < kSupersample; ++sx) {
            const Vec2d pixel(x - 0.5 + (sx + 0.5) / kSupersample, y - 0.5 + (sy + 0.5) / kSupersample);
            Vec3d origin, direction;
            cam1.PixelRay(pixel, &origin, &direction);
            const Vec3d o_w = world_from_cam * origin, d_w = world_from_cam.rotation * direction;
            const Vec3d o_c = chart_from_world * o_w, d_c = chart_from_world.rotation * d_w;
            if (std::abs(d_c.z()) < 1e-12) continue;
            const double t = -o_c.z() / d_c.z();
            if (t <= 0) continue;
            const Vec3d hit = o_c + t * d_c;
            Vec3d albedo = Vec3d::Zero();
            if (std::abs(hit.x()) <= half_w + kMarginM && std::abs(hit.y()) <= half_h + kMarginM) {
              albedo = Vec3d::Constant(kFrameAlbedo);
              const double gx = hit.x() + half_w, gy = half_h - hit.y();
              const int col = int(std::floor(gx / 0.046)), row = int(std::floor(gy / 0.046));
              if (col >= 0 && col < 6 && row >= 0 && row < 4 && gx - col * 0.046 < 0.040 &&
                  gy - row * 0.046 < 0.040) {
                albedo = PatchAlbedo(row * 6 + col);
              }
            }
            const Vec3d point = out.world_from_chart * Vec3d(hit.x(), hit.y(), 0);
            const Vec3d to_light = kLightPosition - point;
            const double d2 = to_light.squaredNorm();
            const double E = kLightIntensity * std::max(0.0, normal.dot(to_light) / std::sqrt(d2)) / d2;
            sum += albedo * (kInvPi * E);
          }
        }
        for (int c = 0; c < 3; ++c) radiance.at(x, y, c) = float(sum[c] / (kSupersample * kSupersample));
      }
    }
    add_photo("chart", "colorchecker", "cam1", radiance);
    Json patches = Json::array();
    for (int i = 0; i < kChartPatches; ++i) {
      Json corners = Json::array();
      for (const Vec2d& p : out.chart_corners[size_t(i)]) corners.push_back({p.x(), p.y()});
      patches.push_back({{"index", i + 1}, {"corners_px", corners}});
    }
    Json chart = {{"chart", {{"patch_m", 0.040}, {"gap_m", 0.006},
                             {"world_from_chart", MatrixJson(out.world_from_chart.ToMatrix())}}},
                  {"patches", patches}};
    ::reflcap::testing::WriteText(dir / "chart/chart.json", chart.dump(1));
  }
  brackets["photos"] = photos;
  brackets["ground_truth"] = {{"response", {{"x_of_code", out.x_of_code}}},
                              {"wb_gains", {o.gains[0], o.gains[1], o.gains[2]}},
                              {"read_noise_sigma", o.read_sigma}};
  if (o.chart) {
    brackets["ground_truth"]["chart"] = {{"photo_id", "chart"}, {"hdr", "truth/chart.exr"},
                                         {"geometry", "chart/chart.json"}};
  }
  ::reflcap::testing::WriteText(out.json, brackets.dump(1));

  // Source capture: the rig and a one-triangle mesh.
  ::reflcap::testing::WriteText(dir / "source/mesh.obj",
                                "v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n");
  Json source = {{"format", "capture/1"}, {"mesh", "mesh.obj"}, {"cameras", brackets["cameras"]},
                 {"lights", brackets["lights"]}, {"turntable", brackets["turntable"]},
                 {"images", Json::array({Json{{"file", "images/0000.exr"}, {"camera", "cam0"}, {"light", "L0"},
                                              {"turntable_deg", 0.0}, {"exposure_s", 1.0}, {"split", "train"}}})}};
  ::reflcap::testing::WriteText(dir / "source/capture.json", source.dump(1));
  return out;
}

}  // namespace reflcap::radiometry::testing
