#version 430 core
// Every reflective sample's label becomes its component's root, and the root's
// count gains the sample.
layout(local_size_x = 16, local_size_y = 16) in;
#include "cluster_labels.glsl"
layout(std430, binding = UNIT_CompCount) buffer CompCount { uint comp_count[]; };
uniform ivec2 u_size;

void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    if (any(greaterThanEqual(p, u_size))) return;
    uint idx = uint(p.y * u_size.x + p.x);
    if (labels[idx] == NONE) return;
    uint root = find_root(idx);
    labels[idx] = root;
    atomicAdd(comp_count[root], 1u);
}
