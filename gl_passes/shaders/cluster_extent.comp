#version 430 core
// §4.4 per-sample extents of a cluster's reflected rays, seen from a centre c in a
// frame (A, B, Z): AABBs (tangent units u = (X-c)·A / (X-c)·Z) of the clipped ray
// start and end points (glossy: end points of the lobe boundary too), the range of
// start depths z = (P-c)·Z, the min clipped start depth, the max clipped end depth
// and (stage 1) the mean projected spacing of neighbouring samples.
// Stage 0: c = e0, frame = fitting plane basis (d_n, d_f of eq. 6), the mirror rays
// only (its extents only place e_c: the lobe's rim is left to stage 1), and of a
// dense cluster one sample per output pixel (stage0_frames); stage 1: c = e_c,
// frame = the cluster camera (image rectangle, far, resolution), every sample and
// its lobe's rim. EXTENT_STAGE (0 or 1) is compiled in.
// Reduction: each invocation first reduces its own rays (1, or 9 for glossy) in
// registers, then one set of atomics into the workgroup's shared record (or the
// global one for samples of another cluster), then one per workgroup into the
// global record. Stage 1: one invocation per listed reflective sample
// (reflective_list.glsl); stage 0: one work group per listed tile, one invocation
// per output pixel whose first sub-sample (SS, the supersampling factor, compiled
// in) lies in the tile: that sub-sample, and the pixel's others where the first is
// not in a dense cluster (a fixed set of samples, and stage 0 reduces by min and max
// only: the same extents whatever order the list's tiles came in). With
// SAMPLE_RUN > 1 (a CPU rasteriser: gl_passes.cluster_camera), either stage takes
// SAMPLE_RUN consecutive listed samples per invocation (stage 0 skipping the
// samples of a pixel whose first sub-sample is in a dense cluster, but that one:
// the same set), reduced in registers while they share a cluster, whose frame is
// read once, and added to its global record once per cluster met (no shared
// record, no barriers: on llvmpipe every atomic and barrier of an invocation costs
// as much as several texel fetches, bench/results/host_costs.md).
#if SAMPLE_RUN > 1
layout(local_size_x = RUN_GROUP) in;  // 256 / SAMPLE_RUN (gl_passes.cluster_camera)
#elif EXTENT_STAGE == 0  // TILE_PIXELS: max(ceil(TILE / SS), 4), at least STRIDE invocations for the flush
layout(local_size_x = TILE_PIXELS, local_size_y = TILE_PIXELS) in;
#else
layout(local_size_x = 256) in;
#endif
#include "reflect_common.glsl"
#include "reflective_list.glsl"
layout(binding = UNIT_u_bins) uniform usampler2D u_bins;
layout(binding = UNIT_u_tri) uniform usampler2D u_tri;
layout(binding = UNIT_u_normal) uniform sampler2D u_normal;
layout(binding = UNIT_u_position) uniform sampler2D u_position;
uniform vec3 u_eye;
layout(std430, binding = UNIT_Ext) buffer Ext { uint ext[]; };
#define STRIDE 16u
#define MAXTAN 20.0
#define SPACING_FIXED 268435456.0
#define D45 0.70710678118654752
const vec2 LOBE_RIM[8] = vec2[8](vec2(1.0, 0.0), vec2(D45, D45), vec2(0.0, 1.0), vec2(-D45, D45), vec2(-1.0, 0.0),
                                 vec2(-D45, -D45), vec2(0.0, -1.0), vec2(D45, -D45));
shared uint s_ext[STRIDE];
shared int s_cid;
bool g_local;
uint g_base;

void amin(uint k, uint v) { if (g_local) atomicMin(s_ext[k], v); else atomicMin(ext[g_base + k], v); }
void amax(uint k, uint v) { if (g_local) atomicMax(s_ext[k], v); else atomicMax(ext[g_base + k], v); }
void add64(uint k, uint v) {
    if (g_local) { uint o = atomicAdd(s_ext[k], v); if (o + v < o) atomicAdd(s_ext[k + 1u], 1u); }
    else { uint o = atomicAdd(ext[g_base + k], v); if (o + v < o) atomicAdd(ext[g_base + k + 1u], 1u); }
}

