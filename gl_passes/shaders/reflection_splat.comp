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
// intermediate image (Lr, r; r >= 0 marks the pixel reliable, cleared to r = -1).
layout(local_size_x = 64) in;
#include "reuse_common.glsl"

layout(binding = UNIT_u_offsets_tex) uniform sampler2D u_offsets_tex;
layout(binding = UNIT_u_grid) uniform usampler2D u_grid;
#ifdef RESOLVE
layout(r32ui, binding = UNIT_u_zbuf) uniform readonly uimage2D u_zbuf;
layout(rgba32f, binding = UNIT_u_inter_img) uniform writeonly image2D u_inter_img;
#else
layout(r32ui, binding = UNIT_u_zbuf) uniform coherent uimage2D u_zbuf;
#endif
layout(std430, binding = UNIT_Pixels) readonly buffer Pixels { uint pixel_ids[]; };
uniform uint u_count;
uniform float u_depth_scale;   // 1 / (largest d + r)
uniform float u_point_bias;
uniform float u_growth;
uniform float u_reflected_jump;

struct Vertex { vec2 xy; float z; vec4 refl; bool valid; };

Vertex grid_vertex(ivec2 p) {
    Vertex v;
    vec4 o = texelFetch(u_offsets_tex, p, 0);
    v.refl = texelFetch(u_kf_reflection, p, 0);
    v.valid = o.z > 0.5 && v.refl.a >= 0.0;
    v.xy = vec2(p) + o.xy + 0.5;                 // window coordinates (pixels)
    v.z = clamp((texelFetch(u_kf_depth, p, 0).r + max(v.refl.a, 0.0)) * u_depth_scale, 0.0, 1.0);
    return v;
}

void fragment(ivec2 pix, float z, vec4 refl) {
    if (!(z < 1.0)) return;
    uint bits = floatBitsToUint(z);
#ifdef RESOLVE
    if (imageLoad(u_zbuf, pix).r == bits) imageStore(u_inter_img, pix, refl);
#else
    imageAtomicMin(u_zbuf, pix, bits);
#endif
}

// Edge equation (A, B, C) of the line from a to b, E(c) = A c.x + B c.y + C, for
// a.id < b.id: each edge is set up once per quad from its lower-id end, so the two
// triangles sharing it evaluate exactly opposite values (watertight).
vec3 edge_equation(Vertex a, Vertex b) {
    vec2 d = b.xy - a.xy;
    return vec3(-d.y, d.x, d.y * a.xy.x - d.x * a.xy.y);
}

// Top-left rule for the edge p → q of a counter-clockwise triangle in GL window
// coordinates (y up).
bool top_left(vec2 p, vec2 q) {
    vec2 d = q - p;
    return d.y < 0.0 || (d.y == 0.0 && d.x < 0.0);
}

bool covers(float e, bool tl) { return e > 0.0 || (e == 0.0 && tl); }

// Narrows the pixel columns [xlo, xhi] of row centre cy to those where the edge
// e (A x + B y + C, interior positive) can be non-negative at a pixel centre. The
// margin (one pixel, plus the bound's float error: a few ulps of the terms over |A|)
// keeps every pixel the exact test below could pass; a horizontal edge, or one whose
// bound lies far outside any image, leaves the span as it is (the exact test decides
// its rows: a row on the edge line depends on the sign of a rounded zero); an empty
// span leaves xlo > xhi.
void span(vec3 e, float cy, inout float xlo, inout float xhi) {
    if (e.x == 0.0) return;    // a horizontal edge bounds rows, not columns
    float r = e.y * cy + e.z;
    float m = 1.0 + 1e-6 * (abs(e.y * cy) + abs(e.z) + abs(e.x) * float(u_kf_size.x)) / abs(e.x);
    float x = -r / e.x - 0.5;
    if (!(abs(x) + m < 1e7)) return;    // a near-horizontal edge (or overflow): no narrowing
    if (e.x > 0.0) xlo = max(xlo, ceil(x - m));
    else xhi = min(xhi, floor(x + m));
}

// Triangle a, b, c with the equations of its edges a → b, b → c, c → a (positive on
// the left of each direction).
void triangle(Vertex a, Vertex b, Vertex c, vec3 e_ab, vec3 e_bc, vec3 e_ca) {
    if (!(a.valid && b.valid && c.valid)) return;
    if (u_reflected_jump > 0.0) {
        if (abs(a.refl.a - b.refl.a) > u_reflected_jump * min(a.refl.a, b.refl.a)) return;
        if (abs(b.refl.a - c.refl.a) > u_reflected_jump * min(b.refl.a, c.refl.a)) return;
        if (abs(c.refl.a - a.refl.a) > u_reflected_jump * min(c.refl.a, a.refl.a)) return;
    }
    vec2 ab = b.xy - a.xy, ac = c.xy - a.xy;
    float area2 = ab.x * ac.y - ab.y * ac.x;      // twice the signed area (px²)
    if (0.5 * abs(area2) > u_growth * 0.5 || area2 == 0.0) return;
    float sg = area2 > 0.0 ? 1.0 : -1.0;          // counter-clockwise: the interior is positive
    e_ab *= sg; e_bc *= sg; e_ca *= sg;
    bool ccw = area2 > 0.0;
    bool tl_ab = ccw ? top_left(a.xy, b.xy) : top_left(b.xy, a.xy);
    bool tl_bc = ccw ? top_left(b.xy, c.xy) : top_left(c.xy, b.xy);
    bool tl_ca = ccw ? top_left(c.xy, a.xy) : top_left(a.xy, c.xy);
    vec2 lo = min(a.xy, min(b.xy, c.xy)), hi = max(a.xy, max(b.xy, c.xy));
    ivec2 p0 = max(ivec2(ceil(lo - 0.5)), ivec2(0));
    ivec2 p1 = min(ivec2(floor(hi - 0.5)), u_kf_size - 1);
    for (int y = p0.y; y <= p1.y; ++y) {
        // the row's span where no edge is negative (one pixel of margin for rounding;
        // the exact test below decides), so a long sliver costs its rows, not its box
        float cy = float(y) + 0.5;
        float xlo = float(p0.x), xhi = float(p1.x);
        span(e_ab, cy, xlo, xhi);
        span(e_bc, cy, xlo, xhi);
        span(e_ca, cy, xlo, xhi);
        xlo = min(xlo, float(p1.x) + 1.0);    // bounded, so the int conversions are defined
        xhi = max(xhi, float(p0.x) - 1.0);
        for (int x = int(xlo); x <= int(xhi); ++x) {
            vec3 cxy = vec3(vec2(x, y) + 0.5, 1.0);
            float wa = dot(e_bc, cxy), wb = dot(e_ca, cxy), wc = dot(e_ab, cxy);
            if (!(covers(wa, tl_bc) && covers(wb, tl_ca) && covers(wc, tl_ab))) continue;
            vec3 bary = vec3(wa, wb, wc) / (wa + wb + wc);
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
    // ids: 00 < 10 < 01 < 11; every edge equation from its lower-id end
    Vertex v11 = grid_vertex(s + ivec2(1, 1));
    vec3 e_00_11 = edge_equation(v00, v11);
    if ((mask & 1u) != 0u) {
        Vertex v10 = grid_vertex(s + ivec2(1, 0));
        triangle(v00, v10, v11, edge_equation(v00, v10), edge_equation(v10, v11), -e_00_11);
    }
    if ((mask & 2u) != 0u) {
        Vertex v01 = grid_vertex(s + ivec2(0, 1));
        triangle(v00, v11, v01, e_00_11, -edge_equation(v01, v11), -edge_equation(v00, v01));
    }
}
