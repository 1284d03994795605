#version 430 core
// Second surface of the cluster's own reflector (one depth peel): like
// cluster_depth.frag, but fragments not behind the first reflector layer (u_prev,
// same atlas viewport) are discarded, so the depth test keeps the next surface.
#include "common.glsl"
layout(binding = UNIT_u_prev) uniform sampler2D u_prev;  // the layer peeled: its depth (out_depth)
in vec3 vs_colour;  // local-shaded per vertex
in float vs_depth;
layout(location = 0) out float out_depth;  // this layer's own depth image (a peel layer's u_prev)
layout(location = 1) out vec4 out_pack;  // the layers' depths: the framebuffer keeps this layer's channel
layout(location = 2) out uvec4 out_colour_pack;  // the layers' colours (pack_colour), likewise

void main() {
    float first = texelFetch(u_prev, ivec2(gl_FragCoord.xy), 0).r;
    if (vs_depth <= first * (1.0 + 1e-5)) discard;
    out_depth = vs_depth;
    out_pack = vec4(vs_depth);
    out_colour_pack = uvec4(pack_colour(vs_colour));
}
