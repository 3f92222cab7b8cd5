// Makes a header valid in both GLSL (via GL_GOOGLE_include_directive) and C++17.
//
// Every shaders/shared/*.h includes this file and then declares its constants with
// REFLCAP_CONST and its buffer structs in the subset both languages read alike:
//   - scalars float, int, uint (C++: std::int32_t / std::uint32_t); no bool (4 bytes in a GLSL
//     buffer, 1 in C++) and no double (use it only where both sides agree it is 8-aligned);
//   - fixed arrays of those scalars (`float params[13];`): std430 strides them by 4, as C++ does;
//   - vec2/vec4/uvec2/uvec4/ivec4, which C++ gets below with the std430 alignment (8 and 16);
//   - no vec3/uvec3 members: std430 aligns them to 16 but sizes them 12, which no plain C++ struct
//     reproduces. Use float[3] (alignment 4) or a vec4.
// C++ checks each struct's std430 size and member offsets with REFLCAP_STD430_SIZE /
// REFLCAP_STD430_OFFSET (static_assert; nothing in GLSL), so a C++/GLSL layout drift fails to
// compile. The GPU side of the same layout is exercised by the probe tests (tests/engine/gpu).
//
// C++ declarations live in namespace reflcap::gpu::shared (REFLCAP_SHARED_BEGIN/_END); GLSL has
// no namespaces, so names must be unique across all shared headers. Include guards, not
// #pragma once (glslang's include directive does not know it).
#ifndef REFLCAP_SHADERS_SHARED_INTEROP_H_
#define REFLCAP_SHADERS_SHARED_INTEROP_H_

#ifdef __cplusplus

#include <cstddef>
#include <cstdint>

#define REFLCAP_SHARED_BEGIN namespace reflcap::gpu::shared {
#define REFLCAP_SHARED_END }
// A compile-time constant visible to both languages: REFLCAP_CONST(float, kTiny, 1e-30f);
#define REFLCAP_CONST(type, name, value) inline constexpr type name = value
#define REFLCAP_STD430_SIZE(type, bytes) \
  static_assert(sizeof(type) == (bytes), #type ": C++ size differs from its std430 size")
#define REFLCAP_STD430_OFFSET(type, member, bytes) \
  static_assert(offsetof(type, member) == (bytes),   \
                #type "::" #member ": offset differs from std430")

namespace reflcap::gpu::shared {
using uint = std::uint32_t;
struct alignas(8) vec2 {
  float x, y;
};
struct alignas(16) vec4 {
  float x, y, z, w;
};
struct alignas(8) uvec2 {
  uint x, y;
};
struct alignas(16) uvec4 {
  uint x, y, z, w;
};
struct alignas(16) ivec4 {
  std::int32_t x, y, z, w;
};
static_assert(sizeof(vec2) == 8 && sizeof(vec4) == 16 && sizeof(uvec2) == 8 &&
              sizeof(uvec4) == 16 && sizeof(ivec4) == 16);
}  // namespace reflcap::gpu::shared

#else  // GLSL

#define REFLCAP_SHARED_BEGIN
#define REFLCAP_SHARED_END
#define REFLCAP_CONST(type, name, value) const type name = value
#define REFLCAP_STD430_SIZE(type, bytes)
#define REFLCAP_STD430_OFFSET(type, member, bytes)

#endif  // __cplusplus

#endif  // REFLCAP_SHADERS_SHARED_INTEROP_H_
