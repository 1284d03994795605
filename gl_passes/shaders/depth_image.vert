#version 430 core
// Scene geometry for depth images (thesis Ch. 2): world position, normal and
// positive eye-space depth per vertex, like scene.vert. With NON_REDUNDANT and
// VS_PROJECT it also projects the vertex into every previous image I_j
// (j < N_PREV) in I_j's texel space: clip coordinates are linear in the world
// position, so their perspective-correct interpolation equals projecting the
// fragment's interpolated world position, at a fraction of the per-fragment cost.
uniform mat4 u_view;
uniform mat4 u_view_proj;
in vec3 in_position;
in vec3 in_normal;
#if defined(NON_REDUNDANT) && defined(VS_PROJECT)
uniform mat4 u_prev_texel[N_PREV];  // world → I_j clip space with xy scaled to texels
#endif
out Frag {
    vec3 position;
    vec3 normal;
    float depth;
#if defined(NON_REDUNDANT) && defined(VS_PROJECT)
    vec4 prev[N_PREV];
#endif
} v_out;

void main() {
    vec4 p = vec4(in_position, 1.0);
    v_out.position = in_position;
    v_out.normal = in_normal;
    v_out.depth = -(u_view * p).z;
    gl_Position = u_view_proj * p;
#if defined(NON_REDUNDANT) && defined(VS_PROJECT)
    for (int j = 0; j < N_PREV; ++j) v_out.prev[j] = u_prev_texel[j] * p;
#endif
}
