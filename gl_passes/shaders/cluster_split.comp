#version 430 core
// Components of at least u_min_samples samples become clusters of their own:
// their root appends (root, raw bin, samples) to the list and marks its count
// entry with SPLIT | list index; the samples of smaller components stay in their
// raw bin's cluster (comp entry 0).
layout(local_size_x = 256) in;  // one invocation per listed reflective sample
#include "cluster_labels.glsl"
#include "reflective_list.glsl"
layout(std430, binding = UNIT_CompCount) buffer CompCount { uint comp_count[]; };
layout(std430, binding = UNIT_SplitList) buffer SplitList { uint n_split; uint split[]; };  // 3 per entry
layout(binding = UNIT_u_bins) uniform usampler2D u_bins;  // raw bin + 1
uniform uint u_min_samples;
uniform uint u_capacity;
#define SPLIT 0x80000000u

void main() {
    if (gl_GlobalInvocationID.x >= n_samples) return;
    ivec2 p = list_sample(gl_GlobalInvocationID.x);
    ivec2 size = textureSize(u_bins, 0);
    uint idx = uint(p.y * size.x + p.x);
    if (labels[idx] != idx) return;  // not a root (or not reflective)
    uint c = comp_count[idx];
    uint mark = 0u;
    if (c >= u_min_samples) {
        uint k = atomicAdd(n_split, 1u);
        if (k < u_capacity) {
            split[3u * k] = idx;
            split[3u * k + 1u] = texelFetch(u_bins, p, 0).r - 1u;
            split[3u * k + 2u] = c;
            mark = SPLIT | k;
        }
    }
    comp_count[idx] = mark;
}
