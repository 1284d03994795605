#version 430 core
// Union of every reflective sample with its left and upper neighbour when both
// lie in the same raw bin and their mirror normals differ by at most the break
// angle (cos u_cos_break): the normal field is continuous between them. Their
// components are the clusters' candidates (cluster_split.comp).
layout(local_size_x = 16, local_size_y = 16) in;
#include "cluster_labels.glsl"
layout(binding = UNIT_u_bins) uniform usampler2D u_bins;      // raw bin + 1 (0 = not reflective)
layout(binding = UNIT_u_mnormal) uniform sampler2D u_mnormal;  // mirror normal
uniform float u_cos_break;

void unite(uint a, uint b) {
    for (;;) {
        a = find_root(a); b = find_root(b);
        if (a == b) return;
        uint hi = max(a, b), lo = min(a, b);
        uint old = atomicMin(labels[hi], lo);
        if (old == hi) return;  // linked
        a = old; b = lo;        // hi was linked elsewhere meanwhile: unite its new parent
    }
}

void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    ivec2 size = textureSize(u_bins, 0);
    if (any(greaterThanEqual(p, size))) return;
    uint bin = texelFetch(u_bins, p, 0).r;
    if (bin == 0u) return;
    vec3 n = texelFetch(u_mnormal, p, 0).xyz;
    uint idx = uint(p.y * size.x + p.x);
    for (int k = 0; k < 2; ++k) {
        ivec2 q = p - (k == 0 ? ivec2(1, 0) : ivec2(0, 1));
        if (q.x < 0 || q.y < 0 || texelFetch(u_bins, q, 0).r != bin) continue;
        if (dot(n, texelFetch(u_mnormal, q, 0).xyz) < u_cos_break) continue;
        unite(idx, uint(q.y * size.x + q.x));
    }
}
