#version 430 core
// Alg. 6 step 3.c.iii + output: colour = mix(diffuse, reflected, s) per sample, then
// ss×ss averages (reference.reflections rules: reflected and ray length averaged
// over the block's reflective samples, ray length +inf if any of them missed).
layout(local_size_x = 8, local_size_y = 8) in;
uniform int u_ss;
layout(binding = UNIT_u_bins) uniform usampler2D u_bins;
layout(binding = UNIT_u_material) uniform sampler2D u_material;
layout(binding = UNIT_u_color) uniform sampler2D u_color;
layout(binding = UNIT_u_reflected) uniform sampler2D u_reflected;
layout(rgba32f, binding = UNIT_u_out_color) writeonly uniform image2D u_out_color;      // rgb, mean s
layout(rgba32f, binding = UNIT_u_out_reflected) writeonly uniform image2D u_out_reflected;  // rgb, ray length
layout(rgba32f, binding = UNIT_u_out_diffuse) writeonly uniform image2D u_out_diffuse;    // rgb, reflective samples

void main() {
    ivec2 o = ivec2(gl_GlobalInvocationID.xy);
    if (any(greaterThanEqual(o, imageSize(u_out_color)))) return;
    vec3 col = vec3(0.0), dif = vec3(0.0), ref = vec3(0.0);
    float s_sum = 0.0, len = 0.0, count = 0.0;
    bool missed = false;
    for (int j = 0; j < u_ss; ++j) for (int i = 0; i < u_ss; ++i) {
        ivec2 p = o * u_ss + ivec2(i, j);
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
    float inv = 1.0 / float(u_ss * u_ss);
    float L = count == 0.0 ? uintBitsToFloat(0x7fc00000u) : (missed ? uintBitsToFloat(0x7f800000u) : len / count);
    imageStore(u_out_color, o, vec4(col * inv, s_sum * inv));
    imageStore(u_out_reflected, o, vec4(count > 0.0 ? ref / count : vec3(0.0), L));
    imageStore(u_out_diffuse, o, vec4(dif * inv, count));
}
