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

// Alg. 4's "not separated by a depth discontinuity": q lies on s's surface when
// it has the same triangle or lies within u_plane_tol pixel footprints of s's
// tangent plane.
bool same_surface(Sample s, Sample q) {
    if (!q.valid) return false;
    if (q.tri == s.tri) return true;
    return abs(dot(s.normal, q.position - s.position)) <= u_plane_tol * footprint(s.position);
}

void emit_vertex(uint index, vec3 position, uint rgba) {
    vertices[index] = Vertex(position, rgba);
}
