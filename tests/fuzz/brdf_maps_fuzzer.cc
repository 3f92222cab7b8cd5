// Fuzz target: a fit's parameter maps (params.exr) as `reflcap render` reads them
// (engine/texel: ReadBrdfMaps against the atlas of a unit quad at kAtlasSize^2). On success there
// is one parameter set per texel with 0..kMaxLobes lobes.
#include <cstddef>
#include <cstdint>

#include "engine/mesh/mesh.h"
#include "engine/mesh/texel_atlas.h"
#include "engine/texel/brdf_maps.h"
#include "tests/fuzz/fuzz_util.h"

namespace {

// The seed params.exr files (tests/fuzz/corpus/brdf_maps) are written for this atlas size.
constexpr int kAtlasSize = 8;

const reflcap::TexelAtlas& QuadAtlas() {
  static const reflcap::TexelAtlas atlas = [] {
    reflcap::TriangleMesh quad;
    quad.positions = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}};
    quad.triangles = {{0, 1, 2}, {0, 2, 3}};
    quad.corner_uvs = {{reflcap::Vec2f(0, 0), reflcap::Vec2f(1, 0), reflcap::Vec2f(1, 1)},
                       {reflcap::Vec2f(0, 0), reflcap::Vec2f(1, 1), reflcap::Vec2f(0, 1)}};
    const reflcap::Vec3f up(0, 0, 1);
    quad.corner_normals = {{up, up, up}, {up, up, up}};
    auto built = reflcap::BuildTexelAtlas(quad, kAtlasSize, kAtlasSize);
    FUZZ_CHECK(built.ok());
    return *built;
  }();
  return atlas;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const bool quiet = (reflcap::fuzz::QuietLogs(), true);
  (void)quiet;
  const auto& atlas = QuadAtlas();
  const auto path = reflcap::fuzz::WriteScratch("params.exr", data, size);
  auto maps = reflcap::ReadBrdfMaps(path, atlas);
  if (!maps.ok()) {
    reflcap::fuzz::Rejected(maps.status());
    return 0;
  }
  FUZZ_CHECK(maps->texels.size() == atlas.TexelCount());
  FUZZ_CHECK(maps->num_lobes >= 0 && maps->num_lobes <= reflcap::brdf::kMaxLobes);
  return 0;
}
