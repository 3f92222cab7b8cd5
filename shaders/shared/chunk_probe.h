// Push constants of shaders/probe/chunk_probe.comp, which transforms one bound chunk of a large
// array in place: data[i] = data[i] * kChunkProbeMultiplier + (first_element + i), i < count.
// The global index term proves that each chunk was bound at the right offset.
#ifndef REFLCAP_SHADERS_SHARED_CHUNK_PROBE_H_
#define REFLCAP_SHADERS_SHARED_CHUNK_PROBE_H_

#include "interop.h"

REFLCAP_SHARED_BEGIN

REFLCAP_CONST(uint, kChunkProbeMultiplier, 2654435761u);

struct ChunkProbePush {
  uint first_element;  // index in the whole array of the binding's element 0
  uint count;          // elements in this chunk
};
REFLCAP_STD430_SIZE(ChunkProbePush, 8);

REFLCAP_SHARED_END

#endif  // REFLCAP_SHADERS_SHARED_CHUNK_PROBE_H_
