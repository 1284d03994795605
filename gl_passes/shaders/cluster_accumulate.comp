#version 430 core
// Every reflective sample's segment: with u_components, n_bins + its component's
// list index when the component is split off (cluster_split.comp), else its raw
// bin; the bin image then holds segment + 1, and the segment's statistics are
// accumulated: count, position and mirror-normal sums in 64-bit fixed point
// (32-bit atomics with carry), and the range of the samples' plane offsets n·P
// (order-preserving uints: a component is planar when its normals agree and this
// range is nil). With TILE_SUMS (a GPU: gl_passes.clustering), each work group
// first sums its samples in shared memory (its 256 listed samples, neighbours on
// screen, mostly share a few segments: up to SLOTS of them, the rest straight to
// the SSBO) and adds each slot to the SSBO once, instead of every sample
// contending for its segment's words (a GPU runs the atomics on one address one
// after another). Without it (llvmpipe, whose barriers and shared atomics cost
// more than the sums save), each invocation takes SAMPLE_RUN consecutive listed
// samples (a work group the same 256, dispatched alike), sums the samples of one
// segment in registers and adds them with one set of atomics when the segment
// changes and at the end (a segment's words, added to by both of llvmpipe's
// threads at once, cost a contended atomic each: bench/results/host_costs.md).
// Integer sums: the totals are the same either way, in any order.
#ifdef TILE_SUMS
layout(local_size_x = 256) in;  // one invocation per listed reflective sample
#define RUN 1u
#else
layout(local_size_x = RUN_GROUP) in;  // 256 / SAMPLE_RUN (gl_passes.clustering)
#define RUN uint(SAMPLE_RUN)
#endif
#include "cluster_sample.glsl"
#include "cluster_labels.glsl"
#include "reflective_list.glsl"
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
#define SLOTS 8u
// A slot's words in the SSBO's layout (STRIDE per segment): count, 3 position and
// 3 normal sums as (low, high) pairs, offset minimum, offset maximum.
shared uint s_seg[SLOTS];
shared uint s_stats[SLOTS * STRIDE];

void add64_global(uint i, uint lo, uint hi) {
    uint old = atomicAdd(stats[i], lo);
    if (old + lo < old) hi += 1u;
    if (hi != 0u) atomicAdd(stats[i + 1u], hi);
}
// ADD_RECORD(A, b, n, s, sn, lo, hi): n samples with position sums s, normal sums sn
// and plane-offset range [lo, hi] into the record at A[b..b+STRIDE) of an array A
// (the SSBO or a shared slot), 64-bit sums by 32-bit atomics with carry. One
// sample: ADD_RECORD(A, b, 1u, q, qn, off, off).
#define ADD64(A, i, v) { uint o_ = atomicAdd(A[i], v); if (o_ + (v) < o_) atomicAdd(A[(i) + 1u], 1u); }
#define ADD_RECORD(A, b, n, s, sn, lo, hi) { \
    atomicAdd(A[b], n); \
    for (uint k = 0u; k < 3u; ++k) { ADD64(A, (b) + 1u + 2u * k, s[k]); ADD64(A, (b) + 7u + 2u * k, sn[k]); } \
    atomicMin(A[(b) + 13u], lo); \
    atomicMax(A[(b) + 14u], hi); \
}

void main() {
    uint t = gl_LocalInvocationIndex;
#ifdef TILE_SUMS
    if (t < SLOTS) s_seg[t] = NONE;
    for (uint k = t; k < SLOTS * STRIDE; k += gl_WorkGroupSize.x * gl_WorkGroupSize.y)
        s_stats[k] = k % STRIDE == 13u ? 0xFFFFFFFFu : 0u;
    memoryBarrierShared();
    barrier();
#endif

    ivec2 size = textureSize(u_mnormal, 0);
    // The run's sums so far, of segment cur (NONE: none yet); q sums of up to RUN
    // samples of at most 2^24 each fit 32 bits.
    uint cur = NONE, cnt = 0u, omin = 0xFFFFFFFFu, omax = 0u;
    uvec3 sq = uvec3(0u), sqn = uvec3(0u);
    for (uint r = 0u; r < RUN; ++r) {
        uint i = gl_GlobalInvocationID.x * RUN + r;
        bool listed = i < n_samples;
        ivec2 p = listed ? list_sample(i) : ivec2(0);
        uint raw = listed ? imageLoad(u_bin_image, p).r : 0u;
        if (raw == 0u) continue;
        uint seg = raw - 1u;
        if (u_components) {
            uint mark = comp_count[labels[uint(p.y * size.x + p.x)]];
            if ((mark & SPLIT) != 0u) seg = u_n_bins + (mark & ~SPLIT);
            imageStore(u_bin_image, p, uvec4(seg + 1u));
        }
        vec3 P = texelFetch(u_position, p, 0).xyz;
        vec3 n = texelFetch(u_mnormal, p, 0).xyz;
        uvec3 q = uvec3(clamp((P - u_lo) * u_inv_ext, 0.0, 1.0) * FIXED + 0.5);
        uvec3 qn = uvec3(clamp(n * 0.5 + 0.5, 0.0, 1.0) * FIXED + 0.5);
        uint off = f2o(dot(n, P));
#ifdef TILE_SUMS
        uint slot = SLOTS;  // the first slot holding seg, or the first free one
        for (uint s = 0u; s < SLOTS; ++s) {
            uint prev = atomicCompSwap(s_seg[s], NONE, seg);
            if (prev == NONE || prev == seg) { slot = s; break; }
        }
        if (slot < SLOTS) ADD_RECORD(s_stats, slot * STRIDE, 1u, q, qn, off, off)
        else ADD_RECORD(stats, seg * STRIDE, 1u, q, qn, off, off)  // more segments in this tile than slots
#else
        if (seg != cur && cur != NONE) {  // another segment: the run so far goes out
            ADD_RECORD(stats, cur * STRIDE, cnt, sq, sqn, omin, omax)
            cnt = 0u; sq = sqn = uvec3(0u); omin = 0xFFFFFFFFu; omax = 0u;
        }
        cur = seg;
        cnt += 1u; sq += q; sqn += qn; omin = min(omin, off); omax = max(omax, off);
#endif
    }
#ifndef TILE_SUMS
    if (cur != NONE) ADD_RECORD(stats, cur * STRIDE, cnt, sq, sqn, omin, omax)
#endif
#ifdef TILE_SUMS
    memoryBarrierShared();
    barrier();

    // Flush: one invocation per (slot, word group): count, the six sums, min, max.
    uint slot = t / 9u, w = t % 9u;
    if (slot >= SLOTS || s_seg[slot] == NONE) return;
    uint b = slot * STRIDE, g = s_seg[slot] * STRIDE;
    if (w == 0u) atomicAdd(stats[g], s_stats[b]);
    else if (w <= 6u) add64_global(g + 2u * w - 1u, s_stats[b + 2u * w - 1u], s_stats[b + 2u * w]);
    else if (w == 7u) atomicMin(stats[g + 13u], s_stats[b + 13u]);
    else atomicMax(stats[g + 14u], s_stats[b + 14u]);
#endif
}
