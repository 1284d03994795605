#version 430 core
// Cluster depth image texel: local-shaded colour (rgb) + linear depth (a), and with
// TRIANGLE_IDS the triangle id. Only the reflector's layers store ids: reading
// gl_PrimitiveID makes llvmpipe run its primitive assembler, which grows a
// per-draw array one primitive at a time (realloc), about a third of the draw time.
#include "common.glsl"
uniform vec3 u_albedo;
uniform uint u_base;  // first global face of the drawn object
in vec3 vs_normal;
in float vs_depth;
layout(location = 0) out vec4 out_color;
layout(location = 1) out vec4 out_pack;  // the layers' depths: the framebuffer keeps this layer's channel
#ifdef TRIANGLE_IDS
layout(location = 2) out uint out_tri;  // triangle id (1-based): the reflector's layers only
#endif

void main() {
    out_color = vec4(local_shade(u_albedo, normalize(vs_normal)), vs_depth);
    out_pack = vec4(vs_depth);
#ifdef TRIANGLE_IDS
    out_tri = u_base + uint(gl_PrimitiveID) + 1u;
#endif
}
