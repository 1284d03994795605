#version 430 core
// The quad splats' depths (shadow_splat.comp) into the depth atlas: drawn over the
// whole atlas (fullscreen.vert) with the depth test, a texel that a splat covers
// writes that depth, so the atlas keeps the nearer of the splats and the triangles.
layout(r32ui, binding = UNIT_splat_depth) uniform readonly uimage2D u_splat_depth;

void main() {
    uint bits = imageLoad(u_splat_depth, ivec2(gl_FragCoord.xy)).r;
    if (bits == EMPTY) discard;
    gl_FragDepth = uintBitsToFloat(bits);
}
