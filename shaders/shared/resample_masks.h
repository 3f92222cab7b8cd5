// Buffer layouts and constants of the Vulkan visibility / cast-shadow masks of `reflcap resample
// --backend vulkan` (acquire/resample/vulkan_masks.cc and shaders/resample/*): the per-image
// MaskParams block, the light-map views, the de-indexed triangle corners the vertex stage pulls,
// the per-texel inputs and the per-texel sample records. All frames are the object frame of the
// capture (the mesh's), as in the CPU path (acquire/resample/image_resampler.cc).
#ifndef REFLCAP_SHADERS_SHARED_RESAMPLE_MASKS_H_
#define REFLCAP_SHADERS_SHARED_RESAMPLE_MASKS_H_

#include "interop.h"
#include "light_map_view.h"

REFLCAP_SHARED_BEGIN

// MaskParams::flags bits.
REFLCAP_CONST(uint, kMaskFlagPinhole, 1u);     // pinhole camera (else orthographic)
REFLCAP_CONST(uint, kMaskFlagPointLight, 2u);  // point light (else directional)
REFLCAP_CONST(uint, kMaskFlagDistortion, 4u);  // the camera has lens distortion
// SamplePoint::kPixel: the sample is the nearest tap's pixel with its hit's geometry.
REFLCAP_CONST(uint, kMaskFlagPixelSample, 8u);
// With kMaskFlagPixelSample: the camera's pixels are point samples (PixelFilter::kPoint), so a
// texel whose taps all hit other texels is rejected (kMaskEdgeTexel) instead of taking the nearest.
REFLCAP_CONST(uint, kMaskFlagPointPixels, 16u);
// resample::kMinResolvedTexelPixels (image_resampler.h): the smallest texel, in pixels, whose
// missing in-texel tap rejects it under kMaskFlagPointPixels (static_assert in vulkan_masks.cc).
REFLCAP_CONST(float, kMaskMinResolvedTexelPixels, 0.5);
// Most light-map views: a cube map's six faces.
REFLCAP_CONST(uint, kMaskMaxLightViews, 6u);
// MaskDrawPush::view of the camera pass (light views are 0 .. num_light_views - 1).
REFLCAP_CONST(uint, kMaskCameraView, 6u);
// Workgroup size of masks.comp (its local_size_x default; one invocation per texel).
REFLCAP_CONST(uint, kMaskWorkgroupSize, 64u);

// Outcome codes: the values of resample::Outcome (image_resampler.h; static_asserts in
// vulkan_masks.cc keep them equal).
REFLCAP_CONST(uint, kMaskKept, 0u);
REFLCAP_CONST(uint, kMaskGrazingView, 1u);
REFLCAP_CONST(uint, kMaskEdgeOutside, 2u);
REFLCAP_CONST(uint, kMaskOccluded, 3u);
REFLCAP_CONST(uint, kMaskGrazingLight, 4u);
REFLCAP_CONST(uint, kMaskShadowed, 5u);
REFLCAP_CONST(uint, kMaskEdgeSurface, 6u);
REFLCAP_CONST(uint, kMaskEdgeShadow, 7u);
REFLCAP_CONST(uint, kMaskInvalid, 8u);
REFLCAP_CONST(uint, kMaskClipped, 9u);
REFLCAP_CONST(uint, kMaskDark, 10u);
REFLCAP_CONST(uint, kMaskEdgeTexel, 11u);

// The light map holds one LightMapView (light_map_view.h) per layer: the light's perspective
// projection (point light: a cube face, or one frustum fitted to the object) or an orthographic
// box (directional).

