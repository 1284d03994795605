// Shared by the clustering passes (§4.3): a G-buffer sample's reflector and the
// normal its mirror ray is reflected about (reflect_common.glsl's mirror_normal:
// the shading normal, or the geometric normal where the below-surface rule
// applies), which is the normal a cluster is binned and fitted by.
#include "reflect_common.glsl"
layout(binding = UNIT_u_obj) uniform usampler2D u_obj;
layout(binding = UNIT_u_material) uniform sampler2D u_material;
layout(binding = UNIT_u_normal) uniform sampler2D u_normal;
layout(binding = UNIT_u_position) uniform sampler2D u_position;
layout(binding = UNIT_u_tri) uniform usampler2D u_tri;
uniform vec3 u_eye;

// The sample's reflector (object id), 0 when it is not reflective (s <= 0).
uint reflector(ivec2 p) {
    uint o = texelFetch(u_obj, p, 0).r;
    return o != 0u && texelFetch(u_material, p, 0).r > 0.0 ? o : 0u;
}

// SHADING_NORMAL_BINS (ClusterSettings.bin_normal = "shading"): the interpolated
// shading normal instead, whatever the ray is reflected about.
vec3 sample_mirror_normal(ivec2 p, vec3 P) {
    vec3 ns = normalize(texelFetch(u_normal, p, 0).xyz);
#ifdef SHADING_NORMAL_BINS
    return ns;
#else
    return mirror_normal(normalize(P - u_eye), ns, geom_normal(texelFetch(u_tri, p, 0).r));
#endif
}
