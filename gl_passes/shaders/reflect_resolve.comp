#version 430 core
// Alg. 6 step 3.c.iii + output: colour = mix(diffuse, reflected, s) per sample, then
// ss×ss averages (reference.reflections rules: reflected and ray length averaged
// over the block's reflective samples, ray length +inf if any of them missed).
// Output: one storage buffer of planes, rows top-down (row 0 = the image's top, as
// readback.read_planes hands them out): colour rgb, mean s, reflected rgb, ray length,
// diffuse rgb, reflective samples; n = W·H values per channel.
// SS (the supersampling factor) is compiled in: a constant loop is unrolled, which a
// CPU rasteriser runs faster than one bounded by a uniform.
layout(local_size_x = 8, local_size_y = 8) in;
uniform ivec2 u_size;  // output W, H
layout(binding = UNIT_u_bins) uniform usampler2D u_bins;
layout(binding = UNIT_u_material) uniform sampler2D u_material;
layout(binding = UNIT_u_color) uniform sampler2D u_color;
layout(binding = UNIT_u_reflected) uniform sampler2D u_reflected;
layout(std430, binding = UNIT_Resolved) writeonly buffer Resolved { float resolved[]; };

void put3(uint plane, uint i, vec3 v) {
    resolved[plane + 3u * i] = v.r; resolved[plane + 3u * i + 1u] = v.g; resolved[plane + 3u * i + 2u] = v.b;
}

void main() {
    ivec2 o = ivec2(gl_GlobalInvocationID.xy);
    if (any(greaterThanEqual(o, u_size))) return;
    vec3 col = vec3(0.0), dif = vec3(0.0), ref = vec3(0.0);
    float s_sum = 0.0, len = 0.0, count = 0.0;
    bool missed = false;
    for (int j = 0; j < SS; ++j) for (int i = 0; i < SS; ++i) {
        ivec2 p = o * SS + ivec2(i, j);
        vec3 d = texelFetch(u_color, p, 0).rgb;
        dif += d;
        if (texelFetch(u_bins, p, 0).r == 0u) { col += d; continue; }
        float s = texelFetch(u_material, p, 0).r;
        vec4 r = texelFetch(u_reflected, p, 0);
        col += mix(d, r.rgb, s);
        s_sum += s;
        ref += r.rgb;
        count += 1.0;
        if (isinf(r.a)) missed = true; else len += r.a;
    }
    float inv = 1.0 / float(SS * SS);
    float L = count == 0.0 ? uintBitsToFloat(0x7fc00000u) : (missed ? uintBitsToFloat(0x7f800000u) : len / count);
    uint n = uint(u_size.x * u_size.y), i = uint((u_size.y - 1 - o.y) * u_size.x + o.x);
    put3(0u, i, col * inv);
    resolved[3u * n + i] = s_sum * inv;
    put3(4u * n, i, count > 0.0 ? ref / count : vec3(0.0));
    resolved[7u * n + i] = L;
    put3(8u * n, i, dif * inv);
    resolved[11u * n + i] = count;
}
