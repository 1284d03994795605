#version 430 core
// §4.3 step 1: reflective samples per object (a_R, n_v). Also, for the passes
// after it: the list of reflective samples (reflective_list.glsl; each 16×16 work
// group takes one contiguous stretch of it with one global atomic, its samples in
// invocation order on a CPU rasteriser, so neighbours stay neighbours), and every
// non-reflective sample's bin (0) and, with u_components, its union-find
// records (label NONE, count 0), since cluster_assign.comp runs over the list only.
layout(local_size_x = 16, local_size_y = 16) in;
#define LIST_ACCESS  // written here
#include "reflective_list.glsl"
#include "cluster_labels.glsl"
layout(binding = UNIT_u_obj) uniform usampler2D u_obj;
layout(binding = UNIT_u_material) uniform sampler2D u_material;
layout(std430, binding = UNIT_ObjCount) buffer ObjCount { uint obj_count[]; };
layout(std430, binding = UNIT_CompCount) writeonly buffer CompCount { uint comp_count[]; };
layout(r32ui, binding = UNIT_u_bin_image) writeonly uniform uimage2D u_bin_image;  // raw bin + 1 (0 = not reflective)
uniform bool u_components;
shared uint s_obj;
shared uint s_n;
shared uint s_listed;
shared uint s_base;

void main() {
    if (gl_LocalInvocationIndex == 0u) { s_obj = 0u; s_n = 0u; s_listed = 0u; }
    barrier();
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    ivec2 size = textureSize(u_obj, 0);
    bool inside = all(lessThan(p, size));
    uint o = 0u;
    if (inside && texelFetch(u_material, p, 0).r > 0.0) o = texelFetch(u_obj, p, 0).r;
    // Most tiles hold one reflector: count it in shared memory, flush once.
    uint slot = 0u;
    if (o != 0u) { atomicCompSwap(s_obj, 0u, o); slot = atomicAdd(s_listed, 1u); }
    barrier();
    if (o != 0u) {
        if (o == s_obj) atomicAdd(s_n, 1u);
        else atomicAdd(obj_count[o], 1u);
    }
    if (gl_LocalInvocationIndex == 0u && s_listed > 0u) {
        s_base = atomicAdd(n_samples, s_listed);
        uint end = s_base + s_listed;
        atomicMax(dispatch64[0], (end + 63u) / 64u);
        atomicMax(dispatch256[0], (end + 255u) / 256u);
    }
    barrier();
    if (gl_LocalInvocationIndex == 0u && s_n > 0u) atomicAdd(obj_count[s_obj], s_n);
    if (o != 0u) sample_xy[s_base + slot] = uint(p.x) | (uint(p.y) << 16);
    else if (inside) {
        imageStore(u_bin_image, p, uvec4(0u));
        if (u_components) {
            uint idx = uint(p.y * size.x + p.x);
            comp_count[idx] = 0u;
            labels[idx] = NONE;
        }
    }
}
