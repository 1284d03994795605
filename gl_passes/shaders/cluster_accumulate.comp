#version 430 core
// Every reflective sample's segment: with u_components, n_bins + its component's
// list index when the component is split off (cluster_split.comp), else its raw
// bin; the bin image then holds segment + 1, and the segment's statistics are
// accumulated: count, position and mirror-normal sums in 64-bit fixed point
// (32-bit atomics with carry), and the range of the samples' plane offsets n·P
// (order-preserving uints: a component is planar when its normals agree and this
// range is nil).
layout(local_size_x = 16, local_size_y = 16) in;
#include "cluster_sample.glsl"
#include "cluster_labels.glsl"
layout(std430, binding = UNIT_CompCount) readonly buffer CompCount { uint comp_count[]; };
layout(std430, binding = UNIT_BinStats) buffer BinStats { uint stats[]; };
layout(r32ui, binding = UNIT_u_bin_image) uniform uimage2D u_bin_image;  // in: raw bin + 1, out: segment + 1
layout(binding = UNIT_u_mnormal) uniform sampler2D u_mnormal;           // mirror normal
uniform vec3 u_lo;       // position normalisation: q = (p - lo) * inv_ext in [0, 1]
uniform vec3 u_inv_ext;
uniform uint u_n_bins;
uniform bool u_components;
#define FIXED 16777216.0
#define SPLIT 0x80000000u
#define STRIDE uint(STATS_STRIDE)
void add64(uint i, uint v) {
    uint old = atomicAdd(stats[i], v);
    if (old + v < old) atomicAdd(stats[i + 1u], 1u);
}

void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    ivec2 size = textureSize(u_mnormal, 0);
    if (any(greaterThanEqual(p, size))) return;
    uint raw = imageLoad(u_bin_image, p).r;
    if (raw == 0u) return;
    uint seg = raw - 1u;
    if (u_components) {
        uint mark = comp_count[labels[uint(p.y * size.x + p.x)]];
        if ((mark & SPLIT) != 0u) seg = u_n_bins + (mark & ~SPLIT);
        imageStore(u_bin_image, p, uvec4(seg + 1u));
    }
    uint base = seg * STRIDE;
    vec3 P = texelFetch(u_position, p, 0).xyz;
    vec3 n = texelFetch(u_mnormal, p, 0).xyz;
    atomicAdd(stats[base], 1u);
    vec3 q = clamp((P - u_lo) * u_inv_ext, 0.0, 1.0) * FIXED;
    vec3 qn = clamp(n * 0.5 + 0.5, 0.0, 1.0) * FIXED;
    for (uint k = 0u; k < 3u; ++k) {
        add64(base + 1u + 2u * k, uint(q[k] + 0.5));
        add64(base + 7u + 2u * k, uint(qn[k] + 0.5));
    }
    uint off = f2o(dot(n, P));
    atomicMin(stats[base + 13u], off);
    atomicMax(stats[base + 14u], off);
}
