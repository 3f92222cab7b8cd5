// `reflcap info CAPTURE`: validates a capture completely (every field, the mesh or normal map,
// the header of every image) and prints a summary.
#include <cstdio>
#include <set>

#include "cli/cli.h"
#include "engine/capture/capture.h"
#include "engine/core/log.h"
#include "engine/mesh/mesh_io.h"
#include "engine/mesh/texel_atlas.h"

namespace reflcap::cli {

int RunInfo(int argc, char** argv) {
  std::string path;
  int atlas_res = kDefaultAtlasResolution;
  ArgParser args("info", "CAPTURE [--atlas-res R]",
                 "Validate a capture/1 dataset completely — every field of capture.json, the mesh\n"
                 "(or normal map and mask) and the header of every image — and print a summary.\n"
                 "Any problem is reported with the file and the field, and exit code 2.");
  args.AddPositional("CAPTURE", &path, "capture.json, or the folder holding it");
  args.AddInt("atlas-res", &atlas_res,
              StrCat("atlas resolution for the texel count (default ", kDefaultAtlasResolution, ")"));
  bool help = false;
  if (Status s = args.Parse(argc, argv, 2, &help); !s.ok()) {
    std::fprintf(stderr, "reflcap info: %s\n", s.message().c_str());
    return kExitUsage;
  }
  if (help) {
    std::printf("%s", args.Help().c_str());
    return 0;
  }
  if (atlas_res < 1 || atlas_res > 16384) {
    std::fprintf(stderr, "reflcap info: --atlas-res must be in [1, 16384]\n");
    return kExitUsage;
  }
  auto capture = ReadCapture(path);
  if (!capture.ok()) {
    // A rig skeleton (reflcap calibrate turntable without --capture) is not a capture yet, but
    // its cameras and turntable are checked and summarised; anything else is the capture error.
    auto rig = ReadRig(path);
    if (!rig.ok() || !rig->IsRig()) return ReportError("info", capture.status());
    const Capture& c = *rig;
    std::printf("rig         %s (capture/1.%d skeleton: cameras and turntable; %s)\n",
                c.json_path.string().c_str(), c.minor_version,
                "add lights, a mesh or normal map and images to make it a capture");
    std::printf("cameras     %zu\n", c.cameras.size());
    for (const Camera& cam : c.cameras) std::printf("  %s\n", cam.ToString().c_str());
    if (c.turntable) {
      std::printf("turntable   axis [%g %g %g] through [%g %g %g]\n", c.turntable->axis.x(),
                  c.turntable->axis.y(), c.turntable->axis.z(), c.turntable->point.x(),
                  c.turntable->point.y(), c.turntable->point.z());
    } else {
      std::printf("turntable   none (fixed object)\n");
    }
    std::printf("lights      %zu\nimages      %zu\ngeometry    %s\n", c.lights.size(),
                c.images.size(), !c.mesh.empty() ? c.mesh.c_str() : c.normal_map ? "normal map" : "none");
    std::printf("as capture  not yet: %s\n", capture.status().message().c_str());
    return 0;
  }
  CaptureFilesReport files;
  REFLCAP_LOG(kInfo) << "checking " << capture->images.size() << " image headers and the geometry";
  if (Status s = ValidateCaptureFiles(*capture, &files); !s.ok()) return ReportError("info", s);

  const Capture& c = *capture;
  std::printf("capture     %s (capture/1.%d)\n", c.json_path.string().c_str(), c.minor_version);
  std::printf("cameras     %zu\n", c.cameras.size());
  for (const Camera& cam : c.cameras) std::printf("  %s\n", cam.ToString().c_str());
  size_t point = 0;
  for (const Light& l : c.lights) point += l.type == LightType::kPoint;
  std::printf("lights      %zu (%zu point, %zu directional)\n", c.lights.size(), point,
              c.lights.size() - point);
  std::set<double> angles;
  for (const auto& image : c.images) angles.insert(image.turntable_deg);
  std::printf("images      %zu (train %zu, holdout %zu)\n", c.images.size(),
              c.CountSplit(Split::kTrain), c.CountSplit(Split::kHoldout));
  if (c.turntable) {
    std::printf("turntable   axis [%g %g %g] through [%g %g %g], %zu steps\n", c.turntable->axis.x(),
                c.turntable->axis.y(), c.turntable->axis.z(), c.turntable->point.x(),
                c.turntable->point.y(), c.turntable->point.z(), angles.size());
  } else {
    std::printf("turntable   none (fixed object)\n");
  }
  if (!c.mesh.empty()) {
    std::printf("mesh        %s: %zu vertices, %zu triangles", c.mesh.c_str(), files.mesh_vertices,
                files.mesh_triangles);
    if (files.mesh_degenerate_skipped) std::printf(" (%zu degenerate skipped)", files.mesh_degenerate_skipped);
    std::printf("\n");
    auto mesh = LoadMesh(c.Resolve(c.mesh));
    if (!mesh.ok()) return ReportError("info", mesh.status());
    auto texels = CountAtlasTexels(*mesh, atlas_res, atlas_res);
    if (!texels.ok()) return ReportError("info", texels.status());
    std::printf("atlas       %zu texels at %dx%d\n", *texels, atlas_res, atlas_res);
  } else {
    std::printf("geometry    normal map %s seen by %s: %zu texels (masked pixels)\n",
                c.normal_map->normals.c_str(), c.cameras[c.normal_map->camera].id.c_str(),
                files.normal_map_texels);
  }
  std::printf("ground truth %s\n", c.ground_truth_json.empty() ? "no" : "yes");
  std::printf("ok: every field, the geometry and %zu image headers are valid", files.images_checked);
  if (files.variance_images_checked > 0) {
    std::printf(" (and %zu variance image headers)", files.variance_images_checked);
  }
  std::printf("\n");
  return 0;
}

}  // namespace reflcap::cli
