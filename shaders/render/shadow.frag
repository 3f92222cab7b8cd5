#version 460
// Fragment stage of the shadow-map pass: stores, as the depth, the distance from the view's origin
// to the surface point under the texel centre — |p - origin| (perspective views) or
// (p - origin) . forward (orthographic) — divided by the view's distance scale (forward.w, beyond
// every surface), which render/shading.glsl InShadow compares against. The depth test (LESS)
// keeps the nearest surface: along one texel's ray the distance orders surfaces as the
// projective depth does. Both faces are drawn (no culling), so open meshes cast shadows too. The
// map is the D32_SFLOAT depth attachment itself (no colour attachment): float distances with a
// 24-bit mantissa, ~1e-7 of the scale. The clear value 1 means "nothing before the scale".
//
// Bindings (set 0): 0 = RenderParams. Push constants: LightMapPush {view}.
// Outputs: gl_FragDepth = distance / forward.w.
#extension GL_GOOGLE_include_directive : require

#include "render/render_inputs.glsl"

layout(push_constant) uniform Push { LightMapPush push; };

layout(location = 0) in vec3 in_position;

void main() {
  LightMapView view = params.views[push.view];
  vec3 d = in_position - view.origin.xyz;
  float distance = view.origin.w > 0.5 ? length(d) : dot(d, view.forward.xyz);
  gl_FragDepth = clamp(distance / view.forward.w, 0.0, 1.0);
}
