// The texel behind a validated pixel (see pixel_texels.h).
#include "render/validate/pixel_texels.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <map>
#include <memory>

#include <nlohmann/json.hpp>

#include "engine/core/atomic_file.h"
#include "engine/core/parallel.h"
#include "engine/image/exr_io.h"
#include "engine/image/png_io.h"
#include "engine/mesh/mesh_io.h"
#include "engine/mesh/ray_scene.h"
#include "engine/mesh/texel_atlas.h"
#include "engine/texel/sample_store.h"

namespace reflcap::validate {
namespace fs = std::filesystem;

namespace {

std::string NameOf(const std::vector<std::string>& names, int code) {
  return code >= 0 && size_t(code) < names.size() ? names[size_t(code)] : std::string();
}

// The texel at each query's pixel centre in `atlas` (mesh: the renderers' ray and UV rule).
std::vector<int64_t> MeshTexels(const Capture& capture, const TexelAtlas& atlas,
                                const TriangleMesh& mesh, const RayScene& scene,
                                const std::vector<PixelQuery>& queries) {
  std::vector<int64_t> texels;
  for (const PixelQuery& q : queries) {
    const CaptureImage& image = capture.images[q.image];
    const Camera& camera = capture.cameras[image.camera];
    const Rigid3 object_from_cam =
        (camera.cam_from_world * capture.WorldFromObject(image)).Inverse();
    Vec3d o, d;
    camera.PixelRay({double(q.x), double(q.y)}, &o, &d);
    const Vec3f origin = (object_from_cam * o).cast<float>();
    const Vec3f dir = (object_from_cam.rotation * d).normalized().cast<float>();
    const RayHit hit = scene.Intersect(origin, dir, 0, std::numeric_limits<float>::infinity());
    if (!hit.hit) {
      texels.push_back(-1);
      continue;
    }
    const auto& cuv = mesh.corner_uvs[hit.triangle];
    const Vec2f uv = (1 - hit.b1 - hit.b2) * cuv[0] + hit.b1 * cuv[1] + hit.b2 * cuv[2];
    texels.push_back(atlas.TexelUnderUv(uv));
  }
  return texels;
}

}  // namespace

std::vector<std::string> FitReportNames(const nlohmann::json& report, const char* key) {
  std::vector<std::string> names;
  const auto it = report.find(key);
  if (it == report.end()) return names;
  const auto text = [](const nlohmann::json& n) {
    return n.is_string() ? n.get<std::string>() : n.dump();
  };
  if (it->is_array()) {
    for (const auto& n : *it) names.push_back(text(n));
  } else if (it->is_object()) {
    for (auto n = it->begin(); n != it->end(); ++n) {
      char* stop = nullptr;
      const long code = std::strtol(n.key().c_str(), &stop, 10);
      // Codes are small non-negative integers (statuses, models); anything else is skipped.
      if (*stop || code < 0 || code > 255) continue;
      if (names.size() <= size_t(code)) names.resize(size_t(code) + 1);
      names[size_t(code)] = text(*n);
    }
  }
  return names;
}

StatusOr<std::unique_ptr<FitTexels>> FitTexels::Load(const Capture& capture,
                                                     const fs::path& fit_dir,
                                                     const fs::path& samples_dir) {
  auto f = std::unique_ptr<FitTexels>(new FitTexels());
  f->capture_ = &capture;
  const fs::path params = fit_dir / "params.exr";
  REFLCAP_ASSIGN_OR_RETURN(ImageInfo params_info, ReadExrInfo(params));
  if (capture.normal_map) {
    // The atlas is the camera's masked pixels (BuildNormalMapAtlas): the pixel is the texel.
    const NormalMapGeometry& g = *capture.normal_map;
    REFLCAP_ASSIGN_OR_RETURN(Image normals, ReadExrRgb(capture.Resolve(g.normals)));
    REFLCAP_ASSIGN_OR_RETURN(Image mask, ReadPng(capture.Resolve(g.mask)));
    REFLCAP_ASSIGN_OR_RETURN(f->atlas_, BuildNormalMapAtlas(normals, mask));
  } else {
    REFLCAP_ASSIGN_OR_RETURN(f->mesh_, LoadMesh(capture.Resolve(capture.mesh)));
    auto built = BuildTexelAtlas(f->mesh_, params_info.width, params_info.height);
    if (!built.ok()) return built.status().WithContext(params.string());
    f->atlas_ = std::move(built).value();
    REFLCAP_ASSIGN_OR_RETURN(f->scene_, RayScene::Create(f->mesh_));
  }
  // status.exr: one large file, decoded on every core (channels are stored sorted by name).
  const fs::path status = fit_dir / "status.exr";
  REFLCAP_ASSIGN_OR_RETURN(f->status_, ReadExrChannels(status, &f->status_channels_,
                                                       HardwareThreads()));
  if (f->status_.width != f->atlas_.width || f->status_.height != f->atlas_.height) {
    return InvalidArgumentError(status.string(), ": is ", f->status_.width, "x",
                                f->status_.height, " but the atlas of ", params.string(),
                                " is ", f->atlas_.width, "x", f->atlas_.height);
  }
  if (auto text = ReadTextFile(fit_dir / "fit_report.json"); text.ok()) {
    nlohmann::json report = nlohmann::json::parse(*text, nullptr, false);
    if (report.is_object()) {
      f->status_names_ = FitReportNames(report, "status_names");
      f->model_names_ = FitReportNames(report, "model_names");
    }
  }
  if (!samples_dir.empty()) {
    REFLCAP_ASSIGN_OR_RETURN(f->store_, SampleStoreReader::Open(samples_dir));
    const SampleStoreInfo& info = f->store_->info();
    if (info.texels != f->atlas_.TexelCount()) {
      return InvalidArgumentError(samples_dir.string(), ": the store has ", info.texels,
                                  " texels but the atlas of ", params.string(), " has ",
                                  f->atlas_.TexelCount(), ": not the fit's store");
    }
  }
  return f;
}

FitTexels::~FitTexels() = default;

StatusOr<std::vector<PixelTexel>> FitTexels::LookUp(const std::vector<PixelQuery>& queries) {
  const Capture& capture = *capture_;
  std::vector<int64_t> texels;
  if (capture.normal_map) {
    const NormalMapGeometry& g = *capture.normal_map;
    for (const PixelQuery& q : queries) {
      const bool inside = capture.images[q.image].camera == g.camera && q.x >= 0 && q.y >= 0 &&
                          q.x < atlas_.width && q.y < atlas_.height;
      texels.push_back(inside ? atlas_.TexelAt(q.x, q.y) : -1);
    }
  } else {
    texels = MeshTexels(capture, atlas_, mesh_, *scene_, queries);
  }
  std::vector<PixelTexel> out(queries.size());
  for (size_t i = 0; i < queries.size(); ++i) out[i].texel = texels[i];

  // status.exr's channels at each texel's atlas pixel.
  const std::vector<std::string>& names = status_channels_;
  const auto channel = [&](const char* name) {
    for (size_t k = 0; k < names.size(); ++k) {
      if (names[k] == name) return int(k);
    }
    return -1;
  };
  int status_channel = channel("status");
  if (status_channel < 0 && names.size() == 1) status_channel = 0;  // an older fit's single "Y"
  const int model_channel = channel("model"), cluster_channel = channel("material_cluster"),
            donor_channel = channel("lobe_donor");
  for (PixelTexel& p : out) {
    if (p.texel < 0) continue;
    const float* px =
        &status_.data[size_t(atlas_.pixel_of_texel[size_t(p.texel)]) * status_.channels];
    // Codes are small integers stored as floats; a non-finite one reads as absent.
    const auto code = [&](int c) {
      return c >= 0 && std::isfinite(px[c]) ? int(std::lround(px[c])) : -1;
    };
    p.status = code(status_channel);
    p.model = code(model_channel);
    p.cluster = code(cluster_channel);
    if (donor_channel >= 0) p.lobe_donor = px[donor_channel];
    p.status_name = NameOf(status_names_, p.status);
    p.model_name = NameOf(model_names_, p.model);
  }

  if (store_ == nullptr) return out;
  const SampleStoreInfo& info = store_->info();
  std::map<uint32_t, TexelSampleChunk> chunks;  // each needed chunk read once
  for (PixelTexel& p : out) {
    if (p.texel < 0) continue;
    const uint32_t c = uint32_t(uint64_t(p.texel) / info.chunk_texels);
    auto it = chunks.find(c);
    if (it == chunks.end()) {
      REFLCAP_ASSIGN_OR_RETURN(TexelSampleChunk chunk, store_->ReadChunk(c));
      it = chunks.emplace(c, std::move(chunk)).first;
    }
    const TexelSampleChunk& chunk = it->second;
    const uint32_t i = uint32_t(uint64_t(p.texel) - chunk.first_texel);
    p.train_samples = int64_t(chunk.SampleCount(i));
    const BrdfSample* s = chunk.SamplesOf(i);
    for (uint64_t k = 0; k < chunk.SampleCount(i); ++k) {
      for (int ch = 0; ch < 3; ++ch) {
        const float w = s[k].weight[ch], y = s[k].value[ch];
        if (w > 0 && std::isfinite(w) && std::isfinite(y)) {
          p.brightest[size_t(ch)] = std::max(p.brightest[size_t(ch)], y);
        }
      }
    }
  }
  return out;
}

StatusOr<std::vector<PixelTexel>> LookUpPixelTexels(const Capture& capture, const fs::path& fit_dir,
                                                    const fs::path& samples_dir,
                                                    const std::vector<PixelQuery>& queries) {
  REFLCAP_ASSIGN_OR_RETURN(std::unique_ptr<FitTexels> fit,
                           FitTexels::Load(capture, fit_dir, samples_dir));
  return fit->LookUp(queries);
}

}  // namespace reflcap::validate
