#version 430 core
// Depth images (thesis Ch. 2): conventional, non-redundant with the pixel
// redundancy test (Alg. 1 + Alg. 3), or one depth-peeling layer (§2.3.1).
// Mode by #define: (none) = conventional; NON_REDUNDANT with N_PREV = i for
// image i (a constant, so the test loop unrolls and sampler indices are
// constant), optionally FOOTPRINT = f and OCCLUDED_MARGIN = m (the footprint
// diagnostics of DepthImageRenderer); PEEL. The triangle id comes from gl_PrimitiveID (no
// geometry shader) unless TRI_FROM_GEOM (depth_image.geom). A discarded fragment writes
// no depth, so the depth test keeps the nearest fragment that passed the test
// (Alg. 1: "if s is not redundant write s").
#include "common.glsl"

uniform vec3 u_albedo;
uniform uint u_base;
in Frag {
    vec3 position;
    vec3 normal;
    float depth;
#if defined(NON_REDUNDANT) && defined(VS_PROJECT)
    vec4 prev[N_PREV];  // this fragment in I_j's texel-space clip coordinates
#endif
} f;
#ifdef TRI_FROM_GEOM
flat in uint g_tri;
#define TRIANGLE_ID g_tri
#else
#define TRIANGLE_ID (u_base + uint(gl_PrimitiveID) + 1u)
#endif

#ifdef NON_REDUNDANT
// Previous images I_j, j < N_PREV: triangle-id textures (element j on unit
// UNIT_u_prev_id0 + j, gl_passes.depth_images.nr_units) and the world →
// texel-space clip matrices T_j = S_j·VP_j (S_j maps NDC xy to [0, size]).
layout(binding = UNIT_u_prev_id0) uniform usampler2D u_prev_id[N_PREV];
uniform vec2 u_prev_size[N_PREV];
#ifdef OCCLUDED_MARGIN
layout(binding = UNIT_u_prev_depth0) uniform sampler2D u_prev_depth[N_PREV];  // I_j's eye-space depths
#endif
#ifndef VS_PROJECT
uniform mat4 u_prev_texel[N_PREV];
#endif
#endif

#ifdef PEEL
// The previous layer (same camera): its triangle ids and linear depths.
layout(binding = UNIT_u_peel_id) uniform usampler2D u_peel_id;  // units: depth_images.PEEL_UNITS
layout(binding = UNIT_u_peel_depth) uniform sampler2D u_peel_depth;
uniform float u_peel_eps;  // relative depth margin
#endif

layout(location = 0) out vec4 out_color;
layout(location = 1) out float out_depth;
layout(location = 2) out vec4 out_normal;
layout(location = 3) out vec4 out_position;
layout(location = 4) out uint out_tri;

void main() {
    uint tri = TRIANGLE_ID;
#ifdef NON_REDUNDANT
    // Alg. 3 against every previous image: reproject into I_j, fetch, compare.
    bool redundant = false;
    for (int j = 0; j < N_PREV; ++j) {
#ifdef VS_PROJECT
        vec4 c = f.prev[j];
#else
        vec4 c = u_prev_texel[j] * vec4(f.position, 1.0);
#endif
#ifdef FOOTPRINT
        // Beyond Alg. 3 (FOOTPRINT = f pixels, ½ = the pixel's corners): the points
        // ±f px from the centre along both screen axes must land on texels of I_j
        // holding the triangle too (reprojected with the screen-space derivatives,
        // taken here in uniform control flow).
        vec2 qxy = c.xy / c.w;
        vec2 hx = FOOTPRINT * dFdx(qxy), hy = FOOTPRINT * dFdy(qxy);
#ifdef OCCLUDED_MARGIN
        float wx = FOOTPRINT * dFdx(c.w), wy = FOOTPRINT * dFdy(c.w);
#endif
#endif
        if (c.w > 0.0) {  // in front of V_j
            vec3 q = c.xyz / c.w;  // (texel x, texel y, NDC z) in I_j
            vec2 size = u_prev_size[j];
            if (all(greaterThanEqual(q.xy, vec2(0.0))) && all(lessThanEqual(q.xy, size))
                && abs(q.z) <= 1.0) {  // inside I_j's frustum
                ivec2 texel = min(ivec2(q.xy), ivec2(size) - 1);
                bool held = texelFetch(u_prev_id[j], texel, 0).r == tri;  // pixel-redundant
#ifdef FOOTPRINT
                for (int k = 0; k < 4 && held; ++k) {
                    vec2 p = q.xy + ((k & 1) == 0 ? -hx : hx) + (k < 2 ? -hy : hy);
#ifdef OCCLUDED_MARGIN
                    // occlusion seams only: a point off the triangle keeps the fragment
                    // where I_j holds another surface nearer than the point (w: its depth)
                    if (all(greaterThanEqual(p, vec2(0.0))) && all(lessThan(p, size))) {
                        uint t = texelFetch(u_prev_id[j], ivec2(p), 0).r;
                        float w = c.w + ((k & 1) == 0 ? -wx : wx) + (k < 2 ? -wy : wy);
                        held = t == tri || t == 0u
                               || texelFetch(u_prev_depth[j], ivec2(p), 0).r >= w * (1.0 - OCCLUDED_MARGIN);
                    }
#else
                    held = all(greaterThanEqual(p, vec2(0.0))) && all(lessThan(p, size))
                           && texelFetch(u_prev_id[j], ivec2(p), 0).r == tri;
#endif
                }
#endif
                redundant = redundant || held;
            }
        }
    }
    if (redundant) discard;
#endif
#ifdef PEEL
    ivec2 px = ivec2(gl_FragCoord.xy);
    uint prev = texelFetch(u_peel_id, px, 0).r;
    if (prev == 0u || prev == tri) discard;  // nothing left behind / the peeled surface
    if (f.depth <= texelFetch(u_peel_depth, px, 0).r * (1.0 + u_peel_eps)) discard;
#endif
    vec3 n = normalize(f.normal);
    if (!gl_FrontFacing) n = -n;
    out_color = vec4(local_shade(u_albedo, n), 1.0);
    out_depth = f.depth;
    out_normal = vec4(n, 0.0);
    out_position = vec4(f.position, 1.0);
    out_tri = tri;
}
