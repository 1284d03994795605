#version 430 core
// §4.4 per-sample extents of a cluster's reflected rays, seen from a centre c in a
// frame (A, B, Z): AABBs (tangent units u = (X-c)·A / (X-c)·Z) of the clipped ray
// start and end points (glossy: end points of the lobe boundary too), the range of
// start depths z = (P-c)·Z, the min clipped start depth, the max clipped end depth
// and (stage 1) the mean projected spacing of neighbouring samples.
// Stage 0: c = e0, frame = fitting plane basis (d_n, d_f of eq. 6);
// stage 1: c = e_c, frame = the cluster camera (image rectangle, far, resolution).
// Reduction: each invocation first reduces its own rays (1, or 9 for glossy) into
// a record in registers; the records of the workgroup's cluster (the first one met
// in the tile) are combined in shared memory, those of another cluster go straight
// to its global record, and the combined one goes to the global record once.
// Combining: with EXTENT_TREE (a GPU: gl_passes.cluster_camera), a tree of
// log2(256) steps over the records, no atomics (NVIDIA spent most of this pass on
// 256 invocations' atomics on the same shared words); else one atomic per record
// word (llvmpipe, where barriers cost more than those atomics). Integer words: the
// result is the same either way.
layout(local_size_x = 16, local_size_y = 16) in;
#include "reflect_common.glsl"
layout(binding = UNIT_u_bins) uniform usampler2D u_bins;
layout(binding = UNIT_u_tri) uniform usampler2D u_tri;
layout(binding = UNIT_u_normal) uniform sampler2D u_normal;
layout(binding = UNIT_u_position) uniform sampler2D u_position;
uniform vec3 u_eye;
uniform int u_stage;
layout(std430, binding = UNIT_Ext) buffer Ext { uint ext[]; };
#define STRIDE 16u
#define MAXTAN 20.0
#define SPACING_FIXED 268435456.0
#define WORKGROUP 256u
#ifdef EXTENT_TREE
shared uint s_rec[WORKGROUP * STRIDE];
#else
shared uint s_ext[STRIDE];
#endif
shared int s_cid;
uint g_rec[STRIDE];  // this invocation's record (words as the global record's)

bool is_min_word(uint k) { return k == 0u || k == 1u || k == 4u || k == 5u || k == 8u || k == 10u; }
bool is_max_word(uint k) { return k == 2u || k == 3u || k == 6u || k == 7u || k == 9u || k == 11u; }
void amin(uint k, uint v) { g_rec[k] = min(g_rec[k], v); }
void amax(uint k, uint v) { g_rec[k] = max(g_rec[k], v); }
void add64(uint k, uint v) { uint o = g_rec[k]; g_rec[k] = o + v; if (o + v < o) g_rec[k + 1u] += 1u; }

// A record's words into the global record of cluster gb / STRIDE, one atomic each
// where the word is not the identity.
void flush_global(uint gb, uint k, uint v, uint hi) {
    if (is_min_word(k)) { if (v != 0xFFFFFFFFu) atomicMin(ext[gb + k], v); }
    else if (is_max_word(k)) { if (v != 0u) atomicMax(ext[gb + k], v); }
    else if (k == 12u) {
        uint o = atomicAdd(ext[gb + 12u], v);
        hi += o + v < o ? 1u : 0u;
        if (hi != 0u) atomicAdd(ext[gb + 13u], hi);
    } else if (k == 14u && v != 0u) atomicAdd(ext[gb + 14u], v);
}

// Per-invocation extents of the sample's rays, reduced in registers first.
vec4 g_box[2];   // (umin, vmin, umax, vmax) of start / end points
vec2 g_z;        // (min clipped start depth, max clipped end depth)
bool g_any;

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

vec2 project_uv(vec3 X, ClusterFrame F) {
    vec3 q = X - F.c_near.xyz;
    float z = max(dot(q, F.fwd_half.xyz), 1e-30);
    return vec2(dot(q, F.right_far.xyz), dot(q, F.up_len.xyz)) / z;
}

