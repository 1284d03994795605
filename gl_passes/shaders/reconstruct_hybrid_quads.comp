#version 430 core
// Hybrid reconstruction, pass 3 of 3 (Alg. 4): every sample of I becomes the two
// triangles c0 c3 c2 and c2 c1 c0 (counter-clockwise as seen from I's camera) over
// its corner vertices from pass 2.
#include "reconstruct_common.glsl"

layout(r32ui, binding = UNIT_u_flags) uniform readonly uimage2D u_flags;
layout(r32ui, binding = UNIT_u_sample_corner) uniform readonly uimage2D u_sample_corner;

void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    if (any(greaterThanEqual(p, u_size))) return;
    if ((imageLoad(u_flags, p).r & 16u) == 0u) return;
    uint v[4];
    for (int k = 0; k < 4; ++k) v[k] = imageLoad(u_sample_corner, 2 * p + CORNER[k]).r;
    emit_quad(v);
}