// Per-invocation extents, reduced in registers over the sample's rays and flushed
// with one set of atomics (atomics are the cost of this pass on a CPU rasteriser).
vec4 g_box[2];   // (umin, vmin, umax, vmax) of start / end points
vec2 g_z;        // (min clipped start depth, max clipped end depth)
bool g_any;
vec2 g_zp;       // (min, max) start depth of the samples, clipped or not
uint g_sp_lo, g_sp_hi, g_pairs;  // stage 1: projected spacing sum (64-bit fixed point) and pair count

void reset_record() {
    g_box[0] = g_box[1] = vec4(3.0e38, 3.0e38, -3.0e38, -3.0e38);
    g_z = vec2(3.0e38, -3.0e38);
    g_any = false;
    g_zp = vec2(3.0e38, -3.0e38);
    g_sp_lo = g_sp_hi = g_pairs = 0u;
}

void accum_point(vec3 X, int slot, ClusterFrame F) {
    vec3 q = X - F.c_near.xyz;
    float z = max(dot(q, F.fwd_half.xyz), 1e-30);
    vec2 uv = clamp(vec2(dot(q, F.right_far.xyz), dot(q, F.up_len.xyz)) / z, -MAXTAN, MAXTAN);
    g_box[slot] = vec4(min(g_box[slot].xy, uv), max(g_box[slot].zw, uv));
}

// Clip P + t·d, t in [0, len], to the clip plane and to depth >= near. False if empty.
bool clip_ray(vec3 P, vec3 d, ClusterFrame F, out float t0, out float t1) {
    t0 = 0.0; t1 = F.up_len.w;
    float a = dot(F.plane.xyz, P) - F.plane.w, da = dot(F.plane.xyz, d);
    if (abs(da) > 1e-12) { float t = -a / da; if (da > 0.0) t0 = max(t0, t); else t1 = min(t1, t); }
    else if (a < 0.0) return false;
    float z = dot(P - F.c_near.xyz, F.fwd_half.xyz) - F.c_near.w, dz = dot(d, F.fwd_half.xyz);
    if (abs(dz) > 1e-12) { float t = -z / dz; if (dz > 0.0) t0 = max(t0, t); else t1 = min(t1, t); }
    else if (z < 0.0) return false;
    return t0 < t1;
}

void accum_ray(vec3 P, vec3 d, ClusterFrame F, bool with_start) {
    float t0, t1;
    if (!clip_ray(P, d, F, t0, t1)) return;
    vec3 S = P + t0 * d, E = P + t1 * d;
    if (with_start) accum_point(S, 0, F);
    accum_point(E, 1, F);
    vec3 Z = F.fwd_half.xyz, c = F.c_near.xyz;
    g_z = vec2(min(g_z.x, dot(S - c, Z)), max(g_z.y, max(dot(E - c, Z), dot(S - c, Z))));
    g_any = true;
}

void flush_rays() {
    if (!g_any) return;
    for (int b = 0; b < 2; ++b) {
        uint slot = uint(4 * b);
        if (g_box[b].x <= g_box[b].z) {
            amin(slot, f2o(g_box[b].x)); amin(slot + 1u, f2o(g_box[b].y));
            amax(slot + 2u, f2o(g_box[b].z)); amax(slot + 3u, f2o(g_box[b].w));
        }
    }
    amin(10u, f2o(g_z.x));
    amax(11u, f2o(g_z.y));
}

