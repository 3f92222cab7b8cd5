// RayScene over Embree 3: one device and one scene per RayScene, a single triangle geometry with
// its own copies of the positions and indices (rtcSetNewGeometryBuffer allocates them with the
// padding Embree's SIMD loads need past the last vertex). The scene is built with
// RTC_BUILD_QUALITY_MEDIUM: HIGH (spatial splits) took 0.22 s for the million preset's 307,200
// triangles on 2 threads against MEDIUM's 0.065 s, and bought no query speed (resample of that
// capture: 24.3 s of rays with HIGH, 24.2 s with MEDIUM; suzanne 6.48 / 6.52 s) and no output
// change (both captures' sample stores and maps byte-identical) -- a cost every resample shard
// pays. It is built without RTC_SCENE_FLAG_ROBUST:
// robust traversal cost 1.34x in occlusion rays (16-wide packets, 2 threads: 12.2 M rays/s with
// it, 16.4 M without) and changed no visibility or shadow decision on the suzanne and synth
// captures (identical occluded and shadowed counts; 0.007 % of the footprint-edge rejections,
// which test primary hits at silhouettes, moved). Neither mode is exactly watertight: a ray
// exactly along a shared edge can slip through in both (Embree issue #387).
// After Embree's tutorials/minimal/minimal.cpp.
#include "engine/mesh/ray_scene.h"

#include <cmath>
#include <limits>
#include <mutex>
#include <string>
#include <utility>

#include <embree3/rtcore.h>

#include "engine/core/log.h"

namespace reflcap {
namespace {

const char* EmbreeErrorName(RTCError code) {
  switch (code) {
    case RTC_ERROR_NONE:
      return "RTC_ERROR_NONE";
    case RTC_ERROR_UNKNOWN:
      return "RTC_ERROR_UNKNOWN";
    case RTC_ERROR_INVALID_ARGUMENT:
      return "RTC_ERROR_INVALID_ARGUMENT";
    case RTC_ERROR_INVALID_OPERATION:
      return "RTC_ERROR_INVALID_OPERATION";
    case RTC_ERROR_OUT_OF_MEMORY:
      return "RTC_ERROR_OUT_OF_MEMORY";
    case RTC_ERROR_UNSUPPORTED_CPU:
      return "RTC_ERROR_UNSUPPORTED_CPU";
    case RTC_ERROR_CANCELLED:
      return "RTC_ERROR_CANCELLED";
  }
  return "RTC_ERROR_?";
}

// Invalid arguments are the caller's; an unsupported CPU means Embree cannot run here; anything
// else (out of memory, unknown) is an unexpected library failure.
Status EmbreeStatus(RTCError code, const std::string& message) {
  const std::string text = StrCat("Embree: ", EmbreeErrorName(code), ": ", message);
  switch (code) {
    case RTC_ERROR_INVALID_ARGUMENT:
      return InvalidArgumentError(text);
    case RTC_ERROR_UNSUPPORTED_CPU:
      return UnavailableError(text);
    default:
      return InternalError(text);
  }
}

void InitRay(const Vec3f& origin, const Vec3f& dir, float tnear, float tfar, RTCRay* ray) {
  ray->org_x = origin.x();
  ray->org_y = origin.y();
  ray->org_z = origin.z();
  ray->dir_x = dir.x();
  ray->dir_y = dir.y();
  ray->dir_z = dir.z();
  ray->tnear = tnear;
  ray->tfar = tfar;
  ray->time = 0;
  ray->mask = std::numeric_limits<unsigned>::max();  // every geometry
  ray->id = 0;
  ray->flags = 0;
}

// Fills lane i of a 16-wide packet; the caller zero-initialises the packet, so inactive lanes
// hold defined values even though Embree does not read them.
void InitRay16(int i, const Vec3f& origin, const Vec3f& dir, float tnear, float tfar,
               RTCRay16* ray) {
  ray->org_x[i] = origin.x();
  ray->org_y[i] = origin.y();
  ray->org_z[i] = origin.z();
  ray->dir_x[i] = dir.x();
  ray->dir_y[i] = dir.y();
  ray->dir_z[i] = dir.z();
  ray->tnear[i] = tnear;
  ray->tfar[i] = tfar;
  ray->time[i] = 0;
  ray->mask[i] = std::numeric_limits<unsigned>::max();
  ray->id[i] = 0;
  ray->flags[i] = 0;
}

// Embree's packet calls take an int mask, -1 for an active lane and 0 for an inactive one,
// aligned like the packet.
struct alignas(64) ValidMask16 {
  int lanes[16];
};

ValidMask16 ToValidMask(const std::array<bool, 16>& valid) {
  ValidMask16 mask;
  for (int i = 0; i < 16; ++i) mask.lanes[i] = valid[i] ? -1 : 0;
  return mask;
}

}  // namespace

struct RayScene::Impl {
  RTCDevice device = nullptr;
  RTCScene scene = nullptr;

