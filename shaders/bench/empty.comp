#version 460
// Does nothing: bench/gpu/gpu_bench.cc times dispatches of it to measure the fixed cost of a
// dispatch and of a submit + fence wait.
//
// Bindings (set 0): 0 = uint[] (unused; bound so that the dispatch pays for a descriptor set like
//                   a real kernel does).
// Push constants:   none.
// Specialization:   constant_id 0 = local_size_x (default 64).
// C++ twin:         none.
layout(local_size_x = 64, local_size_x_id = 0) in;

layout(std430, set = 0, binding = 0) buffer Data { uint data[]; };

void main() {}
