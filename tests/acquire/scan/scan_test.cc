// Tests of acquire/scan: the structured_light/1 reader, decoding, triangulation, the UV atlas and
// the whole pipeline on a sphere rendered in the test (synthetic_scan.h), plus a check of the
// decoder against the ground-truth correspondences of the shared suzanne scan (skipped without
// ../shared).
#include <algorithm>
#include <cmath>
#include <fstream>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "acquire/scan/compare.h"
#include "acquire/scan/decode.h"
#include "acquire/scan/merge.h"
#include "acquire/scan/scan_pipeline.h"
#include "acquire/scan/scan_spec.h"
#include "acquire/scan/triangulate.h"
#include "acquire/scan/uv_atlas.h"
#include "engine/core/atomic_file.h"
#include "engine/image/exr_io.h"
#include "engine/image/png_io.h"
#include "engine/mesh/mesh_io.h"
#include "engine/mesh/texel_atlas.h"
#include "tests/acquire/scan/synthetic_scan.h"
#include "tests/support/test_support.h"

namespace reflcap::scan {
namespace {

namespace fs = std::filesystem;
using reflcap::testing::ScratchDir;
using Json = nlohmann::json;

// 8-bit photographs quantise intensity to 1/255; at the synthetic scene's amplitude (~0.2-0.4)
// an 8-step phase then scatters by ~0.005 px of an 8-px period. 0.02 px leaves a 4x margin.
constexpr double kMaxMedianCoordErrorPx = 0.02;
// Gray code alone is exact to the projector pixel: no decoded coordinate may be off by more
// than half a pixel plus the phase noise.
constexpr double kMaxCoordErrorPx = 0.6;
// Depth error from 0.005 px at a 0.5 m range with a ~0.2 m baseline and f = 350 px: ~0.02 mm;
// 0.1 mm is the bound (rim pixels, where the surface is steep, are the worst).
constexpr double kMaxPointErrorM = 1e-4;
// Normals from 2-pixel central differences on a 40 mm sphere seen at 1.7 mm per pixel are exact
// up to noise in the interior (median bound 1 degree). Where differences are one-sided (rims) the
// error is half the chord's arc: 2 px x 1.7 mm / cos(view angle) / 40 mm rad, so <= 5 degrees up
// to 60 degrees from the view (bound 6) and ~14 degrees at the 80-degree limit (bound 20).
constexpr double kMaxMedianNormalErrorDeg = 1.0;
constexpr double kMaxNormalErrorDeg = 6.0;
constexpr double kMaxNormalErrorSteepDeg = 20.0;
// The merged sphere: the synthetic camera samples it every 1.7 mm (suzanne's: 0.45 mm), and the
// vertex projection's plane fit over 2.5 spacings on a 40 mm radius is biased by ~0.05 mm;
// measured median 0.091 mm, p95 0.264 mm (the same on every run: Poisson runs on one thread).
// Bounds: 0.1 mm median, 0.3 mm p95 (the issue's p95 target).
constexpr double kMaxMeshMedianM = 0.1e-3;
constexpr double kMaxMeshP95M = 0.3e-3;

const std::vector<double> kAngles = {0, 120, 240};

// Writes the synthetic scan once per test binary (about a second).
const testing::SyntheticScan& Scan() {
  static const ScratchDir* dir = &reflcap::testing::NewProcessScratchDir();
  static const testing::SyntheticScan scan = testing::WriteSyntheticScan(dir->path() / "scan");
  return scan;
}

double Median(std::vector<double> v) {
  if (v.empty()) return std::numeric_limits<double>::quiet_NaN();
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

TEST(ScanSpec, ReadsTheSyntheticScan) {
  auto spec = LoadScanSpec(Scan().json);
  ASSERT_TRUE(spec.ok()) << spec.status().ToString();
  ASSERT_EQ(spec->angles.size(), 3u);
  EXPECT_EQ(spec->angles[1].turntable_deg, 120);
  EXPECT_EQ(spec->angles[0].col.bits, 8);
  EXPECT_EQ(spec->angles[0].row.bits, 7);
  EXPECT_EQ(spec->angles[0].col.phase.size(), 3u);
  EXPECT_EQ(spec->angles[0].col.phase.at(8).size(), 8u);
  ASSERT_TRUE(spec->reference_mesh.has_value());
  EXPECT_EQ(spec->reference_mesh->filename(), "sphere.obj");
}

// Rewrites the synthetic scan.json through `edit` into a copy and returns the reader's status.
Status LoadEdited(const std::function<void(Json*)>& edit, const ScratchDir& dir) {
  Json j = Json::parse(*ReadTextFile(Scan().json));
  for (auto& im : j["images"]) im["file"] = (Scan().json.parent_path() / im["file"].get<std::string>()).string();
  j["mesh"] = (Scan().json.parent_path() / "sphere.obj").string();
  edit(&j);
  const fs::path path = dir / "edited.json";
  reflcap::testing::WriteText(path, j.dump());
  return LoadScanSpec(path).status();
}

TEST(ScanSpec, RejectsBadInputNamingTheField) {
  ScratchDir dir;
  struct Case {
    std::string what, expect;
    std::function<void(Json*)> edit;
  };
  const std::vector<Case> cases = {
      {"wrong format", "format", [](Json* j) { (*j)["format"] = "capture/1"; }},
      {"angle not listed", "images[0].turntable_deg",
       [](Json* j) { (*j)["images"][0]["turntable_deg"] = 30.0; }},
      {"angle listed but no images", "no \"white\"",
       [](Json* j) { (*j)["turntable_angles_deg"].push_back(60.0); }},
      {"duplicate angle", "turntable_angles_deg[1]",
       [](Json* j) { (*j)["turntable_angles_deg"][1] = 0.0; }},
      {"unknown pattern", "images[3].pattern", [](Json* j) { (*j)["images"][3]["pattern"] = "stripes"; }},
      {"missing inverse", "gray_col_b2_inv", [](Json* j) {
         auto& ims = (*j)["images"];
         for (size_t i = 0; i < ims.size(); ++i) {
           if (ims[i]["pattern"] == "gray_col_b2_inv" && ims[i]["turntable_deg"] == 0.0) {
             ims.erase(i);
             break;
           }
         }
       }},
      {"bit beyond the projector", "images[2].pattern",
       [](Json* j) { (*j)["images"][2]["pattern"] = "gray_col_b8"; }},
      {"K not a matrix", "camera.K", [](Json* j) { (*j)["camera"]["K"] = {1, 2, 3}; }},
      {"not a rotation", "projector.proj_from_world",
       [](Json* j) { (*j)["projector"]["proj_from_world"][0][0] = 2.0; }},
      {"missing image file", "black_gone.png", [](Json* j) {
         (*j)["images"][1]["file"] = (Scan().json.parent_path() / "images/000/black_gone.png").string();
       }},
  };
  for (const Case& c : cases) {
    const Status s = LoadEdited(c.edit, dir);
    EXPECT_FALSE(s.ok()) << c.what;
    EXPECT_EQ(ExitCodeFor(s), 2) << c.what << ": " << s.ToString();
    EXPECT_NE(s.message().find(c.expect), std::string::npos)
        << c.what << ": " << s.message();
  }
}

// Regressions: inputs that used to throw out of LoadScanSpec and abort `reflcap scan` — a number
// beyond a double's range (json out_of_range.406; tests/cli/bad_input_corpus_test) and a Gray bit
// index too long for std::stoi (tests/fuzz/scan_spec_fuzzer).
TEST(ScanSpec, RejectsNumbersAndIndicesOutOfRangeWithoutThrowing) {
  ScratchDir dir;
  Json j = Json::parse(*ReadTextFile(Scan().json));
  j["turntable_angles_deg"][0] = 123.25;
  std::string text = j.dump();
  text.replace(text.find("123.25"), 6, "1e999");
  const fs::path overflow = dir / "overflow.json";
  reflcap::testing::WriteText(overflow, text);
  const Status s = LoadScanSpec(overflow).status();
  EXPECT_EQ(ExitCodeFor(s), 2) << s.ToString();
  EXPECT_NE(s.message().find("overflow.json"), std::string::npos) << s.message();

  const Status bit = LoadEdited(
      [](Json* j) { (*j)["images"][2]["pattern"] = "gray_col_b99999999999999999999"; }, dir);
  EXPECT_EQ(ExitCodeFor(bit), 2) << bit.ToString();
  EXPECT_NE(bit.message().find("images[2].pattern"), std::string::npos) << bit.message();
}

TEST(ScanSpec, RejectsAnImageOfTheWrongSize) {
  ScratchDir dir;
  const fs::path small = dir / "small.png";
  ASSERT_TRUE(WritePng(small, Image(10, 10, 1, 0.5f)).ok());
  const Status s = LoadEdited([&](Json* j) { (*j)["images"][5]["file"] = small.string(); }, dir);
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(ExitCodeFor(s), 2);
  EXPECT_NE(s.message().find("small.png"), std::string::npos) << s.message();
  EXPECT_NE(s.message().find("10x10"), std::string::npos) << s.message();
}

TEST(ScanDecode, RecoversTheExactProjectorCoordinates) {
  auto spec = LoadScanSpec(Scan().json);
  ASSERT_TRUE(spec.ok());
  auto photos = LoadAnglePhotos(spec->angles[0], spec->camera.width, spec->camera.height);
  ASSERT_TRUE(photos.ok()) << photos.status().ToString();
  auto view = DecodeAngle(*photos, spec->projector.width, spec->projector.height, DecodeOptions());
  ASSERT_TRUE(view.ok()) << view.status().ToString();
  std::vector<double> err;
  int64_t lit = 0;
  for (size_t i = 0; i < view->u.size(); ++i) {
    if (std::isnan(Scan().true_u[0][i])) continue;
    ++lit;
    if (std::isnan(view->u[i])) continue;
    const double e = std::max(std::abs(view->u[i] - Scan().true_u[0][i]), std::abs(view->v[i] - Scan().true_v[0][i]));
    EXPECT_LT(e, kMaxCoordErrorPx) << "pixel " << i;
    err.push_back(e);
  }
  ASSERT_GT(lit, 1000);
  // Rim pixels lit at grazing angles fall below the contrast threshold; the rest decode.
  EXPECT_GT(double(err.size()) / lit, 0.9);
  EXPECT_LT(Median(err), kMaxMedianCoordErrorPx);
  // Nothing decodes off the object.
  for (size_t i = 0; i < view->u.size(); ++i) {
    if (std::isnan(Scan().true_depth[0][i])) {
      EXPECT_TRUE(std::isnan(view->u[i])) << "pixel " << i;
    }
  }
}

TEST(ScanDecode, FlagsACorruptedGrayCodeInsteadOfDecodingIt) {
  auto spec = LoadScanSpec(Scan().json);
  ASSERT_TRUE(spec.ok());
  auto photos = LoadAnglePhotos(spec->angles[0], spec->camera.width, spec->camera.height);
  ASSERT_TRUE(photos.ok());
  // Swap pattern and inverse of column bit 1: decoded columns move by 1..127 px. Moves below
  // half the fine period leave the fine phase's fringe unchanged (the decode stays right); all
  // others must be caught by the temporal unwrapping, whose coarsest period is absolute.
  std::swap(photos->col.gray[1], photos->col.gray_inverse[1]);
  auto view = DecodeAngle(*photos, spec->projector.width, spec->projector.height, DecodeOptions());
  ASSERT_TRUE(view.ok());
  int64_t wrong = 0;
  for (size_t i = 0; i < view->u.size(); ++i) {
    if (!std::isnan(view->u[i]) && std::abs(view->u[i] - Scan().true_u[0][i]) > kMaxCoordErrorPx) ++wrong;
  }
  EXPECT_EQ(wrong, 0);
  EXPECT_GT(view->counts[int(PixelOutcome::kInconsistent)] + view->counts[int(PixelOutcome::kOutOfRange)],
            1000);
}

TEST(ScanDecode, AProjectorThatLightsNothingLeavesOnlyShadow) {
  auto spec = LoadScanSpec(Scan().json);
  ASSERT_TRUE(spec.ok());
  auto photos = LoadAnglePhotos(spec->angles[0], spec->camera.width, spec->camera.height);
  ASSERT_TRUE(photos.ok());
  photos->white = photos->black;
  auto view = DecodeAngle(*photos, spec->projector.width, spec->projector.height, DecodeOptions());
  ASSERT_TRUE(view.ok());
  EXPECT_EQ(view->Decoded(), 0);
  EXPECT_EQ(view->counts[int(PixelOutcome::kShadow)], int64_t(view->u.size()));
}

TEST(ScanTriangulate, PutsEveryPointOnTheSphereInTheObjectFrame) {
  auto spec = LoadScanSpec(Scan().json);
  ASSERT_TRUE(spec.ok());
  for (size_t a = 0; a < spec->angles.size(); ++a) {
    auto photos = LoadAnglePhotos(spec->angles[a], spec->camera.width, spec->camera.height);
    ASSERT_TRUE(photos.ok());
    auto view = DecodeAngle(*photos, spec->projector.width, spec->projector.height, DecodeOptions());
    ASSERT_TRUE(view.ok());
    auto cloud = TriangulateView(*view, spec->camera, spec->projector, spec->ProjectorFromCamera(),
                                 spec->ObjectFromCamera(a), TriangulateOptions());
    ASSERT_TRUE(cloud.ok()) << cloud.status().ToString();
    ASSERT_GT(cloud->points.size(), 1000u);
    EXPECT_EQ(cloud->rejected_epipolar, 0);
    const Vec3d c = Scan().sphere_center_object;
    std::vector<double> normal_err_deg, steep_err_deg;  // viewed within / beyond 60 degrees
    for (size_t i = 0; i < cloud->points.size(); ++i) {
      const Vec3d p = cloud->points[i].cast<double>();
      EXPECT_LT(std::abs((p - c).norm() - Scan().sphere_radius_m), kMaxPointErrorM) << "angle " << a;
      const double err =
          RadToDeg(std::acos(std::clamp(cloud->normals[i].cast<double>().dot((p - c).normalized()), -1.0, 1.0)));
      const double cos_view = (p - c).normalized().dot((cloud->camera_center.cast<double>() - p).normalized());
      (cos_view > 0.5 ? normal_err_deg : steep_err_deg).push_back(err);
      EXPECT_GT(cloud->confidence[i], 0);
      EXPECT_LE(cloud->confidence[i], 1);
    }
    EXPECT_LT(Median(normal_err_deg), kMaxMedianNormalErrorDeg) << "angle " << a;
    EXPECT_LT(*std::max_element(normal_err_deg.begin(), normal_err_deg.end()), kMaxNormalErrorDeg);
    if (!steep_err_deg.empty()) {
      EXPECT_LT(*std::max_element(steep_err_deg.begin(), steep_err_deg.end()), kMaxNormalErrorSteepDeg);
    }
  }
}

TEST(ScanTriangulate, RejectsCoordinatesOffTheEpipolarLine) {
  auto spec = LoadScanSpec(Scan().json);
  ASSERT_TRUE(spec.ok());
  auto photos = LoadAnglePhotos(spec->angles[0], spec->camera.width, spec->camera.height);
  ASSERT_TRUE(photos.ok());
  auto view = DecodeAngle(*photos, spec->projector.width, spec->projector.height, DecodeOptions());
  ASSERT_TRUE(view.ok());
  // Shift every decoded row by 5 px: no camera ray meets the projector ray of (u, v + 5).
  for (float& v : view->v) v += 5;
  auto cloud = TriangulateView(*view, spec->camera, spec->projector, spec->ProjectorFromCamera(),
                               spec->ObjectFromCamera(0), TriangulateOptions());
  ASSERT_TRUE(cloud.ok());
  EXPECT_GT(cloud->rejected_epipolar, int64_t(0.9 * cloud->decoded));
}

// An icosphere refined `levels` times, radius r.
TriangleMesh Icosphere(int levels, double r) {
  const double t = (1 + std::sqrt(5.0)) / 2;
  std::vector<Vec3d> v = {{-1, t, 0}, {1, t, 0}, {-1, -t, 0}, {1, -t, 0}, {0, -1, t}, {0, 1, t},
                          {0, -1, -t}, {0, 1, -t}, {t, 0, -1}, {t, 0, 1}, {-t, 0, -1}, {-t, 0, 1}};
  std::vector<std::array<uint32_t, 3>> f = {{0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11},
                                            {1, 5, 9},  {5, 11, 4}, {11, 10, 2}, {10, 7, 6}, {7, 1, 8},
                                            {3, 9, 4},  {3, 4, 2},  {3, 2, 6},   {3, 6, 8},  {3, 8, 9},
                                            {4, 9, 5},  {2, 4, 11}, {6, 2, 10},  {8, 6, 7},  {9, 8, 1}};
  for (int l = 0; l < levels; ++l) {
    std::map<std::pair<uint32_t, uint32_t>, uint32_t> mid;
    auto midpoint = [&](uint32_t a, uint32_t b) {
      auto key = std::minmax(a, b);
      auto it = mid.find(key);
      if (it != mid.end()) return it->second;
      v.push_back((v[a] + v[b]) / 2);
      return mid[key] = uint32_t(v.size() - 1);
    };
    std::vector<std::array<uint32_t, 3>> next;
    for (const auto& tri : f) {
      const uint32_t a = midpoint(tri[0], tri[1]), b = midpoint(tri[1], tri[2]), c = midpoint(tri[2], tri[0]);
      next.push_back({tri[0], a, c});
      next.push_back({tri[1], b, a});
      next.push_back({tri[2], c, b});
      next.push_back({a, b, c});
    }
    f = next;
  }
  TriangleMesh m;
  for (const auto& p : v) m.positions.push_back((r * p.normalized()).cast<float>());
  m.triangles = f;
  for (size_t i = 0; i < f.size(); ++i) {
    std::array<Vec3f, 3> n;
    for (int k = 0; k < 3; ++k) n[k] = m.positions[f[i][k]].normalized();
    m.corner_normals.push_back(n);
  }
  return m;
}

// The issue asks for >= 70 % on suzanne; on a closed sphere of 1,280 faces the measured area
// use is ~0.75 (gutter 0) and ~0.7 (gutter 1); 0.6 / 0.55 catch a broken packer.
constexpr double kMinSphereAreaUse = 0.6;
constexpr double kMinSphereAreaUseGutter = 0.55;

TEST(UvAtlas, PacksAClosedSphereWithoutOverlap) {
  for (int gutter : {0, 1}) {
    TriangleMesh mesh = Icosphere(3, 0.05);
    UvAtlasOptions options;
    options.gutter_texels = gutter;
    UvAtlasStats stats;
    ASSERT_TRUE(ComputeUvAtlas(&mesh, options, &stats).ok());
    EXPECT_EQ(stats.overlap_pixels, 0) << "gutter " << gutter;
    EXPECT_EQ(CountUvOverlaps(mesh, kOverlapCheckResolution), 0);
    EXPECT_GT(stats.area_use, gutter == 0 ? kMinSphereAreaUse : kMinSphereAreaUseGutter) << "gutter " << gutter;
    EXPECT_LE(stats.max_stretch, 1 / std::cos(DegToRad(options.max_chart_angle_deg)) + 1e-9);
    // Every UV inside the unit square, every UV triangle counter-clockwise (no mirrored chart).
    for (const auto& uv : mesh.corner_uvs) {
      for (const auto& p : uv) {
        EXPECT_GE(p.x(), 0);
        EXPECT_LE(p.x(), 1);
        EXPECT_GE(p.y(), 0);
        EXPECT_LE(p.y(), 1);
      }
      const Vec2f e1 = uv[1] - uv[0], e2 = uv[2] - uv[0];
      EXPECT_GT(e1.x() * e2.y() - e1.y() * e2.x(), 0);
    }
    // reflcap's texel atlas builds on it, and with a gutter no texel neighbours another chart's.
    auto atlas = BuildTexelAtlas(mesh, options.resolution, options.resolution);
    ASSERT_TRUE(atlas.ok()) << atlas.status().ToString();
    EXPECT_GT(double(atlas->TexelCount()) / (options.resolution * options.resolution), stats.area_use);
  }
}

TEST(UvAtlas, SeparatesADoubleLayer) {
  // Two copies of a hemisphere cap, 0.1 mm apart along the normal: their projections coincide,
  // so a chart holding faces of both would overlap itself.
  TriangleMesh sphere = Icosphere(3, 0.05);
  TriangleMesh mesh;
  for (int copy = 0; copy < 2; ++copy) {
    const uint32_t base = uint32_t(mesh.positions.size());
    for (const auto& p : sphere.positions) mesh.positions.push_back(p * (1 + 0.002f * copy));
    for (size_t f = 0; f < sphere.triangles.size(); ++f) {
      if (sphere.GeometricNormal(f).z() < 0.3f) continue;
      const auto& t = sphere.triangles[f];
      mesh.triangles.push_back({t[0] + base, t[1] + base, t[2] + base});
      mesh.corner_normals.push_back(sphere.corner_normals[f]);
    }
  }
  UvAtlasStats stats;
  ASSERT_TRUE(ComputeUvAtlas(&mesh, UvAtlasOptions(), &stats).ok());
  EXPECT_EQ(stats.overlap_pixels, 0);
  EXPECT_GE(stats.charts, 2);
}

TEST(UvAtlas, OverlapCountSeesOverlappingTriangles) {
  TriangleMesh mesh;
  mesh.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  mesh.triangles = {{0, 1, 2}, {0, 1, 3}};
  mesh.corner_uvs = {{Vec2f(0.1f, 0.1f), Vec2f(0.9f, 0.1f), Vec2f(0.1f, 0.9f)},
                     {Vec2f(0.2f, 0.2f), Vec2f(0.8f, 0.2f), Vec2f(0.2f, 0.8f)}};
  EXPECT_GT(CountUvOverlaps(mesh, 256), 1000);
  mesh.corner_uvs[1] = {Vec2f(0.9f, 0.1f), Vec2f(0.9f, 0.9f), Vec2f(0.1f, 0.9f)};  // shares an edge
  EXPECT_EQ(CountUvOverlaps(mesh, 256), 0);
}

TEST(ScanPipeline, MergesTheSphereIntoOneTrimmedUnwrappedMesh) {
  auto spec = LoadScanSpec(Scan().json);
  ASSERT_TRUE(spec.ok());
  ScratchDir out;
  ScanOptions options;
  options.distance_samples = 20000;
  options.merge.target_triangles = 8000;  // a 40 mm sphere needs no more; keeps the test fast
  auto summary = RunScanPipeline(*spec, out.path(), options);
  ASSERT_TRUE(summary.ok()) << summary.status().ToString();
  for (const char* f : {"mesh.obj", "mesh.gltf", "scan_report.json", "preview.png", "atlas.png",
                        "points_000.ply", "decode_120.png"}) {
    EXPECT_TRUE(fs::exists(out / f)) << f;
  }
  auto mesh = LoadMesh(out / "mesh.obj");
  ASSERT_TRUE(mesh.ok()) << mesh.status().ToString();
  auto gltf = LoadMesh(out / "mesh.gltf");
  ASSERT_TRUE(gltf.ok()) << gltf.status().ToString();
  EXPECT_EQ(gltf->triangles.size(), mesh->triangles.size());
  // Distance of the mesh to the analytic sphere.
  std::vector<double> d;
  for (const Vec3f& p : SampleSurface(*mesh, 20000, 3)) {
    d.push_back(std::abs((p.cast<double>() - Scan().sphere_center_object).norm() - Scan().sphere_radius_m));
  }
  const DistanceStats stats = Summarise(d);
  EXPECT_LT(stats.median_m, kMaxMeshMedianM) << "p95 " << stats.p95_m;
  EXPECT_LT(stats.p95_m, kMaxMeshP95M) << "median " << stats.median_m;
  // Trimmed: the projector (25 deg above the horizon) lights the sphere down to 40 cos(25 deg) =
  // 36.3 mm below its centre, and trimming bridges at most 4 spacings (~7 mm of arc) beyond, so
  // nothing of the bottom 1 mm cap remains (Poisson alone closes the sphere down to the pole).
  double min_z = 1e9;
  for (const auto& p : mesh->positions) min_z = std::min(min_z, double(p.z()));
  EXPECT_GT(min_z, Scan().sphere_center_object.z() - Scan().sphere_radius_m + 0.001);
  // The report agrees with the measurement above against the reference OBJ.
  EXPECT_TRUE(summary->has_reference);
  EXPECT_LT(summary->accuracy_median_m, kMaxMeshMedianM);
  EXPECT_EQ(summary->uv_overlap_pixels, 0);
  Json report = Json::parse(*ReadTextFile(out / "scan_report.json"));
  ASSERT_EQ(report["angles"].size(), 3u);
  EXPECT_GT(report["angles"][0]["points"].get<int64_t>(), 1000);
  EXPECT_GT(report["angles"][0]["decode_coverage"].get<double>(), 0.9);
  EXPECT_TRUE(report["angles"][0]["registration"].contains("residual_median_mm"));
}

TEST(ScanPipeline, IcpKeepsTheSurfaceInPlace) {
  auto spec = LoadScanSpec(Scan().json);
  ASSERT_TRUE(spec.ok());
  std::vector<ViewCloud> clouds;
  for (size_t a = 0; a < spec->angles.size(); ++a) {
    auto photos = LoadAnglePhotos(spec->angles[a], spec->camera.width, spec->camera.height);
    ASSERT_TRUE(photos.ok());
    auto view = DecodeAngle(*photos, spec->projector.width, spec->projector.height, DecodeOptions());
    ASSERT_TRUE(view.ok());
    auto cloud = TriangulateView(*view, spec->camera, spec->projector, spec->ProjectorFromCamera(),
                                 spec->ObjectFromCamera(a), TriangulateOptions());
    ASSERT_TRUE(cloud.ok());
    clouds.push_back(*cloud);
  }
  MergeOptions options;
  options.icp = true;
  auto reg = RegisterViews(&clouds, options);
  ASSERT_TRUE(reg.ok()) << reg.status().ToString();
  // A sphere leaves ICP free to spin each view about the centre (that is why ICP is optional);
  // what it must not do is move the surface: every point stays on the sphere and the residuals
  // between views do not grow.
  const Vec3d c = Scan().sphere_center_object;
  for (size_t v = 0; v < reg->size(); ++v) {
    const ViewRegistration& r = (*reg)[v];
    EXPECT_TRUE(r.icp_applied);
    EXPECT_GT(r.residual_points, 100);
    EXPECT_LT(r.residual_median_m, kMaxPointErrorM);
    EXPECT_LT(r.residual_median_after_m, r.residual_median_m + kMaxPointErrorM / 10);
    for (const Vec3f& p : clouds[v].points) {
      ASSERT_LT(std::abs((p.cast<double>() - c).norm() - Scan().sphere_radius_m), 2 * kMaxPointErrorM);
    }
  }
}

// The shared suzanne scan: the decoder against the rendered ground-truth correspondences.
// The README's independent decoder reaches 0.04 px median column error with the period-16 phase;
// ours must do at least as well (0.06 px bound), decode >= 95 % of the lit pixels, and
// triangulate to <= 0.05 mm median depth error (README: 0.030 mm).
constexpr double kSuzanneMaxMedianColPx = 0.06;
constexpr double kSuzanneMinCoverage = 0.95;
constexpr double kSuzanneMaxMedianDepthM = 0.05e-3;

TEST(ScanSharedData, SuzanneDecodesToTheGroundTruthCorrespondences) {
  const auto data = reflcap::testing::SharedDataDir();
  if (!data) GTEST_SKIP() << "../shared/data not present";
  const fs::path dir = *data / "structured_light" / "suzanne";
  if (!fs::exists(dir / "scan.json")) GTEST_SKIP() << dir << " not present";
  auto spec = LoadScanSpec(dir / "scan.json");
  ASSERT_TRUE(spec.ok()) << spec.status().ToString();
  auto photos = LoadAnglePhotos(spec->angles[0], spec->camera.width, spec->camera.height);
  ASSERT_TRUE(photos.ok());
  auto view = DecodeAngle(*photos, spec->projector.width, spec->projector.height, DecodeOptions());
  ASSERT_TRUE(view.ok());
  std::vector<std::string> names;
  auto gt = ReadExrChannels(dir / "gt" / "corr_000.exr", &names);
  ASSERT_TRUE(gt.ok()) << gt.status().ToString();
  auto lit = ReadPng(dir / "gt" / "lit_000.png");
  ASSERT_TRUE(lit.ok());
  // Channels are stored alphabetically: B (v), G (u), R (depth).
  const int cb = int(std::find(names.begin(), names.end(), "B") - names.begin());
  const int cg = int(std::find(names.begin(), names.end(), "G") - names.begin());
  const int cr = int(std::find(names.begin(), names.end(), "R") - names.begin());
  ASSERT_LT(std::max({cb, cg, cr}), gt->channels);
  auto cloud = TriangulateView(*view, spec->camera, spec->projector, spec->ProjectorFromCamera(),
                               spec->ObjectFromCamera(0), TriangulateOptions());
  ASSERT_TRUE(cloud.ok());
  std::vector<double> col_err, depth_err;
  int64_t lit_count = 0, decoded = 0;
  for (size_t i = 0; i < view->u.size(); ++i) {
    const float gu = gt->data[i * gt->channels + cg];
    if (std::isnan(gu) || lit->data[i * lit->channels] < 0.5f) continue;
    ++lit_count;
    if (std::isnan(view->u[i])) continue;
    ++decoded;
    col_err.push_back(std::abs(view->u[i] - gu));
  }
  const Rigid3 cam_from_object = spec->ObjectFromCamera(0).Inverse();
  for (size_t k = 0; k < cloud->points.size(); ++k) {
    const float gz = gt->data[size_t(cloud->pixel[k]) * gt->channels + cr];
    if (std::isnan(gz)) continue;
    depth_err.push_back(std::abs((cam_from_object * cloud->points[k].cast<double>()).z() - gz));
  }
  ASSERT_GT(lit_count, 10000);
  EXPECT_GT(double(decoded) / lit_count, kSuzanneMinCoverage);
  EXPECT_LT(Median(col_err), kSuzanneMaxMedianColPx);
  EXPECT_LT(Median(depth_err), kSuzanneMaxMedianDepthM);
}

}  // namespace
}  // namespace reflcap::scan
