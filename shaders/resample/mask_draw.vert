#version 460
// Vertex stage of the light and camera passes of the Vulkan masks: pulls triangle corner
// gl_VertexIndex (MaskCorner) and projects it with the light view push.view or, for
// push.view == kMaskCameraView, the camera-map projection. Host twin: vulkan_masks.cc (the views
// and projections); CPU counterpart: the Embree rays of image_resampler.cc.
//
// Bindings (set 0): 0 = MaskParams, 1 = MaskCorner[]. Push constants: MaskDrawPush {view}.
// Outputs: object-frame position (location 0), shading normal (location 1) and UV (location 2,
// from the corners' w components; read by the camera pass only), interpolated.
#extension GL_GOOGLE_include_directive : require

#define REFLCAP_MASK_CORNERS
#include "resample/masks_common.glsl"

layout(push_constant) uniform Push { MaskDrawPush push; };

layout(location = 0) out vec3 out_position;
layout(location = 1) out vec3 out_normal;
layout(location = 2) out vec2 out_uv;

void main() {
  MaskCorner c = corners[gl_VertexIndex];
  out_position = c.position.xyz;
  out_normal = c.normal.xyz;
  out_uv = vec2(c.position.w, c.normal.w);
  if (push.view == kMaskCameraView) {
    gl_Position = MaskTransformRows(params.camera_clip_from_object, c.position.xyz);
  } else {
    gl_Position = MaskTransformRows(params.views[push.view].clip_from_object, c.position.xyz);
  }
}
