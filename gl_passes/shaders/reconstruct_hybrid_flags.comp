#version 430 core
// Hybrid reconstruction, pass 1 of 3 (Alg. 4): per sample of I, which of its four
// corners H provides (bits 0..3: corners (x,y), (x+1,y), (x+1,y+1), (x,y+1);
// bit 4: the pixel holds a sample); every H corner taken by some sample is marked
// in u_corner_index (cleared to 0 before).
#include "reconstruct_common.glsl"

layout(rgba32ui, binding = UNIT_u_h_a) uniform readonly uimage2D u_h_a;
layout(rgba32ui, binding = UNIT_u_h_b) uniform readonly uimage2D u_h_b;
layout(r32ui, binding = UNIT_u_flags) uniform writeonly uimage2D u_flags;
layout(r32ui, binding = UNIT_u_corner_index) uniform writeonly uimage2D u_corner_index;

const ivec2 CORNER[4] = ivec2[4](ivec2(0, 0), ivec2(1, 0), ivec2(1, 1), ivec2(0, 1));

void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    if (any(greaterThanEqual(p, u_size))) return;
    Sample s = load_sample(imageLoad(u_i_a, p), imageLoad(u_i_b, p));
    uint flags = 0u;
    if (s.valid) {
        flags = 16u;
        for (int k = 0; k < 4; ++k) {
            ivec2 c = p + CORNER[k];
            Sample h = load_sample(imageLoad(u_h_a, c), imageLoad(u_h_b, c));
            if (same_surface(s, h)) {
                flags |= 1u << k;
                imageStore(u_corner_index, c, uvec4(1u));
            }
        }
    }
    imageStore(u_flags, p, uvec4(flags));
}
