// Fuzz target: glTF 2.0 meshes (engine/mesh: LoadGltf), both the JSON (.gltf, embedded data:
// URIs) and the binary container (.glb, told apart by its magic), checked with CheckMesh on
// success.
#include <cstddef>
#include <cstdint>

#include "engine/mesh/mesh_io.h"
#include "tests/fuzz/fuzz_util.h"
#include "tests/fuzz/mesh_checks.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const bool quiet = (reflcap::fuzz::QuietLogs(), true);
  (void)quiet;
  const auto path = reflcap::fuzz::WriteScratch("mesh.gltf", data, size);
  reflcap::MeshLoadStats stats;
  auto mesh = reflcap::LoadGltf(path, &stats);
  if (!mesh.ok()) {
    reflcap::fuzz::Rejected(mesh.status());
    return 0;
  }
  reflcap::fuzz::CheckMesh(*mesh);
  return 0;
}
