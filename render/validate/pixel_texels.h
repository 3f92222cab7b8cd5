#pragma once
// The texel behind a validated pixel, and what the fit and the train samples say about it: the
// model and status it ended with (FIT/status.exr), how many train samples it had and the
// brightest of them (the sample store). For the worst-pixel table of `reflcap validate`: a
// held-out pixel far brighter than anything its texel's train photographs showed is a
// highlight the fit never saw (the model had to predict it); one that its samples did show is
// a fit that missed what it measured.
#include <array>
#include <cstdint>
#include <filesystem>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "engine/capture/capture.h"
#include "engine/core/status.h"
#include "engine/image/image.h"
#include "engine/mesh/mesh.h"
#include "engine/mesh/ray_scene.h"
#include "engine/mesh/texel_atlas.h"
#include "engine/texel/sample_store.h"

namespace reflcap::validate {

// fit_report.json's names of codes under `key` ("status_names", "model_names"): an array indexed
// by code, or an object from code ("0", "1", ...) to name; empty when absent or malformed (the
// report then shows the codes alone).
std::vector<std::string> FitReportNames(const nlohmann::json& report, const char* key);

struct PixelQuery {
  size_t image = 0;  // capture.images index
  int x = 0, y = 0;  // pixel (column, row; 0 = top)
};

struct PixelTexel {
  int64_t texel = -1;  // -1: the pixel's centre shows no texel (a miss, or outside the atlas)
  // status.exr at the texel; -1 where the file lacks the channel (an older fit).
  int status = -1;          // FitStatus code
  int model = -1;           // TexelModel code
  int cluster = -1;         // material cluster, -1 none
  double lobe_donor = std::numeric_limits<double>::quiet_NaN();  // texel index, or < 0 codes
  std::string status_name, model_name;  // from fit_report.json; empty when it has none
  // The sample store (when given): the texel's train samples, and per channel the brightest
  // value among them with a positive finite weight (0 when none).
  int64_t train_samples = -1;
  std::array<float, 3> brightest{};
};

// What the look-up reads from the fit, loaded once: the atlas of FIT/params.exr (with the mesh
// and its ray scene), FIT/status.exr, fit_report.json's names and the sample store. Load can run
// while `reflcap validate` scores the images (it needs no query); the status map it read serves
// the report's fit figures too. Errors as LookUpPixelTexels.
class FitTexels {
 public:
  static StatusOr<std::unique_ptr<FitTexels>> Load(const Capture& capture,
                                                   const std::filesystem::path& fit_dir,
                                                   const std::filesystem::path& samples_dir);
  ~FitTexels();
  // LookUpPixelTexels's answer for `queries` (reads the store chunks they need).
  StatusOr<std::vector<PixelTexel>> LookUp(const std::vector<PixelQuery>& queries);
  // FIT/status.exr as read: one channel per name of status_channels().
  const Image& status() const { return status_; }
  const std::vector<std::string>& status_channels() const { return status_channels_; }

 private:
  FitTexels() = default;
  const Capture* capture_ = nullptr;
  TriangleMesh mesh_;
  TexelAtlas atlas_;
  std::unique_ptr<RayScene> scene_;
  Image status_;
  std::vector<std::string> status_channels_, status_names_, model_names_;
  std::unique_ptr<SampleStoreReader> store_;
};

// For every query, the texel its pixel centre shows in the atlas of FIT/params.exr, found as
// the renderers find it — mesh captures: the camera ray through the pixel centre, its first
// hit's UV, TexelAtlas::TexelUnderUv; normal-map captures: the camera pixel's texel — then
// status.exr's channels there and, with `samples_dir`, the texel's samples. Errors name the
// file (params.exr, status.exr, the store, the mesh): NotFound, InvalidArgument (a store whose
// texel count is not the atlas's), DataLoss.
StatusOr<std::vector<PixelTexel>> LookUpPixelTexels(const Capture& capture,
                                                    const std::filesystem::path& fit_dir,
                                                    const std::filesystem::path& samples_dir,
                                                    const std::vector<PixelQuery>& queries);

}  // namespace reflcap::validate
