// Shared shading (twin of scenes/shading.py; constants are #defined from there).
uniform vec3 u_sun;  // unit direction toward the sun

vec3 local_shade(vec3 albedo, vec3 n) {
    return albedo * (AMBIENT + (1.0 - AMBIENT) * max(0.0, dot(n, u_sun)));
}

vec3 sky(vec3 d) {
    float h = clamp(d.y, -1.0, 1.0);
    vec3 c = h >= 0.0 ? SKY_HORIZON + (SKY_ZENITH - SKY_HORIZON) * h
                      : SKY_HORIZON + (SKY_GROUND - SKY_HORIZON) * (-h);
    return c + SUN_GLOW * pow(max(0.0, dot(d, u_sun)), SUN_GLOW_EXPONENT);
}
