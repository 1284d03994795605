#version 430 core
// Block union-find, step 2 (cluster_labels.glsl): one work group per listed tile, one
// invocation per sample of its left column (0..TILE-1) and top row
// (TILE..2·TILE-1), each uniting its sample's set with the neighbour's across the
// tile border when connected (cluster_edges.glsl). Neighbouring invocations of a
// side that would unite the same two labels leave it to the first.
#include "cluster_labels.glsl"
#include "cluster_edges.glsl"
#include "reflective_list.glsl"
layout(local_size_x = TILE_SIDES) in;  // one work group per listed tile (a tile without samples has no edge)
shared uvec2 s_pair[TILE_SIDES];

void main() {
    uint t = gl_LocalInvocationID.x;
    bool left = t < uint(TILE);
    uint k = left ? t : t - uint(TILE);
    ivec2 p = list_tile() * TILE + (left ? ivec2(0, k) : ivec2(k, 0));
    ivec2 q = p - (left ? ivec2(1, 0) : ivec2(0, 1));
    ivec2 size = textureSize(u_bins, 0);
    bool edge = connected(p, q);
    // first hops (the tile-local roots, or further up their sets): same sets as p and q
    uvec2 pair = edge ? uvec2(labels[p.y * size.x + p.x], labels[q.y * size.x + q.x]) : uvec2(NONE);
    s_pair[t] = pair;
    memoryBarrierShared();
    barrier();
    if (!edge || (k > 0u && s_pair[t - 1u] == pair)) return;
    unite(pair.x, pair.y);
}
