#version 430 core
// The list of reflective samples (bin != 0), tile by tile: each 16×16 work group
// counts its samples in shared memory, takes one contiguous stretch of the list
// with one global atomic and writes them there (in its invocation order on a CPU
// rasteriser, so neighbouring samples stay neighbours in the list); the dispatch
// triples grow to cover the list's end.
layout(local_size_x = 16, local_size_y = 16) in;
#define LIST_ACCESS  // read and written here
#include "reflective_list.glsl"
layout(binding = UNIT_u_bins) uniform usampler2D u_bins;
shared uint s_count;
shared uint s_base;

void main() {
    if (gl_LocalInvocationIndex == 0u) s_count = 0u;
    barrier();
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    bool reflective = all(lessThan(p, textureSize(u_bins, 0))) && texelFetch(u_bins, p, 0).r != 0u;
    uint slot = reflective ? atomicAdd(s_count, 1u) : 0u;
    barrier();
    if (gl_LocalInvocationIndex == 0u && s_count > 0u) {
        s_base = atomicAdd(n_samples, s_count);
        uint end = s_base + s_count;
        atomicMax(dispatch64[0], (end + 63u) / 64u);
        atomicMax(dispatch256[0], (end + 255u) / 256u);
    }
    barrier();
    if (reflective) sample_xy[s_base + slot] = uint(p.x) | (uint(p.y) << 16);
}
