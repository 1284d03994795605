#version 430 core
// §4.3 steps 2-3: reflective samples per reflector (object id).
layout(local_size_x = 16, local_size_y = 16) in;
layout(binding = UNIT_u_obj) uniform usampler2D u_obj;
layout(binding = UNIT_u_material) uniform sampler2D u_material;
layout(std430, binding = UNIT_ObjCount) buffer ObjCount { uint obj_count[]; };
shared uint s_obj;
shared uint s_n;

void main() {
    if (gl_LocalInvocationIndex == 0u) { s_obj = 0u; s_n = 0u; }
    barrier();
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    ivec2 size = textureSize(u_obj, 0);
    uint o = 0u;
    if (all(lessThan(p, size)) && texelFetch(u_material, p, 0).r > 0.0) o = texelFetch(u_obj, p, 0).r;
    // Most tiles hold one reflector: count it in shared memory, flush once.
    if (o != 0u) atomicCompSwap(s_obj, 0u, o);
    barrier();
    if (o != 0u) {
        if (o == s_obj) atomicAdd(s_n, 1u);
        else atomicAdd(obj_count[o], 1u);
    }
    barrier();
    if (gl_LocalInvocationIndex == 0u && s_n > 0u) atomicAdd(obj_count[s_obj], s_n);
}
