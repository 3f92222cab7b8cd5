// Analytic structured-light renders of a sphere (see synthetic_scan.h).
#include "tests/acquire/scan/synthetic_scan.h"

#include <cmath>
#include <fstream>
#include <limits>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "engine/image/png_io.h"

namespace reflcap::scan::testing {
namespace fs = std::filesystem;
using Json = nlohmann::json;

namespace {

constexpr double kAlbedoGain = 0.85;  // white-pattern radiance at normal incidence (< 1: no clip)
constexpr double kAmbient = 0.01;     // stray light on the object in every photograph

Json MatrixJson(const Mat4d& m) {
  Json rows = Json::array();
  for (int r = 0; r < 4; ++r) rows.push_back({m(r, 0), m(r, 1), m(r, 2), m(r, 3)});
  return rows;
}
Json KJson(const Mat3d& k) {
  Json rows = Json::array();
  for (int r = 0; r < 3; ++r) rows.push_back({k(r, 0), k(r, 1), k(r, 2)});
  return rows;
}

Camera MakeDevice(const std::string& id, int w, int h, double f, double azimuth_deg,
                  double elevation_deg, double distance, const Vec3d& target) {
  Camera c;
  c.id = id;
  c.width = w;
  c.height = h;
  c.K << f, 0, (w - 1) / 2.0, 0, f, (h - 1) / 2.0, 0, 0, 1;
  const double az = DegToRad(azimuth_deg), el = DegToRad(elevation_deg);
  const Vec3d eye = target + distance * Vec3d(std::cos(el) * std::cos(az), std::cos(el) * std::sin(az),
                                              std::sin(el));
  c.cam_from_world = CamFromWorldLookAt(eye, target);
  return c;
}

// A latitude-longitude sphere with UVs, as OBJ (the reference mesh of the scan).
void WriteSphereObj(const fs::path& path, const Vec3d& c, double r) {
  std::ofstream out(path);
  const int stacks = 64, slices = 128;
  for (int i = 0; i <= stacks; ++i) {
    const double th = kPi * i / stacks;
    for (int j = 0; j <= slices; ++j) {
      const double ph = 2 * kPi * j / slices;
      const Vec3d p = c + r * Vec3d(std::sin(th) * std::cos(ph), std::sin(th) * std::sin(ph), std::cos(th));
      out << "v " << p.x() << " " << p.y() << " " << p.z() << "\n";
      out << "vt " << double(j) / slices << " " << 1.0 - double(i) / stacks << "\n";
    }
  }
  auto id = [&](int i, int j) { return i * (slices + 1) + j + 1; };
  for (int i = 0; i < stacks; ++i) {
    for (int j = 0; j < slices; ++j) {
      const int a = id(i, j), b = id(i + 1, j), cc = id(i + 1, j + 1), d = id(i, j + 1);
      if (i > 0) out << "f " << a << "/" << a << " " << b << "/" << b << " " << d << "/" << d << "\n";
      if (i + 1 < stacks) out << "f " << d << "/" << d << " " << b << "/" << b << " " << cc << "/" << cc << "\n";
    }
  }
}

}  // namespace

SyntheticScan WriteSyntheticScan(const fs::path& dir, const SyntheticScanOptions& o) {
  fs::create_directories(dir);
  SyntheticScan s;
  s.json = dir / "scan.json";
  const Vec3d target(0, 0, 0.05);
  s.camera = MakeDevice("cam", o.camera_width, o.camera_height, 300, 0, 15, 0.5, target);
  s.projector = MakeDevice("proj", o.projector_width, o.projector_height, 350, -25, 25, 0.5, target);
  s.angles_deg = o.angles_deg;
  s.sphere_center_object = Vec3d(0.02, 0.01, 0.05);
  s.sphere_radius_m = 0.04;
  WriteSphereObj(dir / "sphere.obj", s.sphere_center_object, s.sphere_radius_m);

  const int col_bits = [&] { int b = 1; while ((1 << b) < o.projector_width) ++b; return b; }();
  const int row_bits = [&] { int b = 1; while ((1 << b) < o.projector_height) ++b; return b; }();
  Json images = Json::array();
  const int w = o.camera_width, h = o.camera_height;
  const size_t n = size_t(w) * h;
  constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
  for (double angle : o.angles_deg) {
    char tag[16];
    std::snprintf(tag, sizeof(tag), "%03d", int(std::lround(angle)));
    fs::create_directories(dir / "images" / tag);
    const Vec3d center = s.turntable.WorldFromObject(angle) * s.sphere_center_object;
    std::vector<float> u(n, kNaN), v(n, kNaN), depth(n, kNaN), shade(n, 0.0f);
    std::vector<char> on_object(n, 0);
    const Rigid3 world_from_cam = s.camera.cam_from_world.Inverse();
    const Vec3d proj_center = s.projector.CenterInWorld();
    for (int y = 0; y < h; ++y) {
      for (int x = 0; x < w; ++x) {
        Vec3d o_cam, d_cam;
        s.camera.PixelRay(Vec2d(x, y), &o_cam, &d_cam);
        const Vec3d origin = world_from_cam * o_cam, dir = world_from_cam.rotation * d_cam;
        const Vec3d oc = origin - center;
        const double b = oc.dot(dir), c = oc.squaredNorm() - s.sphere_radius_m * s.sphere_radius_m;
        const double disc = b * b - c;
        if (disc <= 0) continue;
        const double t = -b - std::sqrt(disc);
        const Vec3d X = origin + t * dir;
        const size_t i = size_t(y) * w + x;
        on_object[i] = 1;
        depth[i] = float((s.camera.cam_from_world * X).z());
        const Vec3d nrm = (X - center).normalized();
        const Vec3d l = (proj_center - X).normalized();
        if (nrm.dot(l) <= 0) continue;  // projector shadow (the sphere's far side)
        Vec2d uv;
        if (!s.projector.Project(s.projector.cam_from_world * X, &uv)) continue;
        if (uv.x() < -0.5 || uv.x() > o.projector_width - 0.5 || uv.y() < -0.5 ||
            uv.y() > o.projector_height - 0.5) {
          continue;
        }
        u[i] = float(uv.x());
        v[i] = float(uv.y());
        shade[i] = float(kAlbedoGain * nrm.dot(l));
      }
    }
    auto write = [&](const std::string& pattern, const std::function<double(double, double)>& value) {
      Image im(w, h, 1, 0.0f);
      for (size_t i = 0; i < n; ++i) {
        if (!on_object[i]) continue;
        const double lit = std::isnan(u[i]) ? 0.0 : shade[i] * value(u[i], v[i]);
        im.data[i] = float(std::round(255 * std::clamp(lit + kAmbient, 0.0, 1.0)) / 255);
      }
      const std::string rel = std::string("images/") + tag + "/" + pattern + ".png";
      const Status st = WritePng(dir / rel, im);
      EXPECT_TRUE(st.ok()) << st.ToString();
      images.push_back({{"file", rel}, {"turntable_deg", angle}, {"pattern", pattern}});
    };
    write("white", [](double, double) { return 1.0; });
    write("black", [](double, double) { return 0.0; });
    for (int axis = 0; axis < 2; ++axis) {
      const int bits = axis == 0 ? col_bits : row_bits;
      const int extent = axis == 0 ? o.projector_width : o.projector_height;
      const char* name = axis == 0 ? "col" : "row";
      for (int b = 0; b < bits; ++b) {
        auto bit = [=](double uu, double vv) {
          const int c = std::clamp(int(std::floor((axis == 0 ? uu : vv) + 0.5)), 0, extent - 1);
          const int g = c ^ (c >> 1);
          return double((g >> (bits - 1 - b)) & 1);
        };
        write(std::string("gray_") + name + "_b" + std::to_string(b), bit);
        write(std::string("gray_") + name + "_b" + std::to_string(b) + "_inv",
              [=](double uu, double vv) { return 1.0 - bit(uu, vv); });
      }
      for (int period : axis == 0 ? o.col_periods : o.row_periods) {
        for (int k = 0; k < o.shifts; ++k) {
          write(std::string("phase_") + name + "_p" + std::to_string(period) + "_k" + std::to_string(k),
                [=](double uu, double vv) {
                  const double x = axis == 0 ? uu : vv;
                  return 0.5 + 0.5 * std::cos(2 * kPi * x / period - 2 * kPi * k / o.shifts);
                });
        }
      }
    }
    s.true_u.push_back(u);
    s.true_v.push_back(v);
    s.true_depth.push_back(depth);
  }
  Json j = {{"format", "structured_light/1"},
            {"mesh", "sphere.obj"},
            {"camera", {{"id", "cam"}, {"width", w}, {"height", h}, {"K", KJson(s.camera.K)},
                        {"dist", {0, 0, 0, 0, 0}},
                        {"cam_from_world", MatrixJson(s.camera.cam_from_world.ToMatrix())}}},
            {"projector", {{"id", "proj"}, {"width", o.projector_width}, {"height", o.projector_height},
                           {"K", KJson(s.projector.K)}, {"dist", {0, 0, 0, 0, 0}},
                           {"proj_from_world", MatrixJson(s.projector.cam_from_world.ToMatrix())}}},
            {"turntable", {{"axis", {0, 0, 1}}, {"point", {0, 0, 0}}}},
            {"turntable_angles_deg", o.angles_deg},
            {"images", images}};
  std::ofstream(s.json) << j.dump(1) << "\n";
  return s;
}

}  // namespace reflcap::scan::testing
