#version 430 core
// G-buffer: local-shaded colour, linear depth, world normal and position,
// triangle id, object id and material (s, g).
#include "common.glsl"
uniform vec3 u_albedo;
uniform float u_specular;
uniform float u_glossiness;
uniform uint u_object;
in vec3 g_position;
in vec3 g_normal;
in float g_depth;
flat in uint g_tri;
layout(location = 0) out vec4 out_color;
layout(location = 1) out float out_depth;
layout(location = 2) out vec4 out_normal;
layout(location = 3) out vec4 out_position;
layout(location = 4) out uint out_tri;
layout(location = 5) out uint out_object;
layout(location = 6) out vec2 out_material;

void main() {
    vec3 n = normalize(g_normal);
    if (!gl_FrontFacing) n = -n;  // only reachable with culling off
    out_color = vec4(local_shade(u_albedo, n), 1.0);
    out_depth = g_depth;
    out_normal = vec4(n, 0.0);
    out_position = vec4(g_position, 1.0);
    out_tri = g_tri;
    out_object = u_object;
    out_material = vec2(u_specular, u_glossiness);
}
