// One photograph -> per-texel outcomes and BRDF samples (see image_resampler.h).
//
// Work is split into blocks of consecutive texels (atlas rows, so neighbouring surface points and
// coherent rays). A block runs the cheap scalar tests for all its texels, then sends the
// survivors' visibility rays in 16-wide packets, then the survivors' shadow rays, then looks their
// taps up in the pixel map and reads the pixel values. Blocks run in parallel; each writes only
// its own texels' outcome bytes and its own sample list, concatenated in block order at the end.
#include "acquire/resample/image_resampler.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>

#include "engine/core/parallel.h"

namespace reflcap::resample {
namespace {

constexpr float kInfinity = std::numeric_limits<float>::infinity();
// Texels per parallel task: large enough to fill many 16-wide packets after the scalar tests
// thin the block out, small enough to balance two to sixteen workers over a 4000-texel atlas.
constexpr int64_t kBlockTexels = 512;
// Pixel-map states: 0 = not cast yet; kMapDone once the pixel's rays are cast, with kMapHit when
// the camera ray hits the object and kMapLit when that hit point is lit.
constexpr uint8_t kMapDone = 1;
constexpr uint8_t kMapHit = 2;
constexpr uint8_t kMapLit = 4;

struct Ray {
  Vec3f origin, dir;
  float tfar;
};

// Occlusion of every ray in `rays`, 16 at a time; (*occluded)[i] receives ray i's answer.
void OccludedPackets(const RayScene& scene, const std::vector<Ray>& rays,
                     std::vector<uint8_t>* occluded) {
  occluded->assign(rays.size(), 0);
  std::array<bool, 16> valid, hit;
  std::array<Vec3f, 16> origin, dir;
  std::array<float, 16> tnear, tfar;
  tnear.fill(0);
  for (size_t base = 0; base < rays.size(); base += 16) {
    const size_t n = std::min<size_t>(16, rays.size() - base);
    for (size_t i = 0; i < 16; ++i) {
      valid[i] = i < n;
      if (!valid[i]) {
        origin[i] = dir[i] = Vec3f::UnitZ();
        tfar[i] = 0;
        continue;
      }
      origin[i] = rays[base + i].origin;
      dir[i] = rays[base + i].dir;
      tfar[i] = rays[base + i].tfar;
    }
    scene.Occluded16(valid, origin, dir, tnear, tfar, &hit);
    for (size_t i = 0; i < n; ++i) (*occluded)[base + i] = hit[i];
  }
}

// The four bilinear taps around a projected point (pixel centres at integers).
struct Taps {
  int x[4], y[4];
  float w[4];
};

Taps BilinearTaps(const Vec2d& px) {
  const double fx0 = std::floor(px.x()), fy0 = std::floor(px.y());
  const float fx = float(px.x() - fx0), fy = float(px.y() - fy0);
  const int x0 = int(fx0), y0 = int(fy0);
  return {{x0, x0 + 1, x0, x0 + 1},
          {y0, y0, y0 + 1, y0 + 1},
          {(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy}};
}

// The projection must be far inside int range before floor() is converted.
constexpr double kMaxPixelCoordinate = 1e8;

}  // namespace

const char* SamplePointName(SamplePoint point) {
  return point == SamplePoint::kTexel ? "texel" : "pixel";
}

StatusOr<SamplePoint> ParseSamplePoint(const std::string& name) {
  if (name == "pixel") return SamplePoint::kPixel;
  if (name == "texel") return SamplePoint::kTexel;
  return InvalidArgumentError("--sample-point: \"", name, "\" is not pixel or texel");
}

StatusOr<std::optional<PixelFilter>> ParsePixelFilter(const std::string& name) {
  if (name == "capture") return std::optional<PixelFilter>();
  if (name == "area") return std::optional<PixelFilter>(PixelFilter::kArea);
  if (name == "point") return std::optional<PixelFilter>(PixelFilter::kPoint);
  return InvalidArgumentError("--pixel-filter: \"", name, "\" is not capture, area or point");
}

const char* OutcomeName(Outcome outcome) {
  switch (outcome) {
    case Outcome::kKept: return "kept";
    case Outcome::kGrazingView: return "grazing_view";
    case Outcome::kEdgeOutside: return "edge_outside_image";
    case Outcome::kOccluded: return "occluded";
    case Outcome::kGrazingLight: return "grazing_light";
    case Outcome::kShadowed: return "shadowed";
    case Outcome::kEdgeSurface: return "edge_silhouette_or_depth";
    case Outcome::kEdgeShadow: return "edge_shadow_boundary";
    case Outcome::kInvalid: return "invalid";
    case Outcome::kClipped: return "clipped";
    case Outcome::kDark: return "dark";
    case Outcome::kEdgeTexel: return "edge_other_texel";
  }
  return "?";
}

const char* ReasonName(Reason reason) {
  switch (reason) {
    case Reason::kOccluded: return "occluded";
    case Reason::kShadowed: return "shadowed";
    case Reason::kGrazing: return "grazing";
    case Reason::kClipped: return "clipped";
    case Reason::kDark: return "dark";
    case Reason::kEdge: return "edge";
    case Reason::kInvalid: return "invalid";
  }
  return "?";
}

Reason ReasonOf(Outcome outcome) {
  switch (outcome) {
    case Outcome::kGrazingView:
    case Outcome::kGrazingLight: return Reason::kGrazing;
    case Outcome::kEdgeOutside:
    case Outcome::kEdgeSurface:
    case Outcome::kEdgeShadow:
    case Outcome::kEdgeTexel: return Reason::kEdge;
    case Outcome::kOccluded: return Reason::kOccluded;
    case Outcome::kShadowed: return Reason::kShadowed;
    case Outcome::kInvalid: return Reason::kInvalid;
    case Outcome::kClipped: return Reason::kClipped;
    case Outcome::kDark: return Reason::kDark;
    case Outcome::kKept: break;
  }
  REFLCAP_CHECK(false) << "ReasonOf(kKept)";
  return Reason::kEdge;
}

// Everything about one photograph that every texel needs, in the object frame.
struct ImageResampler::Frame {
  const Camera* camera = nullptr;
  Rigid3 cam_from_object;
  Rigid3 object_from_cam;
  bool pinhole = true;
  Vec3f cam_centre = Vec3f::Zero();  // pinhole
  Vec3f toward_cam = Vec3f::Zero();  // orthographic: unit, from the object towards the camera
  bool point_light = true;
  Vec3f light_position = Vec3f::Zero();
  Vec3f light_direction = Vec3f::Zero();  // directional: unit, towards the light
  Vec3f intensity = Vec3f::Zero();
  float exposure = 1;
  float saturation = 0;      // 0 = none
  double footprint_scale = 0;  // pinhole: metres per pixel per metre of depth; ortho: metres/pixel
  // Normal-map captures with a height field: the march towards this photograph's light.
  HeightFieldMarch march{};
  // The pixel map, filled lazily by the blocks that need a pixel: what the camera ray through
  // each pixel centre sees. Blocks may cast the same pixel concurrently; they compute identical
  // values, published with release/acquire so a reader sees depth whenever it sees kMapDone.
  std::unique_ptr<std::atomic<uint8_t>[]> map_state;  // kMapDone | kMapHit | kMapLit
  std::unique_ptr<std::atomic<float>[]> map_depth;    // distance along the unit pixel ray
  // SamplePoint::kPixel: the hit's unit shading normal (x, y, z per pixel), stored with depth.
  std::unique_ptr<std::atomic<float>[]> map_normal;
  // SamplePoint::kPixel: the texel under the hit's UV (TexelAtlas::TexelUnderUv; -1: none).
  std::unique_ptr<std::atomic<int32_t>[]> map_texel;
  // SamplePoint::kPixel: the camera's pixels are point samples (PixelFilter::kPoint), so a pair
  // whose taps all hit other texels is rejected (kEdgeTexel) instead of taking the nearest.
  bool point_pixels = false;

