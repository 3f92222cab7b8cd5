#version 460
// Transforms one bound chunk of a large array in place, for the chunked-binding test
// (tests/engine/gpu/buffer_test.cc): data[i] = data[i] * kChunkProbeMultiplier +
// (first_element + i) for i < count, with wrap-around uint arithmetic.
//
// Bindings (set 0): 0 = uint[] (read-write), bound at the chunk's byte offset, <= the device's
//                   maxStorageBufferRange.
// Push constants:   ChunkProbePush {first_element, count} (shared/chunk_probe.h).
// Specialization:   constant_id 0 = local_size_x (default 64).
// C++ twin:         the test's expected-value formula.
#extension GL_GOOGLE_include_directive : require

#include "shared/chunk_probe.h"

layout(local_size_x = 64, local_size_x_id = 0) in;

layout(std430, set = 0, binding = 0) buffer Data { uint data[]; };
layout(push_constant) uniform Push { ChunkProbePush push; };

void main() {
  uint i = gl_GlobalInvocationID.x;
  if (i >= push.count) return;
  data[i] = data[i] * kChunkProbeMultiplier + (push.first_element + i);
}
