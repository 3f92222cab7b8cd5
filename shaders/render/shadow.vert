#version 460
// Vertex stage of the shadow-map pass: pulls triangle corner gl_VertexIndex and projects it with
// the clip_from_object of shadow view push.view (a cube face, a fitted frustum or an orthographic
// box; shared/light_map_view.h).
//
// Bindings (set 0): 0 = RenderParams, 1 = RenderCorner[].
// Push constants: LightMapPush {view}.
#extension GL_GOOGLE_include_directive : require

#define REFLCAP_RENDER_CORNERS
#include "render/render_inputs.glsl"

layout(push_constant) uniform Push { LightMapPush push; };

layout(location = 0) out vec3 out_position;

void main() {
  vec3 p = corners[gl_VertexIndex].position_u.xyz;
  out_position = p;
  gl_Position = TransformRows(params.views[push.view].clip_from_object, p);
}
