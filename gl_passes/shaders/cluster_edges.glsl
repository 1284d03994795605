// The edges of the clustering's components (§4.3, issue 17): two 4-neighbouring
// reflective samples are connected when they lie in the same raw bin and their
// mirror normals differ by at most the break angle (cos u_cos_break), i.e. the
// normal field is continuous between them.
layout(binding = UNIT_u_bins) uniform usampler2D u_bins;      // raw bin + 1 (0 = not reflective)
layout(binding = UNIT_u_mnormal) uniform sampler2D u_mnormal;  // mirror normal
uniform float u_cos_break;

// The rule on two samples' raw bins + 1 and mirror normals.
bool joined(uint bin_a, vec3 n_a, uint bin_b, vec3 n_b) {
    return bin_a != 0u && bin_b == bin_a && dot(n_a, n_b) >= u_cos_break;
}

// The rule on two samples of the images (false when either lies outside).
bool connected(ivec2 p, ivec2 q) {
    ivec2 size = textureSize(u_bins, 0);
    if (any(lessThan(min(p, q), ivec2(0))) || any(greaterThanEqual(max(p, q), size))) return false;
    return joined(texelFetch(u_bins, p, 0).r, texelFetch(u_mnormal, p, 0).xyz,
                  texelFetch(u_bins, q, 0).r, texelFetch(u_mnormal, q, 0).xyz);
}
