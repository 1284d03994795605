#version 430 core
// Hybrid reconstruction, pass 2 of 3 (Alg. 4): the vertices at one pixel corner c
// of I, for the (up to) four samples around it. Samples that take c from H share
// H's sample there as one vertex. The others get the intersection of c's camera ray
// with their tangent plane (depth clamped to ± u_max_extent pixel footprints of the
// sample's, for grazing planes); neighbours around c on one surface (edge-adjacent
// pixels, same_surface both ways) share one vertex, the mean of their intersections,
// so a surface narrower than a pixel (a blade, a twig) stays one connected strip
// instead of a row of separate quads. With evidence images bound, such a corner is
// pulled toward its samples where an earlier image of the set saw past it
// (reconstruct_evidence.glsl). Writes each sample's corner vertex index to
// u_sample_corner at (2x + cx, 2y + cy) for its corner (x + cx, y + cy).
// With u_offset_evidence = p > 0 (a diagnostic, tried and not kept), a tangent-plane
// corner whose own H ray saw past it (H's sample there lies more than u_e_tol pixel
// footprints beyond it) moves the share p of the way to the middle of its samples
// and itself: the surface's edge lies between them.
// With u_offset_quads = e > 0 (a diagnostic, tried and not kept), an H sample that
// no sample around c takes (a surface seen at the corner but at none of the four
// pixel centres) becomes a quad of its own, on its tangent plane over the square
// c ± e pixels.
#include "reconstruct_common.glsl"
#include "reconstruct_evidence.glsl"

layout(rgba32ui, binding = UNIT_u_h_a) uniform readonly uimage2D u_h_a;
layout(rgba32ui, binding = UNIT_u_h_b) uniform readonly uimage2D u_h_b;
layout(r32ui, binding = UNIT_u_flags) uniform readonly uimage2D u_flags;
layout(r32ui, binding = UNIT_u_sample_corner) uniform writeonly uimage2D u_sample_corner;
uniform vec3 u_right;   // camera right × tan(fov/2)·aspect
uniform vec3 u_up;      // camera up × tan(fov/2)
uniform bool u_join;    // share tangent-plane corners between same-surface neighbours
uniform float u_e_pull; // share of the evidence rule's move applied (1: to the expected edge)
uniform float u_offset_quads;  // half size (pixels) of an untaken H sample's own quad; 0: none
uniform float u_offset_evidence;  // share of the move to the middle where H saw past a corner; 0: none

// The point of s's tangent plane on the camera ray through screen point c (pixels
// of I, corner (0, 0) at the top left), its depth clamped for grazing planes.
vec3 tangent_plane_corner(Sample s, vec2 c) {
    vec2 ndc = vec2(2.0 * c.x / float(u_size.x) - 1.0, 1.0 - 2.0 * c.y / float(u_size.y));
    vec3 d = u_forward + ndc.x * u_right + ndc.y * u_up;  // ray direction with dot(d, forward) = 1
    float zs = dot(s.position - u_eye, u_forward);
    float denom = dot(s.normal, d);
    float z = abs(denom) > 1e-12 ? dot(s.normal, s.position - u_eye) / denom : zs;
    float extent = u_max_extent * footprint(s.position);
    z = clamp(z, zs - extent, zs + extent);
    return u_eye + z * d;
}

void main() {
    ivec2 c = ivec2(gl_GlobalInvocationID.xy);
    if (any(greaterThan(c, u_size))) return;  // corners: (W+1)×(H+1)
    // Slot k: the pixel whose corner k is c (k = 0: below right of c, then clockwise
    // as seen on screen: below left, above left, above right); slots k and k+1 share
    // an edge of the pixel grid that ends at c.
    Sample s[4];
    bool tangent[4];
    bool from_h = false;
    ivec2 pix[4];
    for (int k = 0; k < 4; ++k) {
        pix[k] = c - CORNER[k];
        tangent[k] = false;
        s[k].valid = false;
        if (any(lessThan(pix[k], ivec2(0))) || any(greaterThanEqual(pix[k], u_size))) continue;
        uint flags = imageLoad(u_flags, pix[k]).r;
        if ((flags & 16u) == 0u) continue;
        s[k] = load_sample(imageLoad(u_i_a, pix[k]), imageLoad(u_i_b, pix[k]));
        if ((flags & (1u << k)) != 0u) from_h = true;
        else tangent[k] = true;
    }
    uint h_index = 0u;
    Sample h = load_sample(imageLoad(u_h_a, c), imageLoad(u_h_b, c));
    if (from_h) {
        h_index = atomicAdd(n_vertices, 1u);
        emit_vertex(h_index, h.position, h.rgba);
    } else if (u_offset_quads > 0.0 && h.valid) {
        uint base = atomicAdd(n_vertices, 4u);
        uint v[4];
        for (int k = 0; k < 4; ++k) {
            v[k] = base + uint(k);
            emit_vertex(v[k], tangent_plane_corner(h, vec2(c) + (2.0 * vec2(CORNER[k]) - 1.0) * u_offset_quads),
                        h.rgba);
        }
        emit_quad(v);
    }
    // Groups of tangent-plane slots joined across shared grid edges (labels = least slot).
    int label[4] = int[4](0, 1, 2, 3);
    bool link[4];
    for (int k = 0; k < 4; ++k) {
        int m = (k + 1) & 3;
        link[k] = u_join && tangent[k] && tangent[m] && same_surface(s[k], s[m], 1.0) && same_surface(s[m], s[k], 1.0);
    }
    for (int it = 0; it < 3; ++it) {
        for (int k = 0; k < 4; ++k) {
            int m = (k + 1) & 3;
            if (link[k]) label[k] = label[m] = min(label[k], label[m]);
        }
    }
    uint index[4];
    for (int g = 0; g < 4; ++g) {
        if (!tangent[g] || label[g] != g) continue;
        vec3 x = vec3(0.0), sp = vec3(0.0);
        vec4 rgba = vec4(0.0);
        float n = 0.0;
        for (int k = 0; k < 4; ++k) {
            if (!tangent[k] || label[k] != g) continue;
            x += tangent_plane_corner(s[k], vec2(c));
            sp += s[k].position;
            rgba += unpackUnorm4x8(s[k].rgba);
            n += 1.0;
        }
        x /= n;
        sp /= n;
        float keep = 1.0;
        if (u_n_evidence > 0) keep = mix(1.0, evidence_keep(sp, x), u_e_pull);
        if (u_offset_evidence > 0.0 && h.valid && dot(h.position - x, u_forward) > u_e_tol * footprint(x))
            keep = min(keep, 1.0 - 0.5 * u_offset_evidence);
        x = mix(sp, x, keep);
        index[g] = atomicAdd(n_vertices, 1u);
        emit_vertex(index[g], x, packUnorm4x8(rgba / n));
    }
    for (int k = 0; k < 4; ++k) {
        if (!s[k].valid) continue;
        uint v = tangent[k] ? index[label[k]] : h_index;
        imageStore(u_sample_corner, 2 * pix[k] + CORNER[k], uvec4(v));
    }
}
