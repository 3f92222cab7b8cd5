#pragma once
// The SPIR-V of every shader in shaders/, compiled by glslc at build time and embedded in the
// binary (no files are read at run time).
//
// Adding a shader: a reflcap_add_shader(NAME my_kernel SRC dir/my_kernel.comp) line in
// shaders/CMakeLists.txt and the entry kMyKernel below (NAME in PascalCase with a k). The table
// behind ShaderBlob is generated from the CMake lines; a missing or extra enum entry fails to
// compile (shader_blobs.cc), so the two cannot drift apart.
#include <cstddef>
#include <cstdint>

namespace reflcap::gpu {

enum class ShaderId {
  kBrdfProbe,           // shaders/probe/brdf_probe.comp: the safe_math/Lafortune twins probe
  kLoopProbe,           // shaders/probe/loop_probe.comp: loop-iteration counting
  kChunkProbe,          // shaders/probe/chunk_probe.comp: in-place transform of a bound chunk
  kBenchEmpty,          // shaders/bench/empty.comp: empty kernel (dispatch overhead)
  kBenchMadThroughput,  // shaders/bench/mad_throughput.comp: float multiply-add throughput
  kLmFitAnisoK0,        // shaders/fit/lm_fit.comp, aniso, K = 0: the Vulkan fitter's LM
  kLmFitAnisoK1,        //   (one permutation per lobe model and lobe count)
  kLmFitAnisoK2,
  kLmFitAnisoK3,
  kLmFitIsoK0,
  kLmFitIsoK1,
  kLmFitIsoK2,
  kLmFitIsoK3,
  kLmFitSharedK0,
  kLmFitSharedK1,
  kLmFitSharedK2,
  kLmFitClusterAnisoK0,  // shaders/fit/lm_fit_cluster.comp: the same LM laid out for GPUs
  kLmFitClusterAnisoK1,  //   (a cluster of invocations per problem), same permutations
  kLmFitClusterAnisoK2,
  kLmFitClusterAnisoK3,
  kLmFitClusterIsoK0,
  kLmFitClusterIsoK1,
  kLmFitClusterIsoK2,
  kLmFitClusterIsoK3,
  kLmFitClusterSharedK0,
  kLmFitClusterSharedK1,
  kLmFitClusterSharedK2,
  kFitProbe,            // shaders/fit/fit_probe.comp: the fitting model's GLSL twins
  kRenderSurfaceVert,      // shaders/render/surface.vert: camera pass, vertex pulling
  kRenderSurfaceFrag,      // shaders/render/surface.frag: camera pass, per-fragment shading
  kRenderVisibilityFrag,   // shaders/render/visibility.frag: triangle ids (distorted cameras)
  kRenderShadowVert,       // shaders/render/shadow.vert: shadow-map pass, vertex pulling
  kRenderShadowFrag,       // shaders/render/shadow.frag: shadow-map distances
  kRenderDistortResolve,   // shaders/render/distort_resolve.comp: exact rays of distorted cameras
  kRenderDownsample,       // shaders/render/downsample.comp: supersampling box filter
  kRenderNormalMapShade,   // shaders/render/normal_map_shade.comp: normal-map captures
  kRenderShadowRaster,     // shaders/render/shadow_raster.comp: shadow maps by compute
  kResampleMaskDrawVert,   // shaders/resample/mask_draw.vert: light/camera passes, vertex pulling
  kResampleMaskLightFrag,  // shaders/resample/mask_light.frag: light-map distances
  kResampleMaskCameraFrag, // shaders/resample/mask_camera.frag: camera map (distance, lit, hit)
  kResampleMasks,          // shaders/resample/masks.comp: per-texel outcomes and samples
  kCount                // number of shaders; keep last
};

// A SPIR-V module: `size` 32-bit words at `data` (static storage, never null).
struct Span {
  const uint32_t* data = nullptr;
  size_t size = 0;
  size_t size_bytes() const { return size * sizeof(uint32_t); }
};

// The SPIR-V of `id` (id < kCount).
Span ShaderBlob(ShaderId id);
// The reflcap_add_shader NAME of `id`, e.g. "brdf_probe"; its source path under shaders/.
const char* ShaderName(ShaderId id);
const char* ShaderSource(ShaderId id);

}  // namespace reflcap::gpu
