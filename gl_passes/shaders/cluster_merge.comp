#version 430 core
// Union of every reflective sample with its left and upper neighbour when both
// lie in the same raw bin and their mirror normals differ by at most the break
// angle (cos u_cos_break): the normal field is continuous between them. Their
// components are the clusters' candidates (cluster_split.comp).
// Two dispatches, one invocation per row (u_columns false), then per column:
// a row's invocation walks it left to right and points every sample joined to
// its left neighbour at the start of their run, a root; a column's invocation
// walks it top to bottom uniting each sample with the one above. Run per sample
// instead, a GPU links a whole row at once, each sample below its left neighbour,
// a chain as long as the row that every later find walks (time growing with the
// cube of the image's side); here a run is one level deep and a union links roots.
layout(local_size_x = 64) in;
#include "cluster_labels.glsl"
layout(binding = UNIT_u_bins) uniform usampler2D u_bins;      // raw bin + 1 (0 = not reflective)
layout(binding = UNIT_u_mnormal) uniform sampler2D u_mnormal;  // mirror normal
uniform float u_cos_break;
uniform bool u_columns;

void unite(uint a, uint b) {
    for (;;) {
        a = find_root(a); b = find_root(b);
        if (a == b) return;
        uint hi = max(a, b), lo = min(a, b);
        uint old = atomicMin(labels[hi], lo);
        if (old == hi) return;  // linked
        a = old; b = lo;        // hi was linked elsewhere meanwhile: unite its new parent
    }
}

void main() {
    ivec2 size = textureSize(u_bins, 0);
    int line = int(gl_GlobalInvocationID.x);
    ivec2 step = u_columns ? ivec2(0, 1) : ivec2(1, 0);
    int n = u_columns ? size.y : size.x;
    if (line >= (u_columns ? size.x : size.y)) return;
    ivec2 q = u_columns ? ivec2(line, 0) : ivec2(0, line);  // the previous sample along the line
    uint q_bin = texelFetch(u_bins, q, 0).r;
    vec3 q_n = texelFetch(u_mnormal, q, 0).xyz;
    uint run = uint(q.y * size.x + q.x);                    // start of the current run (rows)
    for (int i = 1; i < n; ++i) {
        ivec2 p = q + step;
        uint bin = texelFetch(u_bins, p, 0).r;
        vec3 normal = texelFetch(u_mnormal, p, 0).xyz;
        uint idx = uint(p.y * size.x + p.x);
        bool joined = bin != 0u && bin == q_bin && dot(normal, q_n) >= u_cos_break;
        if (!u_columns) {
            if (joined) labels[idx] = run;
            else run = idx;
        } else if (joined) {
            unite(idx, uint(q.y * size.x + q.x));
        }
        q = p; q_bin = bin; q_n = normal;
    }
}
