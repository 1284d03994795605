#version 430 core
// Shadow-map depth pass (thesis Alg. 5, §3.3): position only, because the vertex
// stage bounds the pass on software rasterisers. Without MAPS_PER_DRAW one map
// per draw (u_light_vp[0]); with it, instance i (+ u_map0) renders map i of the
// batch into its own tile of the depth atlas: clip coordinates are squeezed into
// the tile (u_tile: NDC scale xy, NDC offset zw) and four clip distances keep
// each triangle inside its own tile (the tile's frustum planes, which are
// linear in the homogeneous clip coordinates, so clipping stays exact).
in vec3 in_position;
#ifdef MAPS_PER_DRAW
uniform mat4 u_light_vp[MAPS_PER_DRAW];  // world → clip of each light sample's camera
uniform vec4 u_tile[MAPS_PER_DRAW];
uniform int u_map0;  // batch map of instance 0 (occluders drawn once per map)
out gl_PerVertex {
    vec4 gl_Position;
    float gl_ClipDistance[4];
};
#else
uniform mat4 u_light_vp[1];
#endif

void main() {
#ifdef MAPS_PER_DRAW
    int i = u_map0 + gl_InstanceID;
    vec4 c = u_light_vp[i] * vec4(in_position, 1.0);
    gl_ClipDistance[0] = c.w + c.x;
    gl_ClipDistance[1] = c.w - c.x;
    gl_ClipDistance[2] = c.w + c.y;
    gl_ClipDistance[3] = c.w - c.y;
    vec4 t = u_tile[i];
    gl_Position = vec4(c.xy * t.xy + t.zw * c.w, c.zw);
#else
    gl_Position = u_light_vp[0] * vec4(in_position, 1.0);
#endif
}
