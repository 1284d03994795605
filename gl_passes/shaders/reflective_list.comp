#version 430 core
// The lists of reflective_list.glsl from a bin image (0 = not reflective), for a
// union-find over bins that did not come from the clustering's count pass.
layout(local_size_x = 16, local_size_y = 16) in;
#define LIST_ACCESS  // written here
#define LIST_WRITER
#include "reflective_list.glsl"
layout(binding = UNIT_u_bins) uniform usampler2D u_bins;

void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    list_tile_samples(all(lessThan(p, textureSize(u_bins, 0))) && texelFetch(u_bins, p, 0).r != 0u, p);
}
