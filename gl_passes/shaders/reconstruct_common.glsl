// Inputs of the reconstructions (thesis Ch. 3, Alg. 4): a depth image I (W×H) and
// its offset image H ((W+1)×(H+1), pixel centres at I's pixel corners). Texel
// (x, y) is pixel column x, row y with row 0 = top, as the numpy arrays. Each image
// is two rgba32ui textures: A = (position xyz as float bits, triangle id; 0 = no
// sample), B = (unit normal xyz as float bits, colour packed RGBA8).
layout(local_size_x = 8, local_size_y = 8) in;

layout(rgba32ui, binding = UNIT_u_i_a) uniform readonly uimage2D u_i_a;
layout(rgba32ui, binding = UNIT_u_i_b) uniform readonly uimage2D u_i_b;

uniform ivec2 u_size;          // W, H of I
uniform vec3 u_eye;
uniform float u_footprint;     // pixel size per unit eye depth: 2·tan(fov/2)/H
uniform vec3 u_forward;        // unit view direction
uniform float u_plane_tol;     // same-surface tolerance, in pixel footprints at the sample
uniform float u_max_extent;    // depth clamp of tangent-plane corners, in pixel footprints
uniform bool u_depth_gate;     // other triangles: within u_max_extent footprints of depth too
uniform bool u_smooth;         // ... unless both lie on one smooth surface (SMOOTH_COS)

const float CORNER_REACH = 0.70710678;  // pixels from a pixel centre to its corners
const float SMOOTH_COS = 0.95;          // normals within 18° of each other: one smooth surface
const ivec2 CORNER[4] = ivec2[4](ivec2(0, 0), ivec2(1, 0), ivec2(1, 1), ivec2(0, 1));

struct Vertex { vec3 position; uint rgba; };
layout(std430, binding = UNIT_Vertices) buffer Vertices { Vertex vertices[]; };
layout(std430, binding = UNIT_Indices) buffer Indices { uint indices[]; };
layout(std430, binding = UNIT_Counters) buffer Counters { uint n_vertices; uint n_indices; };

struct Sample { bool valid; uint tri; vec3 position; vec3 normal; uint rgba; };

Sample load_sample(uvec4 a, uvec4 b) {
    return Sample(a.w != 0u, a.w, uintBitsToFloat(a.xyz), uintBitsToFloat(b.xyz), b.w);
}

// World size of one pixel at the depth of point p.
float footprint(vec3 p) {
    return max(dot(p - u_eye, u_forward), 0.0) * u_footprint;
}

// Alg. 4's "not separated by a depth discontinuity": q, `reach` pixels from s on
// screen, lies on s's surface when it has the same triangle or lies within
// u_plane_tol pixel footprints of s's tangent plane and (u_depth_gate) its depth
// differs from s's by at most what the tangent-plane corners' clamp allows over
// that distance (u_max_extent footprints per half pixel): near a grazing plane
// every point along the ray is near the plane, and this keeps a far surface out.
// The gate does not apply (u_smooth) where s and q lie on one smooth surface: their
// normals within SMOOTH_COS, and each within u_plane_tol footprints of the other's
// tangent plane (a curved surface turning grazing, a sphere near its outline, whose
// true depth runs past the clamp; a far surface behind a grazing sample faces
// another way, and one in s's plane but apart from it passes, as without the gate).
bool same_surface(Sample s, Sample q, float reach) {
    if (!q.valid) return false;
    if (q.tri == s.tri) return true;
    float fp = footprint(s.position);
    vec3 d = q.position - s.position;
    if (abs(dot(s.normal, d)) > u_plane_tol * fp) return false;
    if (!u_depth_gate || abs(dot(d, u_forward)) <= 2.0 * reach * u_max_extent * fp) return true;
    return u_smooth && dot(s.normal, q.normal) >= SMOOTH_COS
        && abs(dot(q.normal, d)) <= u_plane_tol * footprint(q.position);
}

void emit_vertex(uint index, vec3 position, uint rgba) {
    vertices[index] = Vertex(position, rgba);
}

// The two triangles of a quad with vertices v[k] at CORNER[k]: c0 c3 c2 and c2 c1
// c0, counter-clockwise as seen from I's camera.
void emit_quad(uint v[4]) {
    uint i = atomicAdd(n_indices, 6u);
    indices[i] = v[0]; indices[i + 1u] = v[3]; indices[i + 2u] = v[2];
    indices[i + 3u] = v[2]; indices[i + 4u] = v[1]; indices[i + 5u] = v[0];
}
