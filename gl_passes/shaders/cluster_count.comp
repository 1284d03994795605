#version 430 core
// §4.3 step 1: reflective samples per object (a_R, n_v). Also, for the passes
// after it: the lists of reflective samples and tiles (reflective_list.glsl), and
// every non-reflective sample's bin (0) and, with u_components, union-find label
// (NONE), since cluster_assign.comp runs over the list only. One work group per
// TILE×TILE tile, one invocation per 2×2 samples of it (a CPU rasteriser switches
// between a group's invocations at every barrier, and runs its atomics lane by
// lane: a quarter of the invocations, and one atomic per invocation instead of
// per sample, cost less); three barriers.
layout(local_size_x = TILE_HALF, local_size_y = TILE_HALF) in;  // TILE / 2 (gl_passes.clustering)
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
    list_begin();
    barrier();
    ivec2 size = textureSize(u_obj, 0);
    ivec2 p0 = ivec2(gl_WorkGroupID.xy) * TILE + ivec2(gl_LocalInvocationID.xy) * 2;
    uvec4 o = uvec4(0u);  // the reflector of each of the 2×2 samples (0: none)
    uint first = 0u, n = 0u;
    for (int k = 0; k < 4; ++k) {
        ivec2 p = p0 + ivec2(k & 1, k >> 1);
        if (all(lessThan(p, size)) && texelFetch(u_material, p, 0).r > 0.0) o[k] = texelFetch(u_obj, p, 0).r;
        if (o[k] != 0u) { n += 1u; if (first == 0u) first = o[k]; }
    }
    // Most tiles hold one reflector: count it in shared memory, flush once.
    if (first != 0u) atomicCompSwap(s_obj, 0u, first);
    uint slot = list_reserve(n);
    barrier();
    uint mine = 0u;
    for (int k = 0; k < 4; ++k) {
        if (o[k] == 0u) continue;
        if (o[k] == s_obj) mine += 1u;
        else atomicAdd(obj_count[o[k]], 1u);
    }
    if (mine > 0u) atomicAdd(s_n, mine);
    list_publish();
    barrier();
    if (gl_LocalInvocationIndex == 0u && s_n > 0u) atomicAdd(obj_count[s_obj], s_n);
    for (int k = 0; k < 4; ++k) {
        ivec2 p = p0 + ivec2(k & 1, k >> 1);
        if (o[k] != 0u) {
            list_put(slot, p);
            slot += 1u;
        } else if (all(lessThan(p, size))) {
            imageStore(u_bin_image, p, uvec4(0u));
            if (u_components) labels[uint(p.y * size.x + p.x)] = NONE;
        }
    }
}
