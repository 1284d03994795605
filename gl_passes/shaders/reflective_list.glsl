// The reflective samples of the supersampled G-buffer as one list (built by
// reflective_list.comp, tile by tile): the passes that work per reflective sample
// (cluster_extent.comp, reflect_trace.comp) run over it instead of over every
// sample, since a CPU rasteriser runs an invocation's code under a lane mask even
// when none of its lanes has a reflective sample. The two dispatch triples are
// glDispatchComputeIndirect arguments for groups of 64 and 256 invocations.
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

ivec2 list_sample(uint i) { uint v = sample_xy[i]; return ivec2(int(v & 0xFFFFu), int(v >> 16)); }
