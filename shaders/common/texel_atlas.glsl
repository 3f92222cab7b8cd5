// The texel atlas's UV -> pixel map for the GLSL twins (render/shading.glsl's texel lookup,
// resample/masks_common.glsl's): TexelAtlas::PixelOfUv (engine/mesh/texel_atlas.h).
#ifndef REFLCAP_SHADERS_COMMON_TEXEL_ATLAS_GLSL_
#define REFLCAP_SHADERS_COMMON_TEXEL_ATLAS_GLSL_

// kTexelTieOffset of texel_atlas.h: every texel boundary shifted by 1/300 texel, so a UV that
// lands on one (synthetic scenes, orthographic cameras) is not split by float rounding noise.
const float kTexelTieOffset = 1.0 / 300.0;

// x = floor(u W + kTexelTieOffset), y = floor((1 - v) H + kTexelTieOffset), clamped to the
// layout, with the C++'s float operations in the same order (`precise`: no fused multiply-add;
// texel_atlas.h says why), so equal UVs give equal texels on every device.
ivec2 AtlasPixelOfUv(vec2 uv, uvec2 size) {
  precise float sx = uv.x * float(size.x);
  precise float x = floor(sx + kTexelTieOffset);
  precise float one_minus_v = 1.0 - uv.y;
  precise float sy = one_minus_v * float(size.y);
  precise float y = floor(sy + kTexelTieOffset);
  x = clamp(x, 0.0, float(size.x - 1u));
  y = clamp(y, 0.0, float(size.y - 1u));
  return ivec2(int(x), int(y));
}

#endif  // REFLCAP_SHADERS_COMMON_TEXEL_ATLAS_GLSL_
