// `reflcap calibrate intrinsics|turntable CALIB.json --out FILE`: camera intrinsics from planar
// board photos, and the rig (camera poses, turntable axis) from photos of the checkerboard cuboid
// by bundle adjustment (calib/intrinsics.h, calib/turntable.h). Each writes its file and a report
// folder beside it, both only once everything succeeded.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <string>

#include "calib/calib_file.h"
#include "calib/intrinsics.h"
#include "calib/report.h"
#include "calib/rig_io.h"
#include "calib/turntable.h"
#include "cli/cli.h"
#include "engine/capture/capture.h"
#include "engine/core/atomic_file.h"
#include "engine/core/progress.h"

namespace reflcap::cli {
namespace fs = std::filesystem;
namespace {

constexpr char kVerb[] = "calibrate";

constexpr char kTopUsage[] =
    "usage: reflcap calibrate intrinsics CALIB.json --out INTRINSICS.json [options]\n"
    "       reflcap calibrate turntable CALIB.json --out RIG.json [--intrinsics INTRINSICS.json] [options]\n"
    "\n"
    "  intrinsics   each camera's K and lens distortion from the planar board photos\n"
    "  turntable    camera poses, turntable axis and cuboid pose by bundle adjustment\n"
    "(reflcap calibrate intrinsics --help, reflcap calibrate turntable --help for each)\n";

int Usage(const std::string& what, const std::string& message) {
  std::fprintf(stderr, "reflcap calibrate %s: %s\n", what.c_str(), message.c_str());
  return kExitUsage;
}

// The report folder beside an output file: RIG.json -> RIG_report.
// The solver flags both calibrations share (their options structs name the fields alike).
template <typename Options>
void AddSolverFlags(ArgParser* args, Options* options) {
  args->AddDouble("loss-scale", &options->loss_scale_px,
                  StrCat("Huber loss scale, pixels (default ", options->loss_scale_px, ")"));
  args->AddDouble("outlier-sigmas", &options->outlier_sigmas,
                  StrCat("reject corners beyond this many robust sigmas (default ",
                         options->outlier_sigmas, ")"));
  args->AddInt("threads", &options->threads, "worker threads (default: all cores)");
}

// Corner refinement flags, shared by both verbs (board_detect.h).
struct DetectFlags {
  std::string refiner;
  bool linear_photos = false;
};

void AddDetectFlags(ArgParser* args, DetectFlags* flags) {
  args->AddString("corner-refiner", &flags->refiner, "NAME",
                  "symmetry (default: point symmetry of the board around each corner) or subpix "
                  "(OpenCV cornerSubPix)");
  args->AddFlag("linear-photos", &flags->linear_photos,
                "the photos hold linear values (default: sRGB-encoded, decoded before refinement)");
}

Status ApplyDetectFlags(const DetectFlags& flags, calib::DetectOptions* detect) {
  if (!flags.refiner.empty()) {
    const auto refiner = calib::ParseCornerRefiner(flags.refiner);
    if (!refiner) {
      return InvalidArgumentError("--corner-refiner: unknown refiner \"", flags.refiner,
                                  "\" (expected symmetry or subpix)");
    }
    detect->refiner = *refiner;
  }
  detect->photos_srgb = !flags.linear_photos;
  return OkStatus();
}

fs::path DefaultReportDir(const fs::path& out) {
  return out.parent_path() / (out.stem().string() + "_report");
}

// Refuses an existing output file unless --overwrite (a folder is StagingDir's business).
Status CheckOutputFile(const fs::path& out, bool overwrite) {
  if (fs::is_directory(out)) return FailedPreconditionError(out.string(), ": is a folder (expected a file name)");
  if (fs::exists(out) && !overwrite) {
    return FailedPreconditionError(out.string(), ": exists (use --overwrite to replace it)");
  }
  const fs::path parent = fs::absolute(out).parent_path();
  if (!fs::is_directory(parent)) return NotFoundError(parent.string(), ": no such folder for the output");
  return OkStatus();
}

double Seconds(std::chrono::steady_clock::time_point since) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - since).count();
}

