#version 430 core
// Every reflective sample's label becomes its component's root, and the root's
// count gains the sample.
layout(local_size_x = 256) in;  // one invocation per listed reflective sample
#include "cluster_labels.glsl"
#include "reflective_list.glsl"
layout(std430, binding = UNIT_CompCount) buffer CompCount { uint comp_count[]; };
uniform ivec2 u_size;

void main() {
    if (gl_GlobalInvocationID.x >= n_samples) return;
    ivec2 p = list_sample(gl_GlobalInvocationID.x);
    uint idx = uint(p.y * u_size.x + p.x);
    if (labels[idx] == NONE) return;
    uint root = find_root(idx);
    labels[idx] = root;
    atomicAdd(comp_count[root], 1u);
}
