// Connected components of the clustering (§4.3, issue 17: clusters split where
// the reflector's normal field breaks) by union-find over the samples (Playne &
// Hawick 2018, "A new algorithm for parallel connected-component labelling on
// GPUs"): labels[i] is sample i's parent (linear index ss·W·y + x), a root is its
// own parent, and a union links the larger root below the smaller with atomicMin,
// so every component's root is its least sample index. NONE: not reflective.
layout(std430, binding = UNIT_Labels) coherent volatile buffer Labels { uint labels[]; };
#define NONE 0xFFFFFFFFu

uint find_root(uint x) {
    uint y = labels[x];
    while (y != x) { x = y; y = labels[x]; }
    return x;
}
