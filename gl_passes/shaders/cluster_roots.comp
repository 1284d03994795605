#version 430 core
// Block union-find, step 3 (cluster_labels.glsl): every tile-local root (flagged
// by cluster_merge.comp) points at its component's root, and its flag is
// cleared, so that cluster_compress.comp finds every sample's root in two hops.
layout(local_size_x = 256) in;  // one invocation per listed reflective sample
#include "cluster_labels.glsl"
#include "reflective_list.glsl"
layout(std430, binding = UNIT_CompCount) buffer CompCount { uint comp_count[]; };
uniform ivec2 u_size;

void main() {
    if (gl_GlobalInvocationID.x >= n_samples) return;
    ivec2 p = list_sample(gl_GlobalInvocationID.x);
    uint idx = uint(p.y * u_size.x + p.x);
    if (comp_count[idx] == 0u) return;
    comp_count[idx] = 0u;
    atomicMin(labels[idx], find_root_halving(idx));
}
