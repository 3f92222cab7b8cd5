#version 460
// Fragment stage of the light pass of the Vulkan masks: stores, as the depth, the distance from
// the view's origin to the surface under the texel centre — |p - origin| (perspective) or
// (p - origin) . forward (orthographic) — divided by the view's distance scale (forward.w, beyond
// every surface), which LightShadowed (masks_common.glsl) compares against. Depth test LESS keeps
// the nearest surface; both faces are drawn (no culling), so open meshes cast shadows too, as
// Embree's occlusion rays see both faces. The clear value 1 means "nothing before the scale".
//
// Bindings (set 0): 0 = MaskParams. Push constants: MaskDrawPush {view}.
// Outputs: gl_FragDepth = distance / forward.w.
#extension GL_GOOGLE_include_directive : require

#include "resample/masks_common.glsl"

layout(push_constant) uniform Push { MaskDrawPush push; };

layout(location = 0) in vec3 in_position;
layout(location = 1) in vec3 in_normal;

void main() {
  LightMapView view = params.views[push.view];
  vec3 d = in_position - view.origin.xyz;
  float distance = view.origin.w > 0.5 ? length(d) : dot(d, view.forward.xyz);
  // [0, 1] is the depth attachment's range; the host puts every surface inside it.
  gl_FragDepth = clamp(distance / view.forward.w, 0.0, 1.0);
}
