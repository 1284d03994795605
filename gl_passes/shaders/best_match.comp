#version 430 core
// Best reflection-pixel match (thesis §5.4.1, Alg. 9), one invocation per reflective
// keyframe pixel s (the keyframe's pixel list; the other offsets stay invalid).
// R = W + reflect(W - E_old, s.n)·s.r is the reflected point (Eq. 8). The match distance
// of a candidate pixel s_n is the distance from the new eye E_cur to the line through
// W_n and M, the mirror image of R in s_n's tangent plane (Fig. 37). A local descent
// over the 3×3 hollow neighbourhood, started at s + (previous frame's offset) when that
// is valid, moves to the neighbour of least distance while it decreases. Invalid: the
// better neighbour lies across a depth discontinuity (outside the reflector's
// silhouette), the search leaves the image, it runs out of u_max_steps, or the local
// minimum is not the minimum (its distance exceeds the largest rise to a neighbour:
// the true minimum lies more than about a pixel away, beyond the silhouette or the
// image border; the rise is taken over the reflective neighbours). Sub-pixel refinement (beyond Alg. 9's whole pixels): the point X where the
// line from E_cur to M (mirrored in s*'s tangent plane) meets that plane, projected into
// the keyframe — exact on a planar mirror, first order on curved ones; kept when within
// one pixel of s*, snapped to s* within 0.01 pixel. Output per pixel (texel units, GL orientation): (ox, oy, valid 0/1, steps).
// u_predict = 1 (beyond Alg. 9, a better start for the same descent): a search also
// resumes where the previous frame's ended when that one was invalid (at a silhouette,
// or at the step bound: a long search spreads over frames instead of restarting at s
// every frame and holding up its SIMD neighbours), and when the two previous frames'
// offsets are valid it starts at their linear extrapolation (the reflection keeps
// moving as the camera does); either start only where that pixel is reflective.
// It also tries s's own plane match (the point of s's tangent plane that reflects R
// toward the new eye, projected into the keyframe: the match itself on a planar
// mirror, first order on curved ones) and starts there when that pixel lies on s's
// object and its distance is the lesser: the first frames after a keyframe, with no
// previous offsets, start next to their match instead of at s.
// u_direct = 1: the direct-reprojection baseline, offset 0 for every reflective pixel.
layout(local_size_x = 64) in;
#include "reuse_common.glsl"

layout(rgba32f, binding = UNIT_u_prev) uniform readonly image2D u_prev;
layout(rgba32f, binding = UNIT_u_prev2) uniform readonly image2D u_prev2;
uniform int u_predict;
uniform int u_history;   // how many of u_prev, u_prev2 hold this keyframe's offsets (0, 1, 2)
layout(rgba32f, binding = UNIT_u_offsets) uniform writeonly image2D u_offsets;
uniform vec3 u_eye_old;
uniform vec3 u_eye_new;
uniform int u_max_steps;
uniform int u_direct;
uniform uint u_count;
layout(std430, binding = UNIT_Pixels) readonly buffer Pixels { uint pixel_ids[]; };
uniform mat4 u_kf_view_proj;

const ivec2 RING[8] = ivec2[8](ivec2(-1, -1), ivec2(0, -1), ivec2(1, -1), ivec2(-1, 0),
                               ivec2(1, 0), ivec2(-1, 1), ivec2(0, 1), ivec2(1, 1));

// A keyframe sample as the search uses it: world position w and eye depth d
// (position.w), normal n, reflective (normal.w = its ray length, < 0 where it is not).
struct Sample { vec3 w; float d; vec3 n; bool reflective; };

Sample fetch_sample(ivec2 p) {
    vec4 wd = texelFetch(u_kf_position, p, 0);
    vec4 nr = texelFetch(u_kf_normal, p, 0);
    return Sample(wd.xyz, wd.w, nr.xyz, nr.w >= 0.0);
}

float match_distance(Sample c, vec3 R) {
    vec3 m = R - 2.0 * dot(R - c.w, c.n) * c.n;     // R mirrored in s_n's tangent plane
    vec3 dir = normalize(c.w - m);
    vec3 v = u_eye_new - c.w;
    return length(v - dot(v, dir) * dir);           // E_cur to the line through M and W_n
}

// kf_same_surface for two fetched samples and their object ids.
bool same_surface(Sample a, uint oa, Sample b, uint ob) {
    float tol = u_plane_tol * u_pixel_angle;
    return oa != 0u && oa == ob && abs(dot(a.w - b.w, b.n)) <= tol * b.d && abs(dot(b.w - a.w, a.n)) <= tol * a.d;
}

