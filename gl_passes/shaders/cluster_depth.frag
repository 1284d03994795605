#version 430 core
// Cluster depth image texel: linear depth (in the layer's own image and its channel
// of the pack) and local-shaded colour (its channel of the colour pack). No triangle
// ids: reading gl_PrimitiveID makes llvmpipe run its primitive assembler, which
// grows a per-draw array one primitive at a time (realloc), about a third of the
// draw time; the trace's self-hit test is geometric (reflect_trace.comp).
#include "common.glsl"
in vec3 vs_colour;  // local-shaded per vertex
in float vs_depth;
layout(location = 0) out float out_depth;  // this layer's own depth image (a peel layer's u_prev)
layout(location = 1) out vec4 out_pack;  // the layers' depths: the framebuffer keeps this layer's channel
layout(location = 2) out uvec4 out_colour_pack;  // the layers' colours (pack_colour), likewise

void main() {
    out_depth = vs_depth;
    out_pack = vec4(vs_depth);
    out_colour_pack = uvec4(pack_colour(vs_colour));
}
