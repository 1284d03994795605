#version 430 core
// Quad splats (shadow_splat.vert): a texel of the sprite is kept when its centre
// lies in either triangle of the quad and in the map's tile, at the depth of that
// triangle's plane (window depth is affine in window x, y over a planar triangle,
// as the rasteriser interpolates it).
flat in vec3 v_s0;
flat in vec3 v_dz;
flat in mat2 v_inv0;
flat in mat2 v_inv1;
flat in ivec2 v_live;
flat in vec4 v_rect;

// Whether shares w of a window offset (along s1 − s0, along o − s0) lie in the triangle.
bool inside(vec2 w) {
    return w.x >= 0.0 && w.y >= 0.0 && w.x + w.y <= 1.0;
}

void main() {
    vec2 p = gl_FragCoord.xy;
    if (any(lessThan(p, v_rect.xy)) || any(greaterThanEqual(p, v_rect.zw))) discard;
    vec2 q = p - v_s0.xy;
    vec2 w0 = v_inv0 * q;
    if (v_live.x == 1 && inside(w0)) {
        gl_FragDepth = v_s0.z + w0.x * v_dz.x + w0.y * v_dz.y;
        return;
    }
    vec2 w1 = v_inv1 * q;
    if (v_live.y == 1 && inside(w1)) {
        gl_FragDepth = v_s0.z + w1.x * v_dz.x + w1.y * v_dz.z;
        return;
    }
    discard;
}
