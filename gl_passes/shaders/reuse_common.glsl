// Shared by the temporal reflection reuse passes (thesis Ch. 5): the keyframe's
// reflection depth image (§5.3) and the same-surface test that stands for the
// thesis's depth discontinuities (reflector silhouettes).
//   u_kf_position: world position (xyz), eye-space depth d (w);
//   u_kf_normal: world normal (xyz), reflected-ray length r (w; < 0: not reflective);
//   u_kf_depth: eye-space depth d;        u_kf_obj: object id (0 = background);
//   (the w channels are filled once per keyframe by keyframe_pack.comp)
//   u_kf_reflection: reflected colour Lr (rgb) and reflected-ray length r (a),
//                    r < 0 where the pixel is not reflective (B.3, B.4).
layout(binding = UNIT_u_kf_position) uniform sampler2D u_kf_position;
layout(binding = UNIT_u_kf_normal) uniform sampler2D u_kf_normal;
layout(binding = UNIT_u_kf_depth) uniform sampler2D u_kf_depth;
layout(binding = UNIT_u_kf_obj) uniform usampler2D u_kf_obj;
layout(binding = UNIT_u_kf_reflection) uniform sampler2D u_kf_reflection;

uniform ivec2 u_kf_size;        // keyframe image size (texels)
uniform float u_pixel_angle;    // 2 tan(fov/2) / H of the keyframe camera: a pixel's footprint at depth 1
uniform float u_plane_tol;      // same-surface tolerance, in pixel footprints

bool kf_inside(ivec2 p) { return all(greaterThanEqual(p, ivec2(0))) && all(lessThan(p, u_kf_size)); }

// A world point lies on the keyframe sample at p's surface: same object and within
// u_plane_tol pixel footprints of its tangent plane.
bool on_kf_surface(ivec2 p, vec3 point, uint obj) {
    uint o = texelFetch(u_kf_obj, p, 0).r;
    if (o == 0u || o != obj) return false;
    vec4 w = texelFetch(u_kf_position, p, 0);
    vec3 n = texelFetch(u_kf_normal, p, 0).xyz;
    return abs(dot(point - w.xyz, n)) <= u_plane_tol * u_pixel_angle * w.w;
}

// Two keyframe samples lie on one continuous surface (no depth discontinuity between them).
bool kf_same_surface(ivec2 a, ivec2 b) {
    uint oa = texelFetch(u_kf_obj, a, 0).r;
    return on_kf_surface(b, texelFetch(u_kf_position, a, 0).xyz, oa)
        && on_kf_surface(a, texelFetch(u_kf_position, b, 0).xyz, texelFetch(u_kf_obj, b, 0).r);
}

bool kf_reflective(ivec2 p) { return texelFetch(u_kf_normal, p, 0).w >= 0.0; }
