#version 430 core
// Baseline grid reconstruction (§3.2): one vertex per sample (index y·W + x) and,
// for the 2×2 block a b / d c whose top-left pixel a is this one, two triangles
// split along a–c (a d c, c b a) or, when a and c are not joined, along b–d
// (a d b, d c b), counter-clockwise from I's camera; each is emitted when its three
// samples exist and are pairwise on the same surface (no depth discontinuity).
#include "reconstruct_common.glsl"

Sample at(ivec2 q) {
    return load_sample(imageLoad(u_i_a, q), imageLoad(u_i_b, q));
}

bool joined(Sample p, Sample q) {
    return same_surface(p, q, 1.0) && same_surface(q, p, 1.0);
}

void emit_triangle(uint a, uint b, uint c) {
    uint i = atomicAdd(n_indices, 3u);
    indices[i] = a; indices[i + 1u] = b; indices[i + 2u] = c;
}

void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    if (any(greaterThanEqual(p, u_size))) return;
    Sample a = at(p);
    uint ia = uint(p.y * u_size.x + p.x);
    if (a.valid) emit_vertex(ia, a.position, a.rgba);
    if (p.x + 1 >= u_size.x || p.y + 1 >= u_size.y) return;
    Sample b = at(p + ivec2(1, 0)), c = at(p + ivec2(1, 1)), d = at(p + ivec2(0, 1));
    uint ib = ia + 1u, ic = ia + uint(u_size.x) + 1u, id = ia + uint(u_size.x);
    if (a.valid && c.valid && joined(a, c)) {  // split along a–c
        if (d.valid && joined(a, d) && joined(d, c)) emit_triangle(ia, id, ic);
        if (b.valid && joined(a, b) && joined(b, c)) emit_triangle(ic, ib, ia);
    } else if (b.valid && d.valid && joined(b, d)) {  // else along b–d
        if (a.valid && joined(a, b) && joined(a, d)) emit_triangle(ia, id, ib);
        if (c.valid && joined(c, b) && joined(c, d)) emit_triangle(id, ic, ib);
    }
}
