// Evidence of the earlier images of a set (beyond Alg. 4): a tangent-plane corner x
// of a sample s of image I_i is pulled toward s when an earlier image I_j (j < i)
// saw past x — its texel at x's projection holds nothing (and I_j is complete: a
// conventional image, or the set's first image) or a sample more than u_e_tol of
// I_j's pixel footprints farther than x — and no earlier image holds a sample at
// x's depth there. I_j's ray through that texel's centre missed s's surface, so the
// surface's edge lies between s and that ray: x moves to the middle of s and the
// point of the segment s→x nearest to that ray (in I_j's image), the expected
// position of the edge. Up to MAX_EVIDENCE earlier images, all of I's size, as the
// layers of u_evidence (the A words of reconstruct_common.glsl).
#define MAX_EVIDENCE 15
layout(rgba32ui, binding = UNIT_u_evidence) uniform readonly uimage2DArray u_evidence;
uniform int u_n_evidence;
uniform vec3 u_e_eye[MAX_EVIDENCE];
uniform vec3 u_e_forward[MAX_EVIDENCE];
uniform vec3 u_e_right[MAX_EVIDENCE];   // right × tan(fov/2)·aspect of I_j
uniform vec3 u_e_up[MAX_EVIDENCE];      // up × tan(fov/2) of I_j
uniform int u_e_complete[MAX_EVIDENCE]; // 1: an empty texel is a miss (not a redundant sample)
uniform float u_e_footprint[MAX_EVIDENCE];
uniform float u_e_tol;

// (pixel x, pixel y (row 0 = top), eye depth) of world point x in evidence image j.
vec3 evidence_project(int j, vec3 x) {
    vec3 v = x - u_e_eye[j];
    float z = dot(v, u_e_forward[j]);
    vec2 ndc = vec2(dot(v, u_e_right[j]) / dot(u_e_right[j], u_e_right[j]),
                    dot(v, u_e_up[j]) / dot(u_e_up[j], u_e_up[j])) / z;
    vec2 size = vec2(imageSize(u_evidence).xy);
    return vec3((ndc.x + 1.0) * 0.5 * size.x, (1.0 - ndc.y) * 0.5 * size.y, z);
}

// The fraction of the way from sample position sp to corner x the corner keeps (1: x).
float evidence_keep(vec3 sp, vec3 x) {
    bool held = false;
    bool past = false;
    float t_min = 1.0;
    ivec2 size = imageSize(u_evidence).xy;
    for (int j = 0; j < u_n_evidence; ++j) {
        vec3 px = evidence_project(j, x);
        if (px.z <= 0.0 || any(lessThan(px.xy, vec2(0.0))) || any(greaterThanEqual(px.xy, vec2(size)))) continue;
        ivec2 texel = ivec2(floor(px.xy));
        uvec4 a = imageLoad(u_evidence, ivec3(texel, j));
        if (a.w == 0u) {
            if (u_e_complete[j] == 0) continue;  // redundant samples or a miss: no evidence
        } else {
            float zq = dot(uintBitsToFloat(a.xyz) - u_e_eye[j], u_e_forward[j]);
            if (abs(zq - px.z) <= u_e_tol * u_e_footprint[j] * px.z) { held = true; continue; }
            if (zq < px.z) continue;  // occluded in I_j: no evidence
        }
        past = true;
        vec2 ps = evidence_project(j, sp).xy;
        vec2 d = px.xy - ps;
        vec2 miss = vec2(texel) + 0.5;  // I_j's ray that missed the surface
        t_min = min(t_min, dot(d, d) > 1e-12 ? clamp(dot(miss - ps, d) / dot(d, d), 0.0, 1.0) : 1.0);
    }
    return (held || !past) ? 1.0 : 0.5 * t_min;
}
