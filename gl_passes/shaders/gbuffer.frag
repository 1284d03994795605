#version 430 core
// G-buffer: local-shaded colour (rgb; a = the specular factor s, so that one read-back
// brings both), linear depth, world normal and position,
// triangle id (the object's base face offset u_base + gl_PrimitiveID + 1, which
// counts the draw's triangles from 0: no geometry shader), object id and material (s, g).
#include "common.glsl"
uniform vec3 u_albedo;
uniform float u_specular;
uniform float u_glossiness;
uniform uint u_object;
uniform uint u_base;
in vec3 vs_position;
in vec3 vs_normal;
in float vs_depth;
layout(location = 0) out vec4 out_color;
layout(location = 1) out float out_depth;
layout(location = 2) out vec4 out_normal;
layout(location = 3) out vec4 out_position;
layout(location = 4) out uint out_tri;
layout(location = 5) out uint out_object;
layout(location = 6) out vec2 out_material;

void main() {
    vec3 n = normalize(vs_normal);
    if (!gl_FrontFacing) n = -n;  // only reachable with culling off
    out_color = vec4(local_shade(u_albedo, n), u_specular);
    out_depth = vs_depth;
    out_normal = vec4(n, 0.0);
    out_position = vec4(vs_position, 1.0);
    out_tri = u_base + uint(gl_PrimitiveID) + 1u;
    out_object = u_object;
    out_material = vec2(u_specular, u_glossiness);
}
