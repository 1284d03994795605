#version 430 core
// Triangle id = object's base face offset + primitive id + 1 (0 = background).
layout(triangles) in;
layout(triangle_strip, max_vertices = 3) out;
uniform uint u_base;
in vec3 vs_position[];
in vec3 vs_normal[];
in float vs_depth[];
out vec3 g_position;
out vec3 g_normal;
out float g_depth;
flat out uint g_tri;

void main() {
    for (int i = 0; i < 3; ++i) {
        g_position = vs_position[i];
        g_normal = vs_normal[i];
        g_depth = vs_depth[i];
        g_tri = u_base + uint(gl_PrimitiveIDIn) + 1u;
        gl_Position = gl_in[i].gl_Position;
        EmitVertex();
    }
    EndPrimitive();
}
