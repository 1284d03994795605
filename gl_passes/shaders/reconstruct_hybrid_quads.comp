#version 430 core
// Hybrid reconstruction, pass 3 of 3 (Alg. 4): every sample of I becomes the two
// triangles c0 c3 c2 and c2 c1 c0 (counter-clockwise as seen from I's camera). A
// corner H provides is the shared vertex of pass 2; a missing corner is the
// intersection of the corner's camera ray with the sample's tangent plane, its
// depth clamped to ± u_max_extent pixel footprints of the sample's (grazing planes).
#include "reconstruct_common.glsl"

layout(r32ui, binding = UNIT_u_flags) uniform readonly uimage2D u_flags;
layout(r32ui, binding = UNIT_u_corner_index) uniform readonly uimage2D u_corner_index;
uniform vec3 u_right;   // camera right × tan(fov/2)·aspect
uniform vec3 u_up;      // camera up × tan(fov/2)
uniform float u_max_extent;

const ivec2 CORNER[4] = ivec2[4](ivec2(0, 0), ivec2(1, 0), ivec2(1, 1), ivec2(0, 1));

vec3 tangent_plane_corner(Sample s, ivec2 c) {
    vec2 ndc = vec2(2.0 * float(c.x) / float(u_size.x) - 1.0, 1.0 - 2.0 * float(c.y) / float(u_size.y));
    vec3 d = u_forward + ndc.x * u_right + ndc.y * u_up;  // ray direction with dot(d, forward) = 1
    float zs = dot(s.position - u_eye, u_forward);
    float denom = dot(s.normal, d);
    float z = abs(denom) > 1e-12 ? dot(s.normal, s.position - u_eye) / denom : zs;
    float extent = u_max_extent * footprint(s.position);
    z = clamp(z, zs - extent, zs + extent);
    return u_eye + z * d;
}

void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    if (any(greaterThanEqual(p, u_size))) return;
    uint flags = imageLoad(u_flags, p).r;
    if ((flags & 16u) == 0u) return;
    Sample s = load_sample(imageLoad(u_i_a, p), imageLoad(u_i_b, p));
    uint missing = 4u - uint(bitCount(flags & 15u));
    uint next = missing > 0u ? atomicAdd(n_vertices, missing) : 0u;
    uint v[4];
    for (int k = 0; k < 4; ++k) {
        ivec2 c = p + CORNER[k];
        if ((flags & (1u << k)) != 0u) {
            v[k] = imageLoad(u_corner_index, c).r;
        } else {
            v[k] = next++;
            emit_vertex(v[k], tangent_plane_corner(s, c), s.rgba);
        }
    }
    uint i = atomicAdd(n_indices, 6u);
    indices[i] = v[0]; indices[i + 1u] = v[3]; indices[i + 2u] = v[2];
    indices[i + 3u] = v[2]; indices[i + 4u] = v[1]; indices[i + 5u] = v[0];
}
