#version 430 core
// Shadow-map lookups of thesis Alg. 5 (§3.3): for every receiver point P and
// every light sample s of the current batch (one tile of the depth atlas each),
// set bit s of P's visibility words when P is lit by s.
//   * s on or behind P's tangent plane (dot(n, s - P) <= 0): not visible (the rule
//     shared with the Embree reference);
//   * bias: P is moved u_normal_offset texels along n, and is lit when its light-space
//     depth is at most the map's depth + (u_depth_bias + u_depth_slope * tan t) texels,
//     t the angle between n and the direction to s (tan t clamped at MAX_TAN_T): a
//     surface tilted by t from s changes depth by tan t texels across one texel. One
//     texel is the world size of a shadow-map texel at P's depth along the light's
//     axis (u_light[i].w * depth along u_forward[i]); depths are linear (eye-space z of the light camera);
//   * P outside the map, or in front of an empty texel: lit (nothing occludes it).
// Each invocation owns one point's words, so no atomics are needed.
layout(local_size_x = 64) in;

layout(std430, binding = UNIT_points) readonly buffer Points { vec4 points[]; };    // xyz world, w unused
layout(std430, binding = UNIT_normals) readonly buffer Normals { vec4 normals[]; };  // xyz unit world normal
layout(std430, binding = UNIT_bits) buffer Bits { uint bits[]; };                 // WORDS per point

layout(binding = UNIT_depth) uniform sampler2D u_depth;               // depth atlas, window depth in [0, 1]
uniform mat4 u_light_vp[MAPS_PER_DRAW];    // world → clip of each map of the batch
uniform vec4 u_light[MAPS_PER_DRAW];       // light sample position (world), texel size per unit depth
uniform vec2 u_clip[MAPS_PER_DRAW];        // near, far of each light camera
uniform vec4 u_forward[MAPS_PER_DRAW];     // each light camera's view axis (unit xyz)
uniform int u_first;                       // global sample index of the batch's map 0
uniform int u_count;                       // maps in this batch
uniform int u_tiles;                       // tiles per atlas row
uniform int u_res;                         // texels per map side
uniform uint u_n_points;
uniform float u_normal_offset;            // texels
uniform float u_depth_bias;                // texels
uniform float u_depth_slope;               // texels per unit tan t

// tan t at which the slope-scaled depth bias stops growing (t = 89.4 degrees).
const float MAX_TAN_T = 100.0;

float linear_depth(float d, vec2 nf) {
    float z_ndc = 2.0 * d - 1.0;
    return 2.0 * nf.x * nf.y / (nf.y + nf.x - z_ndc * (nf.y - nf.x));
}

bool lit(vec3 p, vec3 n, int i) {
    vec3 s = u_light[i].xyz;
    if (dot(n, s - p) <= 0.0) return false;
    float texel = u_light[i].w * dot(p - s, u_forward[i].xyz);
    float cos_t = dot(n, normalize(s - p));
    float tan_t = min(sqrt(max(1.0 - cos_t * cos_t, 0.0)) / cos_t, MAX_TAN_T);
    vec3 q = p + n * (u_normal_offset * texel);
    vec4 c = u_light_vp[i] * vec4(q, 1.0);
    if (c.w <= 0.0) return true;
    vec2 ndc = c.xy / c.w;
    if (any(greaterThanEqual(abs(ndc), vec2(1.0)))) return true;
    ivec2 xy = min(ivec2(floor((ndc * 0.5 + 0.5) * float(u_res))), ivec2(u_res - 1));
    xy += ivec2(i % u_tiles, i / u_tiles) * u_res;
    float d = texelFetch(u_depth, xy, 0).r;
    if (d >= 1.0) return true;
    return c.w <= linear_depth(d, u_clip[i]) + (u_depth_bias + u_depth_slope * tan_t) * texel;
}

void main() {
    uint p = (gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x) * gl_WorkGroupSize.x
             + gl_LocalInvocationID.x;
    if (p >= u_n_points) return;
    vec3 pos = points[p].xyz;
    vec3 n = normals[p].xyz;
    for (int i = 0; i < u_count; ++i) {
        int s = u_first + i;
        if (lit(pos, n, i)) bits[p * uint(WORDS) + uint(s >> 5)] |= 1u << uint(s & 31);
    }
}
