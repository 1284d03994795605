// The reflective samples of the supersampled G-buffer as one list, and the 16×16
// tiles holding any, built tile by tile (list_tile_samples: by cluster_count.comp
// in a frame, by reflective_list.comp from a bin image): the passes that work per
// reflective sample or per tile run over them instead of over every sample, since
// a CPU rasteriser runs an invocation's code under a lane mask even when none of
// its lanes has a reflective sample. The dispatch triples are
// glDispatchComputeIndirect arguments: groups of 64 or 256 invocations over the
// samples, one group per listed tile.
#ifndef LIST_ACCESS
#define LIST_ACCESS readonly
#endif
layout(std430, binding = UNIT_SampleList) LIST_ACCESS buffer SampleList {
    uint n_samples;
    uint dispatch64[3];
    uint dispatch256[3];
    uint list_pad_;
    uint sample_xy[];  // x | y << 16
};
layout(std430, binding = UNIT_TileList) LIST_ACCESS buffer TileList {
    uint n_tiles;
    uint dispatch_tiles[3];
    uint tile_xy[];  // tile x | tile y << 16
};

ivec2 list_unpack(uint v) { return ivec2(int(v & 0xFFFFu), int(v >> 16)); }
ivec2 list_sample(uint i) { return list_unpack(sample_xy[i]); }
ivec2 list_tile() { return list_unpack(tile_xy[gl_WorkGroupID.x]); }  // this work group's tile

#ifdef LIST_WRITER
shared uint s_listed_;
shared uint s_list_base_;
// A work group over one 16×16 tile lists its samples in one contiguous stretch (in
// invocation order on a CPU rasteriser, so neighbours stay neighbours) and the tile
// when it listed any, in three phases between which the caller puts barriers:
// list_begin() | list_reserve(n) per invocation: the first of its n slots |
// list_publish() | list_put(slot, p) for each of its slots.
void list_begin() { if (gl_LocalInvocationIndex == 0u) s_listed_ = 0u; }
uint list_reserve(uint n) { return n > 0u ? atomicAdd(s_listed_, n) : 0u; }
void list_publish() {
    if (gl_LocalInvocationIndex == 0u && s_listed_ > 0u) {
        s_list_base_ = atomicAdd(n_samples, s_listed_);
        uint end = s_list_base_ + s_listed_;
        atomicMax(dispatch64[0], (end + 63u) / 64u);
        atomicMax(dispatch256[0], (end + 255u) / 256u);
        uint t = atomicAdd(n_tiles, 1u);
        tile_xy[t] = gl_WorkGroupID.x | (gl_WorkGroupID.y << 16);
        atomicMax(dispatch_tiles[0], t + 1u);
    }
}
void list_put(uint slot, ivec2 p) { sample_xy[s_list_base_ + slot] = uint(p.x) | (uint(p.y) << 16); }

// One sample per invocation of a 16×16 work group, in uniform control flow (it
// holds barriers): lists p when `listed`.
void list_tile_samples(bool listed, ivec2 p) {
    list_begin();
    barrier();
    uint slot = list_reserve(listed ? 1u : 0u);
    barrier();
    list_publish();
    barrier();
    if (listed) list_put(slot, p);
}
#endif