struct MaskParams {
  vec4 camera_clip_from_object[4];  // camera-map projection (rows): object frame -> clip
  vec4 cam_from_object[3];          // rows of [R | t]: object frame -> camera frame
  vec4 object_from_cam[3];          // rows of [R | t]: camera frame -> object frame
  vec4 camera_centre;               // xyz: camera centre (pinhole) / origin (ortho), object frame
  vec4 toward_cam;                  // xyz: unit, from the object towards the camera (-axis)
  vec4 intrinsics;                  // fx, fy, cx, cy of the photograph (pixels)
  vec4 intrinsics_extra;            // x: skew; y: orthographic pixel size (m); z: footprint scale
                                    // (pinhole: 1 / min(fx, fy); ortho: pixel size); w: unused
  vec4 distortion;                  // k1, k2, p1, p2
  vec4 distortion_extra;            // x: k3; yzw: unused
  vec4 map_intrinsics;              // fx, fy, cx, cy of the camera map (pinhole)
  vec4 map_intrinsics_extra;        // x: skew of the camera map; y, z: the texel atlas's width
                                    // and height (TexelUnderUv; exact as floats below 2^24);
                                    // w: unused
  vec4 light;                       // xyz: light position (point) or unit direction to it
  vec4 intensity;                   // rgb: radiant intensity; w: exposure_s
  vec4 noise;                       // photon_sigma_at_1², read_sigma², dark floor, invalid floor
  vec4 tests;                       // x: min_cos; y: saturation (0 = none); z: edge depth slack
                                    // (kEdgeDepthSlack); w: surface offset (m)
  vec4 bias;                        // x: light-map bias, texel footprints; y: light-map plane
                                    // limit, footprints; z: camera-map bias, pixel footprints;
                                    // w: camera-map plane limit, pixel footprints
  vec4 relative_sigma_floor;        // x: kRelativeSigmaFloor; y: 1 = binding 10 holds the
                                    // variance image; z: kDarkSigmas; w: kInvalidSigmas
  uint flags;                       // kMaskFlag* bits
  uint width;                       // photograph size, pixels
  uint height;
  uint map_width;                   // camera-map size, texels
  uint map_height;
  uint light_resolution;            // light-map width = height, texels
  uint num_light_views;             // 1 or 6 (cube map)
  uint image_index;                 // written into every sample
  LightMapView views[kMaskMaxLightViews];
};
REFLCAP_STD430_OFFSET(MaskParams, cam_from_object, 64);
REFLCAP_STD430_OFFSET(MaskParams, camera_centre, 160);
REFLCAP_STD430_OFFSET(MaskParams, light, 288);
REFLCAP_STD430_OFFSET(MaskParams, relative_sigma_floor, 368);
REFLCAP_STD430_OFFSET(MaskParams, flags, 384);
REFLCAP_STD430_OFFSET(MaskParams, views, 416);
REFLCAP_STD430_SIZE(MaskParams, 416 + 6 * 128);

// One triangle corner, de-indexed (corner c of triangle t at 3 t + c).
struct MaskCorner {
  vec4 position;  // xyz: object frame (m); w: the corner's u
  vec4 normal;    // xyz: unit shading normal of the corner; w: the corner's v
};
REFLCAP_STD430_SIZE(MaskCorner, 32);

// One texel of the atlas (TexelAtlas's arrays, interleaved).
struct MaskTexel {
  vec4 position;          // xyz: object frame (m); w: the texel's side on the surface (m,
                          // TexelSidesM)
  vec4 shading_normal;    // xyz: unit
  vec4 geometric_normal;  // xyz: unit
  vec4 tangent;           // xyz: unit
};
REFLCAP_STD430_SIZE(MaskTexel, 64);

// The BRDF sample of a kept texel (BrdfSample without the image index); undefined otherwise.
struct MaskSample {
  float wi[3];
  float wo[3];
  float value[3];
  float weight[3];
};
REFLCAP_STD430_SIZE(MaskSample, 48);

// Push constants of the light and camera passes: which view to draw.
// The light pass's draws push it as a LightMapPush (light_map_view.h: the same single uint).
struct MaskDrawPush {
  uint view;  // 0 .. kMaskMaxLightViews - 1: light view; kMaskCameraView: the camera
};
REFLCAP_STD430_SIZE(MaskDrawPush, 4);

// Push constants of masks.comp: the texels of this dispatch (a chunk of the bound buffers).
struct MaskTexelPush {
  uint first_texel;  // atlas index of the chunk's first texel
  uint count;        // texels in the chunk
};
REFLCAP_STD430_SIZE(MaskTexelPush, 8);

REFLCAP_SHARED_END

#endif  // REFLCAP_SHADERS_SHARED_RESAMPLE_MASKS_H_
