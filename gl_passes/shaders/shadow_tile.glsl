// The light cameras of a batch of shadow maps (thesis Alg. 5) as the triangle
// pass (shadow_map.vert) reads them.
// Without MAPS_PER_DRAW one map per draw (u_light_vp[0], the whole viewport);
// with it, instance i (+ u_map0) renders map i of the batch into its own tile of
// the depth atlas: clip coordinates are squeezed into the tile (u_tile: NDC
// scale xy, NDC offset zw).
#ifdef MAPS_PER_DRAW
uniform mat4 u_light_vp[MAPS_PER_DRAW];  // world → clip of each light sample's camera
uniform vec4 u_tile[MAPS_PER_DRAW];
uniform int u_map0;  // batch map of instance 0 (occluders drawn once per map)
int map_index() { return u_map0 + gl_InstanceID; }
vec4 map_tile(int i) { return u_tile[i]; }
#else
uniform mat4 u_light_vp[1];
int map_index() { return 0; }
vec4 map_tile(int i) { return vec4(1.0, 1.0, 0.0, 0.0); }
#endif

// Clip coordinates `c` of a light camera → clip coordinates in its tile `t`.
vec4 in_tile(vec4 c, vec4 t) {
    return vec4(c.xy * t.xy + t.zw * c.w, c.zw);
}