// The record's atomics (amin, amax, add64: into the shared or the global record).
void flush_record() {
    if (g_zp.x <= g_zp.y) { amin(8u, f2o(g_zp.x)); amax(9u, f2o(g_zp.y)); }
    flush_rays();
    if (g_pairs > 0u) {
        add64(12u, g_sp_lo);
        if (g_local) { atomicAdd(s_ext[13], g_sp_hi); atomicAdd(s_ext[14], g_pairs); }
        else { atomicAdd(ext[g_base + 13u], g_sp_hi); atomicAdd(ext[g_base + 14u], g_pairs); }
    }
}

vec2 project_uv(vec3 X, ClusterFrame F) {
    vec3 q = X - F.c_near.xyz;
    float z = max(dot(q, F.fwd_half.xyz), 1e-30);
    return vec2(dot(q, F.right_far.xyz), dot(q, F.up_len.xyz)) / z;
}

// The cluster of a sample's bin + 1 (-1: not reflective or no cluster).
int bin_cluster(uint bin) { return bin > 0u ? remap[bin - 1u] : -1; }

// Sample p's extents (its rays, start depth and, stage 1, projected spacing) added
// to the record in registers (reset_record, flush_record) of its cluster, whose
// frame is F (bin: its u_bins value).
void extent_sample(ivec2 p, uint bin, ClusterFrame F, ivec2 size) {
    vec3 P = texelFetch(u_position, p, 0).xyz;
    vec3 n = normalize(texelFetch(u_normal, p, 0).xyz);
    vec3 ng = geom_normal(texelFetch(u_tri, p, 0).r);
    vec3 r = mirror_dir(normalize(P - u_eye), n, ng);
    float zp = dot(P - F.c_near.xyz, F.fwd_half.xyz);
    g_zp = vec2(min(g_zp.x, zp), max(g_zp.y, zp));
    accum_ray(P, r, F, true);
#if EXTENT_STAGE == 1
    float half_angle = F.fwd_half.w;
    if (half_angle > 0.0) {
        // The lobe's rim (lobe_dir at rho = 1, every 45°), its frame and tilt
        // worked out once for the eight rays.
        vec3 t1, t2;
        lobe_frame(r, t1, t2);
        float tilt = tan(half_angle);
        t1 *= tilt;
        t2 *= tilt;
        for (int k = 0; k < 8; ++k)
            accum_ray(P, lift_above(normalize(r + LOBE_RIM[k].x * t1 + LOBE_RIM[k].y * t2), ng), F, true);
    }
#endif
#if EXTENT_STAGE == 1
    if (zp > 0.0) {
        vec2 uv = project_uv(P, F);
        for (int k = 0; k < 2; ++k) {
            ivec2 q = p + (k == 0 ? ivec2(1, 0) : ivec2(0, 1));
            if (any(greaterThanEqual(q, size)) || texelFetch(u_bins, q, 0).r != bin) continue;
            vec3 Pq = texelFetch(u_position, q, 0).xyz;
            if (dot(Pq - F.c_near.xyz, F.fwd_half.xyz) <= 0.0) continue;
            float dist = min(length(project_uv(Pq, F) - uv), 15.0);
            uint v = uint(dist * SPACING_FIXED + 0.5), lo = g_sp_lo;
            g_sp_lo += v;
            if (g_sp_lo < lo) g_sp_hi += 1u;
            g_pairs += 1u;
        }
    }
#endif
}

// One sample's record into the shared record of the work group's cluster or the
// global one of another cluster.
void extent_one(ivec2 p, uint bin, int cid, ivec2 size) {
    g_local = cid == s_cid;
    g_base = uint(cid) * STRIDE;
    reset_record();
    extent_sample(p, bin, frames[cid], size);
    flush_record();
}

