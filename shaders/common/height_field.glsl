// Cast shadow on the height field of a normal-map capture: GLSL twin of HeightFieldShadowed in
// engine/mesh/height_field.cc (the march, its bias and its bounds are explained in
// engine/mesh/height_field.h and shaders/shared/height_field.h). The same float operations in the
// same order; every product and sum is `precise` (no fused multiply-add, as the C++ build), so
// both sides decide every pixel alike.
//
// The including shader declares the field, row-major width x height floats (kHeightFieldOutside
// off the object), as `float height_field_px[]` in a readonly storage buffer, before including.
// One call runs at most march.steps <= kMaxHeightFieldMarchSteps loop iterations (the four
// bilinear taps are unrolled), well inside lavapipe's 65,535 per invocation.
#ifndef REFLCAP_SHADERS_COMMON_HEIGHT_FIELD_GLSL_
#define REFLCAP_SHADERS_COMMON_HEIGHT_FIELD_GLSL_

#include "shared/height_field.h"

// Adds tap (x, y) of bilinear weight w to the running weight and weighted height when it lies on
// the object.
void HeightFieldTap(int x, int y, int width, float w, inout float weight, inout float weighted) {
  float s = height_field_px[y * width + x];
  if (s > kHeightFieldInsideAbove) {
    precise float ws = w * s;
    precise float sum_w = weight + w;
    precise float sum_ws = weighted + ws;
    weight = sum_w;
    weighted = sum_ws;
  }
}

// True when the point on pixel (x, y) (on the object) is in cast shadow under march's light.
bool HeightFieldShadowed(HeightFieldMarch march, int x, int y) {
  int w = int(march.width), h = int(march.height);
  float h0 = height_field_px[y * w + x];
  float x0f = float(x), y0f = float(y);
  float last_x = float(w - 1), last_y = float(h - 1);
  uint steps = min(march.steps, kMaxHeightFieldMarchSteps);
  for (uint i = 1u; i <= steps; ++i) {
    float t = float(i);
    precise float rise = t * march.step.z;
    precise float ray = h0 + rise;
    if (ray > march.step.w) return false;  // above the highest point of the field
    precise float du = t * march.step.x;
    precise float dv = t * march.step.y;
    precise float u = x0f + du;
    precise float v = y0f + dv;
    if (!(u >= 0.0) || !(v >= 0.0) || u > last_x || v > last_y) return false;  // left the image
    float fu = floor(u), fv = floor(v);
    precise float ax = u - fu;
    precise float ay = v - fv;
    precise float bx = 1.0 - ax;
    precise float by = 1.0 - ay;
    int xa = int(fu), ya = int(fv);
    int xb = min(xa + 1, w - 1), yb = min(ya + 1, h - 1);
    precise float w00 = bx * by;
    precise float w10 = ax * by;
    precise float w01 = bx * ay;
    precise float w11 = ax * ay;
    float weight = 0.0, weighted = 0.0;
    HeightFieldTap(xa, ya, w, w00, weight, weighted);
    HeightFieldTap(xb, ya, w, w10, weight, weighted);
    HeightFieldTap(xa, yb, w, w01, weight, weighted);
    HeightFieldTap(xb, yb, w, w11, weight, weighted);
    precise float limit = ray + kHeightFieldShadowBiasPx;
    precise float scaled = limit * weight;
    if (weight >= kHeightFieldMinTapWeight && weighted > scaled) return true;
  }
  return false;
}

#endif  // REFLCAP_SHADERS_COMMON_HEIGHT_FIELD_GLSL_
