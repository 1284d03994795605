#version 430 core
// Reflection offset (thesis §5.4.2) as a compute rasteriser of the same grid mesh as
// reflection_offset.vert/.geom/.frag: one invocation per reflective keyframe pixel s,
// which owns the triangles (00, 10, 11) and (00, 11, 01) of its 2×2 block (present
// when u_grid says the block is continuous there) and its own sample point. Vertices
// move from their pixel centres by their best-match offsets; a triangle is dropped
// when a vertex has no valid match, when its area exceeds u_growth × its source area
// (0.5 px²), or (u_reflected_jump > 0) when its reflected-ray lengths jump. Pixel
// centres are covered by the edge-function test with the top-left rule, each shared
// edge evaluated the same way from both sides (watertight); depth d + r (scaled to
// [0, 1], as the GL pass) is interpolated linearly in the image, like every attribute.
// The sample point covers the one pixel its moved centre falls in, at depth
// × (1 + u_point_bias), so it only fills what no triangle covers.
// Pass DEPTH: atomic minimum of the depth bits per pixel (u_zbuf, cleared to 1.0).
// Pass RESOLVE (defined): the fragments whose depth is that minimum write the
// intermediate image (Lr, r) and reliable = 1.
layout(local_size_x = 64) in;
#include "reuse_common.glsl"

layout(binding = UNIT_u_offsets_tex) uniform sampler2D u_offsets_tex;
layout(binding = UNIT_u_grid) uniform usampler2D u_grid;
#ifdef RESOLVE
layout(r32ui, binding = UNIT_u_zbuf) uniform readonly uimage2D u_zbuf;
layout(rgba32f, binding = UNIT_u_inter_img) uniform writeonly image2D u_inter_img;
layout(r32f, binding = UNIT_u_reliable_img) uniform writeonly image2D u_reliable_img;
#else
layout(r32ui, binding = UNIT_u_zbuf) uniform coherent uimage2D u_zbuf;
#endif
layout(std430, binding = UNIT_Pixels) readonly buffer Pixels { uint pixel_ids[]; };
uniform uint u_count;
uniform float u_depth_scale;   // 1 / (largest d + r)
uniform float u_point_bias;
uniform float u_growth;
uniform float u_reflected_jump;

struct Vertex { vec2 xy; float z; vec4 refl; bool valid; uint id; };

Vertex grid_vertex(ivec2 p) {
    Vertex v;
    vec4 o = texelFetch(u_offsets_tex, p, 0);
    v.refl = texelFetch(u_kf_reflection, p, 0);
    v.valid = o.z > 0.5 && v.refl.a >= 0.0;
    v.xy = vec2(p) + o.xy + 0.5;                 // window coordinates (pixels)
    v.z = clamp((texelFetch(u_kf_depth, p, 0).r + max(v.refl.a, 0.0)) * u_depth_scale, 0.0, 1.0);
    v.id = uint(p.y * u_kf_size.x + p.x);
    return v;
}

void fragment(ivec2 pix, float z, vec4 refl) {
    if (!(z < 1.0)) return;
    uint bits = floatBitsToUint(z);
#ifdef RESOLVE
    if (imageLoad(u_zbuf, pix).r == bits) {
        imageStore(u_inter_img, pix, refl);
        imageStore(u_reliable_img, pix, vec4(1.0));
    }
#else
    imageAtomicMin(u_zbuf, pix, bits);
#endif
}

// Edge function of a → b at c, always evaluated from the vertex with the lower id, so
// that the two triangles sharing an edge get exactly opposite values.
float edge(Vertex a, Vertex b, vec2 c) {
    if (a.id < b.id) {
        vec2 d = b.xy - a.xy, e = c - a.xy;
        return d.x * e.y - d.y * e.x;
    }
    vec2 d = a.xy - b.xy, e = c - b.xy;
    return -(d.x * e.y - d.y * e.x);
}

// Top-left rule for a counter-clockwise triangle in GL window coordinates (y up).
bool top_left(vec2 a, vec2 b) {
    vec2 d = b - a;
    return d.y < 0.0 || (d.y == 0.0 && d.x < 0.0);
}

bool covers(float e, bool tl) { return e > 0.0 || (e == 0.0 && tl); }

void triangle(Vertex a, Vertex b, Vertex c) {
    if (!(a.valid && b.valid && c.valid)) return;
    if (u_reflected_jump > 0.0) {
        if (abs(a.refl.a - b.refl.a) > u_reflected_jump * min(a.refl.a, b.refl.a)) return;
        if (abs(b.refl.a - c.refl.a) > u_reflected_jump * min(b.refl.a, c.refl.a)) return;
        if (abs(c.refl.a - a.refl.a) > u_reflected_jump * min(c.refl.a, a.refl.a)) return;
    }
    vec2 ab = b.xy - a.xy, ac = c.xy - a.xy;
    float area2 = ab.x * ac.y - ab.y * ac.x;      // twice the signed area (px²)
    if (0.5 * abs(area2) > u_growth * 0.5 || area2 == 0.0) return;
    if (area2 < 0.0) { Vertex t = b; b = c; c = t; area2 = -area2; }
    bool tl0 = top_left(b.xy, c.xy), tl1 = top_left(c.xy, a.xy), tl2 = top_left(a.xy, b.xy);
    vec2 lo = min(a.xy, min(b.xy, c.xy)), hi = max(a.xy, max(b.xy, c.xy));
    ivec2 p0 = max(ivec2(ceil(lo - 0.5)), ivec2(0));
    ivec2 p1 = min(ivec2(floor(hi - 0.5)), u_kf_size - 1);
    for (int y = p0.y; y <= p1.y; ++y) {
        for (int x = p0.x; x <= p1.x; ++x) {
            vec2 cxy = vec2(x, y) + 0.5;
            float w0 = edge(b, c, cxy), w1 = edge(c, a, cxy), w2 = edge(a, b, cxy);
            if (!(covers(w0, tl0) && covers(w1, tl1) && covers(w2, tl2))) continue;
            vec3 bary = vec3(w0, w1, w2) / area2;
            float z = bary.x * a.z + bary.y * b.z + bary.z * c.z;
            fragment(ivec2(x, y), z, bary.x * a.refl + bary.y * b.refl + bary.z * c.refl);
        }
    }
}

void main() {
    if (gl_GlobalInvocationID.x >= u_count) return;
    uint id = pixel_ids[gl_GlobalInvocationID.x];
    ivec2 s = ivec2(int(id) % u_kf_size.x, int(id) / u_kf_size.x);
    Vertex v00 = grid_vertex(s);
    if (v00.valid) {
        ivec2 pix = ivec2(floor(v00.xy));
        if (kf_inside(pix)) fragment(pix, v00.z * (1.0 + u_point_bias), v00.refl);
    }
    uint mask = texelFetch(u_grid, s, 0).r;
    if (mask == 0u || !v00.valid) return;
    Vertex v11 = grid_vertex(s + ivec2(1, 1));
    if ((mask & 1u) != 0u) triangle(v00, grid_vertex(s + ivec2(1, 0)), v11);
    if ((mask & 2u) != 0u) triangle(v00, v11, grid_vertex(s + ivec2(0, 1)));
}
