// Descriptor bindings of the Vulkan renderer's shaders (set 0), with the numbers
// render/vulkan/vulkan_renderer.cc binds; each shader declares only those it uses, through the
// REFLCAP_RENDER_* macros it defines before including this file:
//   0  RenderParams params                (every pass)
//   1  RenderCorner corners[]             (REFLCAP_RENDER_CORNERS: vertex pulling, resolve)
//   2  RenderTriangle triangles[]         (REFLCAP_RENDER_SHADING)
//   3  material: sampler2DArray, atlas layout, RGBA32F layers of BRDF parameters
//      (component k = c * params_per_channel + i of texel at that pixel: layer k / 4, lane k % 4)
//                                         (REFLCAP_RENDER_SHADING, REFLCAP_RENDER_MATERIAL)
//   4  frame: sampler2DArray, atlas layout, RGBA32F: xyz the texel's unit tangent, w 1 where
//      the pixel is a texel, 0 elsewhere  (REFLCAP_RENDER_SHADING)
//   5  shadow map: sampler2DArray of the D32 depth image, one layer per LightMapView, holding
//      distance / LightMapView.forward.w (REFLCAP_RENDER_SHADING)
// Bindings 6 and up belong to single passes and are declared there.
#ifndef REFLCAP_SHADERS_RENDER_RENDER_INPUTS_GLSL_
#define REFLCAP_SHADERS_RENDER_RENDER_INPUTS_GLSL_

#include "shared/render_params.h"

layout(std430, set = 0, binding = 0) readonly buffer ParamsBlock { RenderParams params; };

#ifdef REFLCAP_RENDER_CORNERS
layout(std430, set = 0, binding = 1) readonly buffer CornerBlock { RenderCorner corners[]; };
#endif

#if defined(REFLCAP_RENDER_SHADING) || defined(REFLCAP_RENDER_MATERIAL)
layout(set = 0, binding = 3) uniform sampler2DArray material_map;
#endif

#ifdef REFLCAP_RENDER_SHADING
layout(std430, set = 0, binding = 2) readonly buffer TriangleBlock { RenderTriangle triangles[]; };
layout(set = 0, binding = 4) uniform sampler2DArray frame_map;
layout(set = 0, binding = 5) uniform sampler2DArray shadow_map;
#endif

// rows[0..3] . p: a row-major 4x4 matrix times a point.
vec4 TransformRows(vec4 rows[4], vec3 p) {
  precise vec4 q = vec4(p, 1.0);
  return vec4(dot(rows[0], q), dot(rows[1], q), dot(rows[2], q), dot(rows[3], q));
}

#endif  // REFLCAP_SHADERS_RENDER_RENDER_INPUTS_GLSL_
