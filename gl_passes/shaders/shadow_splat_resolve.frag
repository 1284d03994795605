#version 430 core
// The quad splats' depths (shadow_splat.comp) into the depth atlas: drawn over the
// tile rows of the batch (fullscreen.vert) with the depth test, a texel that a
// splat covers writes that depth, so the atlas keeps the nearer of the splats and
// the triangles; the texel is emptied as it is read, which leaves the splat depth
// image empty for the next batch (no separate clear).
layout(r32ui, binding = UNIT_splat_depth) uniform uimage2D u_splat_depth;

void main() {
    ivec2 p = ivec2(gl_FragCoord.xy);
    uint bits = imageLoad(u_splat_depth, p).r;
    if (bits == EMPTY) discard;
    imageStore(u_splat_depth, p, uvec4(EMPTY));
    gl_FragDepth = uintBitsToFloat(bits);
}