int RunIntrinsics(int argc, char** argv) {
  const auto t0 = std::chrono::steady_clock::now();
  std::string input, out, report, model_list;
  bool overwrite = false;
  calib::IntrinsicsOptions options;
  ArgParser args(
      "calibrate intrinsics", "CALIB.json --out INTRINSICS.json [options]",
      "Calibrate each camera's K and lens distortion from the planar board photos of a calib/1\n"
      "session (intrinsics_images, intrinsics_board): board detection (findChessboardCornersSB,\n"
      "identification by the squares' colours, each corner refined by the board's point symmetry),\n"
      "wrong detections rejected by PnP reprojection, then one Ceres adjustment per camera over K,\n"
      "distortion and every view's pose with a Huber loss and outlier rejection. Writes\n"
      "INTRINSICS.json (reflcap-intrinsics/1: K, dist, their sigmas and covariance per camera,\n"
      "per-view reprojection, frame coverage) and a report folder (index.html, report.json,\n"
      "residuals drawn on one photo per camera). `calibrate turntable --intrinsics` reads it.");
  args.AddPositional("CALIB.json", &input, "a calib/1 file");
  args.AddString("out", &out, "INTRINSICS.json", "output file (required)");
  args.AddString("report", &report, "DIR", "report folder (default: beside the output, <name>_report)");
  args.AddString("intrinsics-params", &model_list, "LIST",
                 StrCat("what to estimate (default ", options.model.ToString(),
                        "; add k3; \"f\" instead of fx,fy ties them: square pixels)"));
  AddSolverFlags(&args, &options);
  DetectFlags detect_flags;
  AddDetectFlags(&args, &detect_flags);
  args.AddFlag("overwrite", &overwrite, "replace INTRINSICS.json and the report if they exist");
  bool help = false;
  if (Status s = args.Parse(argc, argv, 3, &help); !s.ok()) return Usage("intrinsics", s.message());
  if (help) {
    std::printf("%s", args.Help().c_str());
    return 0;
  }
  if (out.empty()) return Usage("intrinsics", "--out INTRINSICS.json is required");
  if (!model_list.empty()) {
    auto model = calib::IntrinsicsModel::Parse(model_list);
    if (!model.ok()) return Usage("intrinsics", StrCat("--intrinsics-params: ", model.status().message()));
    options.model = *model;
  }
  if (Status s = ApplyDetectFlags(detect_flags, &options.detect); !s.ok()) return Usage("intrinsics", s.message());
  if (Status s = options.Validate(); !s.ok()) return Usage("intrinsics", s.message());
  if (report.empty()) report = DefaultReportDir(out).string();
  if (Status s = CheckOutputFile(out, overwrite); !s.ok()) return ReportError(kVerb, s);
  auto staging = StagingDir::Create(report, overwrite);
  if (!staging.ok()) return ReportError(kVerb, staging.status());

  auto file = calib::ReadCalibFile(input);
  if (!file.ok()) return ReportError(kVerb, file.status());
  auto result = calib::CalibrateIntrinsics(*file, options);
  if (!result.ok()) return ReportError(kVerb, result.status());
  if (Status s = calib::WriteIntrinsicsReport(*file, *result, options, staging->path()); !s.ok()) {
    return ReportError(kVerb, s);
  }
  const std::string json = calib::IntrinsicsToJson(*file, *result, options);
  if (Status s = staging->Commit(); !s.ok()) return ReportError(kVerb, s);
  if (Status s = WriteTextFileAtomic(out, json); !s.ok()) {
    std::error_code ec;
    fs::remove_all(report, ec);
    return ReportError(kVerb, s);
  }
  std::printf("%-6s %9s %9s %8s %8s %9s %9s %8s %8s  %7s %6s %8s\n", "camera", "fx", "fy", "cx", "cy", "k1",
              "k2", "p1", "p2", "RMS px", "views", "coverage");
  for (const auto& c : result->cameras) {
    const auto& p = c.intrinsics.params;
    const auto& s = c.intrinsics.sigma;
    std::printf("%-6s %9.2f %9.2f %8.2f %8.2f %9.5f %9.5f %8.5f %8.5f  %7.4f %2d/%-3d %7.0f%%\n",
                c.intrinsics.id.c_str(), p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7], c.rms_px, c.views_used,
                c.views_found, 100 * c.coverage_cells);
    std::printf("%-6s %9.2f %9.2f %8.2f %8.2f %9.5f %9.5f %8.5f %8.5f\n", "  ±", s[0], s[1], s[2], s[3], s[4],
                s[5], s[6], s[7]);
    if (c.error) {
      const auto& e = *c.error;
      std::printf("%-6s %+9.2f %+9.2f %+8.2f %+8.2f %+9.5f %+9.5f %+8.5f %+8.5f   (estimate - ground truth)\n",
                  "  err", e[0], e[1], e[2], e[3], e[4], e[5], e[6], e[7]);
    }
  }
  int not_used = 0;
  for (const auto& v : result->views) not_used += !v.used;
  if (not_used > 0) std::printf("%d board photo(s) not used (why: the report)\n", not_used);
  std::printf("intrinsics: %s\nreport:     %s/index.html\ntime:       %s (detection %s, adjustment %s)\n",
              out.c_str(), report.c_str(), FormatDuration(Seconds(t0)).c_str(),
              FormatDuration(result->detect_s).c_str(), FormatDuration(result->solve_s).c_str());
  return 0;
}

