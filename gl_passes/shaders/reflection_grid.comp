#version 430 core
// Reflection offset (thesis §5.4.2), once per keyframe: which grid-mesh triangles of
// the keyframe exist. Invocation k takes the reflective keyframe pixel s = (x, y) as
// corner 00 of its 2×2 block; the block's triangles (00, 10, 11) (bit 0) and
// (00, 11, 01) (bit 1) exist when all three vertices are reflective and every pair
// lies on one surface (kf_same_surface: no depth discontinuity between them) — the
// rule of reflection_offset.grid_indices, which builds the GL mesh's index buffer.
layout(local_size_x = 64) in;
#include "reuse_common.glsl"

layout(r32ui, binding = UNIT_u_grid_img) uniform writeonly uimage2D u_grid_img;
layout(std430, binding = UNIT_Pixels) readonly buffer Pixels { uint pixel_ids[]; };
uniform uint u_count;

bool linked(ivec2 a, ivec2 b) { return kf_inside(b) && kf_reflective(b) && kf_same_surface(a, b); }

void main() {
    if (gl_GlobalInvocationID.x >= u_count) return;
    uint id = pixel_ids[gl_GlobalInvocationID.x];
    ivec2 s = ivec2(int(id) % u_kf_size.x, int(id) / u_kf_size.x);
    ivec2 p10 = s + ivec2(1, 0), p11 = s + ivec2(1, 1), p01 = s + ivec2(0, 1);
    bool dia = linked(s, p11);
    uint mask = 0u;
    if (dia && linked(s, p10) && linked(p10, p11)) mask |= 1u;
    if (dia && linked(s, p01) && linked(p01, p11)) mask |= 2u;
    imageStore(u_grid_img, s, uvec4(mask));
}
