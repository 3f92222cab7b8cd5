#pragma once
// RayScene: a TriangleMesh in an Embree 3 BVH for closest-hit and occlusion queries, single rays
// and 16-wide packets. Embree stays out of this header (PIMPL). Embree errors reported through its
// device callback become Status errors of Create(); later ones are logged.
//
// Self-intersection: callers offset ray origins along the geometric normal by
// SurfaceOffset(p) (relative to the scene's size, see kRelativeRayOffset) and set tnear = 0.
#include <array>
#include <cstdint>
#include <memory>

#include "engine/core/status.h"
#include "engine/math/types.h"
#include "engine/mesh/mesh.h"

namespace reflcap {

struct RayHit {
  bool hit = false;
  float t = 0;            // distance along the (unit) direction
  uint32_t triangle = 0;  // index into TriangleMesh::triangles
  float b1 = 0, b2 = 0;   // barycentrics of corners 1 and 2 (corner 0 = 1 - b1 - b2)
};

class RayScene {
 public:
  // Builds the BVH (high quality build, robust intersection). The mesh is copied.
  // InvalidArgument: no positions or no triangles, a non-finite position, an index out of range,
  // or Embree rejecting an argument; Unavailable: Embree does not support this CPU; Internal: any
  // other Embree error (out of memory, unknown). Embree's message is part of the status.
  static StatusOr<std::unique_ptr<RayScene>> Create(const TriangleMesh& mesh);
  ~RayScene();

  // Closest hit of origin + t*dir, t in [tnear, tfar]; dir need not be unit (t is then in units
  // of |dir|).
  RayHit Intersect(const Vec3f& origin, const Vec3f& dir, float tnear, float tfar) const;
  // True when anything lies on origin + t*dir for t in [tnear, tfar].
  bool Occluded(const Vec3f& origin, const Vec3f& dir, float tnear, float tfar) const;

  // 16-wide packets (rtcIntersect16 / rtcOccluded16), same results as the single-ray calls; lanes
  // with valid[i] == false are ignored (their outputs untouched).
  void Intersect16(const std::array<bool, 16>& valid, const std::array<Vec3f, 16>& origin,
                   const std::array<Vec3f, 16>& dir, const std::array<float, 16>& tnear,
                   const std::array<float, 16>& tfar, std::array<RayHit, 16>* hits) const;
  void Occluded16(const std::array<bool, 16>& valid, const std::array<Vec3f, 16>& origin,
                  const std::array<Vec3f, 16>& dir, const std::array<float, 16>& tnear,
                  const std::array<float, 16>& tfar, std::array<bool, 16>* occluded) const;

  // Origin offset that avoids self-intersection for a point of this scene: the bounding-box
  // diagonal times kRelativeRayOffset.
  float SurfaceOffset() const { return surface_offset_; }
  const TriangleMesh& mesh() const { return mesh_; }

  // 1e-5 of the object's size: well above float rounding of positions (~1e-7 relative) and Embree's
  // own error bound, well below any geometric feature reflcap resolves (a texel is >= 1e-3 of it).
  static constexpr float kRelativeRayOffset = 1e-5f;

 private:
  RayScene() = default;
  struct Impl;
  std::unique_ptr<Impl> impl_;
  TriangleMesh mesh_;
  float surface_offset_ = 0;
};

}  // namespace reflcap