void PrintTruth(const calib::CalibFile& file, const calib::TurntableResult& r, bool refined) {
  const calib::TruthComparison& a = *r.truth;
  const calib::TruthComparison& b = *r.baseline_truth;
  std::printf("against ground truth (gauge-free)        adjusted     baseline (averaged poses)\n");
  std::printf("  axis direction                     %9.5f deg  %9.5f deg\n", a.axis_deg, b.axis_deg);
  std::printf("  axis point                         %9.4f mm   %9.4f mm\n", a.point_mm, b.point_mm);
  std::printf("  axis direction, worst camera       %9.5f deg  %9.5f deg\n", a.max_axis_deg, b.max_axis_deg);
  std::printf("  axis point, worst camera           %9.4f mm   %9.4f mm\n", a.max_point_mm, b.max_point_mm);
  std::printf("  camera rotation vs %-6s (max)     %9.5f deg  %9.5f deg\n", file.cameras[0].id.c_str(),
              a.max_camera_rotation_deg, b.max_camera_rotation_deg);
  std::printf("  camera centre vs %-6s (max)       %9.4f mm   %9.4f mm\n", file.cameras[0].id.c_str(),
              a.max_camera_centre_mm, b.max_camera_centre_mm);
  std::printf("  cuboid pose per photo (median)     %9.5f deg  %9.5f deg   %.4f / %.4f mm\n",
              a.box_rotation_median_deg, b.box_rotation_median_deg, a.box_translation_median_mm,
              b.box_translation_median_mm);
  std::printf("  reprojection RMS                   %9.4f px   %9.4f px\n", r.total.rms_px, r.baseline_total.rms_px);
  if (refined) {
    for (size_t i = 0; i < a.intrinsics_error.size(); ++i) {
      const auto& e = a.intrinsics_error[i];
      std::printf("  %-6s intrinsics error: fx %+.2f fy %+.2f cx %+.2f cy %+.2f px\n", file.cameras[i].id.c_str(),
                  e[calib::kFx], e[calib::kFy], e[calib::kCx], e[calib::kCy]);
    }
  }
}

