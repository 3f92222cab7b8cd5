// The texel behind a validated pixel (see pixel_texels.h).
#include "render/validate/pixel_texels.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <map>
#include <memory>

#include <nlohmann/json.hpp>

#include "engine/core/atomic_file.h"
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
StatusOr<std::vector<int64_t>> MeshTexels(const Capture& capture, const TexelAtlas& atlas,
                                          const TriangleMesh& mesh,
                                          const std::vector<PixelQuery>& queries) {
  REFLCAP_ASSIGN_OR_RETURN(std::unique_ptr<RayScene> scene, RayScene::Create(mesh));
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
    const RayHit hit = scene->Intersect(origin, dir, 0, std::numeric_limits<float>::infinity());
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

StatusOr<std::vector<PixelTexel>> LookUpPixelTexels(const Capture& capture, const fs::path& fit_dir,
                                                    const fs::path& samples_dir,
                                                    const std::vector<PixelQuery>& queries) {
  const fs::path params = fit_dir / "params.exr";
  REFLCAP_ASSIGN_OR_RETURN(ImageInfo params_info, ReadExrInfo(params));
  TexelAtlas atlas;
  std::vector<int64_t> texels;
  if (capture.normal_map) {
    // The atlas is the camera's masked pixels (BuildNormalMapAtlas): the pixel is the texel.
    const NormalMapGeometry& g = *capture.normal_map;
    REFLCAP_ASSIGN_OR_RETURN(Image normals, ReadExrRgb(capture.Resolve(g.normals)));
    REFLCAP_ASSIGN_OR_RETURN(Image mask, ReadPng(capture.Resolve(g.mask)));
    REFLCAP_ASSIGN_OR_RETURN(atlas, BuildNormalMapAtlas(normals, mask));
    for (const PixelQuery& q : queries) {
      const bool inside = capture.images[q.image].camera == g.camera && q.x >= 0 && q.y >= 0 &&
                          q.x < atlas.width && q.y < atlas.height;
      texels.push_back(inside ? atlas.TexelAt(q.x, q.y) : -1);
    }
  } else {
    REFLCAP_ASSIGN_OR_RETURN(TriangleMesh mesh, LoadMesh(capture.Resolve(capture.mesh)));
    auto built = BuildTexelAtlas(mesh, params_info.width, params_info.height);
    if (!built.ok()) return built.status().WithContext(params.string());
    atlas = std::move(built).value();
    REFLCAP_ASSIGN_OR_RETURN(texels, MeshTexels(capture, atlas, mesh, queries));
  }
  std::vector<PixelTexel> out(queries.size());
  for (size_t i = 0; i < queries.size(); ++i) out[i].texel = texels[i];

  // status.exr's channels at each texel's atlas pixel (channels are stored sorted by name).
  const fs::path status = fit_dir / "status.exr";
  std::vector<std::string> names;
  REFLCAP_ASSIGN_OR_RETURN(Image codes, ReadExrChannels(status, &names));
  if (codes.width != atlas.width || codes.height != atlas.height) {
    return InvalidArgumentError(status.string(), ": is ", codes.width, "x", codes.height,
                                " but the atlas of ", params.string(), " is ", atlas.width, "x",
                                atlas.height);
  }
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
  nlohmann::json report;
  if (auto text = ReadTextFile(fit_dir / "fit_report.json"); text.ok()) {
    report = nlohmann::json::parse(*text, nullptr, false);
    if (!report.is_object()) report = nlohmann::json::object();
  }
  const std::vector<std::string> status_names = FitReportNames(report, "status_names");
  const std::vector<std::string> model_names = FitReportNames(report, "model_names");
  for (PixelTexel& p : out) {
    if (p.texel < 0) continue;
    const float* px = &codes.data[size_t(atlas.pixel_of_texel[size_t(p.texel)]) * codes.channels];
    // Codes are small integers stored as floats; a non-finite one reads as absent.
    const auto code = [&](int c) {
      return c >= 0 && std::isfinite(px[c]) ? int(std::lround(px[c])) : -1;
    };
    p.status = code(status_channel);
    p.model = code(model_channel);
    p.cluster = code(cluster_channel);
    if (donor_channel >= 0) p.lobe_donor = px[donor_channel];
    p.status_name = NameOf(status_names, p.status);
    p.model_name = NameOf(model_names, p.model);
  }

  if (samples_dir.empty()) return out;
  REFLCAP_ASSIGN_OR_RETURN(std::unique_ptr<SampleStoreReader> store,
                           SampleStoreReader::Open(samples_dir));
  const SampleStoreInfo& info = store->info();
  if (info.texels != atlas.TexelCount()) {
    return InvalidArgumentError(samples_dir.string(), ": the store has ", info.texels,
                                " texels but the atlas of ", params.string(), " has ",
                                atlas.TexelCount(), ": not the fit's store");
  }
  std::map<uint32_t, TexelSampleChunk> chunks;  // each needed chunk read once
  for (PixelTexel& p : out) {
    if (p.texel < 0) continue;
    const uint32_t c = uint32_t(uint64_t(p.texel) / info.chunk_texels);
    auto it = chunks.find(c);
    if (it == chunks.end()) {
      REFLCAP_ASSIGN_OR_RETURN(TexelSampleChunk chunk, store->ReadChunk(c));
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

}  // namespace reflcap::validate