void main() {
    uint t = gl_LocalInvocationIndex;
    for (uint k = 0u; k < STRIDE; ++k) g_rec[k] = is_min_word(k) ? 0xFFFFFFFFu : 0u;
#ifndef EXTENT_TREE
    if (t < STRIDE) s_ext[t] = g_rec[t];
#endif
    if (t == 0u) s_cid = -1;
    barrier();
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    ivec2 size = textureSize(u_bins, 0);
    uint bin = all(lessThan(p, size)) ? texelFetch(u_bins, p, 0).r : 0u;
    int cid = bin > 0u ? remap[bin - 1u] : -1;
    if (cid >= 0) atomicCompSwap(s_cid, -1, cid);
    barrier();
    if (cid >= 0) {
        ClusterFrame F = frames[cid];
        vec3 P = texelFetch(u_position, p, 0).xyz;
        vec3 n = normalize(texelFetch(u_normal, p, 0).xyz);
        vec3 ng = geom_normal(texelFetch(u_tri, p, 0).r);
        vec3 r = mirror_dir(normalize(P - u_eye), n, ng);
        float zp = dot(P - F.c_near.xyz, F.fwd_half.xyz);
        amin(8u, f2o(zp)); amax(9u, f2o(zp));
        g_box[0] = g_box[1] = vec4(3.0e38, 3.0e38, -3.0e38, -3.0e38);
        g_z = vec2(3.0e38, -3.0e38);
        g_any = false;
        accum_ray(P, r, F, true);
        float half_angle = F.fwd_half.w;
        if (half_angle > 0.0) {
            for (int k = 0; k < 8; ++k) {
                float a = float(k) * 0.78539816339;
                accum_ray(P, lift_above(lobe_dir(r, half_angle, vec2(cos(a), sin(a))), ng), F, true);
            }
        }
        flush_rays();
        if (u_stage == 1 && zp > 0.0) {
            vec2 uv = project_uv(P, F);
            for (int k = 0; k < 2; ++k) {
                ivec2 q = p + (k == 0 ? ivec2(1, 0) : ivec2(0, 1));
                if (any(greaterThanEqual(q, size)) || texelFetch(u_bins, q, 0).r != bin) continue;
                vec3 Pq = texelFetch(u_position, q, 0).xyz;
                if (dot(Pq - F.c_near.xyz, F.fwd_half.xyz) <= 0.0) continue;
                float dist = min(length(project_uv(Pq, F) - uv), 15.0);
                add64(12u, uint(dist * SPACING_FIXED + 0.5));
                g_rec[14] += 1u;
            }
        }
        if (cid != s_cid) {  // another cluster than the workgroup's: straight to its record
            for (uint k = 0u; k < STRIDE; ++k) if (k != 13u) flush_global(uint(cid) * STRIDE, k, g_rec[k], g_rec[13]);
            for (uint k = 0u; k < STRIDE; ++k) g_rec[k] = is_min_word(k) ? 0xFFFFFFFFu : 0u;
        }
    }
    if (s_cid < 0) return;  // uniform across the workgroup
#ifdef EXTENT_TREE
    for (uint k = 0u; k < STRIDE; ++k) s_rec[t * STRIDE + k] = g_rec[k];
    memoryBarrierShared();
    barrier();
    for (uint half_n = WORKGROUP / 2u; half_n > 0u; half_n /= 2u) {
        if (t < half_n) {
            uint a = t * STRIDE, b = (t + half_n) * STRIDE;
            for (uint k = 0u; k < 12u; ++k)
                s_rec[a + k] = is_min_word(k) ? min(s_rec[a + k], s_rec[b + k]) : max(s_rec[a + k], s_rec[b + k]);
            uint lo = s_rec[a + 12u], add = s_rec[b + 12u];
            s_rec[a + 12u] = lo + add;
            s_rec[a + 13u] += s_rec[b + 13u] + (lo + add < lo ? 1u : 0u);
            s_rec[a + 14u] += s_rec[b + 14u];
        }
        memoryBarrierShared();
        barrier();
    }
    if (t < STRIDE && t != 13u) flush_global(uint(s_cid) * STRIDE, t, s_rec[t], s_rec[13]);
#else
    if (cid == s_cid) {
        for (uint k = 0u; k < 12u; ++k) {
            if (is_min_word(k)) { if (g_rec[k] != 0xFFFFFFFFu) atomicMin(s_ext[k], g_rec[k]); }
            else if (g_rec[k] != 0u) atomicMax(s_ext[k], g_rec[k]);
        }
        if (g_rec[14] != 0u) {
            uint o = atomicAdd(s_ext[12], g_rec[12]);
            atomicAdd(s_ext[13], g_rec[13] + (o + g_rec[12] < o ? 1u : 0u));
            atomicAdd(s_ext[14], g_rec[14]);
        }
    }
    memoryBarrierShared();
    barrier();
    if (t < STRIDE && t != 13u) flush_global(uint(s_cid) * STRIDE, t, s_ext[t], s_ext[13]);
#endif
}
