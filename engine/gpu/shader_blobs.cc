#include "engine/gpu/shader_blobs.h"

#include <iterator>

#include "engine/core/check.h"

namespace reflcap::gpu {
namespace {

struct ShaderTableRow {
  ShaderId id;
  const char* name;
  const char* source;
  const uint32_t* words;
  size_t size;
};

// kSpirv<Name>[] arrays and kShaderTable[], one row per reflcap_add_shader
// (shaders/CMakeLists.txt).
#include "shaders/shader_table.inc"

constexpr bool TableCoversEveryIdOnce() {
  constexpr size_t n = static_cast<size_t>(ShaderId::kCount);
  if (std::size(kShaderTable) != n) return false;
  bool seen[n] = {};
  for (const ShaderTableRow& row : kShaderTable) {
    const size_t i = static_cast<size_t>(row.id);
    if (i >= n || seen[i]) return false;
    seen[i] = true;
  }
  return true;
}
static_assert(TableCoversEveryIdOnce(),
              "enum ShaderId and the reflcap_add_shader lines in shaders/CMakeLists.txt differ: "
              "each shader needs exactly one k<Name> entry");

const ShaderTableRow& Row(ShaderId id) {
  for (const ShaderTableRow& row : kShaderTable) {
    if (row.id == id) return row;
  }
  REFLCAP_CHECK(false) << "ShaderId " << static_cast<int>(id) << " has no shader";
  return kShaderTable[0];
}

}  // namespace

Span ShaderBlob(ShaderId id) {
  const ShaderTableRow& row = Row(id);
  return Span{row.words, row.size};
}

const char* ShaderName(ShaderId id) { return Row(id).name; }
const char* ShaderSource(ShaderId id) { return Row(id).source; }

}  // namespace reflcap::gpu
