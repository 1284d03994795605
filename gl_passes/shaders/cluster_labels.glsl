// Connected components of the clustering (§4.3, issue 17: clusters split where
// the reflector's normal field breaks) by block union-find over the samples
// (Playne & Hawick 2018, "A new algorithm for parallel connected-component
// labelling on GPUs"): labels[i] is sample i's parent (linear index W·y + x), a
// root is its own parent, and a union links the larger root below the smaller
// with atomicMin, so every component's root is its least sample index. Each
// 16×16 tile is first labelled in shared memory (cluster_merge.comp), then only
// the tiles' local roots are united across tile borders (cluster_border.comp):
// run over every sample at once, a GPU links a whole row's samples into one chain
// that every later union walks. NONE: not reflective.
layout(std430, binding = UNIT_Labels) coherent volatile buffer Labels { uint labels[]; };
#define NONE 0xFFFFFFFFu
// TILE (the tile side) and TILE_SIDES (2 · TILE: a tile's left column and top row)
// come from gl_passes.clustering (GROUP).

// UNION_FIND(FIND, FIND_HALVING, UNITE, A): over the parent array A (a storage
// buffer or a shared array), FIND(x) is x's root; FIND_HALVING(x) also points
// every node it passes at its grandparent (same set, smaller index: atomicMin,
// so a concurrent link is never undone); UNITE(a, b) joins a's and b's sets.
#define UNION_FIND(FIND, FIND_HALVING, UNITE, A) \
uint FIND(uint x) { \
    uint y = A[x]; \
    while (y != x) { x = y; y = A[x]; } \
    return x; \
} \
uint FIND_HALVING(uint x) { \
    uint y = A[x]; \
    while (y != x) { \
        uint z = A[y]; \
        if (z != y) atomicMin(A[x], z); \
        x = y; y = z; \
    } \
    return x; \
} \
void UNITE(uint a, uint b) { \
    for (;;) { \
        a = FIND_HALVING(a); b = FIND_HALVING(b); \
        if (a == b) return; \
        uint hi = max(a, b), lo = min(a, b); \
        uint old = atomicMin(A[hi], lo); \
        if (old == hi) return; \
        a = old; b = lo; \
    } \
}

UNION_FIND(find_root, find_root_halving, unite, labels)
