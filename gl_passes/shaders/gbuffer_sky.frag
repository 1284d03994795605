#version 430 core
// Background of the G-buffer: sky colour along the pixel's ray (a: s = 0), ids 0.
#include "common.glsl"
// Camera basis scaled by the half-extents of the image plane at unit distance.
uniform vec3 u_cam_right;
uniform vec3 u_cam_up;
uniform vec3 u_cam_forward;
in vec2 v_ndc;
layout(location = 0) out vec4 out_color;
layout(location = 1) out float out_depth;
layout(location = 2) out vec4 out_normal;
layout(location = 3) out vec4 out_position;
layout(location = 4) out uint out_tri;
layout(location = 5) out uint out_object;
layout(location = 6) out vec2 out_material;

void main() {
    vec3 d = normalize(u_cam_forward + v_ndc.x * u_cam_right + v_ndc.y * u_cam_up);
    out_color = vec4(sky(d), 0.0);
    out_depth = 0.0;
    out_normal = vec4(0.0);
    out_position = vec4(0.0);
    out_tri = 0u;
    out_object = 0u;
    out_material = vec2(0.0);
}
