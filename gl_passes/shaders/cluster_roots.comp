#version 430 core
// Block union-find, step 3 (cluster_labels.glsl): every tile-local root (flagged
// by cluster_merge.comp) points at its component's root, and its flag is
// cleared, so that cluster_compress.comp finds every sample's root in two hops.
layout(local_size_x = 16, local_size_y = 16) in;
#include "cluster_labels.glsl"
layout(std430, binding = UNIT_CompCount) buffer CompCount { uint comp_count[]; };
uniform ivec2 u_size;

void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    if (any(greaterThanEqual(p, u_size))) return;
    uint idx = uint(p.y * u_size.x + p.x);
    if (comp_count[idx] == 0u) return;
    comp_count[idx] = 0u;
    atomicMin(labels[idx], find_root_halving(idx));
}
