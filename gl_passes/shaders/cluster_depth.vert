#version 430 core
// Cluster depth image (§4.4-4.5): scene geometry seen from a cluster camera; the
// fitting plane is the near clip plane (gl_ClipDistance), depth is linear along
// the camera axis. Local shading per vertex (Gouraud): fragments interpolate one
// colour instead of normalising and shading a normal (cheaper on llvmpipe, where
// fragments are about half of this step; bench/results/reflections.md).
#include "common.glsl"
uniform vec3 u_albedo;
uniform mat4 u_view;
uniform mat4 u_view_proj;
uniform vec4 u_clip_plane;  // keep dot(xyz, p) >= w
in vec3 in_position;
in vec3 in_normal;
out vec3 vs_colour;
out float vs_depth;
out gl_PerVertex { vec4 gl_Position; float gl_ClipDistance[1]; };

void main() {
    vs_colour = local_shade(u_albedo, normalize(in_normal));
    vs_depth = -(u_view * vec4(in_position, 1.0)).z;
    gl_ClipDistance[0] = dot(u_clip_plane.xyz, in_position) - u_clip_plane.w;
    gl_Position = u_view_proj * vec4(in_position, 1.0);
}
