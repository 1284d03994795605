#version 430 core
// Hybrid reconstruction, pass 1 of 3 (Alg. 4): per sample of I, which of its four
// corners H provides (bits 0..3: corners (x,y), (x+1,y), (x+1,y+1), (x,y+1);
// bit 4: the pixel holds a sample).
#include "reconstruct_common.glsl"

layout(rgba32ui, binding = UNIT_u_h_a) uniform readonly uimage2D u_h_a;
layout(rgba32ui, binding = UNIT_u_h_b) uniform readonly uimage2D u_h_b;
layout(r32ui, binding = UNIT_u_flags) uniform writeonly uimage2D u_flags;

void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    if (any(greaterThanEqual(p, u_size))) return;
    Sample s = load_sample(imageLoad(u_i_a, p), imageLoad(u_i_b, p));
    uint flags = 0u;
    if (s.valid) {
        flags = 16u;
        for (int k = 0; k < 4; ++k) {
            ivec2 c = p + CORNER[k];
            if (same_surface(s, load_sample(imageLoad(u_h_a, c), imageLoad(u_h_b, c)), CORNER_REACH)) flags |= 1u << k;
        }
    }
    imageStore(u_flags, p, uvec4(flags));
}
