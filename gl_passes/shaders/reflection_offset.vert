#version 430 core
// Reflection offset (thesis §5.4.2): a grid mesh with one vertex per keyframe pixel,
// drawn from index buffers only (gl_VertexID = the pixel index y·W + x, GL rows):
// triangles of the 2×2 pixel blocks, or POINTS one per pixel. Each vertex moves
// from its pixel centre by its best-match offset (texel units) and carries its
// pixel's reflected colour and ray length; depth = d + r (the reflected path
// length from the keyframe eye) resolves overlaps.
#include "reuse_common.glsl"

layout(binding = UNIT_u_offsets_tex) uniform sampler2D u_offsets_tex;
uniform float u_depth_scale;   // 1 / (largest d + r): maps d + r into [0, 1]
uniform float u_point_bias;    // POINTS: depth × (1 + bias), so samples only fill what no triangle covers

out vec4 v_reflection;   // Lr, r
flat out int v_valid;    // best-match offset valid and the pixel reflective

ivec2 grid_pixel() { return ivec2(gl_VertexID % u_kf_size.x, gl_VertexID / u_kf_size.x); }

void main() {
    ivec2 p = grid_pixel();
    vec4 o = texelFetch(u_offsets_tex, p, 0);
    vec4 refl = texelFetch(u_kf_reflection, p, 0);
    v_reflection = refl;
    v_valid = (o.z > 0.5 && refl.a >= 0.0) ? 1 : 0;
    vec2 ndc = (vec2(p) + o.xy + 0.5) / vec2(u_kf_size) * 2.0 - 1.0;
    float depth = (texelFetch(u_kf_depth, p, 0).r + max(refl.a, 0.0)) * u_depth_scale;
#ifdef POINTS
    depth *= 1.0 + u_point_bias;
#endif
    gl_Position = vec4(ndc, clamp(depth, 0.0, 1.0) * 2.0 - 1.0, 1.0);
}
