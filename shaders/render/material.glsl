// The material texture of the Vulkan renderer (binding 3, atlas layout; see
// render/render_inputs.glsl) and the BRDF evaluated from it: brdf::EvalRgb's twin.
#ifndef REFLCAP_SHADERS_RENDER_MATERIAL_GLSL_
#define REFLCAP_SHADERS_RENDER_MATERIAL_GLSL_

#define REFLCAP_RENDER_MATERIAL
#include "common/lafortune.glsl"
#include "render/render_inputs.glsl"

// brdf::EvalRgb for the texel at atlas pixel `texel`: EvalChannel (common/lafortune.glsl) per
// channel on the parameters of the material texture.
vec3 EvalRgbAt(ivec2 texel, vec3 wi, vec3 wo) {
  int per_channel = int(params.params_per_channel);
  int layers = (3 * per_channel + 3) / 4;
  vec4 m[kMaxMaterialLayers];
  for (int l = 0; l < layers; ++l) m[l] = texelFetch(material_map, ivec3(texel, l), 0);
  vec3 f;
  for (int c = 0; c < 3; ++c) {
    float p[kMaxParamsPerChannel];
    for (int i = 0; i < kMaxParamsPerChannel; ++i) {
      int k = c * per_channel + i;
      p[i] = i < per_channel ? m[k >> 2][k & 3] : 0.0;
    }
    f[c] = EvalChannel(wi, wo, p, int(params.num_lobes));
  }
  return f;
}

#endif  // REFLCAP_SHADERS_RENDER_MATERIAL_GLSL_
