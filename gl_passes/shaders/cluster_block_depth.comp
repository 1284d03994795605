#version 430 core
// Depth bounds of the packed cluster images per BLOCK×BLOCK atlas texels, per layer
// (other objects, reflector, reflector 2nd, others 2nd): the nearest depth (u_block_min) and
// the farthest depth of a stored surface (u_block_max; 0 when the layer is empty
// there). The intersection march skips a whole block when, in every layer, each
// surface lies either behind the ray's deepest point there or in front of its
// nearest hit depth (the ray passes behind it): no hit is possible in the block.
// Blocks may straddle two cluster viewports: the bounds then only widen, i.e. the
// skip stays conservative.
layout(local_size_x = 8, local_size_y = 8) in;
layout(binding = UNIT_u_pack) uniform sampler2D u_pack;   // (depth other, self, self 2nd, other 2nd)
uniform ivec2 u_size;       // used atlas area (fine texels)
layout(rgba32f, binding = UNIT_u_block_min_image) writeonly uniform image2D u_block_min_image;
layout(rgba32f, binding = UNIT_u_block_max_image) writeonly uniform image2D u_block_max_image;

void main() {
    ivec2 c = ivec2(gl_GlobalInvocationID.xy);
    ivec2 base = c * BLOCK;
    if (any(greaterThanEqual(base, u_size))) return;
    vec4 lo = vec4(3.0e38), hi = vec4(0.0);
    for (int j = 0; j < BLOCK; ++j) for (int i = 0; i < BLOCK; ++i) {
        ivec2 p = base + ivec2(i, j);
        if (all(lessThan(p, u_size))) {
            vec4 d = texelFetch(u_pack, p, 0);
            lo = min(lo, d);
            hi = max(hi, mix(d, vec4(0.0), greaterThanEqual(d, vec4(0.5 * BACKGROUND_DEPTH))));
        }
    }
    imageStore(u_block_min_image, c, lo);
    imageStore(u_block_max_image, c, hi);
}
