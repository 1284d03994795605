#version 430 core
// Quad splats of the shadow-map pass (gl_passes/quad_splats.py): a quad of a small
// piece (two triangles sharing the diagonal s0–s1, the others' corners o0 and o1,
// world units; a lone triangle has o1 = o0) drawn as one point sprite that bounds
// its window footprint; the fragment stage keeps exactly the two triangles' pixels
// and their plane depths.
in vec3 in_s0;
in vec3 in_s1;
in vec3 in_o0;
in vec3 in_o1;
#include "shadow_tile.glsl"
uniform vec2 u_viewport;  // viewport (atlas) size in texels
uniform float u_max_point_size;  // GL_POINT_SIZE_RANGE's upper end
out gl_PerVertex {
    vec4 gl_Position;
    float gl_PointSize;
    float gl_ClipDistance[4];
};
flat out vec3 v_s0;    // window x, y (texels) and depth of s0
flat out vec3 v_dz;    // depth of s1, o0, o1 minus s0's
flat out mat2 v_inv0;  // window offset from s0 → (share of s1 − s0, share of o0 − s0)
flat out mat2 v_inv1;  // the same for the triangle s0 s1 o1
flat out ivec2 v_live; // whether each triangle covers any area
flat out vec4 v_rect;  // the map's tile in window texels: x0, y0, x1, y1

// Window coordinates of world point p (x, y in texels, z the depth in [0, 1]).
vec3 window(mat4 vp, vec4 t, vec3 p) {
    vec4 c = in_tile(vp * vec4(p, 1.0), t);
    vec3 n = c.xyz / c.w;
    return vec3((n.xy * 0.5 + 0.5) * u_viewport, n.z * 0.5 + 0.5);
}

// Inverse of the window edge matrix [d e] of a triangle; live = its area is not zero.
mat2 edge_inverse(vec2 d, vec2 e, out int live) {
    mat2 m = mat2(d, e);
    float det = determinant(m);
    live = abs(det) > 1e-8 ? 1 : 0;
    return live == 1 ? inverse(m) : mat2(0.0);
}

void main() {
    int i = map_index();
    mat4 vp = u_light_vp[i];
    vec4 t = map_tile(i);
    vec3 s0 = window(vp, t, in_s0), s1 = window(vp, t, in_s1);
    vec3 o0 = window(vp, t, in_o0), o1 = window(vp, t, in_o1);
    v_s0 = s0;
    v_dz = vec3(s1.z, o0.z, o1.z) - s0.z;
    v_inv0 = edge_inverse(s1.xy - s0.xy, o0.xy - s0.xy, v_live.x);
    v_inv1 = edge_inverse(s1.xy - s0.xy, o1.xy - s0.xy, v_live.y);
    v_rect = vec4(((t.zw - t.xy) * 0.5 + 0.5) * u_viewport, ((t.zw + t.xy) * 0.5 + 0.5) * u_viewport);
    vec2 lo = min(min(s0.xy, s1.xy), min(o0.xy, o1.xy));
    vec2 hi = max(max(s0.xy, s1.xy), max(o0.xy, o1.xy));
    // a square around the box's centre holding every pixel centre of the box
    float size = max(hi.x - lo.x, hi.y - lo.y) + 1.0;
    // every clip distance passes: the fragment stage keeps the sprite inside its tile
    gl_ClipDistance[0] = 1.0;
    gl_ClipDistance[1] = 1.0;
    gl_ClipDistance[2] = 1.0;
    gl_ClipDistance[3] = 1.0;
    // clamped at the implementation's largest point (the quads made splats are small:
    // quad_splats.SPLAT_PIXELS); a quad of no area is culled (a point outside the view)
    gl_PointSize = min(size, u_max_point_size);
    gl_Position = v_live.x + v_live.y > 0 ? vec4((lo + hi) / u_viewport - 1.0, 0.0, 1.0) : vec4(2.0, 2.0, 0.0, 1.0);
}
