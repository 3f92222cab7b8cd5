// Buffer layouts and constants of the Vulkan renderer (render/vulkan/vulkan_renderer.cc and
// shaders/render/*): the per-image RenderParams block, the shadow-map views, the de-indexed
// triangle corners the vertex shaders pull, and the per-triangle data. All frames are the object
// frame of the capture (the mesh's), as in the CPU reference renderer.
#ifndef REFLCAP_SHADERS_SHARED_RENDER_PARAMS_H_
#define REFLCAP_SHADERS_SHARED_RENDER_PARAMS_H_

#include "height_field.h"
#include "interop.h"
#include "light_map_view.h"

REFLCAP_SHARED_BEGIN

// RenderParams::flags bits.
REFLCAP_CONST(uint, kRenderFlagCastShadows, 1u);  // test the shadow map
REFLCAP_CONST(uint, kRenderFlagPinhole, 2u);      // pinhole camera (else orthographic)
REFLCAP_CONST(uint, kRenderFlagPointLight, 4u);   // point light (else directional)
REFLCAP_CONST(uint, kRenderFlagDistortion, 8u);   // the camera has lens distortion
// Most shadow-map views: a cube map's six faces.
REFLCAP_CONST(int, kMaxShadowViews, 6);
// Largest component count of the material texture: 3 channels x ParamsPerChannel(kMaxLobes) = 39
// floats, 4 per RGBA layer.
REFLCAP_CONST(int, kMaxMaterialLayers, 10);

// The shadow map holds one LightMapView (light_map_view.h) per layer: the light's perspective
// (point light: the six faces of a cube map, or one frustum fitted to the object) or
// orthographic (directional) projection.

struct RenderParams {
  vec4 clip_from_object[4];  // camera projection (rows), object frame -> clip; Vulkan depth [0,1]
  vec4 camera_origin;        // xyz: camera centre (pinhole) in the object frame
  vec4 camera_axis;          // xyz: the camera's +z (viewing direction) in the object frame
  vec4 object_from_cam[3];   // rows of the rotation camera -> object frame
  vec4 light;                // xyz: light position (point) or unit direction to it (directional)
  vec4 intensity;            // rgb: radiant intensity; w: pixel weight = exposure_s / samples
  vec4 intrinsics;           // fx, fy, cx, cy of the output camera (pixels)
  vec4 intrinsics_extra;     // x: skew s; y: orthographic pixel size (m); z: samples per pixel
                             // side of the rasterised pass (1, or N when supersampled); w: side
                             // of the square the resolve's N x N samples cover, px (1 = pixel)
  vec4 distortion;           // k1, k2, p1, p2
  vec4 distortion_extra;     // x: k3; yzw: unused
  vec4 vis_intrinsics;       // fx, fy, cx, cy of the visibility image (distortion resolve)
  vec4 vis_intrinsics_extra; // x: skew of the visibility image; yzw: unused
  // x: constant shadow bias (m, the CPU renderer's surface offset); y: texel-footprint bias
  // factor; z: largest receiver-plane correction, in footprints; w: unused.
  vec4 shadow_bias;
  uint flags;                // kRenderFlag* bits
  uint num_lobes;            // 0..kMaxLobes
  uint num_shadow_views;     // 0 (no shadows), 1 (one view) or 6 (cube map)
  uint shadow_resolution;    // shadow-map width = height, texels
  uint atlas_width;          // material texture size (atlas layout)
  uint atlas_height;
  uint width;                // output image size, pixels
  uint height;
  uint vis_width;            // visibility image size (distortion resolve)
  uint vis_height;
  uint supersampling;        // N: N x N samples per pixel in the resolve
  uint params_per_channel;   // ParamsPerChannel(num_lobes)
  LightMapView views[kMaxShadowViews];
};
REFLCAP_STD430_OFFSET(RenderParams, camera_origin, 64);
REFLCAP_STD430_OFFSET(RenderParams, light, 144);
REFLCAP_STD430_OFFSET(RenderParams, shadow_bias, 272);
REFLCAP_STD430_OFFSET(RenderParams, flags, 288);
REFLCAP_STD430_OFFSET(RenderParams, views, 336);
REFLCAP_STD430_SIZE(RenderParams, 336 + 6 * 128);

// One triangle corner, de-indexed (3 per triangle, corner c of triangle t at 3 t + c): the
// position and the corner's UV and shading normal.
struct RenderCorner {
  vec4 position_u;  // xyz: position (object frame, m); w: u
  vec4 normal_v;    // xyz: unit shading normal; w: v
};
REFLCAP_STD430_SIZE(RenderCorner, 32);

// Per triangle: its unit geometric normal (TriangleMesh::GeometricNormal, computed on the host so
// both renderers use the same float vector), its scale-free curvature (SurfaceCurvature), and
// its neighbours across its edges (for distort_resolve.comp's walk): neighbours[k] shares the edge
// opposite corner k (the edge a point with barycentric b_k < 0 lies beyond), -1 where that edge
// is a boundary or shared by more than two triangles. Vertices are matched by position (equal
// floats), so charts whose seam vertices are duplicated are still connected.
struct RenderTriangle {
  vec4 normal_curvature;  // xyz: geometric normal; w: curvature
  ivec4 neighbours;       // xyz: triangles across the edges opposite corners 0, 1, 2; w: unused
};
REFLCAP_STD430_SIZE(RenderTriangle, 32);

// The shadow pass pushes a LightMapPush (light_map_view.h).

// Push constants of the compute rasteriser of shadow maps (shadow_raster.comp): one view (its
// layer of the raster buffer), the map's resolution, the triangle count, and the dispatch's
// workgroups along x (triangle = group.y * groups_x + group.x).
struct ShadowRasterPush {
  uint view;
  uint resolution;
  uint triangles;
  uint groups_x;
};
REFLCAP_STD430_SIZE(ShadowRasterPush, 16);

// Push constants of the supersampling box filter.
struct DownsamplePush {
  uint width;   // output size
  uint height;
  uint factor;  // N
  uint pad;
};
REFLCAP_STD430_SIZE(DownsamplePush, 16);

// Per texel of a normal-map capture (normal_map_shade.comp).
struct NormalMapTexel {
  vec4 normal_curvature;  // xyz: unit normal (world frame); w: NormalMapCurvature
  vec4 tangent;           // xyz: unit tangent; w: unused
  vec4 bitangent;         // xyz: unit bitangent; w: unused
  uvec4 pixel;            // xy: the texel's pixel; zw: unused
};
REFLCAP_STD430_SIZE(NormalMapTexel, 64);

// Push constants of normal_map_shade.comp: the texel count and this image's height-field march
// (march.steps = 0: no cast shadows).
struct NormalMapPush {
  uint texels;
  uint pad0;
  uint pad1;
  uint pad2;
  HeightFieldMarch march;
};
REFLCAP_STD430_OFFSET(NormalMapPush, march, 16);
REFLCAP_STD430_SIZE(NormalMapPush, 48);

REFLCAP_SHARED_END

#endif  // REFLCAP_SHADERS_SHARED_RENDER_PARAMS_H_
