#version 430 core
// Composition (thesis §5.4.3): depth-based reprojection of the intermediate reflection
// image into the new view, one invocation per new-frame pixel q on a reflector (s > 0;
// the caller's list of them, y·W + x with row 0 at the top): its world
// point P is projected into the keyframe; when the keyframe sample there (the nearest
// texel, or at the silhouette of P's surface the nearest of the 2×2 that is) lies
// on P's surface (same object, P within u_plane_tol footprints of its tangent plane) the
// reflection is the intermediate image bilinearly interpolated over the reliable
// texels of that surface among the 2×2 around P's projection, provided the nearest
// texel is reliable. Output per listed pixel: results (Lr, r) and flags: 1 reused,
// 2 disoccluded (P not seen by the keyframe), 3 unreliable (the intermediate image
// holds no reliable value there); 2 and 3 are recomputed. The intermediate image is
// reliable where its r >= 0 (the offset passes clear r to -1).
layout(local_size_x = 64) in;
#include "reuse_common.glsl"

layout(binding = UNIT_u_position) uniform sampler2D u_position;
layout(binding = UNIT_u_obj) uniform usampler2D u_obj;
layout(binding = UNIT_u_inter) uniform sampler2D u_inter;
layout(std430, binding = UNIT_Pixels) readonly buffer Pixels { uint pixel_ids[]; };
layout(std430, binding = UNIT_Results) writeonly buffer Results { vec4 results[]; };
layout(std430, binding = UNIT_Flags) writeonly buffer Flags { uint flags[]; };
uniform uint u_count;
uniform mat4 u_kf_view_proj;
uniform ivec2 u_size;

void main() {
    uint k = gl_GlobalInvocationID.x;
    if (k >= u_count) return;
    uint id = pixel_ids[k];
    ivec2 q = ivec2(int(id) % u_size.x, u_size.y - 1 - int(id) / u_size.x);   // GL rows
    uint obj = texelFetch(u_obj, q, 0).r;
    vec3 P = texelFetch(u_position, q, 0).xyz;
    vec4 clip = u_kf_view_proj * vec4(P, 1.0);
    uint flag = 2u;
    vec4 result = vec4(0.0);
    if (clip.w > 0.0) {
        vec2 t = (clip.xy / clip.w * 0.5 + 0.5) * vec2(u_kf_size) - 0.5;   // texel coordinates
        ivec2 p = ivec2(floor(t + 0.5));
        bool in_front = kf_inside(p) && texelFetch(u_kf_depth, p, 0).r < clip.w * (1.0 - 1e-3);
        if (kf_inside(p) && !in_front && !on_kf_surface(p, P, obj)) {
            // at P's own surface's silhouette the nearest texel may lie behind it (the
            // keyframe saw past the edge): take the nearest of the 2×2 around P's
            // projection that is on P's surface. Not when the nearest texel lies in
            // front of P (clip.w is P's keyframe depth): then P is hidden, disoccluded.
            ivec2 b = ivec2(floor(t));
            float best = 1e30;
            ivec2 found = ivec2(-1);
            for (int j = 0; j < 2; ++j) for (int i = 0; i < 2; ++i) {
                ivec2 c = b + ivec2(i, j);
                float d2 = dot(vec2(c) - t, vec2(c) - t);
                if (kf_inside(c) && d2 < best && on_kf_surface(c, P, obj)) { best = d2; found = c; }
            }
            if (found.x >= 0) p = found;
        }
        if (kf_inside(p) && on_kf_surface(p, P, obj)) {
            flag = 3u;
            vec4 nearest = texelFetch(u_inter, p, 0);
            if (nearest.a >= 0.0) {
                ivec2 b = ivec2(floor(t));
                vec2 f = t - vec2(b);
                vec4 sum = vec4(0.0);
                float wsum = 0.0;
                for (int j = 0; j < 2; ++j) for (int i = 0; i < 2; ++i) {
                    ivec2 c = b + ivec2(i, j);
                    if (!kf_inside(c)) continue;
                    vec4 inter = texelFetch(u_inter, c, 0);
                    if (inter.a < 0.0 || !on_kf_surface(c, P, obj)) continue;
                    float w = (i == 1 ? f.x : 1.0 - f.x) * (j == 1 ? f.y : 1.0 - f.y);
                    sum += w * inter;
                    wsum += w;
                }
                if (wsum <= 0.0) { sum = nearest; wsum = 1.0; }
                result = sum / wsum;
                flag = 1u;
            }
        }
    }
    results[k] = result;
    flags[k] = flag;
}
