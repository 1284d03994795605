#version 430 core
// Empties the splat depth image (shadow_splat.comp) when it is made, and after a
// batch that drew splats without resolving them (the resolve empties what it reads).
layout(local_size_x = 16, local_size_y = 16) in;
layout(r32ui, binding = UNIT_splat_depth) uniform writeonly uimage2D u_splat_depth;

void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    if (all(lessThan(p, imageSize(u_splat_depth)))) imageStore(u_splat_depth, p, uvec4(EMPTY));
}
