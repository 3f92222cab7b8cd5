// Constants and the per-light march of the height-field shadow test (engine/mesh/height_field.h,
// C++ twin HeightFieldShadowed; GLSL twin shaders/common/height_field.glsl), shared by the CPU
// paths (resampling, the reference renderer) and the Vulkan renderer's normal_map_shade.comp.
//
// A height field here is the surface of a normal-map capture seen by its orthographic camera:
// one float per pixel of the camera (row-major, width x height), the height towards the camera
// in pixel units, kHeightFieldOutside where the pixel is not on the object.
#ifndef REFLCAP_SHADERS_SHARED_HEIGHT_FIELD_H_
#define REFLCAP_SHADERS_SHARED_HEIGHT_FIELD_H_

#include "interop.h"

REFLCAP_SHARED_BEGIN

// Stored height of a pixel that is not on the object (outside the mask, or a masked pixel without
// a usable normal): far below any real height (heights are bounded by the image size times the
// largest slope, < 1e7 px), so it never occludes. Test with kHeightFieldInsideAbove.
REFLCAP_CONST(float, kHeightFieldOutside, -1.0e30f);
// A stored height above this is on the object (half-way to the sentinel in exponent: no rounding
// of either can cross it).
REFLCAP_CONST(float, kHeightFieldInsideAbove, -1.0e29f);
// Most march steps per shadow test. One step crosses one pixel column or row, so 8192 steps
// cover the diagonal of a 5792 x 5792 image; a march that would need more is cut there and the
// point counts as lit beyond it. lavapipe silently ends an invocation's loops after 65,535 steps
// in total (engine/gpu: MaxLoopIterationsPerInvocation = 65,000 for kernels), and one
// normal_map_shade.comp invocation marches once, so 8192 stays far inside that budget.
REFLCAP_CONST(uint, kMaxHeightFieldMarchSteps, 8192u);
// Shadow bias, in pixel units of height: a march sample blocks the light only when the height
// field there is more than this above the ray. The least-squares heights deviate from the true
// surface by a fraction of a pixel (tests/engine/mesh/height_field_test.cc: 0.02 px on a sphere
// cap of radius 40 px, 0.4 px at the crease of a pit's rim), and a ray leaving a lit point
// nearly tangentially runs within that of the field for several pixels, where an unbiased test
// would shadow it by integration error alone; one pixel is above that error and far below the
// height of any occluder that casts a visible shadow (tens of pixels on DiLiGenT).
REFLCAP_CONST(float, kHeightFieldShadowBiasPx, 1.0f);

// A march sample is on the object when the texels among its four bilinear taps carry at least
// this share of the weight (their heights are then averaged with renormalised weights): the
// silhouette lies half-way between an object pixel's centre and a background pixel's, so a
// sample nearer the background sees no object there.
REFLCAP_CONST(float, kHeightFieldMinTapWeight, 0.5f);

// One light's march over a height field (MakeHeightFieldMarch): the ray from a surface point
// towards the light, in (column, row, height) pixel units, advanced one step at a time; a step
// moves one pixel along the major image axis of the light's projection.
struct HeightFieldMarch {
  vec4 step;   // x, y: pixel offset per step (max(|x|, |y|) = 1); z: height gained per step (px);
               // w: the field's largest height (px): a ray above it has escaped
  uint steps;  // steps to march; 0 = this light casts no shadow (along the view axis, or off)
  uint width;  // height-field size, pixels
  uint height;
  uint pad;
};
REFLCAP_STD430_SIZE(HeightFieldMarch, 32);

REFLCAP_SHARED_END

#endif  // REFLCAP_SHADERS_SHARED_HEIGHT_FIELD_H_
