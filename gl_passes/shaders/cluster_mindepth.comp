#version 430 core
// Coarse min-depth of the packed cluster images: one texel per BLOCK×BLOCK atlas
// texels holding the minimum depth of both layers. The intersection march skips a
// whole block when even its nearest surface lies behind the ray's deepest point in
// that block (no hit is possible there). Blocks may straddle two cluster viewports:
// the minimum then only gets smaller, i.e. the skip stays conservative.
layout(local_size_x = 8, local_size_y = 8) in;
uniform sampler2D u_pack;   // (depth other, depth self)
uniform ivec2 u_size;       // used atlas area (fine texels)
layout(r32f, binding = 6) writeonly uniform image2D u_coarse;

void main() {
    ivec2 c = ivec2(gl_GlobalInvocationID.xy);
    ivec2 base = c * BLOCK;
    if (any(greaterThanEqual(base, u_size))) return;
    float m = 3.0e38;
    for (int j = 0; j < BLOCK; ++j) for (int i = 0; i < BLOCK; ++i) {
        ivec2 p = base + ivec2(i, j);
        if (all(lessThan(p, u_size))) { vec2 d = texelFetch(u_pack, p, 0).xy; m = min(m, min(d.x, d.y)); }
    }
    imageStore(u_coarse, c, vec4(m));
}
