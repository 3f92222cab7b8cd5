// GLSL twin (float) of the pinhole model of engine/camera/camera.{h,cc}: Distort, Undistort and
// PixelRay with the C++ names, the OpenCV model (k1, k2, p1, p2, k3) and the same fixed-point
// inversion. The C++ runs in double; here float, so Undistort stops at a float-sized step
// (kUndistortStep2) instead of 1e-24 — its result differs from the double one by ~1e-7 (a hit
// point moves by 1e-7 of its distance, far below anything the renderer resolves).
// dist0 = (k1, k2, p1, p2), k3 separate; intrinsics = (fx, fy, cx, cy), skew s.
#ifndef REFLCAP_SHADERS_RENDER_CAMERA_GLSL_
#define REFLCAP_SHADERS_RENDER_CAMERA_GLSL_

// engine/camera/camera.h kUndistortIterations.
const int kUndistortIterations = 30;
// Squared step below which the float iteration has converged (~(1e-7)^2 of a unit coordinate).
const float kUndistortStep2 = 1e-14;

vec2 Distort(vec2 xy, vec4 dist0, float k3) {
  float x = xy.x, y = xy.y;
  float r2 = x * x + y * y;
  float radial = 1.0 + r2 * (dist0.x + r2 * (dist0.y + r2 * k3));
  float p1 = dist0.z, p2 = dist0.w;
  return vec2(x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
              y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y);
}

// Inverse of Distort by the fixed point xy = xy_d - (Distort(xy) - xy).
vec2 Undistort(vec2 xy_distorted, vec4 dist0, float k3) {
  vec2 xy = xy_distorted;
  for (int i = 0; i < kUndistortIterations; ++i) {
    vec2 next = xy - (Distort(xy, dist0, k3) - xy_distorted);
    vec2 step = next - xy;
    xy = next;
    if (dot(step, step) < kUndistortStep2) break;
  }
  return xy;
}

// Unit direction (camera frame) of the pinhole ray through pixel `pixel` (pixel centres at
// integer coordinates), undistorting when `distorted`.
vec3 PixelRay(vec2 pixel, vec4 intrinsics, float skew, bool distorted, vec4 dist0, float k3) {
  float yd = (pixel.y - intrinsics.w) / intrinsics.y;
  float xd = (pixel.x - intrinsics.z - skew * yd) / intrinsics.x;
  vec2 xy = distorted ? Undistort(vec2(xd, yd), dist0, k3) : vec2(xd, yd);
  return normalize(vec3(xy, 1.0));
}

#endif  // REFLCAP_SHADERS_RENDER_CAMERA_GLSL_