  // The camera ray through pixel (x, y), object frame; dir unit.
  void PixelRay(int x, int y, Vec3f* origin, Vec3f* dir) const {
    Vec3d o, d;
    camera->PixelRay({double(x), double(y)}, &o, &d);
    *origin = (object_from_cam * o).cast<float>();
    *dir = (object_from_cam.rotation * d).normalized().cast<float>();
  }

  // Unit direction from p towards the light, distance (infinite for directional lights).
  void ToLight(const Vec3f& p, Vec3f* wi, float* dist) const {
    if (point_light) {
      const Vec3f d = light_position - p;
      *dist = d.norm();
      *wi = d / *dist;
    } else {
      *wi = light_direction;
      *dist = kInfinity;
    }
  }
};

StatusOr<std::unique_ptr<ImageResampler>> ImageResampler::Create(const Capture& capture,
                                                                 const TexelAtlas& atlas,
                                                                 const RayScene* scene,
                                                                 const NoiseModel& noise,
                                                                 double min_cos, int threads) {
  const std::string file = capture.json_path.string();
  if (!(min_cos >= 0 && min_cos < 1)) {
    return InvalidArgumentError("min_cos must be in [0, 1), got ", min_cos);
  }
  if (!(noise.photon_sigma_at_1 >= 0) || !(noise.read_sigma >= 0) ||
      !std::isfinite(noise.photon_sigma_at_1) || !std::isfinite(noise.read_sigma)) {
    return InvalidArgumentError("noise model sigmas must be finite and >= 0");
  }
  std::unique_ptr<ImageResampler> r(new ImageResampler());
  r->capture_ = &capture;
  r->atlas_ = &atlas;
  r->scene_ = scene;
  r->noise_ = noise;
  r->min_cos_ = float(min_cos);
  r->threads_ = threads;
  if (scene != nullptr) {
    for (size_t i = 0; i < capture.cameras.size(); ++i) {
      const Camera& cam = capture.cameras[i];
      if (cam.model == CameraModel::kOrthographic && !(cam.pixel_size_m > 0)) {
        return FailedPreconditionError(file, ": cameras[", i, "].pixel_size_m: an orthographic "
                                       "camera needs it to project a mesh");
      }
    }
    const TriangleMesh& mesh = scene->mesh();
    r->triangle_normals_.resize(mesh.TriangleCount());
    for (size_t t = 0; t < mesh.TriangleCount(); ++t) {
      r->triangle_normals_[t] = mesh.GeometricNormal(t);
    }
    r->texel_sides_m_ = TexelSidesM(mesh, atlas);
  } else {
    for (size_t i = 0; i < capture.images.size(); ++i) {
      const CaptureImage& image = capture.images[i];
      if (capture.lights[image.light].type != LightType::kDirectional) {
        return FailedPreconditionError(
            file, ": lights[", image.light, "].type: a normal-map capture needs directional "
            "lights (its texels have no positions to measure a point light's distance from)");
      }
      if (image.turntable_deg != 0) {
        return FailedPreconditionError(file, ": images[", i, "].turntable_deg: a normal-map "
                                       "capture is seen from one fixed pose (got ",
                                       image.turntable_deg, ")");
      }
    }
  }
  return r;
}

Status ImageResampler::SetHeightField(const HeightField* field) {
  if (field == nullptr) {
    height_field_ = nullptr;
    return OkStatus();
  }
  if (scene_ != nullptr) {
    return FailedPreconditionError("SetHeightField: a mesh capture's cast shadows come from its "
                                   "rays, not from a height field");
  }
  if (field->width != atlas_->width || field->height != atlas_->height ||
      field->heights_px.size() != size_t(field->width) * size_t(field->height)) {
    return InvalidArgumentError("SetHeightField: the height field is ", field->width, "x",
                                field->height, " but the normal map is ", atlas_->width, "x",
                                atlas_->height);
  }
  height_field_ = field;
  return OkStatus();
}

Status CheckPhotograph(const Capture& capture, uint32_t image_index, const Image& pixels,
                       const Image* variance) {
  if (image_index >= capture.images.size()) {
    return InvalidArgumentError("image index ", image_index, " out of range");
  }
  const CaptureImage& image = capture.images[image_index];
  const Camera& camera = capture.cameras[image.camera];
  if (pixels.width != camera.width || pixels.height != camera.height || pixels.channels != 3) {
    return InvalidArgumentError(capture.json_path.string(), ": images[", image_index, "].file: ",
                                image.file, " is ", pixels.width, "x", pixels.height, "x",
                                pixels.channels, ", expected ", camera.width, "x", camera.height,
                                " RGB");
  }
  if (variance != nullptr) return CheckVarianceImage(capture, image_index, *variance);
  return OkStatus();
}

Status ImageResampler::Process(uint32_t image_index, const Image& pixels, ImageOutput* out,
                              const Image* variance) const {
  const Capture& capture = *capture_;
  const TexelAtlas& atlas = *atlas_;
  REFLCAP_RETURN_IF_ERROR(CheckPhotograph(capture, image_index, pixels, variance));
  const CaptureImage& image = capture.images[image_index];
  const Camera& camera = capture.cameras[image.camera];
  const std::string field = StrCat(capture.json_path.string(), ": images[", image_index, "].file");
  if (scene_ == nullptr && image.camera != capture.normal_map->camera) {
    return InvalidArgumentError(field, ": seen by camera \"", camera.id,
                                "\", not by the normal map's camera");
  }

  Frame f;
  f.camera = &camera;
  const Rigid3 world_from_object = capture.WorldFromObject(image);
  const Rigid3 object_from_world = world_from_object.Inverse();
  f.cam_from_object = camera.cam_from_world * world_from_object;
  f.object_from_cam = f.cam_from_object.Inverse();
  f.pinhole = camera.model == CameraModel::kPinhole;
  f.cam_centre = f.object_from_cam.translation.cast<float>();
  f.toward_cam = (-f.object_from_cam.rotation.col(2)).normalized().cast<float>();
  const Light& light = capture.lights[image.light];
  f.point_light = light.type == LightType::kPoint;
  f.light_position = (object_from_world * light.position).cast<float>();
  f.light_direction = (object_from_world.rotation * light.direction).normalized().cast<float>();
  f.intensity = light.intensity.cast<float>();
  f.exposure = float(image.exposure_s);
  f.saturation = float(image.saturation);
  f.point_pixels = pixel_filter_.value_or(camera.pixel_filter) == PixelFilter::kPoint;
  f.footprint_scale = f.pinhole ? 1.0 / std::min(std::abs(camera.K(0, 0)), std::abs(camera.K(1, 1)))
                                : camera.pixel_size_m;
  // A normal-map capture has no turntable (Create checked), so the object frame is the world's.
  if (height_field_ != nullptr) f.march = MakeHeightFieldMarch(*height_field_, light.direction);

  const size_t texels = atlas.TexelCount();
  out->outcome.assign(texels, uint8_t(Outcome::kKept));
  out->kept.clear();
  out->primary_rays = out->tap_shadow_rays = out->visibility_rays = out->shadow_rays = 0;

  if (scene_ != nullptr) {
    const size_t pixel_count = size_t(camera.width) * camera.height;
    f.map_state.reset(new std::atomic<uint8_t>[pixel_count]());
    f.map_depth.reset(new std::atomic<float>[pixel_count]());
    if (sample_point_ == SamplePoint::kPixel) {
      f.map_normal.reset(new std::atomic<float>[3 * pixel_count]());
      f.map_texel.reset(new std::atomic<int32_t>[pixel_count]());
    }
  }

  // ---- Texels -------------------------------------------------------------------------------
  const int64_t blocks = (int64_t(texels) + kBlockTexels - 1) / kBlockTexels;
  std::vector<std::vector<TexelSample>> kept(size_t(std::max<int64_t>(blocks, 0)));
  std::atomic<uint64_t> visibility{0}, shadow{0}, primary{0}, tap_shadow{0};
  ParallelFor(
      0, blocks, 1,
      [&](int64_t b0, int64_t b1, int) {
        for (int64_t b = b0; b < b1; ++b) {
          const int64_t begin = b * kBlockTexels;
          const int64_t end = std::min<int64_t>(int64_t(texels), begin + kBlockTexels);
          if (scene_ != nullptr) {
            uint64_t rays[4] = {0, 0, 0, 0};
            ProcessMeshBlock(f, pixels, variance, image_index, begin, end, out, &kept[b], rays);
            visibility += rays[0];
            shadow += rays[1];
            primary += rays[2];
            tap_shadow += rays[3];
          } else {
            ProcessNormalMapBlock(f, pixels, variance, image_index, begin, end, out, &kept[b]);
          }
        }
      },
      threads_);
  out->visibility_rays = visibility;
  out->shadow_rays = shadow;
  out->primary_rays = primary;
  out->tap_shadow_rays = tap_shadow;
  size_t total = 0;
  for (const auto& k : kept) total += k.size();
  out->kept.reserve(total);
  for (const auto& k : kept) out->kept.insert(out->kept.end(), k.begin(), k.end());
  return OkStatus();
}

namespace {

// Reads the taps of a texel and, when they are usable, turns them into a BRDF sample.
// wi, wo: unit, object frame; cos_i = n_s·wi; irradiance_per_cos = I / d² (or I).
// variance: the photograph's variance image, or nullptr for the noise model.
Outcome MakeSample(const Image& pixels, const Image* variance, const Taps& taps, int tap_count,
                   const NoiseModel& noise, float saturation, float exposure,
                   const Vec3f& irradiance_per_cos, float cos_i, const Vec3f& wi_local,
                   const Vec3f& wo_local, uint32_t image_index, BrdfSample* sample) {
  for (int k = 0; k < tap_count; ++k) {
    if (taps.w[k] == 0) continue;
    const float* p = pixels.pixel(taps.x[k], taps.y[k]);
    if (!std::isfinite(p[0]) || !std::isfinite(p[1]) || !std::isfinite(p[2])) return Outcome::kInvalid;
  }
  Vec3f value = Vec3f::Zero();
  for (int k = 0; k < tap_count; ++k) {
    if (taps.w[k] == 0) continue;
    const float* p = pixels.pixel(taps.x[k], taps.y[k]);
    if (saturation > 0 && (p[0] >= saturation || p[1] >= saturation || p[2] >= saturation)) {
      return Outcome::kClipped;
    }
    value += taps.w[k] * Vec3f(p[0], p[1], p[2]);
  }
  const float max_channel = value.maxCoeff();
  Vec3f measured = Vec3f::Zero();  // Σ w_k² var_k when the photograph has a variance image
  if (variance == nullptr) {
    if (value.minCoeff() < float(noise.InvalidFloor())) return Outcome::kInvalid;
    if (max_channel <= float(noise.DarkFloor())) return Outcome::kDark;
  } else {
    measured = MeasuredVariance(*variance, taps.x, taps.y, taps.w, tap_count);
    if (MeasuredInvalid(value, measured)) return Outcome::kInvalid;
    if (MeasuredDark(value, measured)) return Outcome::kDark;
  }
  for (int c = 0; c < 3; ++c) {
    sample->wi[c] = wi_local[c];
    sample->wo[c] = wo_local[c];
    const double scale = double(exposure) * double(irradiance_per_cos[c]) * double(cos_i);
    // A light with no output in a channel (or an unusable exposure) tells nothing about it.
    if (!(scale > 0) || !std::isfinite(scale)) {
      sample->value[c] = 0;
      sample->weight[c] = 0;
      continue;
    }
    const double pixel_variance = variance == nullptr
                                      ? noise.PixelVariance(value[c], max_channel)
                                      : MeasuredPixelVariance(measured[c], max_channel);
    const double sample_variance = pixel_variance / (scale * scale);
    sample->value[c] = float(value[c] / scale);
    // sample_variance > 0: a sample that is not dark has max_channel > 0 (noise model:
    // > DarkFloor >= 0; variance image: some channel > 3 σ >= 0), so the relative floor is > 0.
    const double weight = 1.0 / sample_variance;
    sample->weight[c] = std::isfinite(weight) && float(weight) < std::numeric_limits<float>::max()
                            ? float(weight)
                            : std::numeric_limits<float>::max();
    if (!std::isfinite(sample->value[c])) return Outcome::kInvalid;
  }
  sample->image = image_index;
  return Outcome::kKept;
}

// wi and wo in the texel's tangent frame, built as the reference renderer builds it.
void ToTangentFrame(const Vec3f& tangent, const Vec3f& n_s, const Vec3f& wi, const Vec3f& wo,
                    Vec3f* wi_local, Vec3f* wo_local) {
  Vec3f t = tangent - n_s * n_s.dot(tangent);
  if (t.squaredNorm() < 1e-12f) t = n_s.unitOrthogonal();  // tangent ∥ normal: any will do
  t.normalize();
  const Vec3f b = n_s.cross(t);
  *wi_local = Vec3f(t.dot(wi), b.dot(wi), n_s.dot(wi));
  *wo_local = Vec3f(t.dot(wo), b.dot(wo), n_s.dot(wo));
}

}  // namespace

void ImageResampler::ProcessMeshBlock(const Frame& f, const Image& pixels, const Image* variance,
                                      uint32_t image_index, int64_t begin, int64_t end,
                                      ImageOutput* out, std::vector<TexelSample>* kept,
                                      uint64_t* rays) const {
  const TexelAtlas& atlas = *atlas_;
  const Camera& camera = *f.camera;
  const float offset = scene_->SurfaceOffset();
  const float min_cos = min_cos_;
  struct Candidate {
    uint32_t texel;
    Vec3f v;          // unit, towards the camera
    float cos_v;
    Vec2d pixel;
    double depth;     // camera-frame z
    Vec3f wi;         // unit, towards the light
    float cos_i;
    float inv_d2;     // 1 / d² (point light) or 1
  };
  std::vector<Candidate> cand;
  cand.reserve(size_t(end - begin));
  std::vector<Ray> ray_list;
  std::vector<uint8_t> occluded;
  auto set = [&](uint32_t t, Outcome o) { out->outcome[t] = uint8_t(o); };

  // 1. View grazing and projection.
  for (int64_t ti = begin; ti < end; ++ti) {
    const uint32_t t = uint32_t(ti);
    const Vec3f& p = atlas.position[t];
    const Vec3f& n_s = atlas.shading_normal[t];
    const Vec3f& n_g = atlas.geometric_normal[t];
    Vec3f v = f.pinhole ? Vec3f(f.cam_centre - p).normalized() : f.toward_cam;
    const float cos_v = n_s.dot(v);
    if (!(cos_v > min_cos) || !(n_g.dot(v) > 0)) {
      set(t, Outcome::kGrazingView);
      continue;
    }
    const Vec3d p_cam = f.cam_from_object * p.cast<double>();
    Vec2d px;
    if (!camera.Project(p_cam, &px) || !(std::abs(px.x()) < kMaxPixelCoordinate) ||
        !(std::abs(px.y()) < kMaxPixelCoordinate)) {
      set(t, Outcome::kEdgeOutside);
      continue;
    }
    const Taps taps = BilinearTaps(px);
    bool inside = true;
    for (int k = 0; k < 4; ++k) {
      if (taps.w[k] == 0) continue;
      inside &= taps.x[k] >= 0 && taps.x[k] < camera.width && taps.y[k] >= 0 &&
                taps.y[k] < camera.height;
    }
    if (!inside) {
      set(t, Outcome::kEdgeOutside);
      continue;
    }
    cand.push_back({t, v, cos_v, px, p_cam.z(), Vec3f::Zero(), 0, 1});
  }

  // 2. Visibility: texel -> camera centre (or along the view axis).
  ray_list.clear();
  for (const Candidate& c : cand) {
    const Vec3f origin = atlas.position[c.texel] + offset * atlas.geometric_normal[c.texel];
    if (f.pinhole) {
      const Vec3f d = f.cam_centre - origin;
      const float dist = d.norm();
      ray_list.push_back({origin, d / dist, dist});
    } else {
      // The camera plane z = 0 lies at depth z in front of the texel.
      ray_list.push_back({origin, f.toward_cam, float(std::max(c.depth, 0.0))});
    }
  }
  OccludedPackets(*scene_, ray_list, &occluded);
  rays[0] += ray_list.size();
  size_t kept_count = 0;
  for (size_t i = 0; i < cand.size(); ++i) {
    Candidate& c = cand[i];
    if (occluded[i]) {
      set(c.texel, Outcome::kOccluded);
      continue;
    }
    // 3. Light grazing.
    const Vec3f& p = atlas.position[c.texel];
    float dist;
    f.ToLight(p, &c.wi, &dist);
    c.cos_i = atlas.shading_normal[c.texel].dot(c.wi);
    if (!(c.cos_i > min_cos) || !(atlas.geometric_normal[c.texel].dot(c.wi) > 0)) {
      set(c.texel, Outcome::kGrazingLight);
      continue;
    }
    c.inv_d2 = f.point_light ? 1.0f / (dist * dist) : 1.0f;
    cand[kept_count++] = c;
  }
  cand.resize(kept_count);

  // 4. Shadow: texel -> light.
  ray_list.clear();
  for (const Candidate& c : cand) {
    const Vec3f origin = atlas.position[c.texel] + offset * atlas.geometric_normal[c.texel];
    if (f.point_light) {
      const Vec3f d = f.light_position - origin;
      const float dist = d.norm();
      ray_list.push_back({origin, d / dist, dist});
    } else {
      ray_list.push_back({origin, f.light_direction, kInfinity});
    }
  }
  OccludedPackets(*scene_, ray_list, &occluded);
  rays[1] += ray_list.size();

  // 5. The pixel map entries of the survivors' taps that no block has cast yet.
  std::vector<uint32_t> needed;
  std::vector<Taps> cand_taps(cand.size());
  for (size_t i = 0; i < cand.size(); ++i) {
    if (occluded[i]) continue;
    cand_taps[i] = BilinearTaps(cand[i].pixel);
    for (int k = 0; k < 4; ++k) {
      if (cand_taps[i].w[k] == 0) continue;
      const uint32_t m = uint32_t(cand_taps[i].y[k]) * uint32_t(camera.width) + uint32_t(cand_taps[i].x[k]);
      if (f.map_state[m].load(std::memory_order_acquire) == 0) needed.push_back(m);
    }
  }
  std::sort(needed.begin(), needed.end());
  needed.erase(std::unique(needed.begin(), needed.end()), needed.end());
  CastPixels(f, needed, rays);

  // 6. Footprint (edge) and pixel tests.
  for (size_t i = 0; i < cand.size(); ++i) {
    const Candidate& c = cand[i];
    if (occluded[i]) {
      set(c.texel, Outcome::kShadowed);
      continue;
    }
    const Vec3f& p = atlas.position[c.texel];
    const Taps& taps = cand_taps[i];
    const double footprint = f.pinhole ? c.depth * f.footprint_scale : f.footprint_scale;
    const double cos_v = c.cos_v;
    const double tan_v = std::sqrt(std::max(0.0, 1 - cos_v * cos_v)) / cos_v;
    const float tolerance = float(kEdgeDepthSlack * footprint * (1 + std::sqrt(2.0) * tan_v));
    Outcome outcome = Outcome::kKept;
    // SamplePoint::kPixel: of the taps whose hit lies in the texel, the one nearest its centre;
    // when there is none, the nearest of all (ties: the first).
    int nearest = -1;
    bool nearest_inside = false;
    float nearest_d2 = kInfinity;
    Vec3f nearest_hit = Vec3f::Zero(), nearest_dir = Vec3f::Zero();
    for (int k = 0; k < 4 && outcome == Outcome::kKept; ++k) {
      if (taps.w[k] == 0) continue;
      const size_t m = size_t(taps.y[k]) * camera.width + taps.x[k];
      const uint8_t state = f.map_state[m].load(std::memory_order_acquire);
      REFLCAP_DCHECK(state & kMapDone);
      if (!(state & kMapHit)) {
        outcome = Outcome::kEdgeSurface;  // the tap sees the background: silhouette
        break;
      }
      // Depth of the tap's hit minus the texel's depth along the tap's ray.
      Vec3f origin, dir;
      f.PixelRay(taps.x[k], taps.y[k], &origin, &dir);
      const float depth = f.map_depth[m].load(std::memory_order_relaxed);
      if (!(std::abs(depth + (origin - p).dot(dir)) <= tolerance)) {
        outcome = Outcome::kEdgeSurface;
        break;
      }
      if (!(state & kMapLit)) outcome = Outcome::kEdgeShadow;
      if (f.map_texel == nullptr) continue;
      const Vec3f hit = origin + depth * dir;
      const float d2 = (hit - p).squaredNorm();
      const bool inside = f.map_texel[m].load(std::memory_order_relaxed) == int32_t(c.texel);
      if ((inside && !nearest_inside) || (inside == nearest_inside && d2 < nearest_d2)) {
        nearest = k;
        nearest_inside = inside;
        nearest_d2 = d2;
        nearest_hit = hit;
        nearest_dir = dir;
      }
    }
    // A point camera's texel that no tap's hit lies in, which this view resolves: each of those
    // pixels measured another texel (kEdgeTexel); an unresolved one keeps the nearest.
    if (outcome == Outcome::kKept && sample_point_ == SamplePoint::kPixel && !nearest_inside &&
        f.point_pixels &&
        texel_sides_m_[c.texel] * std::sqrt(c.cos_v) >= kMinResolvedTexelPixels * float(footprint)) {
      outcome = Outcome::kEdgeTexel;
    }
    if (outcome != Outcome::kKept) {
      set(c.texel, outcome);
      continue;
    }
    TexelSample s;
    s.texel = c.texel;
    Vec3f wi_local, wo_local;
    if (sample_point_ == SamplePoint::kTexel) {
      ToTangentFrame(atlas.tangent[c.texel], atlas.shading_normal[c.texel], c.wi, c.v, &wi_local,
                     &wo_local);
      outcome = MakeSample(pixels, variance, taps, 4, noise_, f.saturation, f.exposure,
                           f.intensity * c.inv_d2, c.cos_i, wi_local, wo_local, image_index,
                           &s.sample);
    } else {
      REFLCAP_DCHECK(nearest >= 0);
      const size_t m = size_t(taps.y[nearest]) * camera.width + taps.x[nearest];
      const Vec3f n_hit(f.map_normal[3 * m].load(std::memory_order_relaxed),
                        f.map_normal[3 * m + 1].load(std::memory_order_relaxed),
                        f.map_normal[3 * m + 2].load(std::memory_order_relaxed));
      Vec3f wi;
      float dist;
      f.ToLight(nearest_hit, &wi, &dist);
      const Vec3f wo = -nearest_dir;
      const float cos_i = n_hit.dot(wi);
      // The hit is within a pixel of the texel centre, which passed both grazing tests; its own
      // normal may still tip past min_cos: a rim or the terminator inside the footprint.
      if (!(n_hit.dot(wo) > min_cos)) {
        set(c.texel, Outcome::kEdgeSurface);
        continue;
      }
      if (!(cos_i > min_cos)) {
        set(c.texel, Outcome::kEdgeShadow);
        continue;
      }
      ToTangentFrame(atlas.tangent[c.texel], n_hit, wi, wo, &wi_local, &wo_local);
      Taps one = taps;
      for (int k = 0; k < 4; ++k) one.w[k] = k == nearest ? 1.0f : 0.0f;
      outcome = MakeSample(pixels, variance, one, 4, noise_, f.saturation, f.exposure,
                           f.intensity * (f.point_light ? 1.0f / (dist * dist) : 1.0f), cos_i,
                           wi_local, wo_local, image_index, &s.sample);
    }
    set(c.texel, outcome);
    if (outcome == Outcome::kKept) kept->push_back(s);
  }
}

void ImageResampler::CastPixels(const Frame& f, const std::vector<uint32_t>& pixels,
                                uint64_t* rays) const {
  const TriangleMesh& mesh = scene_->mesh();
  const float offset = scene_->SurfaceOffset();
  const int width = f.camera->width;
  std::array<bool, 16> valid, lit_valid, occluded;
  std::array<Vec3f, 16> origin, dir, lorigin, ldir;
  std::array<float, 16> tnear, tfar, ltfar;
  std::array<RayHit, 16> hits;
  tnear.fill(0);
  tfar.fill(kInfinity);
  for (size_t base = 0; base < pixels.size(); base += 16) {
    const size_t n = std::min<size_t>(16, pixels.size() - base);
    for (size_t i = 0; i < 16; ++i) {
      valid[i] = i < n;
      if (!valid[i]) {
        origin[i] = dir[i] = Vec3f::UnitZ();
        continue;
      }
      f.PixelRay(int(pixels[base + i] % width), int(pixels[base + i] / width), &origin[i], &dir[i]);
    }
    scene_->Intersect16(valid, origin, dir, tnear, tfar, &hits);
    rays[2] += n;
    std::array<uint8_t, 16> state{};
    std::array<Vec3f, 16> hit_normal;
    std::array<int32_t, 16> hit_texel;
    for (size_t i = 0; i < 16; ++i) {
      hit_normal[i] = Vec3f::Zero();
      hit_texel[i] = -1;
      lit_valid[i] = false;
      lorigin[i] = ldir[i] = Vec3f::UnitZ();
      ltfar[i] = 0;
      if (!valid[i]) continue;
      state[i] = kMapDone;
      if (!hits[i].hit) continue;
      state[i] |= kMapHit;
      // Lit as the renderer decides it: both normals face the light and the shadow ray is free.
      const Vec3f p = origin[i] + hits[i].t * dir[i];
      const uint32_t tri = hits[i].triangle;
      const auto& cn = mesh.corner_normals[tri];
      const float b1 = hits[i].b1, b2 = hits[i].b2;
      const Vec3f n_s = ((1 - b1 - b2) * cn[0] + b1 * cn[1] + b2 * cn[2]).normalized();
      hit_normal[i] = n_s;
      if (f.map_texel != nullptr) {
        const auto& cuv = mesh.corner_uvs[tri];
        hit_texel[i] = atlas_->TexelUnderUv((1 - b1 - b2) * cuv[0] + b1 * cuv[1] + b2 * cuv[2]);
      }
      const Vec3f& n_g = triangle_normals_[tri];
      Vec3f wi;
      float dist;
      f.ToLight(p, &wi, &dist);
      if (!(n_s.dot(wi) > 0) || !(n_g.dot(wi) > 0)) continue;
      lit_valid[i] = true;
      lorigin[i] = p + offset * n_g;
      if (f.point_light) {
        const Vec3f to_light = f.light_position - lorigin[i];
        ltfar[i] = to_light.norm();
        ldir[i] = to_light / ltfar[i];
      } else {
        ldir[i] = wi;
        ltfar[i] = kInfinity;
      }
      ++rays[3];
    }
    scene_->Occluded16(lit_valid, lorigin, ldir, tnear, ltfar, &occluded);
    for (size_t i = 0; i < n; ++i) {
      if (lit_valid[i] && !occluded[i]) state[i] |= kMapLit;
      const uint32_t m = pixels[base + i];
      f.map_depth[m].store(hits[i].hit ? hits[i].t : 0.0f, std::memory_order_relaxed);
      if (f.map_normal != nullptr) {
        for (int k = 0; k < 3; ++k) {
          f.map_normal[3 * m + k].store(hit_normal[i][k], std::memory_order_relaxed);
        }
        f.map_texel[m].store(hit_texel[i], std::memory_order_relaxed);
      }
      f.map_state[m].store(state[i], std::memory_order_release);
    }
  }
}

void ImageResampler::ProcessNormalMapBlock(const Frame& f, const Image& pixels,
                                           const Image* variance, uint32_t image_index,
                                           int64_t begin, int64_t end, ImageOutput* out,
                                           std::vector<TexelSample>* kept) const {
  const TexelAtlas& atlas = *atlas_;
  for (int64_t ti = begin; ti < end; ++ti) {
    const uint32_t t = uint32_t(ti);
    int x, y;
    atlas.PixelOf(t, &x, &y);
    const Vec3f& n = atlas.shading_normal[t];
    Vec3f v = f.toward_cam;
    if (f.pinhole) {
      Vec3d o, d;
      f.camera->PixelRay({double(x), double(y)}, &o, &d);
      v = -(f.object_from_cam.rotation * d).normalized().cast<float>();
    }
    const float cos_v = n.dot(v);
    if (!(cos_v > min_cos_)) {
      out->outcome[t] = uint8_t(Outcome::kGrazingView);
      continue;
    }
    const Vec3f wi = f.light_direction;  // directional (Create checked)
    const float cos_i = n.dot(wi);
    if (!(cos_i > min_cos_)) {
      out->outcome[t] = uint8_t(Outcome::kGrazingLight);
      continue;
    }
    if (height_field_ != nullptr &&
        HeightFieldShadowed(height_field_->heights_px.data(), f.march, x, y)) {
      out->outcome[t] = uint8_t(Outcome::kShadowed);
      continue;
    }
    Vec3f wi_local, wo_local;
    ToTangentFrame(atlas.tangent[t], n, wi, v, &wi_local, &wo_local);
    Taps taps{{x, x, x, x}, {y, y, y, y}, {1, 0, 0, 0}};
    TexelSample s;
    s.texel = t;
    const Outcome outcome =
        MakeSample(pixels, variance, taps, 1, noise_, f.saturation, f.exposure, f.intensity, cos_i,
                   wi_local, wo_local, image_index, &s.sample);
    out->outcome[t] = uint8_t(outcome);
    if (outcome == Outcome::kKept) kept->push_back(s);
  }
}

}  // namespace reflcap::resample