int RunTurntable(int argc, char** argv) {
  const auto t0 = std::chrono::steady_clock::now();
  std::string input, out, report, intrinsics_path, capture_path, model_list;
  bool overwrite = false, no_boards = false;
  calib::TurntableOptions options;
  ArgParser args(
      "calibrate turntable", "CALIB.json --out RIG.json [--intrinsics INTRINSICS.json] [options]",
      "Calibrate the rig from the photos of the checkerboard cuboid on the turntable (calib/1\n"
      "images): every visible face's board is detected and identified, the cuboid's pose in each\n"
      "photo found by PnP, and one bundle adjustment estimates every camera's pose (fixed on the\n"
      "arm), the turntable axis and axis point and the cuboid's pose at angle 0 — optionally\n"
      "per-angle offsets and the intrinsics — with a Huber loss, outlier rejection and the sigma\n"
      "of every parameter. The seed's baseline (axis from the averaged per-angle poses) is\n"
      "reported beside it, and the comparison with ground truth when the file has one.\n"
      "Writes RIG.json, a capture/1 skeleton (cameras with K, dist and cam_from_world; turntable;\n"
      "the calibration under \"calibration\"), or with --capture a complete capture/1, and a\n"
      "report folder. World frame: z along the turntable axis, origin where the axis meets the\n"
      "cuboid's bottom face, x towards the first camera.");
  args.AddPositional("CALIB.json", &input, "a calib/1 file");
  args.AddString("out", &out, "RIG.json", "output file (required)");
  args.AddString("intrinsics", &intrinsics_path, "FILE",
                 "INTRINSICS.json from calibrate intrinsics (default: K, dist of CALIB.json)");
  args.AddFlag("refine-intrinsics", &options.refine_intrinsics,
               "adjust the intrinsics with the rig (with the board photos of CALIB.json)");
  args.AddString("intrinsics-params", &model_list, "LIST",
                 StrCat("with --refine-intrinsics: what (default ", options.intrinsics_model.ToString(),
                        "; \"f\" = fx and fy tied; others held at their start)"));
  args.AddFlag("no-board-photos", &no_boards, "with --refine-intrinsics: leave CALIB.json's board photos out");
  args.AddFlag("angle-offsets", &options.angle_offsets,
               "estimate one offset per turntable angle (stepper backlash; the first angle's is 0)");
  args.AddDouble("min-cos", &options.min_cos,
                 StrCat("use face views seen at cos >= X, in (0, 1) (default ", options.min_cos, ")"));
  args.AddString("capture", &capture_path, "CAPTURE.json",
                 "write RIG.json as this capture/1 with its cameras and turntable calibrated");
  args.AddString("report", &report, "DIR", "report folder (default: beside the output, <name>_report)");
  AddSolverFlags(&args, &options);
  DetectFlags detect_flags;
  AddDetectFlags(&args, &detect_flags);
  args.AddFlag("overwrite", &overwrite, "replace RIG.json and the report if they exist");
  bool help = false;
  if (Status s = args.Parse(argc, argv, 3, &help); !s.ok()) return Usage("turntable", s.message());
  if (help) {
    std::printf("%s", args.Help().c_str());
    return 0;
  }
  if (out.empty()) return Usage("turntable", "--out RIG.json is required");
  options.board_photos = !no_boards;
  if (!model_list.empty()) {
    if (!options.refine_intrinsics) return Usage("turntable", "--intrinsics-params needs --refine-intrinsics");
    auto model = calib::IntrinsicsModel::Parse(model_list);
    if (!model.ok()) return Usage("turntable", StrCat("--intrinsics-params: ", model.status().message()));
    options.intrinsics_model = *model;
  }
  if (no_boards && !options.refine_intrinsics) return Usage("turntable", "--no-board-photos needs --refine-intrinsics");
  if (Status s = ApplyDetectFlags(detect_flags, &options.detect); !s.ok()) return Usage("turntable", s.message());
  if (Status s = options.Validate(); !s.ok()) return Usage("turntable", s.message());
  if (report.empty()) report = DefaultReportDir(out).string();
  if (Status s = CheckOutputFile(out, overwrite); !s.ok()) return ReportError(kVerb, s);
  auto staging = StagingDir::Create(report, overwrite);
  if (!staging.ok()) return ReportError(kVerb, staging.status());

  auto file = calib::ReadCalibFile(input);
  if (!file.ok()) return ReportError(kVerb, file.status());
  if (Status s = calib::CheckCuboidSession(*file); !s.ok()) return ReportError(kVerb, s);
  std::optional<Capture> capture;
  if (!capture_path.empty()) {
    auto c = ReadCapture(capture_path);
    if (!c.ok()) return ReportError(kVerb, c.status());
    if (Status s = calib::CheckCaptureCameras(*c, *file); !s.ok()) return ReportError(kVerb, s);
    capture = std::move(*c);
  }
  // Start intrinsics: INTRINSICS.json, else the calib/1 file's.
  std::vector<calib::IntrinsicParams> start;
  std::string note;
  if (!intrinsics_path.empty()) {
    auto intr = calib::ReadIntrinsicsFile(intrinsics_path);
    if (!intr.ok()) return ReportError(kVerb, intr.status());
    for (const auto& cam : file->cameras) {
      const calib::CameraIntrinsics* match = nullptr;
      for (const auto& i : *intr) {
        if (i.id == cam.id) match = &i;
      }
      if (match == nullptr) {
        return ReportError(kVerb, InvalidArgumentError(intrinsics_path, ": cameras: no entry for camera \"",
                                                       cam.id, "\" of ", input));
      }
      if (match->width != cam.width || match->height != cam.height) {
        return ReportError(kVerb, InvalidArgumentError(intrinsics_path, ": camera \"", cam.id, "\" is ",
                                                       match->width, "x", match->height, " but ", input,
                                                       " has it ", cam.width, "x", cam.height));
      }
      start.push_back(match->params);
    }
    note = StrCat("from ", intrinsics_path);
  } else {
    for (size_t c = 0; c < file->cameras.size(); ++c) {
      if (!file->cameras[c].has_intrinsics) {
        return ReportError(kVerb, InvalidArgumentError(
                                      input, ": cameras[", c, "].K: missing; the turntable calibration needs "
                                      "every camera's intrinsics (in CALIB.json, or --intrinsics INTRINSICS.json "
                                      "from reflcap calibrate intrinsics)"));
      }
      start.push_back(calib::ToIntrinsicParams(file->cameras[c].K, file->cameras[c].dist));
    }
    note = StrCat("given in ", input);
  }
  if (options.refine_intrinsics) {
    note += StrCat("; refined with the rig (", options.intrinsics_model.ToString(), ")");
  } else {
    note += "; held";
  }

  auto result = calib::CalibrateTurntable(*file, start, options);
  if (!result.ok()) return ReportError(kVerb, result.status());
  const calib::TurntableResult& r = *result;
  if (!r.board_views.empty()) {
    int used = 0;
    for (const auto& v : r.board_views) used += v.used;
    note += StrCat(" and ", used, " board photos");
  }
  calib::RigProvenance provenance;
  provenance.intrinsics = note;
  provenance.report = (fs::absolute(report).lexically_normal() / "index.html")
                          .lexically_relative(fs::absolute(out).parent_path().lexically_normal())
                          .generic_string();
  std::string json;
  if (capture) {
    auto merged = calib::MergeRigIntoCapture(*capture, *file, r, options, provenance, fs::absolute(out).parent_path());
    if (!merged.ok()) return ReportError(kVerb, merged.status());
    json = std::move(*merged);
  } else {
    json = calib::RigToJson(*file, r, options, provenance);
  }
  if (Status s = calib::WriteTurntableReport(*file, r, options, note, staging->path()); !s.ok()) {
    return ReportError(kVerb, s);
  }
  if (Status s = staging->Commit(); !s.ok()) return ReportError(kVerb, s);
  if (Status s = WriteTextFileAtomic(out, json); !s.ok()) {
    std::error_code ec;
    fs::remove_all(report, ec);
    return ReportError(kVerb, s);
  }

  int used = 0, rejected = 0, empty = 0;
  for (const auto& v : r.views) {
    used += v.used;
    rejected += !v.used;
  }
  for (const auto& im : r.images) empty += im.status == "no board found";
  std::printf("cuboid: %zu photos, %d face views used (%d not used), %d corners; %d photo(s) without a board\n",
              r.images.size(), used, rejected, r.total.corners, empty);
  std::printf("reprojection RMS %.4f px (max %.3f px); the seed's averaged-poses baseline %.4f px\n",
              r.total.rms_px, r.total.max_px, r.baseline_total.rms_px);
  std::printf("%-6s %28s %8s %12s %12s %9s %9s %8s %8s\n", "camera", "centre (world, m)", "RMS px",
              "σ rot deg", "σ centre mm", "fx", "fy", "cx", "cy");
  for (size_t c = 0; c < file->cameras.size(); ++c) {
    const Vec3d centre = r.rig.cam_from_world[c].Inverse().translation;
    const auto& p = r.rig.intrinsics[c];
    std::printf("%-6s [%8.4f %8.4f %8.4f] %8.4f %12.5f %12.4f %9.2f %9.2f %8.2f %8.2f\n",
                file->cameras[c].id.c_str(), centre.x(), centre.y(), centre.z(), r.per_camera[c].rms_px,
                r.sigma.camera_rotation_deg[c].norm(), r.sigma.camera_centre_mm[c].norm(), p[0], p[1], p[2], p[3]);
  }
  std::printf("turntable axis [%.6f %.6f %.6f] (σ %.5f deg), point [%.5f %.5f %.5f] m (σ %.4f mm)\n",
              r.rig.axis.x(), r.rig.axis.y(), r.rig.axis.z(), r.sigma.axis_deg, r.rig.point.x(), r.rig.point.y(),
              r.rig.point.z(), r.sigma.point_mm);
  if (options.angle_offsets) {
    std::printf("angle offsets (deg):");
    for (size_t a = 0; a < file->angles_deg.size(); ++a) {
      std::printf(" %g:%+.4f±%.4f", file->angles_deg[a], r.rig.angle_offset_deg[a], r.sigma.angle_offset_deg[a]);
    }
    std::printf("\n");
  }
  if (options.refine_intrinsics) {
    for (size_t c = 0; c < file->cameras.size(); ++c) {
      const auto& sig = r.sigma.intrinsics[c];
      const double f = r.rig.intrinsics[c][calib::kFx];
      // A focal length known to worse than 0.5 % or a principal point to worse than 5 px is not
      // a calibration: say so (the views cannot separate them from the camera's pose).
      if (sig[calib::kFx] > 0.005 * f || std::max(sig[calib::kCx], sig[calib::kCy]) > 5) {
        std::fprintf(stderr,
                     "reflcap calibrate: warning: camera \"%s\": the photos determine its intrinsics poorly "
                     "(sigma fx %.1f px, cx %.1f px, cy %.1f px)%s\n",
                     file->cameras[c].id.c_str(), sig[calib::kFx], sig[calib::kCx], sig[calib::kCy],
                     r.board_views.empty() ? "; board photos in CALIB.json would pin them" : "");
      }
    }
  }
  if (r.truth) PrintTruth(*file, r, options.refine_intrinsics);
  std::printf("rig:    %s%s\nreport: %s/index.html\ntime:   %s (detection %s, adjustment %s)\n", out.c_str(),
              capture ? " (capture/1 with the calibrated rig)" : " (capture/1 skeleton)", report.c_str(),
              FormatDuration(Seconds(t0)).c_str(), FormatDuration(r.detect_s).c_str(),
              FormatDuration(r.solve_s).c_str());
  return 0;
}

}  // namespace

int RunCalibrate(int argc, char** argv) {
  if (argc < 3) {
    std::fprintf(stderr, "%s", kTopUsage);
    return kExitUsage;
  }
  const std::string what = argv[2];
  if (what == "--help" || what == "-h") {
    std::printf("%s", kTopUsage);
    return 0;
  }
  if (what == "intrinsics") return RunIntrinsics(argc, argv);
  if (what == "turntable") return RunTurntable(argc, argv);
  std::fprintf(stderr, "reflcap calibrate: unknown calibration \"%s\"\n\n%s", what.c_str(), kTopUsage);
  return kExitUsage;
}

}  // namespace reflcap::cli