// Where the line from E_cur to M (R mirrored in c's tangent plane) meets that plane,
// projected into the keyframe: pixel coordinates (texel units, GL orientation; row
// centres at integer + 0.5 - 0.5 = integer). false when the line is parallel to the
// plane or the point lies behind the keyframe camera. Exact on a planar mirror.
bool plane_match(Sample c, vec3 R, out vec2 pixel) {
    vec3 m = R - 2.0 * dot(R - c.w, c.n) * c.n;
    vec3 d = m - u_eye_new;
    float denom = dot(d, c.n);
    pixel = vec2(0.0);
    if (abs(denom) < 1e-12) return false;
    vec3 x = u_eye_new + d * (dot(c.w - u_eye_new, c.n) / denom);
    vec4 clip = u_kf_view_proj * vec4(x, 1.0);
    if (clip.w <= 0.0) return false;
    pixel = (clip.xy / clip.w * 0.5 + 0.5) * vec2(u_kf_size) - 0.5;
    return true;
}

vec2 subpixel(ivec2 sc, Sample c, vec3 R) {
    vec2 x;
    if (!plane_match(c, R, x)) return vec2(0.0);
    vec2 delta = x - vec2(sc);
    if (any(greaterThan(abs(delta), vec2(1.0)))) return vec2(0.0);
    return mix(delta, vec2(0.0), lessThan(abs(delta), vec2(0.01)));
}

void main() {
    if (gl_GlobalInvocationID.x >= u_count) return;
    uint id = pixel_ids[gl_GlobalInvocationID.x];
    ivec2 s = ivec2(int(id) % u_kf_size.x, int(id) / u_kf_size.x);
    vec4 refl = texelFetch(u_kf_reflection, s, 0);
    if (refl.a < 0.0) { imageStore(u_offsets, s, vec4(0.0)); return; }
    if (u_direct == 1) { imageStore(u_offsets, s, vec4(0.0, 0.0, 1.0, 0.0)); return; }
    vec3 w = texelFetch(u_kf_position, s, 0).xyz;
    vec3 n = texelFetch(u_kf_normal, s, 0).xyz;
    vec3 R = w + reflect(normalize(w - u_eye_old), n) * refl.a;
    vec4 prev = u_history >= 1 ? imageLoad(u_prev, s) : vec4(0.0);
    ivec2 sc = s;
    if (prev.z > 0.5 || (u_predict == 1 && prev.w > 0.0)) {      // w: steps, > 0 once searched
        ivec2 start = s + ivec2(round(prev.xy));
        if (kf_inside(start) && kf_reflective(start)) sc = start;
        vec4 prev2 = u_history >= 2 ? imageLoad(u_prev2, s) : vec4(0.0);
        if (u_predict == 1 && prev.z > 0.5 && prev2.z > 0.5) {
            start = s + ivec2(round(2.0 * prev.xy - prev2.xy));
            if (kf_inside(start) && kf_reflective(start)) sc = start;
        }
    }
    Sample cur = fetch_sample(sc);
    uint obj_cur = texelFetch(u_kf_obj, sc, 0).r;
    float former = match_distance(cur, R);
    if (u_predict == 1) {
        // s's own plane match (exact on a planar mirror, first order on curved ones):
        // the start when its distance is the lesser, on s's object
        vec2 x;
        if (plane_match(Sample(w, 0.0, n, true), R, x)) {
            ivec2 start = ivec2(round(x));
            if (start != sc && kf_inside(start)) {
                Sample c = fetch_sample(start);
                uint obj_start = texelFetch(u_kf_obj, start, 0).r;
                float dist = match_distance(c, R);
                if (c.reflective && obj_start == texelFetch(u_kf_obj, s, 0).r && dist < former) {
                    sc = start;
                    cur = c;
                    obj_cur = obj_start;
                    former = dist;
                }
            }
        }
    }
    int steps = 0;
    bool valid = false;
    for (; steps < u_max_steps; ++steps) {
        float best = 3.4e38, rise = 0.0;
        ivec2 best_p = sc;
        Sample best_s = cur;
        for (int k = 0; k < 8; ++k) {
            ivec2 q = sc + RING[k];
            if (!kf_inside(q)) continue;
            Sample c = fetch_sample(q);
            float dq = match_distance(c, R);
            if (c.reflective) rise = max(rise, dq - former);
            if (dq < best) { best = dq; best_p = q; best_s = c; }
        }
        if (best >= former) {                       // local minimum at sc
            valid = former <= rise;                 // ... and within about a pixel of the true one
            break;
        }
        // the minimum lies outside the silhouette (the surface test only for the step taken)
        uint obj_best = texelFetch(u_kf_obj, best_p, 0).r;
        if (!(best_s.reflective && same_surface(cur, obj_cur, best_s, obj_best))) break;
        former = best;
        sc = best_p;
        cur = best_s;
        obj_cur = obj_best;
    }
    vec2 offset = vec2(sc - s);
    if (valid) offset += subpixel(sc, cur, R);
    imageStore(u_offsets, s, vec4(offset, valid ? 1.0 : 0.0, float(steps)));
}
