#version 430 core
// Scene geometry: world position, normal and positive eye-space depth per vertex.
uniform mat4 u_view;
uniform mat4 u_view_proj;
in vec3 in_position;
in vec3 in_normal;
out vec3 vs_position;
out vec3 vs_normal;
out float vs_depth;

void main() {
    vs_position = in_position;
    vs_normal = in_normal;
    vs_depth = -(u_view * vec4(in_position, 1.0)).z;
    gl_Position = u_view_proj * vec4(in_position, 1.0);
}