#if SAMPLE_RUN > 1
void main() {
    ivec2 size = textureSize(u_bins, 0);
    g_local = false;
    int cur = -1;  // the cluster of the record in registers (reset when it changes), and its frame
    ClusterFrame F;
    for (uint r = 0u; r < uint(SAMPLE_RUN); ++r) {
        uint i = gl_GlobalInvocationID.x * uint(SAMPLE_RUN) + r;
        if (i >= n_samples) break;
        ivec2 p = list_sample(i);
        uint bin = texelFetch(u_bins, p, 0).r;
        int cid = bin_cluster(bin);
        if (cid < 0) continue;
#if EXTENT_STAGE == 0
        ivec2 first = p / SS * SS;  // its pixel's first sub-sample
        if (p != first) {
            int cf = bin_cluster(texelFetch(u_bins, first, 0).r);
            if (cf >= 0 && frames[cf].misc.y <= 0.0) continue;  // a dense cluster's: that one alone
        }
#endif
        if (cid != cur) {
            if (cur >= 0) flush_record();
            cur = cid;
            g_base = uint(cid) * STRIDE;
            F = frames[cid];
            reset_record();
        }
        extent_sample(p, bin, F, size);
    }
    if (cur >= 0) flush_record();
}
#else
void main() {
    if (gl_LocalInvocationIndex < STRIDE) {
        uint k = gl_LocalInvocationIndex;
        bool is_min = k == 0u || k == 1u || k == 4u || k == 5u || k == 8u || k == 10u;
        bool is_max = k == 2u || k == 3u || k == 6u || k == 7u || k == 9u || k == 11u;
        s_ext[k] = is_min ? 0xFFFFFFFFu : 0u;
    }
    if (gl_LocalInvocationIndex == 0u) s_cid = -1;
    barrier();
    ivec2 size = textureSize(u_bins, 0);
#if EXTENT_STAGE == 0
    ivec2 t0 = list_tile() * TILE, t1 = min(t0 + TILE, size);
    ivec2 p = (t0 + SS - 1) / SS * SS + ivec2(gl_LocalInvocationID.xy) * SS;  // a pixel's first sub-sample
    bool listed = all(lessThan(p, t1));
#else
    uint i = gl_GlobalInvocationID.x;
    bool listed = i < n_samples;
    ivec2 p = listed ? list_sample(i) : ivec2(0);
#endif
    uint bin = listed ? texelFetch(u_bins, p, 0).r : 0u;
    int cid = bin_cluster(bin);
    if (cid >= 0) atomicCompSwap(s_cid, -1, cid);
    barrier();
    if (cid >= 0) extent_one(p, bin, cid, size);
#if EXTENT_STAGE == 0
    // A pixel whose first sub-sample lies in no cluster or in a sparse one (misc.y,
    // stage0_frames) adds its other sub-samples of whatever cluster.
    if (listed && (cid < 0 || frames[cid].misc.y > 0.0)) {
        for (int j = 0; j < SS; ++j) for (int i = 0; i < SS; ++i) {
            ivec2 q = p + ivec2(i, j);
            if (i + j == 0 || any(greaterThanEqual(q, size))) continue;
            uint bq = texelFetch(u_bins, q, 0).r;
            int cq = bin_cluster(bq);
            if (cq >= 0) extent_one(q, bq, cq, size);
        }
    }
#endif
    barrier();
    if (s_cid >= 0 && gl_LocalInvocationIndex < STRIDE) {
        uint k = gl_LocalInvocationIndex, gb = uint(s_cid) * STRIDE;
        uint v = s_ext[k];
        bool is_min = k == 0u || k == 1u || k == 4u || k == 5u || k == 8u || k == 10u;
        bool is_max = k == 2u || k == 3u || k == 6u || k == 7u || k == 9u || k == 11u;
        if (is_min) { if (v != 0xFFFFFFFFu) atomicMin(ext[gb + k], v); }
        else if (is_max) { if (v != 0u) atomicMax(ext[gb + k], v); }
        else if (k == 12u) { uint o = atomicAdd(ext[gb + 12u], v); atomicAdd(ext[gb + 13u], s_ext[13] + (o + v < o ? 1u : 0u)); }
        else if (k == 14u) atomicAdd(ext[gb + 14u], v);
    }
}
#endif
