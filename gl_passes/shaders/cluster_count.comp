#version 430 core
// §4.3 step 1: reflective samples per object (a_R, n_v). Also, for the passes
// after it: the lists of reflective samples and tiles (reflective_list.glsl), and
// every non-reflective sample's bin (0) and, with u_components, union-find label
// (NONE), since cluster_assign.comp runs over the list only.
layout(local_size_x = 16, local_size_y = 16) in;
#define LIST_ACCESS  // written here
#define LIST_WRITER
#include "reflective_list.glsl"
#include "cluster_labels.glsl"
layout(binding = UNIT_u_obj) uniform usampler2D u_obj;
layout(binding = UNIT_u_material) uniform sampler2D u_material;
layout(std430, binding = UNIT_ObjCount) buffer ObjCount { uint obj_count[]; };
layout(r32ui, binding = UNIT_u_bin_image) writeonly uniform uimage2D u_bin_image;  // raw bin + 1 (0 = not reflective)
uniform bool u_components;
shared uint s_obj;
shared uint s_n;

void main() {
    if (gl_LocalInvocationIndex == 0u) { s_obj = 0u; s_n = 0u; }
    barrier();
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    ivec2 size = textureSize(u_obj, 0);
    bool inside = all(lessThan(p, size));
    uint o = 0u;
    if (inside && texelFetch(u_material, p, 0).r > 0.0) o = texelFetch(u_obj, p, 0).r;
    // Most tiles hold one reflector: count it in shared memory, flush once.
    if (o != 0u) atomicCompSwap(s_obj, 0u, o);
    barrier();
    if (o != 0u) {
        if (o == s_obj) atomicAdd(s_n, 1u);
        else atomicAdd(obj_count[o], 1u);
    }
    barrier();
    if (gl_LocalInvocationIndex == 0u && s_n > 0u) atomicAdd(obj_count[s_obj], s_n);
    list_tile_samples(o != 0u, p);
    if (inside && o == 0u) {
        imageStore(u_bin_image, p, uvec4(0u));
        if (u_components) labels[uint(p.y * size.x + p.x)] = NONE;
    }
}
