#pragma once
// View and projection matrices for Vulkan rasterisation (clip space as Vulkan defines it: NDC y
// down the image, depth in [0, 1]) and their float rows for the layouts shared with GLSL. Used
// by the Vulkan renderer (render/vulkan) and the Vulkan masks (acquire/resample), which
// rasterise the same cameras and the same light maps.
#include "engine/geometry/rigid3.h"
#include "engine/math/types.h"
#include "shaders/shared/interop.h"

namespace reflcap::gpu {

// (x, y, z, w) in float.
shared::vec4 V4(const Vec3d& v, double w);
// The four rows of m, in float (a GLSL mat4 given as rows).
void SetRows(const Mat4d& m, shared::vec4 rows[4]);
// The 4x4 of a rigid transform b_from_a.
Mat4d Homogeneous(const Rigid3& t);

// Pinhole projection (camera frame -> clip, depth [0, 1] from near to far) for a w x h image
// whose pixel centres sit at integer coordinates: u = fx x + s y + cx lands on framebuffer
// x = u + 0.5.
Mat4d PinholeClipFromCam(double fx, double fy, double s, double cx, double cy, int w, int h,
                         double near, double far);
// Orthographic projection for pixels of `pixel_m` metres and a w x h image centred on the axis
// (the camera's cx = (w - 1) / 2), depth range [near, far] along +z.
Mat4d OrthoClipFromCam(double pixel_m, int w, int h, double near, double far);

// Two unit vectors completing the unit `forward` to an orthonormal frame (right, up).
void Basis(const Vec3d& forward, Vec3d* right, Vec3d* up);
// The view matrix to (right, up, forward) coordinates of p - origin.
Mat4d ViewMatrix(const Vec3d& origin, const Vec3d& forward, const Vec3d& right, const Vec3d& up);

}  // namespace reflcap::gpu