  // Embree calls ErrorCallback from any thread (its builder runs on TBB workers). Until Create()
  // finishes, the first error is kept for its Status; afterwards errors are logged.
  std::mutex error_mutex;
  bool creating = true;
  RTCError first_error = RTC_ERROR_NONE;
  std::string first_error_message;

  ~Impl() {
    if (scene != nullptr) rtcReleaseScene(scene);
    if (device != nullptr) rtcReleaseDevice(device);
  }

  static void ErrorCallback(void* user_ptr, RTCError code, const char* message) {
    Impl* impl = static_cast<Impl*>(user_ptr);
    const std::string text = message != nullptr ? message : "";
    std::lock_guard<std::mutex> lock(impl->error_mutex);
    if (impl->creating) {
      if (impl->first_error == RTC_ERROR_NONE) {
        impl->first_error = code;
        impl->first_error_message = text;
      }
      return;
    }
    REFLCAP_LOG(kError) << "Embree: " << EmbreeErrorName(code) << ": " << text;
  }

  // The first error recorded during creation, as a Status (OK when there was none). `step` names
  // the Embree call that failed, in case it reported no error through the callback.
  Status CreationError(const char* step) {
    std::lock_guard<std::mutex> lock(error_mutex);
    if (first_error != RTC_ERROR_NONE) {
      return EmbreeStatus(first_error, StrCat(first_error_message, " (during ", step, ")"));
    }
    return OkStatus();
  }
};

StatusOr<std::unique_ptr<RayScene>> RayScene::Create(const TriangleMesh& mesh) {
  if (mesh.positions.empty() || mesh.triangles.empty()) {
    return InvalidArgumentError("RayScene: empty mesh (", mesh.positions.size(), " positions, ",
                                mesh.triangles.size(), " triangles)");
  }
  // Embree counts vertices and primitives in unsigned int.
  constexpr size_t kMaxCount = std::numeric_limits<unsigned>::max();
  if (mesh.positions.size() > kMaxCount || mesh.triangles.size() > kMaxCount) {
    return InvalidArgumentError("RayScene: mesh too large for Embree (", mesh.positions.size(),
                                " positions, ", mesh.triangles.size(), " triangles)");
  }
  for (size_t i = 0; i < mesh.positions.size(); ++i) {
    if (!mesh.positions[i].allFinite()) {
      return InvalidArgumentError("RayScene: position ", i, " is not finite");
    }
  }
  for (size_t t = 0; t < mesh.triangles.size(); ++t) {
    for (uint32_t index : mesh.triangles[t]) {
      if (index >= mesh.positions.size()) {
        return InvalidArgumentError("RayScene: triangle ", t, " refers to position ", index,
                                    " of ", mesh.positions.size());
      }
    }
  }

  std::unique_ptr<RayScene> scene(new RayScene());
  scene->impl_ = std::make_unique<Impl>();
  Impl& impl = *scene->impl_;

#if defined(__SANITIZE_THREAD__)
  // Under ThreadSanitizer Embree builds on the calling thread only: its TBB workers' synchronisation
  // is invisible to TSan (both libraries are uninstrumented), which reports races inside them
  // (tests/sanitize/tsan.supp).
  impl.device = rtcNewDevice("threads=1");
#else
  impl.device = rtcNewDevice(nullptr);
#endif
  if (impl.device == nullptr) {
    // No device, so no callback yet: Embree keeps this error for rtcGetDeviceError(nullptr).
    return EmbreeStatus(rtcGetDeviceError(nullptr), "rtcNewDevice failed");
  }
  rtcSetDeviceErrorFunction(impl.device, &Impl::ErrorCallback, &impl);

  impl.scene = rtcNewScene(impl.device);
  if (impl.scene == nullptr) {
    REFLCAP_RETURN_IF_ERROR(impl.CreationError("rtcNewScene"));
    return InternalError("Embree: rtcNewScene returned no scene");
  }
  rtcSetSceneFlags(impl.scene, RTC_SCENE_FLAG_NONE);
  rtcSetSceneBuildQuality(impl.scene, RTC_BUILD_QUALITY_MEDIUM);

  RTCGeometry geometry = rtcNewGeometry(impl.device, RTC_GEOMETRY_TYPE_TRIANGLE);
  if (geometry == nullptr) {
    REFLCAP_RETURN_IF_ERROR(impl.CreationError("rtcNewGeometry"));
    return InternalError("Embree: rtcNewGeometry returned no geometry");
  }
  rtcSetGeometryBuildQuality(geometry, RTC_BUILD_QUALITY_MEDIUM);
  auto* vertices = static_cast<float*>(
      rtcSetNewGeometryBuffer(geometry, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                              3 * sizeof(float), mesh.positions.size()));
  auto* indices = static_cast<unsigned*>(
      rtcSetNewGeometryBuffer(geometry, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                              3 * sizeof(unsigned), mesh.triangles.size()));
  if (vertices == nullptr || indices == nullptr) {
    rtcReleaseGeometry(geometry);
    REFLCAP_RETURN_IF_ERROR(impl.CreationError("rtcSetNewGeometryBuffer"));
    return InternalError("Embree: rtcSetNewGeometryBuffer returned no buffer");
  }
  for (size_t i = 0; i < mesh.positions.size(); ++i) {
    vertices[3 * i + 0] = mesh.positions[i].x();
    vertices[3 * i + 1] = mesh.positions[i].y();
    vertices[3 * i + 2] = mesh.positions[i].z();
  }
  for (size_t t = 0; t < mesh.triangles.size(); ++t) {
    indices[3 * t + 0] = mesh.triangles[t][0];
    indices[3 * t + 1] = mesh.triangles[t][1];
    indices[3 * t + 2] = mesh.triangles[t][2];
  }
  rtcCommitGeometry(geometry);
  // Geometry 0: the only one, so geomID needs no mapping. The scene now holds a reference.
  rtcAttachGeometryByID(impl.scene, geometry, 0);
  rtcReleaseGeometry(geometry);
  rtcCommitScene(impl.scene);
  REFLCAP_RETURN_IF_ERROR(impl.CreationError("scene build"));
  {
    std::lock_guard<std::mutex> lock(impl.error_mutex);
    impl.creating = false;
  }

  scene->mesh_ = mesh;
  scene->surface_offset_ = kRelativeRayOffset * mesh.Bounds().diagonal().norm();
  return StatusOr<std::unique_ptr<RayScene>>(std::move(scene));
}

RayScene::~RayScene() = default;

RayHit RayScene::Intersect(const Vec3f& origin, const Vec3f& dir, float tnear, float tfar) const {
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  RTCRayHit ray_hit;
  InitRay(origin, dir, tnear, tfar, &ray_hit.ray);
  ray_hit.hit.geomID = RTC_INVALID_GEOMETRY_ID;
  ray_hit.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
  rtcIntersect1(impl_->scene, &context, &ray_hit);
  RayHit hit;
  if (ray_hit.hit.geomID == RTC_INVALID_GEOMETRY_ID) return hit;
  hit.hit = true;
  hit.t = ray_hit.ray.tfar;
  hit.triangle = ray_hit.hit.primID;
  hit.b1 = ray_hit.hit.u;
  hit.b2 = ray_hit.hit.v;
  return hit;
}

bool RayScene::Occluded(const Vec3f& origin, const Vec3f& dir, float tnear, float tfar) const {
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  RTCRay ray;
  InitRay(origin, dir, tnear, tfar, &ray);
  rtcOccluded1(impl_->scene, &context, &ray);
  // Embree marks an occluded ray by setting tfar to -inf.
  return ray.tfar < 0 && std::isinf(ray.tfar);
}

void RayScene::Intersect16(const std::array<bool, 16>& valid, const std::array<Vec3f, 16>& origin,
                           const std::array<Vec3f, 16>& dir, const std::array<float, 16>& tnear,
                           const std::array<float, 16>& tfar,
                           std::array<RayHit, 16>* hits) const {
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  const ValidMask16 mask = ToValidMask(valid);
  alignas(64) RTCRayHit16 ray_hit = {};
  for (int i = 0; i < 16; ++i) {
    InitRay16(i, origin[i], dir[i], tnear[i], tfar[i], &ray_hit.ray);
    ray_hit.hit.geomID[i] = RTC_INVALID_GEOMETRY_ID;
    ray_hit.hit.instID[0][i] = RTC_INVALID_GEOMETRY_ID;
  }
  rtcIntersect16(mask.lanes, impl_->scene, &context, &ray_hit);
  for (int i = 0; i < 16; ++i) {
    if (!valid[i]) continue;
    RayHit& hit = (*hits)[i];
    hit = RayHit();
    if (ray_hit.hit.geomID[i] == RTC_INVALID_GEOMETRY_ID) continue;
    hit.hit = true;
    hit.t = ray_hit.ray.tfar[i];
    hit.triangle = ray_hit.hit.primID[i];
    hit.b1 = ray_hit.hit.u[i];
    hit.b2 = ray_hit.hit.v[i];
  }
}

void RayScene::Occluded16(const std::array<bool, 16>& valid, const std::array<Vec3f, 16>& origin,
                          const std::array<Vec3f, 16>& dir, const std::array<float, 16>& tnear,
                          const std::array<float, 16>& tfar,
                          std::array<bool, 16>* occluded) const {
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  const ValidMask16 mask = ToValidMask(valid);
  alignas(64) RTCRay16 ray = {};
  for (int i = 0; i < 16; ++i) InitRay16(i, origin[i], dir[i], tnear[i], tfar[i], &ray);
  rtcOccluded16(mask.lanes, impl_->scene, &context, &ray);
  for (int i = 0; i < 16; ++i) {
    if (valid[i]) (*occluded)[i] = ray.tfar[i] < 0 && std::isinf(ray.tfar[i]);
  }
}

}  // namespace reflcap
