#version 460
// Vertex stage of the Vulkan renderer's camera passes (depth pre-pass, surface.frag,
// visibility.frag): pulls
// triangle corner gl_VertexIndex (3 t + c, non-indexed draw of every triangle) from the corner
// buffer and projects it with the camera's clip_from_object.
//
// Bindings (set 0): 0 = RenderParams, 1 = RenderCorner[] (render/render_inputs.glsl).
// Outputs: object-frame position, shading normal and UV (perspective-correct interpolation), and
// the triangle index (flat), for the fragment stage.
// C++ twin: the ray generation of render/reference/reference_renderer.cc (the rasteriser samples
// each pixel centre; the CPU traces the ray through it).
#extension GL_GOOGLE_include_directive : require

#define REFLCAP_RENDER_CORNERS
#include "render/render_inputs.glsl"

layout(location = 0) out vec3 out_position;
layout(location = 1) out vec3 out_normal;
layout(location = 2) out vec2 out_uv;
layout(location = 3) flat out uint out_triangle;
// The depth pre-pass and the shading pass (depth test EQUAL) must compute the same depth.
invariant gl_Position;

void main() {
  RenderCorner c = corners[gl_VertexIndex];
  out_position = c.position_u.xyz;
  out_normal = c.normal_v.xyz;
  out_uv = vec2(c.position_u.w, c.normal_v.w);
  out_triangle = uint(gl_VertexIndex) / 3u;
  gl_Position = TransformRows(params.clip_from_object, c.position_u.xyz);
}
