// Möller–Trumbore ray/plane hit of one triangle, shared by the renderer's exact surface hits
// (render/surface_hit.glsl) and the masks' camera map (resample/mask_camera.frag): the rasteriser
// decides which triangle a pixel sees, this decides where on it, so the point is the CPU's (Embree's
// ray hit) to float rounding rather than the rasteriser's sub-pixel-snapped interpolation.
// C++ counterpart: Embree's triangle intersection (engine/mesh/ray_scene.cc) and the hit
// interpolation of render/reference/reference_renderer.cc.
#ifndef REFLCAP_SHADERS_COMMON_RAY_TRIANGLE_GLSL_
#define REFLCAP_SHADERS_COMMON_RAY_TRIANGLE_GLSL_

// t along the (unit) ray o + t d and the barycentrics (b0, b1, b2) of the point where it meets
// the plane of the triangle (v0, v1, v2). False for a ray parallel to the plane (det = 0 exactly:
// any other determinant gives a finite t, however large, which the caller's t > 0 test and the
// rasteriser's choice of triangle bound).
bool RayTrianglePlane(vec3 o, vec3 d, vec3 v0, vec3 v1, vec3 v2, out float t, out vec3 b) {
  vec3 e1 = v1 - v0;
  vec3 e2 = v2 - v0;
  vec3 pvec = cross(d, e2);
  float det = dot(e1, pvec);
  t = 0.0;
  b = vec3(0.0);
  if (det == 0.0) return false;
  float inv = 1.0 / det;
  vec3 tvec = o - v0;
  float b1 = dot(tvec, pvec) * inv;
  vec3 qvec = cross(tvec, e1);
  float b2 = dot(d, qvec) * inv;
  t = dot(e2, qvec) * inv;
  b = vec3(1.0 - b1 - b2, b1, b2);
  return true;
}

#endif  // REFLCAP_SHADERS_COMMON_RAY_TRIANGLE_GLSL_
