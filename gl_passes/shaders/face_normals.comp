#version 430 core
// The unit geometric normal (CCW front) of every triangle of a scene, once per scene
// (gl_passes.reflections' per-scene records), for reflect_common.glsl's
// geom_normal: the clustering, the extent passes and the intersection read a
// sample's triangle's normal as three floats instead of gathering its three
// indices and nine vertex coordinates (on llvmpipe every gathered word is a
// per-lane load). A degenerate triangle gets +y. One invocation per triangle, in
// rows of u_row_groups work groups.
layout(local_size_x = 256) in;
layout(std430, binding = UNIT_MeshVerts) readonly buffer MeshVerts { float mesh_v[]; };  // (pos, normal) × V
layout(std430, binding = UNIT_MeshFaces) readonly buffer MeshFaces { uint mesh_f[]; };   // 3 × F
layout(std430, binding = UNIT_FaceNormals) writeonly buffer FaceNormals { float face_n[]; };  // 3 × F
uniform uint u_faces;
uniform uint u_row_groups;

vec3 mesh_pos(uint i) { return vec3(mesh_v[6u * i], mesh_v[6u * i + 1u], mesh_v[6u * i + 2u]); }

void main() {
    uint t = (gl_WorkGroupID.y * u_row_groups + gl_WorkGroupID.x) * 256u + gl_LocalInvocationIndex;
    if (t >= u_faces) return;
    uint f = 3u * t;
    vec3 a = mesh_pos(mesh_f[f]), b = mesh_pos(mesh_f[f + 1u]), c = mesh_pos(mesh_f[f + 2u]);
    vec3 n = cross(b - a, c - a);
    float l = length(n);
    vec3 g = l > 0.0 ? n / l : vec3(0.0, 1.0, 0.0);
    face_n[f] = g.x;
    face_n[f + 1u] = g.y;
    face_n[f + 2u] = g.z;
}
