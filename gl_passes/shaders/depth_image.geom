#version 430 core
// Optional geometry stage for depth images: triangle id = object's base face
// offset + primitive id + 1 (the thesis, §2.3.1). Only used to measure its cost
// (TRI_FROM_GEOM); by default the fragment shader reads gl_PrimitiveID instead,
// as the G-buffer's does.
layout(triangles) in;
layout(triangle_strip, max_vertices = 3) out;
uniform uint u_base;
in Frag {
    vec3 position;
    vec3 normal;
    float depth;
#if defined(NON_REDUNDANT) && defined(VS_PROJECT)
    vec4 prev[N_PREV];
#endif
} g_in[];
out Frag {
    vec3 position;
    vec3 normal;
    float depth;
#if defined(NON_REDUNDANT) && defined(VS_PROJECT)
    vec4 prev[N_PREV];
#endif
} g_out;
flat out uint g_tri;

void main() {
    for (int i = 0; i < 3; ++i) {
        g_out.position = g_in[i].position;
        g_out.normal = g_in[i].normal;
        g_out.depth = g_in[i].depth;
#if defined(NON_REDUNDANT) && defined(VS_PROJECT)
        g_out.prev = g_in[i].prev;
#endif
        g_tri = u_base + uint(gl_PrimitiveIDIn) + 1u;
        gl_Position = gl_in[i].gl_Position;
        EmitVertex();
    }
    EndPrimitive();
}
