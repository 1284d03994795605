#version 430 core
// §4.3 step 4: the raw bin of every reflective sample, by (mirror-normal theta
// bin, phi bin, reflector id), and its mirror normal (for the normal-break test
// of cluster_merge.comp and the statistics of cluster_accumulate.comp); with
// u_components, its union-find label (itself) and component count (0). One
// invocation per listed reflective sample (cluster_count.comp wrote the others').
layout(local_size_x = 256) in;
#include "cluster_sample.glsl"
#include "cluster_labels.glsl"
#include "reflective_list.glsl"
layout(std430, binding = UNIT_BinTable) readonly buffer BinTable { uvec4 bin_info[]; };  // per object id: base, n_theta, n_phi
layout(std430, binding = UNIT_CompCount) writeonly buffer CompCount { uint comp_count[]; };
layout(r32ui, binding = UNIT_u_bin_image) writeonly uniform uimage2D u_bin_image;  // raw bin + 1 (0 = not reflective)
layout(rgba32f, binding = UNIT_u_mnormal_image) writeonly uniform image2D u_mnormal_image;
uniform bool u_components;
#define PI 3.14159265358979

void main() {
    if (gl_GlobalInvocationID.x >= n_samples) return;
    ivec2 p = list_sample(gl_GlobalInvocationID.x);
    uint idx = uint(p.y * textureSize(u_obj, 0).x + p.x);
    uint o = reflector(p);
    if (u_components) {
        comp_count[idx] = 0u;
        labels[idx] = idx;
    }
    vec3 n = sample_mirror_normal(p, texelFetch(u_position, p, 0).xyz);
    float theta = atan(n.z, n.x);
    if (theta < 0.0) theta += 2.0 * PI;
    float phi = acos(clamp(n.y, -1.0, 1.0));
    uvec4 b = bin_info[o];
    uint i = min(uint(theta / (2.0 * PI) * float(b.y)), b.y - 1u);
    uint j = min(uint(phi / PI * float(b.z)), b.z - 1u);
    imageStore(u_bin_image, p, uvec4(b.x + i * b.z + j + 1u));
    imageStore(u_mnormal_image, p, vec4(n, 0.0));
}
