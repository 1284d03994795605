#version 430 core
// bench/host_costs.py: the cost of a compute dispatch's building blocks on this
// host's GL (on llvmpipe: work groups run as coroutines, a barrier switches them;
// an atomic runs lane by lane), in the shape of the clustering's passes (16×16
// work groups over a supersampled G-buffer, gl_passes.clustering). Compiled in:
// BARRIERS (work-group barriers per invocation) and ATOMIC (0 none; 1 one
// shared-memory atomicAdd per invocation; 2 one atomicAdd per invocation on a
// single storage-buffer word, contended by every thread).
layout(local_size_x = 16, local_size_y = 16) in;
layout(std430, binding = SINK_BINDING) buffer Sink { uint sink[]; };
uniform uint u_never;  // never equal to an invocation's value: keeps the work observable
shared uint s_count;

void main() {
    uint v = gl_GlobalInvocationID.x ^ (gl_GlobalInvocationID.y << 16);
    if (gl_LocalInvocationIndex == 0u) s_count = 0u;
    for (int i = 0; i < BARRIERS; ++i) {
        barrier();
        if (gl_LocalInvocationIndex == uint(i)) s_count += v;
    }
#if ATOMIC == 1
    v += atomicAdd(s_count, 1u);
#elif ATOMIC == 2
    v += atomicAdd(sink[1], 1u);
#endif
    if (v == u_never) sink[0] = s_count;
}
