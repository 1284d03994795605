#version 430 core
// §4.3 step 4: bin every reflective sample by (normal theta bin, normal phi bin,
// reflector id) and accumulate the bin's statistics (count, position and normal
// sums in 64-bit fixed point: 32-bit atomics with carry). The normal is the one
// the sample's mirror ray is reflected about (reflect_common.glsl mirror_normal);
// SHADING_NORMAL_BINS: the interpolated shading normal, whatever the ray.
layout(local_size_x = 16, local_size_y = 16) in;
#include "reflect_common.glsl"
layout(binding = UNIT_u_tri) uniform usampler2D u_tri;
uniform vec3 u_eye;
layout(binding = UNIT_u_obj) uniform usampler2D u_obj;
layout(binding = UNIT_u_material) uniform sampler2D u_material;
layout(binding = UNIT_u_normal) uniform sampler2D u_normal;
layout(binding = UNIT_u_position) uniform sampler2D u_position;
uniform vec3 u_lo;       // position normalisation: q = (p - lo) * inv_ext in [0, 1]
uniform vec3 u_inv_ext;
layout(std430, binding = UNIT_BinTable) readonly buffer BinTable { uvec4 bin_info[]; };  // per object id: base, n_theta, n_phi
layout(std430, binding = UNIT_BinStats) buffer BinStats { uint stats[]; };
layout(r32ui, binding = UNIT_u_bin_image) writeonly uniform uimage2D u_bin_image;  // raw bin + 1 (0 = not reflective)
#define STRIDE 13u
#define FIXED 16777216.0
#define PI 3.14159265358979

void add64(uint i, uint v) {
    uint old = atomicAdd(stats[i], v);
    if (old + v < old) atomicAdd(stats[i + 1u], 1u);
}

void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    ivec2 size = textureSize(u_obj, 0);
    if (any(greaterThanEqual(p, size))) return;
    uint o = texelFetch(u_obj, p, 0).r;
    if (o == 0u || texelFetch(u_material, p, 0).r <= 0.0) { imageStore(u_bin_image, p, uvec4(0u)); return; }
    vec3 P = texelFetch(u_position, p, 0).xyz;
    vec3 n = normalize(texelFetch(u_normal, p, 0).xyz);
#ifndef SHADING_NORMAL_BINS
    n = mirror_normal(normalize(P - u_eye), n, geom_normal(texelFetch(u_tri, p, 0).r));
#endif
    float theta = atan(n.z, n.x);
    if (theta < 0.0) theta += 2.0 * PI;
    float phi = acos(clamp(n.y, -1.0, 1.0));
    uvec4 b = bin_info[o];
    uint i = min(uint(theta / (2.0 * PI) * float(b.y)), b.y - 1u);
    uint j = min(uint(phi / PI * float(b.z)), b.z - 1u);
    uint bin = b.x + i * b.z + j;
    imageStore(u_bin_image, p, uvec4(bin + 1u));
    uint base = bin * STRIDE;
    atomicAdd(stats[base], 1u);
    vec3 q = clamp((P - u_lo) * u_inv_ext, 0.0, 1.0) * FIXED;
    vec3 qn = clamp(n * 0.5 + 0.5, 0.0, 1.0) * FIXED;
    for (uint k = 0u; k < 3u; ++k) {
        add64(base + 1u + 2u * k, uint(q[k] + 0.5));
        add64(base + 7u + 2u * k, uint(qn[k] + 0.5));
    }
}
