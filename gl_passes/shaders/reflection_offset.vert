#version 430 core
// Reflection offset (thesis §5.4.2): a grid mesh with one vertex per keyframe pixel,
// drawn without vertex buffers. TRIANGLES: vertex k of quad q (two triangles per 2×2
// pixel block, 6 vertices per quad); POINTS: one vertex per pixel. Each vertex moves
// from its pixel centre by its best-match offset (texel units) and carries its
// pixel's reflected colour and ray length; depth = d + r (the reflected path
// length from the keyframe eye) resolves overlaps.
#include "reuse_common.glsl"

layout(binding = UNIT_u_offsets_tex) uniform sampler2D u_offsets_tex;
uniform float u_depth_scale;   // 1 / (largest d + r): maps d + r into [0, 1]
uniform float u_point_bias;    // POINTS: depth × (1 + bias), so samples only fill what no triangle covers

out vec4 v_reflection;   // Lr, r
out vec3 v_position;     // keyframe world position of the source pixel
flat out ivec2 v_pixel;  // source pixel
flat out int v_valid;    // best-match offset valid and the pixel reflective

#ifdef POINTS
ivec2 grid_pixel() { return ivec2(gl_VertexID % u_kf_size.x, gl_VertexID / u_kf_size.x); }
#else
const ivec2 CORNER[6] = ivec2[6](ivec2(0, 0), ivec2(1, 0), ivec2(1, 1), ivec2(0, 0), ivec2(1, 1), ivec2(0, 1));
ivec2 grid_pixel() {
    int quad = gl_VertexID / 6;
    int qw = u_kf_size.x - 1;
    return ivec2(quad % qw, quad / qw) + CORNER[gl_VertexID % 6];
}
#endif

void main() {
    ivec2 p = grid_pixel();
    vec4 o = texelFetch(u_offsets_tex, p, 0);
    vec4 refl = texelFetch(u_kf_reflection, p, 0);
    v_reflection = refl;
    v_position = texelFetch(u_kf_position, p, 0).xyz;
    v_pixel = p;
    v_valid = (o.z > 0.5 && refl.a >= 0.0) ? 1 : 0;
    vec2 ndc = (vec2(p) + o.xy + 0.5) / vec2(u_kf_size) * 2.0 - 1.0;
    float depth = (texelFetch(u_kf_depth, p, 0).r + max(refl.a, 0.0)) * u_depth_scale;
#ifdef POINTS
    depth *= 1.0 + u_point_bias;
#endif
    gl_Position = vec4(ndc, clamp(depth, 0.0, 1.0) * 2.0 - 1.0, 1.0);
}
