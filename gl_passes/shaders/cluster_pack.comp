#version 430 core
// Packs the four cluster-image layers' depths into one texel, so the intersection
// march fetches one texel per step.
layout(local_size_x = 16, local_size_y = 16) in;
layout(binding = UNIT_u_atlas) uniform sampler2D u_atlas;        // other objects: rgb colour, a = depth
layout(binding = UNIT_u_atlas_self) uniform sampler2D u_atlas_self;   // the cluster's reflector: rgb colour, a = depth
layout(binding = UNIT_u_atlas_peel) uniform sampler2D u_atlas_peel;   // the reflector's second surface: rgb colour, a = depth
layout(binding = UNIT_u_atlas_peel_other) uniform sampler2D u_atlas_peel_other;  // the other objects' second surface: rgb colour, a = depth
uniform ivec2 u_size;             // used atlas area
layout(rgba32f, binding = UNIT_u_pack_image) writeonly uniform image2D u_pack_image;  // (depth other, self, self 2nd, other 2nd)

void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    if (any(greaterThanEqual(p, u_size))) return;
    imageStore(u_pack_image, p, vec4(texelFetch(u_atlas, p, 0).a, texelFetch(u_atlas_self, p, 0).a,
                               texelFetch(u_atlas_peel, p, 0).a, texelFetch(u_atlas_peel_other, p, 0).a));
}
