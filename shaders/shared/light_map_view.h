// One view of a light map — distances rendered from a light by the depth passes of the Vulkan
// renderer's shadow maps (render_params.h) and the Vulkan masks' light maps (resample_masks.h):
// a fitted perspective frustum, one face of a cube map, or an orthographic box. Built on the host
// by engine/gpu/depth_pass.h; read by shaders/common/light_map.glsl.
//
// Valid C++17 and GLSL (GL_GOOGLE_include_directive): see interop.h.
#ifndef REFLCAP_SHADERS_SHARED_LIGHT_MAP_VIEW_H_
#define REFLCAP_SHADERS_SHARED_LIGHT_MAP_VIEW_H_

#include "interop.h"

REFLCAP_SHARED_BEGIN

// The map stores, per texel, the distance from `origin` along the texel's ray to the nearest
// surface — |x - origin| for perspective views, (x - origin) . forward for orthographic ones —
// divided by forward.w. The texel at NDC (xc, yc) has the ray
//   perspective:  origin, direction normalize(forward + xc right.w right + yc up.w up)
//   orthographic: origin + xc right.w right + yc up.w up, direction forward.
struct LightMapView {
  vec4 clip_from_object[4];  // rows of the 4x4 projection (object frame -> clip), Vulkan depth
  vec4 origin;               // xyz: light position / centre of the orthographic near plane; w: 1
                             // perspective, 0 orthographic
  vec4 forward;              // xyz: unit viewing direction; w: distance scale (m): the map
                             // stores distance / scale in [0, 1] (scale beyond every surface)
  vec4 right;                // xyz: unit NDC +x axis; w: tan(half-angle) or half-width (m)
  vec4 up;                   // xyz: unit NDC +y axis; w: tan(half-angle) or half-height (m)
};
REFLCAP_STD430_SIZE(LightMapView, 128);

// Push constant of a light-map pass draw (engine/gpu/depth_pass.h LightMapPass): the view, which
// is also the layer drawn into.
struct LightMapPush {
  uint view;
};
REFLCAP_STD430_SIZE(LightMapPush, 4);

REFLCAP_SHARED_END

#endif  // REFLCAP_SHADERS_SHARED_LIGHT_MAP_VIEW_H_
