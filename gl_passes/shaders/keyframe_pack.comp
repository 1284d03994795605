#version 430 core
// Keyframe (thesis §5.3): fields of the reflection depth image that the reuse passes
// test together go into the spare channels of the keyframe's G-buffer textures, so
// that one fetch brings them: position.w = eye-space depth d (B.1) and normal.w =
// reflected-ray length r (B.4; −1 where the pixel is not reflective). One invocation
// per keyframe pixel.
layout(local_size_x = 8, local_size_y = 8) in;
#include "reuse_common.glsl"

layout(rgba32f, binding = UNIT_u_kf_position_img) uniform image2D u_kf_position_img;
layout(rgba32f, binding = UNIT_u_kf_normal_img) uniform image2D u_kf_normal_img;

void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    if (!kf_inside(p)) return;
    vec4 w = imageLoad(u_kf_position_img, p);
    vec4 n = imageLoad(u_kf_normal_img, p);
    imageStore(u_kf_position_img, p, vec4(w.xyz, texelFetch(u_kf_depth, p, 0).r));
    imageStore(u_kf_normal_img, p, vec4(n.xyz, texelFetch(u_kf_reflection, p, 0).a));
}
