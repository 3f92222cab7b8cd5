#pragma once
// TexelAtlas: the surface samples ("texels") that reflectance is fitted on, and their layout as an
// image so per-texel data can be written as EXR maps.
//
// Mesh atlas: the UV square is rasterised at width x height; atlas pixel (x, y) covers
// u in [x/W, (x+1)/W], v in [1-(y+1)/H, 1-y/H] (row 0 at the top = v = 1, the OBJ/PNG convention).
// Coverage is conservative: every pixel whose square overlaps a UV triangle with positive area is
// a texel; a pixel overlapped by several triangles is assigned to exactly one (the one containing
// the pixel centre, else the nearest in UV), and its surface point is that triangle's point
// nearest the pixel centre in UV (barycentrics clamped to the triangle). So no chart texel lacks a
// surface point and no texel belongs to two charts.
//
// Normal-map atlas: the texels are the masked pixels of the capture's camera; layout = image.
//
// Each texel carries its object-frame position, unit shading normal (interpolated), unit geometric
// normal, and a right-handed tangent frame (tangent, bitangent, normal = shading normal) in which
// BRDF directions are expressed: z = normal, x = tangent follows increasing u (continuous within
// a chart: per-vertex tangents accumulated from the UV parameterisation, then Gram–Schmidt).
#include <cstdint>
#include <vector>

#include "engine/core/status.h"
#include "engine/image/image.h"
#include "engine/math/types.h"
#include "engine/mesh/mesh.h"

namespace reflcap {

// PixelOfUv's shift of every texel boundary, in texels. A UV that lands on a texel boundary —
// as synthetic scenes and orthographic cameras make it do — comes out of two renderers (Embree's
// barycentrics on the CPU, a GPU's) a float ulp or two to either side of it, and floor() would
// split such ties by rounding noise. Shifted by a non-dyadic 1/300 texel, the tie lies where no
// float lands exactly, far beyond that noise (a UV times 16,384 texels keeps ~2^-10 of a
// texel); the shift itself is invisible. The arithmetic is float, in this order, as in its GLSL
// twin (shaders/common/texel_atlas.glsl, `precise`: no fused multiply-add), so equal UVs give
// equal texels on every device.
constexpr float kTexelTieOffset = 1.0f / 300.0f;

struct TexelAtlas {
  int width = 0;   // layout size in pixels
  int height = 0;
  std::vector<int32_t> texel_of_pixel;  // width*height, -1 where no texel
  std::vector<uint32_t> pixel_of_texel; // y*width + x for each texel
  std::vector<Vec3f> position;          // object frame, metres
  std::vector<Vec3f> shading_normal;    // unit
  std::vector<Vec3f> geometric_normal;  // unit
  std::vector<Vec3f> tangent;           // unit, orthogonal to shading_normal
  std::vector<Vec3f> bitangent;         // unit, = shading_normal x tangent
  std::vector<int32_t> triangle;        // source triangle, -1 for normal-map texels

  size_t TexelCount() const { return pixel_of_texel.size(); }
  int TexelAt(int x, int y) const { return texel_of_pixel[size_t(y) * width + x]; }
  void PixelOf(size_t texel, int* x, int* y) const {
    *x = int(pixel_of_texel[texel] % uint32_t(width));
    *y = int(pixel_of_texel[texel] / uint32_t(width));
  }
  // Atlas pixel containing UV (u, v), clamped to the layout: x = floor(u W + kTexelTieOffset),
  // y = floor((1 - v) H + kTexelTieOffset) in float; non-finite coordinates map to 0.
  void PixelOfUv(float u, float v, int* x, int* y) const;
  // The texel whose parameters shade a surface point at UV `uv` (the renderers' lookup, which
  // the resampler mirrors to tell which texel a pixel saw): the atlas pixel under it.
  // Conservative coverage guarantees one for UVs inside a triangle; rounding at a chart border
  // can land one pixel off, so the 3x3 neighbourhood is searched (rows, then columns) before
  // giving up (-1).
  int TexelUnderUv(const Vec2f& uv) const;
};

// Rasterises mesh's UV layout at width x height (each >= 1, width * height < 2^31; else
// InvalidArgument). FailedPrecondition when the mesh has no UVs; InvalidArgument when a triangle
// index is out of range. Triangles with zero UV area or non-finite UVs cover nothing; a mesh
// without corner normals gets geometric ones. Texels are numbered row-major by pixel (y, then
// x), so the numbering is deterministic. Coverage treats an overlap thinner than a few float ulps
// of the UVs (8 * 2^-24 in UV units, see texel_atlas.cc) as touching. Runs on all cores.
StatusOr<TexelAtlas> BuildTexelAtlas(const TriangleMesh& mesh, int width, int height);

// Texels from a normal map: one per pixel with mask > 0.5 and a finite normal of length > 0.5
// (normalised). `normals` has 3 channels (world = object frame for such captures); `mask` has 1
// or more channels (channel 0 is used) and the same size; otherwise InvalidArgument. Positions
// are 0 (orthographic, directional lights: position is unused), geometric normal = shading
// normal, tangent frame from the normal alone (Duff et al. 2017), triangle = -1.
StatusOr<TexelAtlas> BuildNormalMapAtlas(const Image& normals, const Image& mask);

// Per texel of a mesh atlas, the side of its atlas pixel on the surface in metres:
// sqrt(3D area / UV area / (width * height)) of its triangle, the texel's size if the
// parameterisation is conformal. 0 for a texel without a triangle (normal-map atlases) or one on a
// triangle of zero UV area. The resampler compares it with the pixel footprint (float, so the CPU
// and Vulkan paths compare the same value).
std::vector<float> TexelSidesM(const TriangleMesh& mesh, const TexelAtlas& atlas);

// Counts the texels BuildTexelAtlas would produce (same coverage, no per-texel data kept), for
// `reflcap info`. Same errors as BuildTexelAtlas.
StatusOr<size_t> CountAtlasTexels(const TriangleMesh& mesh, int width, int height);

// Default atlas resolution (square) used when a command is not told otherwise.
constexpr int kDefaultAtlasResolution = 512;

}  // namespace reflcap
