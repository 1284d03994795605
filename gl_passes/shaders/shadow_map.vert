#version 430 core
// Shadow-map depth pass (thesis Alg. 5, §3.3): position only, because the vertex
// stage bounds the pass on software rasterisers. Batched maps (MAPS_PER_DRAW,
// shadow_tile.glsl): four clip distances keep each triangle inside its own tile
// (the tile's frustum planes, which are linear in the homogeneous clip
// coordinates, so clipping stays exact).
in vec3 in_position;
#include "shadow_tile.glsl"
out gl_PerVertex {
    vec4 gl_Position;
    float gl_ClipDistance[4];
};

void main() {
    int i = map_index();
    vec4 c = u_light_vp[i] * vec4(in_position, 1.0);
#ifdef MAPS_PER_DRAW
    gl_ClipDistance[0] = c.w + c.x;
    gl_ClipDistance[1] = c.w - c.x;
    gl_ClipDistance[2] = c.w + c.y;
    gl_ClipDistance[3] = c.w - c.y;
#endif
    gl_Position = in_tile(c, map_tile(i));
}
