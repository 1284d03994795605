#version 430 core
// Reflection offset (thesis §5.4.2): drops the grid triangles (POINTS: the samples)
// whose reuse is unreliable: a vertex without a valid match; an area grown more than
// u_growth times by the offsets; (beyond the thesis, u_reflected_jump > 0) reflected
// ray lengths that differ by more than that fraction (a discontinuity of the
// reflected scene, whose gap would otherwise be smeared). Triangles across a depth
// discontinuity of the keyframe are not in the index buffer (reflection_offset.py).
#include "reuse_common.glsl"

#ifdef POINTS
layout(points) in;
layout(points, max_vertices = 1) out;
#define N 1
#else
layout(triangles) in;
layout(triangle_strip, max_vertices = 3) out;
#define N 3
#endif

uniform float u_growth;
uniform float u_reflected_jump;

in vec4 v_reflection[];
flat in int v_valid[];
out vec4 f_reflection;

void main() {
    for (int i = 0; i < N; ++i) if (v_valid[i] == 0) return;
#ifndef POINTS
    for (int i = 0; i < 3; ++i) {
        int j = (i + 1) % 3;
        float ra = v_reflection[i].a, rb = v_reflection[j].a;
        if (u_reflected_jump > 0.0 && abs(ra - rb) > u_reflected_jump * min(ra, rb)) return;
    }
    vec2 size = vec2(u_kf_size);
    vec2 a = gl_in[1].gl_Position.xy - gl_in[0].gl_Position.xy;
    vec2 b = gl_in[2].gl_Position.xy - gl_in[0].gl_Position.xy;
    float moved = 0.5 * abs(a.x * b.y - a.y * b.x) * size.x * size.y * 0.25;  // pixels²
    if (moved > u_growth * 0.5) return;                                      // source area 0.5 px²
#endif
    for (int i = 0; i < N; ++i) {
        gl_Position = gl_in[i].gl_Position;
        f_reflection = v_reflection[i];
        EmitVertex();
    }
    EndPrimitive();
}
