#version 430 core
// Quad splats of the shadow-map pass (thesis Alg. 5 over Alg. 4's small pieces;
// gl_passes/quad_splats.py): a compute rasteriser. Invocation (splat s, map i of
// the batch) projects the splat's quad (two triangles sharing the diagonal s0-s1,
// the others' corners o0 and o1, world units; a lone triangle has o1 = o0) into
// map i, and for every texel centre of map i's tile that lies in either triangle
// keeps the nearest window depth of that triangle's plane (window depth is affine
// in window x, y over a planar triangle, as the rasteriser interpolates it; clamped
// to [0, 1] as depth clamping does) by an atomic min on the depth's bits, which
// order as the depths do for depths >= 0. A splat with a corner behind a light
// camera's eye (w <= 0) is skipped in that map (light cameras hold the scene box
// in front of them). Work groups: x, y the splat (row-major, u_groups_x per row),
// z the map.
layout(local_size_x = 64) in;

layout(std430, binding = UNIT_splats) readonly buffer Splats { float corners[]; };  // 12 per splat
layout(r32ui, binding = UNIT_splat_depth) uniform uimage2D u_splat_depth;  // EMPTY or depth bits

uniform mat4 u_light_vp[MAPS_PER_DRAW];  // world → clip of each map of the batch
uniform int u_res;                       // texels per map side
uniform int u_tiles;                     // tiles per atlas row (map i: column i % u_tiles, row i / u_tiles)
uniform uint u_count;                    // splats
uniform uint u_groups_x;                 // work groups per row of the dispatch

vec3 corner(uint s, uint k) {
    uint b = s * 12u + k * 3u;
    return vec3(corners[b], corners[b + 1u], corners[b + 2u]);
}

// A triangle s0, s0 + d, s0 + e in window coordinates: the inverse of its edge
// matrix [d e] (zero when it has no area) and its window depths at s0, along d, along e.
struct Edges {
    mat2 inv;
    vec3 z;
    bool live;
};

Edges edges(vec2 d, vec2 e, vec3 z) {
    mat2 m = mat2(d, e);
    float det = determinant(m);
    bool live = abs(det) > 1e-8;
    return Edges(live ? inverse(m) : mat2(0.0), z, live);
}

// Depth of the texel centre at offset q from s0 in triangle t, or 2.0 outside it.
float plane_depth(vec2 q, Edges t) {
    vec2 w = t.inv * q;
    return (t.live && w.x >= 0.0 && w.y >= 0.0 && w.x + w.y <= 1.0) ? t.z.x + w.x * t.z.y + w.y * t.z.z : 2.0;
}

void main() {
    uint s = (gl_WorkGroupID.y * u_groups_x + gl_WorkGroupID.x) * gl_WorkGroupSize.x + gl_LocalInvocationID.x;
    int i = int(gl_WorkGroupID.z);
    if (s >= u_count) return;
    vec3 w[4];
    for (uint k = 0u; k < 4u; ++k) {
        vec4 c = u_light_vp[i] * vec4(corner(s, k), 1.0);
        if (c.w <= 0.0) return;
        vec3 n = c.xyz / c.w;
        w[k] = vec3((n.xy * 0.5 + 0.5) * float(u_res), n.z * 0.5 + 0.5);
    }
    vec2 lo = min(min(w[0].xy, w[1].xy), min(w[2].xy, w[3].xy));
    vec2 hi = max(max(w[0].xy, w[1].xy), max(w[2].xy, w[3].xy));
    // the texel centres (x + 0.5, y + 0.5) in the box, within the tile (clamped as
    // floats: a corner near the eye's plane lies far outside any int)
    ivec2 a = ivec2(clamp(ceil(lo - 0.5), vec2(0.0), vec2(float(u_res))));
    ivec2 b = ivec2(clamp(floor(hi - 0.5), vec2(-1.0), vec2(float(u_res - 1))));
    ivec2 origin = ivec2(i % u_tiles, i / u_tiles) * u_res;
    vec2 d = w[1].xy - w[0].xy;
    Edges t0 = edges(d, w[2].xy - w[0].xy, vec3(w[0].z, w[1].z - w[0].z, w[2].z - w[0].z));
    Edges t1 = edges(d, w[3].xy - w[0].xy, vec3(w[0].z, w[1].z - w[0].z, w[3].z - w[0].z));
    bool lone = w[2] == w[3];  // a lone triangle (o1 = o0): its second is the first again
    for (int y = a.y; y <= b.y; ++y) {
        for (int x = a.x; x <= b.x; ++x) {
            vec2 q = vec2(x, y) + 0.5 - w[0].xy;
            float z = plane_depth(q, t0);
            if (z > 1.5 && !lone) z = plane_depth(q, t1);
            if (z <= 1.5) imageAtomicMin(u_splat_depth, origin + ivec2(x, y), floatBitsToUint(clamp(z, 0.0, 1.0)));
        }
    }
}
