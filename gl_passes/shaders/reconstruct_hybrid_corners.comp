#version 430 core
// Hybrid reconstruction, pass 2 of 3 (Alg. 4): one shared vertex per H corner that
// some sample takes (its position and colour are H's sample there); its vertex
// index replaces the mark in u_corner_index.
#include "reconstruct_common.glsl"

layout(rgba32ui, binding = UNIT_u_h_a) uniform readonly uimage2D u_h_a;
layout(rgba32ui, binding = UNIT_u_h_b) uniform readonly uimage2D u_h_b;
layout(r32ui, binding = UNIT_u_corner_index) uniform uimage2D u_corner_index;

void main() {
    ivec2 c = ivec2(gl_GlobalInvocationID.xy);
    if (any(greaterThan(c, u_size))) return;  // H is (W+1)×(H+1)
    if (imageLoad(u_corner_index, c).r == 0u) return;
    Sample h = load_sample(imageLoad(u_h_a, c), imageLoad(u_h_b, c));
    uint index = atomicAdd(n_vertices, 1u);
    emit_vertex(index, h.position, h.rgba);
    imageStore(u_corner_index, c, uvec4(index));
}
