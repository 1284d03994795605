// Shared shading (twin of scenes/shading.py; constants are #defined from there).
uniform vec3 u_sun;  // unit direction toward the sun

vec3 local_shade(vec3 albedo, vec3 n) {
    return albedo * (AMBIENT + (1.0 - AMBIENT) * max(0.0, dot(n, u_sun)));
}

// A shaded colour in [0, 1] as one uint, 11/11/10 bits unorm (r, g, b): the cluster
// depth images keep every layer's colour in one channel of one texture, so that a
// march reads the colour of any layer with one fetch (reflect_trace.comp).
uint pack_colour(vec3 c) {
    uvec3 q = uvec3(round(clamp(c, 0.0, 1.0) * vec3(2047.0, 2047.0, 1023.0)));
    return q.r | (q.g << 11) | (q.b << 22);
}

vec3 unpack_colour(uint u) {
    return vec3(float(u & 2047u), float((u >> 11) & 2047u), float(u >> 22)) / vec3(2047.0, 2047.0, 1023.0);
}

vec3 sky(vec3 d) {
    float h = clamp(d.y, -1.0, 1.0);
    vec3 c = h >= 0.0 ? SKY_HORIZON + (SKY_ZENITH - SKY_HORIZON) * h
                      : SKY_HORIZON + (SKY_GROUND - SKY_HORIZON) * (-h);
    return c + SUN_GLOW * pow(max(0.0, dot(d, u_sun)), SUN_GLOW_EXPONENT);
}
