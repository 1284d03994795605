// Shared by the cluster/reflection compute shaders (technique 3, Ch. 4).
// Geometric normals, the mirror-direction rules and the glossy lobe of
// scenes/glossy.py + reference/reflections.py (same formulas).
layout(std430, binding = UNIT_FaceNormals) readonly buffer FaceNormals { float face_n[]; };  // 3 × F (face_normals.comp)

// Unit geometric normal (CCW front) of triangle id `tri` (1-based).
vec3 geom_normal(uint tri) {
    uint f = 3u * (tri - 1u);
    return vec3(face_n[f], face_n[f + 1u], face_n[f + 2u]);
}

// Mirror direction about the shading normal; below-surface rule: reflect about
// the geometric normal when that direction points into the surface.
vec3 mirror_dir(vec3 d, vec3 n, vec3 ng) {
    vec3 r = normalize(d - 2.0 * dot(d, n) * n);
    if (dot(r, ng) < 0.0) r = normalize(d - 2.0 * dot(d, ng) * ng);
    return r;
}

// The normal the mirror direction (mirror_dir) is reflected about: the shading
// normal n, or the geometric normal ng where the below-surface rule applies,
// turned toward the viewer (-d); exactly n or ng up to sign, so that a flat
// surface's samples share one normal to the last bit.
vec3 mirror_normal(vec3 d, vec3 n, vec3 ng) {
    vec3 m = dot(normalize(d - 2.0 * dot(d, n) * n), ng) < 0.0 ? ng : n;
    return dot(m, d) > 0.0 ? -m : m;
}

// The branchless orthonormal frame (t1, t2) around the unit axis m of Duff et al.
// (scenes.glossy.lobe_directions).
void lobe_frame(vec3 m, out vec3 t1, out vec3 t2) {
    float sgn = m.z >= 0.0 ? 1.0 : -1.0;
    float a = -1.0 / (sgn + m.z);
    float b = m.x * m.y * a;
    t1 = vec3(1.0 + sgn * m.x * m.x * a, sgn * b, -sgn * m.x);
    t2 = vec3(b, sgn + m.y * m.y * a, -m.y);
}

// Lobe direction: tilt the axis m by rho·half toward phi, offset = rho·(cos phi, sin phi),
// in lobe_frame's frame.
vec3 lobe_dir(vec3 m, float half_angle, vec2 off) {
    vec3 t1, t2;
    lobe_frame(m, t1, t2);
    float rho = length(off);
    float scale = rho > 0.0 ? tan(rho * half_angle) / rho : half_angle;
    return normalize(m + off.x * scale * t1 + off.y * scale * t2);
}

// Lobe directions below the geometric tangent plane are mirrored about it.
vec3 lift_above(vec3 d, vec3 ng) {
    float dn = dot(d, ng);
    return dn < 0.0 ? d - 2.0 * dn * ng : d;
}

// Per-cluster camera record (8 vec4, see gl_passes/cluster_camera.py FRAME_LAYOUT).
struct ClusterFrame {
    vec4 c_near;      // centre of projection, projection near depth
    vec4 right_far;   // image-plane x axis, far depth
    vec4 up_len;      // image-plane y axis, ray length (far distance along rays)
    vec4 fwd_half;    // viewing axis, glossy lobe half-angle (rad)
    vec4 plane;       // clip plane: dot(n, X) >= w (the fitting plane, shifted to hold all ray starts)
    vec4 rect;        // off-axis image rectangle (u0, v0, u1, v1) in tangent units
    vec4 atlas;       // atlas viewport (x, y, w, h) in texels
    vec4 misc;        // glossiness, stage 0: sparse cluster (1: every sample, cluster_extent.comp), 0, 0
};
layout(std430, binding = UNIT_Frames) readonly buffer Frames { ClusterFrame frames[]; };
layout(std430, binding = UNIT_Remap) readonly buffer Remap { int remap[]; };  // raw bin -> cluster (-1 none)

// Order-preserving float <-> uint map for atomicMin/atomicMax on floats.
uint f2o(float f) {
    uint u = floatBitsToUint(f);
    return (u & 0x80000000u) != 0u ? ~u : (u | 0x80000000u);
}
