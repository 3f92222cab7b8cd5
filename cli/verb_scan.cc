// `reflcap scan SCAN.json --out MESH_DIR`: structured-light photographs (structured_light/1) ->
// a merged, trimmed, UV-unwrapped mesh in the object frame (acquire/scan/scan_pipeline.h).
#include <cstdio>

#include "acquire/scan/scan_pipeline.h"
#include "acquire/scan/scan_spec.h"
#include "cli/cli.h"
#include "engine/core/atomic_file.h"
#include "engine/core/progress.h"

namespace reflcap::cli {

int RunScan(int argc, char** argv) {
  std::string scan_json, out;
  bool overwrite = false, no_clouds = false;
  scan::ScanOptions options;
  double trim_mm = 0, icp_mm = options.merge.icp_max_distance_m * 1e3, refine_mm = 0;
  double normal_mm = -1;
  int64_t distance_samples = options.distance_samples;
  ArgParser args(
      "scan", "SCAN.json --out MESH_DIR [options]",
      "Decode a structured-light scan (format structured_light/1: camera, projector, turntable,\n"
      "white/black, Gray codes with inverses and phase-shift sequences per turntable angle),\n"
      "triangulate every angle, register the views with the turntable pose (optionally ICP),\n"
      "merge them by screened Poisson reconstruction, trim what no view saw, decimate, project\n"
      "the vertices onto the measured points and unwrap a UV atlas. Writes mesh.obj, mesh.gltf,\n"
      "points_AAA.ply, decode_AAA.png, preview.png, atlas.png and scan_report.json (with\n"
      "distances to the scan's reference mesh when it names one). The mesh is in the object\n"
      "frame (= world at turntable 0), so it can replace the mesh of a capture/1 on the same\n"
      "turntable: --capture writes such a capture.json into MESH_DIR.");
  args.AddPositional("SCAN.json", &scan_json, "structured_light/1 description");
  args.AddString("out", &out, "MESH_DIR", "output folder (must not exist or be empty)");
  args.AddInt("target-triangles", &options.merge.target_triangles,
              "decimate to this many triangles (default 60000; 0 = keep Poisson's resolution)");
  args.AddInt("atlas-res", &options.atlas.resolution,
              "texel atlas resolution the UV packing is made for (default 512, resample's default)");
  args.AddInt("gutter", &options.atlas.gutter_texels, "empty texels between charts (default 1)");
  args.AddDouble("chart-angle", &options.atlas.max_chart_angle_deg,
                 "largest face-normal deviation within a UV chart, degrees (default 60)");
  args.AddInt("poisson-depth", &options.merge.poisson_depth,
              "Poisson octree depth (default 0 = voxel ~ point spacing)");
  args.AddDouble("trim-mm", &trim_mm,
                 "cut surface farther than this from every measured point (default 0 = max(4\n"
                 "spacings, 5 % of the bounding-box diagonal))");
  args.AddFlag("icp", &options.merge.icp, "refine each view's turntable pose by point-to-plane ICP");
  args.AddDouble("icp-mm", &icp_mm, "ICP correspondence distance in mm (default 2)");
  args.AddInt("refine-passes", &options.merge.refine_passes,
              "passes projecting the vertices onto the points (default 2; 0 = off)");
  args.AddDouble("refine-mm", &refine_mm, "projection radius in mm (default 0 = 2.5x spacing)");
  args.AddDouble("normal-radius-mm", &normal_mm,
                 "shading normals averaged over this radius in mm (default: 2 % of the\n"
                 "bounding-box diagonal; 0 = plain vertex normals)");
  args.AddDouble("min-contrast", &options.decode.min_contrast,
                 "white - black below this is shadow (default 0.03 of full scale)");
  args.AddDouble("min-bit-contrast", &options.decode.min_bit_contrast,
                 "mean coarse-bit |code - inverse| / (white - black) below this is low contrast (0.25)");
  args.AddDouble("min-modulation", &options.decode.min_modulation,
                 "phase amplitude / half the white-black contrast below this is rejected (0.3)");
  args.AddDouble("max-gray-phase-px", &options.decode.max_gray_phase_px,
                 "largest |phase - Gray code| in projector px (default 3)");
  args.AddDouble("max-sigma-px", &options.decode.max_sigma_px,
                 "largest phase standard deviation in projector px (default 0.5)");
  args.AddDouble("max-epipolar-px", &options.triangulate.max_epipolar_px,
                 "largest distance of (u, v) from the epipolar line, projector px (default 1)");
  args.AddDouble("max-incidence-deg", &options.triangulate.max_incidence_deg,
                 "drop points seen or lit more obliquely than this (default 80)");
  args.AddString("reference", &options.reference, "MESH",
                 "mesh to measure the scan against (default: the scan's \"mesh\"; none = skip)");
  args.AddString("capture", &options.capture, "CAPTURE",
                 "also write MESH_DIR/capture.json: this capture/1 with the scanned mesh (its\n"
                 "images/, masks/... linked into MESH_DIR)");
  args.AddInt64("distance-samples", &distance_samples,
                "surface samples for the distance statistics (default 200000)");
  args.AddFlag("no-clouds", &no_clouds, "do not write points_AAA.ply");
  args.AddFlag("overwrite", &overwrite, "replace MESH_DIR if it exists (only once the new one is complete)");
  bool help = false;
  if (Status s = args.Parse(argc, argv, 2, &help); !s.ok()) {
    std::fprintf(stderr, "reflcap scan: %s\n", s.message().c_str());
    return kExitUsage;
  }
  if (help) {
    std::printf("%s", args.Help().c_str());
    return 0;
  }
  if (out.empty()) {
    std::fprintf(stderr, "reflcap scan: --out MESH_DIR is required\n");
    return kExitUsage;
  }
  options.merge.trim_distance_m = trim_mm * 1e-3;
  options.merge.icp_max_distance_m = icp_mm * 1e-3;
  options.merge.refine_radius_m = refine_mm * 1e-3;
  options.merge.normal_radius_m = normal_mm * 1e-3;
  options.distance_samples = distance_samples;
  options.write_clouds = !no_clouds;
  if (Status s = options.Validate(); !s.ok()) {
    std::fprintf(stderr, "reflcap scan: %s\n", s.message().c_str());
    return kExitUsage;
  }
  auto spec = scan::LoadScanSpec(scan_json);
  if (!spec.ok()) return ReportError("scan", spec.status());
  auto staging = StagingDir::Create(out, overwrite);
  if (!staging.ok()) return ReportError("scan", staging.status());
  auto summary = scan::RunScanPipeline(*spec, staging->path(), options);
  if (!summary.ok()) return ReportError("scan", summary.status());
  if (Status s = staging->Commit(); !s.ok()) return ReportError("scan", s);
  const scan::ScanSummary& r = *summary;
  std::printf("scanned %zu angles: %lld points (decode coverage %.1f %%), %lld triangles, UV atlas "
              "%.1f %% area / %.1f %% texels, %lld overlapping pixels\n",
              spec->angles.size(), static_cast<long long>(r.points), 100 * r.coverage,
              static_cast<long long>(r.triangles), 100 * r.area_use, 100 * r.texel_use,
              static_cast<long long>(r.uv_overlap_pixels));
  if (r.has_reference) {
    std::printf("vs reference: median %.3f mm, p95 %.3f mm (scan -> reference); seen reference -> "
                "scan p95 %.3f mm, %.2f %% farther than 1 mm\n",
                r.accuracy_median_m * 1e3, r.accuracy_p95_m * 1e3, r.completeness_p95_m * 1e3,
                100 * r.completeness_over_1mm);
  }
  std::printf("in %s: %s/mesh.obj, mesh.gltf, scan_report.json, preview.png\n",
              FormatDuration(r.seconds).c_str(), out.c_str());
  return 0;
}

}  // namespace reflcap::cli
