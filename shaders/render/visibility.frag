#version 460
// Fragment stage of the visibility pass (distorted cameras): writes which triangle is nearest at
// each pixel centre of the undistorted visibility image, for distort_resolve.comp.
//
// Bindings: none beyond surface.vert's.
// Outputs: location 0 (R32_UINT) = triangle index + 1; the clear value 0 marks the background.
#extension GL_GOOGLE_include_directive : require

layout(location = 3) flat in uint in_triangle;
layout(location = 0) out uint out_triangle;

void main() { out_triangle = in_triangle + 1u; }
