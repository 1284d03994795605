#version 430 core
// Block union-find, step 1 (cluster_labels.glsl): every 16×16 tile unites its
// connected samples (cluster_edges.glsl) inside the tile, in shared memory; each
// reflective sample's label becomes its tile-local root, and the local roots are
// flagged (comp_count = 1) for cluster_roots.comp. A row's stretch of samples
// connected to their left neighbours needs no union: each points at the stretch's
// first sample; then a sample connected to its upper neighbour unites the two
// stretches unless its left neighbour already did (connected to it, to its own
// upper neighbour, and that one to ours): one union per pair of touching stretches
// instead of one per edge (unions are loops of atomics, which a CPU rasteriser runs
// lane by lane). The roots are the same: each component's least index.
#include "cluster_labels.glsl"
#include "cluster_edges.glsl"
#include "reflective_list.glsl"
layout(local_size_x = TILE, local_size_y = TILE) in;  // one work group per listed tile
layout(std430, binding = UNIT_CompCount) buffer CompCount { uint comp_count[]; };
shared uint s_parent[TILE * TILE];
shared uint s_bin[TILE * TILE];     // the tile's raw bins + 1 and mirror normals, fetched once
shared vec3 s_normal[TILE * TILE];
shared uint s_edge[TILE * TILE];    // bit 0: connected to the left neighbour, bit 1: to the upper one
UNION_FIND(local_find, local_find_halving, local_unite, s_parent)

// cluster_edges.glsl's rule between two samples of the tile (local indices)
bool local_connected(uint a, uint b) {
    return joined(s_bin[a], s_normal[a], s_bin[b], s_normal[b]);
}

void main() {
    ivec2 tile = list_tile();
    ivec2 l = ivec2(gl_LocalInvocationID.xy);
    ivec2 p = tile * TILE + l;
    uint li = gl_LocalInvocationIndex;
    ivec2 size = textureSize(u_bins, 0);
    bool inside = all(lessThan(p, size));
    uint bin = inside ? texelFetch(u_bins, p, 0).r : 0u;
    s_parent[li] = li;
    s_bin[li] = bin;
    s_normal[li] = bin != 0u ? texelFetch(u_mnormal, p, 0).xyz : vec3(0.0);
    memoryBarrierShared();
    barrier();
    bool left = bin != 0u && l.x > 0 && local_connected(li, li - 1u);
    bool up = bin != 0u && l.y > 0 && local_connected(li, li - uint(TILE));
    s_edge[li] = (left ? 1u : 0u) | (up ? 2u : 0u);
    memoryBarrierShared();
    barrier();
    uint first = li;  // the first sample of this row's stretch
    while ((s_edge[first] & 1u) != 0u) first -= 1u;
    s_parent[li] = first;
    memoryBarrierShared();
    barrier();
    if (up && !(left && (s_edge[li - 1u] & 2u) != 0u && (s_edge[li - uint(TILE)] & 1u) != 0u))
        local_unite(li, li - uint(TILE));
    memoryBarrierShared();
    barrier();
    if (bin == 0u) return;
    uint r = local_find(li);
    ivec2 rp = tile * TILE + ivec2(r % uint(TILE), r / uint(TILE));
    uint idx = uint(p.y * size.x + p.x);
    labels[idx] = uint(rp.y * size.x + rp.x);
    if (r == li) comp_count[idx] = 1u;
}
