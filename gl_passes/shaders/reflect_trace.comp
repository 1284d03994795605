#version 430 core
// Alg. 7 per reflective sample: march the reflected ray's projection through its
// cluster's depth image one texel per step, depth interpolated perspective-correctly
// (1/z linear in the image). Hit rule: in the texel where the ray's depth span
// [z_lo, z_hi] first reaches the stored depth D (D <= z_hi) and the surface is not
// in front of the span by more than u_thickness·(z_hi - z_lo) (else the ray passes
// behind a thin surface and marching goes on), and never in front of the ray's entry
// depth. Four layers per cluster image: other objects / the cluster's own reflector /
// its second surface / the other objects' second surface. Miss -> sky (mirror) or the diffuse
// colour (glossy: a miss within far contributes diffuse, §4.6 / reference).
// u_mode 1 = environment map baseline (no intersection).
// With CROSSING defined, also a hit where the ray goes from in front of a layer's
// surface (previous step) to behind it (this step) while that surface's depth jumps
// by at most u_continuity of itself between the two texels (steep surface, not a
// silhouette); the hit point is where the inverse depths cross between the steps.
// With SURFACE_CROSSING defined (u_slope > 0), also a hit where the ray goes from in
// front of a layer's surface interpolated at the ray's exact image point (bilinear in
// 1/z over the 2×2 texels around it) to behind it between two steps, both footprints
// continuous (depths within 1 + 1.5·u_slope·texel angle); with NEAR_CROSSING
// (u_near_steps > 0), in the ray's first u_near_steps texels a thin-surface hit
// counts only where the ray crosses the interpolated surface inside the step (the
// ray starts on its reflector, within the thin-surface tolerance of its texels).
// The hit's colour: the mirror ray refines the hit inside its step and filters the
// hit surface's texels (surface_at); a glossy sample's lobe rays, averaged eight or
// more at a time, take their hit texel's colour as Alg. 7 does (trace's exact_hit,
// a constant per call, so each call compiles only its own hit processing).
// One invocation per listed reflective sample (reflective_list.glsl).
layout(local_size_x = TRACE_GROUP) in;
#define SELF_PLANE 1e-4  // relative to depth: the stored point on the own triangle's plane
#include "common.glsl"
#include "reflect_common.glsl"
#include "reflective_list.glsl"
layout(binding = UNIT_u_bins) uniform usampler2D u_bins;
layout(binding = UNIT_u_tri) uniform usampler2D u_tri;
layout(binding = UNIT_u_normal) uniform sampler2D u_normal;
layout(binding = UNIT_u_position) uniform sampler2D u_position;
layout(binding = UNIT_u_material) uniform sampler2D u_material;
layout(binding = UNIT_u_color) uniform sampler2D u_color;
// Four layers per cluster image, their colours in one texel (pack_colour, channel =
// layer): 0 every other object; 1 the cluster's own reflector only
// (self-reflections; the first layer holds every other object, so the reflector
// cannot hide them); 2 the reflector's second surface (depth peel: a ray passing
// behind the reflector's nearest surface can still meet the one behind it); 3 the
// other objects' second surface (depth peel; non-planar clusters), what the first
// layer hides from e_c but the reflected rays may see.
layout(binding = UNIT_u_colour_pack) uniform usampler2D u_colour_pack;
// The layers' depths packed (written with the layers, BACKGROUND_DEPTH where a layer
// holds nothing this frame): one fetch per step; per
// BLOCK×BLOCK block and layer their min and max stored depth
// (cluster_block_depth.comp) for skipping stretches without a possible hit.
layout(binding = UNIT_u_pack) uniform sampler2D u_pack;
layout(binding = UNIT_u_block_min) uniform sampler2D u_block_min;
layout(binding = UNIT_u_block_max) uniform sampler2D u_block_max;
// Self-hit test: a reflected ray leaves the plane of the sample's own triangle, so a
// reflector texel (layers 1, 2) whose stored point lies on that plane is never its
// hit (the own triangle, and any triangle coplanar with it). The stored point of
// texel centre (u, v) at depth D is c + D·(fwd + u·right + v·up); its signed
// distance to the plane is g_plane.x + D·(g_plane.y + u·g_plane.z + v·g_plane.w).
vec4 g_plane;
uniform vec3 u_eye;
uniform int u_mode;
uniform int u_rays;
uniform vec2 u_lobe[MAX_RAYS];
uniform float u_thickness;
uniform float u_continuity;  // crossing rule: max relative depth jump of a continuous surface
#ifdef NEAR_CROSSING
uniform int u_near_steps;
#endif
layout(rgba32f, binding = UNIT_u_out) writeonly uniform image2D u_out;  // reflected rgb, mirror-ray length

float f_inf() { return uintBitsToFloat(0x7f800000u); }

// Clip P + t·d, t in [0, len], to the clip plane and the depth range [near, far].
bool clip_ray(vec3 P, vec3 d, ClusterFrame F, out float t0, out float t1) {
    t0 = 0.0; t1 = F.up_len.w;
    float a = dot(F.plane.xyz, P) - F.plane.w, da = dot(F.plane.xyz, d);
    if (abs(da) > 1e-12) { float t = -a / da; if (da > 0.0) t0 = max(t0, t); else t1 = min(t1, t); }
    else if (a < 0.0) return false;
    float z = dot(P - F.c_near.xyz, F.fwd_half.xyz), dz = dot(d, F.fwd_half.xyz);
    float zn = F.c_near.w, zf = F.right_far.w;
    if (abs(dz) > 1e-12) {
        float ta = (zn - z) / dz, tb = (zf - z) / dz;
        t0 = max(t0, min(ta, tb)); t1 = min(t1, max(ta, tb));
    } else if (z < zn || z > zf) return false;
    return t0 < t1;
}

vec2 to_texel(vec3 X, ClusterFrame F, out float z) {
    vec3 q = X - F.c_near.xyz;
    z = dot(q, F.fwd_half.xyz);
    vec2 uv = vec2(dot(q, F.right_far.xyz), dot(q, F.up_len.xyz)) / z;
    return (uv - F.rect.xy) / (F.rect.zw - F.rect.xy) * F.atlas.zw;
}

// Layer test at one step: the hit rule above, against the stored depth D.
bool layer_hit(float D, float zhi, float lower) { return D <= zhi * (1.0 + 1e-5) && D >= lower; }

// Colour of texel q of layer l (one fetch whatever the layer).
vec3 layer_colour(int l, ivec2 q) { return unpack_colour(texelFetch(u_colour_pack, q, 0)[l]); }

// Bilinear colour (rgb, when `colour`; else 0) and depth (a) of layer l's surface
// (0 other objects, 1 reflector, 2 reflector 2nd, 3 others 2nd) at image point pix,
// over the 2×2 texels whose depth is within dtol of D (the hit surface). Depths and
// coverage come from u_pack: the colour pack is not cleared, so a texel a layer
// does not cover this frame holds an earlier frame's colour and is never read.
vec4 surface_at(int l, ivec2 org, ivec2 top, vec2 pix, float D, float dtol, bool colour) {
    vec2 f = pix - 0.5;
    ivec2 b = ivec2(floor(f));
    vec2 w = f - floor(f);
    vec4 acc = vec4(0.0);
    float wsum = 0.0;
    for (int j = 0; j < 2; ++j) for (int i = 0; i < 2; ++i) {
        ivec2 q = org + clamp(b + ivec2(i, j), ivec2(0), top);
        float dq = texelFetch(u_pack, q, 0)[l];
        float wt = (i == 1 ? w.x : 1.0 - w.x) * (j == 1 ? w.y : 1.0 - w.y);
        if (abs(dq - D) <= dtol) {
            acc += wt * vec4(colour ? layer_colour(l, q) : vec3(0.0), dq);
            wsum += wt;
        }
    }
    if (wsum > 1e-6) return acc / wsum;
    if (!colour) return vec4(0.0, 0.0, 0.0, D);
    ivec2 q = org + clamp(ivec2(floor(pix)), ivec2(0), top);  // black where the layer holds nothing
    return vec4(texelFetch(u_pack, q, 0)[l] < 0.5 * BACKGROUND_DEPTH ? layer_colour(l, q) : vec3(0.0), D);
}

#ifdef SURFACE_CROSSING
uniform float u_slope;  // steepest surface (tan of its angle to the view ray) treated as continuous
// Per layer (other objects, reflector, reflector 2nd, others 2nd) inverse depth of the stored
// surface at image point pix: bilinear over the 2×2 texels around pix in inverse
// depth (exact on planes); ok[l] where those four depths lie within the relative
// span `rel` (one continuous surface, not a silhouette or the background).
vec4 surface_inv(ivec2 org, ivec2 top, vec2 pix, float rel, out bvec4 ok) {
    vec2 f = pix - 0.5;
    ivec2 b = ivec2(floor(f));
    vec2 w = f - floor(f);
    vec4 acc = vec4(0.0), lo = vec4(3.0e38), hi = vec4(0.0);
    for (int j = 0; j < 2; ++j) for (int i = 0; i < 2; ++i) {
        vec4 d = texelFetch(u_pack, org + clamp(b + ivec2(i, j), ivec2(0), top), 0);
        acc += (i == 1 ? w.x : 1.0 - w.x) * (j == 1 ? w.y : 1.0 - w.y) / d;
        lo = min(lo, d); hi = max(hi, d);
    }
    ok = lessThanEqual(hi, lo * (1.0 + rel));
    return acc;
}
#endif

// Hit refinement inside the step [alo, ahi]: where the ray's depth crosses layer
// l's bilinearly interpolated surface depth. Returns the image
// parameter of the crossing, or -1 when the ray does not cross there.
float refine(int l, ivec2 org, ivec2 top, vec2 s2, vec2 e2, float is2, float ie2, float alo,
             float ahi, float D, float dtol) {
    // In inverse depth both the ray and a planar surface are linear in the image.
    float glo = mix(is2, ie2, alo) - 1.0 / surface_at(l, org, top, mix(s2, e2, alo), D, dtol, false).a;
    float ghi = mix(is2, ie2, ahi) - 1.0 / surface_at(l, org, top, mix(s2, e2, ahi), D, dtol, false).a;
    if (glo >= 0.0 && ghi <= 0.0 && glo > ghi) return alo + (ahi - alo) * glo / (glo - ghi);
    return -1.0;
}

// Distance along the ray of the hit at image parameter ac (of [a0, a1]) and depth D;
// zs, ze: depths at the clipped ray's ends t0, t1.
float hit_distance(float t0, float t1, float zs, float ze, float a0, float a1, float ac, float D) {
    if (abs(ze - zs) > 1e-5 * zs) return t0 + (t1 - t0) * clamp((D - zs) / (ze - zs), 0.0, 1.0);
    float ao = mix(a0, a1, ac);  // nearly constant depth: the image parameter, made perspective-correct
    return t0 + (t1 - t0) * ao * (1.0 / ze) / mix(1.0 / zs, 1.0 / ze, ao);
}

// The ray P + t·d through cluster image F: its hit's colour and distance, or false.
// exact_hit: refine the hit and filter its colour (the mirror ray), else the hit
// texel's colour (lobe rays).
bool trace(vec3 P, vec3 d, ClusterFrame F, out vec3 col, out float t_hit, const bool exact_hit) {
    col = vec3(0.0); t_hit = f_inf();
    if (F.atlas.z <= 0.0) return false;  // cluster without a valid camera: miss
    float t0, t1;
    if (!clip_ray(P, d, F, t0, t1)) return false;
    float zs, ze;
    vec2 ps = to_texel(P + t0 * d, F, zs), pe = to_texel(P + t1 * d, F, ze);
    vec2 wh = F.atlas.zw, dp = pe - ps;
    float a0 = 0.0, a1 = 1.0;
    for (int k = 0; k < 2; ++k) {  // Liang-Barsky against the image rectangle
        if (abs(dp[k]) < 1e-9) { if (ps[k] < 0.0 || ps[k] > wh[k]) return false; continue; }
        float ta = -ps[k] / dp[k], tb = (wh[k] - ps[k]) / dp[k];
        a0 = max(a0, min(ta, tb)); a1 = min(a1, max(ta, tb));
    }
    if (a0 > a1) return false;
    float is = 1.0 / zs, ie = 1.0 / ze;
    vec2 s2 = ps + a0 * dp, e2 = ps + a1 * dp;
    float is2 = mix(is, ie, a0), ie2 = mix(is, ie, a1);
    vec2 span = abs(e2 - s2);
    int steps = max(1, int(ceil(max(span.x, span.y))));
    ivec2 org = ivec2(F.atlas.xy), top = ivec2(wh) - 1;
    // A ray moving away from the camera never hits a surface in front of its entry
    // point (e.g. the reflector's own far side seen from e_c).
    float zfirst = ie2 < is2 ? (1.0 + 1e-4) / is2 : 0.0;
    float inv_steps = 1.0 / float(steps);
    vec2 delta = (e2 - s2) * inv_steps;
    vec2 inv_delta = 1.0 / delta;
    // Previous step (crossing rule): stored depths and the ray's depth at its centre.
    vec4 prev_d = vec4(0.0);
    float prev_z = 0.0, prev_a = 0.0;
    bool prev_ok = false;
#ifdef SURFACE_CROSSING
    // Surface crossing: the ray's inverse depth minus the interpolated surface's at
    // the previous step (valid when sc_ok), per layer.
    vec4 sc_g = vec4(0.0);
    bvec4 sc_c = bvec4(false);
    bool sc_ok = false;
    float sc_rel = u_slope * 1.5 * max((F.rect.z - F.rect.x) / wh.x, (F.rect.w - F.rect.y) / wh.y);
#endif
    // The march (per step: a few fetches and compares) and the hit processing
    // (refinement and colour: many fetches) are separate loops: llvmpipe runs both
    // sides of a branch under a lane mask, so hit code inside the per-step loop would
    // cost every step (measured: about 4x the intersection time).
    int k = 0;
    // The candidate step the march hands to the hit processing.
    vec4 pk = vec4(0.0), pd = vec4(0.0);
    float ac = 0.0, alo = 0.0, ahi = 0.0, zlo = 0.0, zhi = 0.0, zc = 0.0, pz = 0.0, pa = 0.0, tol = 0.0, lower = 0.0;
    vec2 pix = vec2(0.0);
    ivec2 tx = ivec2(0);
    bvec4 h = bvec4(false), xing = bvec4(false);  // per layer: candidate hit, crossing-rule hit
#ifdef SURFACE_CROSSING
    bvec4 sx = bvec4(false);
    vec4 sxa = vec4(0.0);
#endif
    for (;;) {
        bool found = false;
        for (; k <= steps; ++k) {
            ac = float(k) * inv_steps;
            pix = mix(s2, e2, ac);
            tx = clamp(ivec2(floor(pix)), ivec2(0), top);
            // Block skip: the steps that stay in this block cannot hit when, in every
            // layer, the block's surfaces all lie behind the ray's deepest point there
            // (min depth) or all in front of the lowest depth a hit may have there
            // (max depth below min over those steps of `lower`: the ray passes behind
            // them or they are in front of its entry point).
#ifndef NO_BLOCK_SKIP
            if (all(equal(tx, ivec2(floor(pix))))) {
                ivec2 cb = (org + tx) / BLOCK;
                vec2 b0 = vec2(cb * BLOCK - org), b1 = b0 + float(BLOCK);
                float ex = delta.x > 0.0 ? (b1.x - pix.x) * inv_delta.x : (delta.x < 0.0 ? (b0.x - pix.x) * inv_delta.x : 1e9);
                float ey = delta.y > 0.0 ? (b1.y - pix.y) * inv_delta.y : (delta.y < 0.0 ? (b0.y - pix.y) * inv_delta.y : 1e9);
                int last = min(k + int(max(floor(min(ex, ey) - 1e-4), 0.0)), steps);
                if (last > k) {
                    float aa = max(0.0, (float(k) - 0.5) * inv_steps), ab = min(1.0, (float(last) + 0.5) * inv_steps);
                    float zaa = 1.0 / mix(is2, ie2, aa), zab = 1.0 / mix(is2, ie2, ab);
                    float zmax = max(zaa, zab);
                    bvec4 clear = greaterThan(texelFetch(u_block_min, cb, 0), vec4(zmax * (1.0 + 1e-5)));
#if !defined(CROSSING) && !defined(SURFACE_CROSSING)
                    // Every step's tolerance is at most that of the deepest one (the
                    // ray's depth span per step grows with z²); the crossing rules can
                    // hit surfaces in front of `lower`, so they keep the min test only.
                    float tmax = u_thickness * zmax * zmax * abs(ie2 - is2) * inv_steps + 1e-4 * zmax;
                    float lmin = max(min(zaa, zab) - tmax, zfirst) * (1.0 - 1e-5);
                    clear = bvec4(vec4(clear) + vec4(lessThan(texelFetch(u_block_max, cb, 0), vec4(lmin))));
#endif
                    if (all(clear)) {
                        k = last;  // no hit possible up to step `last`
                        prev_ok = false;
#ifdef SURFACE_CROSSING
                        sc_ok = false;
#endif
                        continue;
                    }
                }
            }
#endif
            alo = max(0.0, (float(k) - 0.5) * inv_steps);
            ahi = min(1.0, (float(k) + 0.5) * inv_steps);
            float za = 1.0 / mix(is2, ie2, alo), zb = 1.0 / mix(is2, ie2, ahi);
            zlo = min(za, zb); zhi = max(za, zb);
            pk = texelFetch(u_pack, org + tx, 0);  // depth: other objects, reflector, reflector 2nd, others 2nd
#if defined(CROSSING) || defined(SURFACE_CROSSING)
            zc = 1.0 / mix(is2, ie2, ac);
            pd = prev_d; pz = prev_z; pa = prev_a;
            bool pok = prev_ok;
            prev_d = pk; prev_z = zc; prev_a = ac; prev_ok = true;
#endif
            // Fast reject (the common case): every stored surface behind the ray here
            // (a second surface lies behind its layer's first).
#ifdef SURFACE_CROSSING
            if (min(pk.x, pk.y) > zhi * (1.0 + 1e-5)) { sc_ok = false; continue; }
#else
            if (min(pk.x, pk.y) > zhi * (1.0 + 1e-5)) continue;
#endif
            tol = u_thickness * (zhi - zlo) + 1e-4 * zhi;
            lower = max(zlo - tol, zfirst);
            h = bvec4(layer_hit(pk.x, zhi, lower), layer_hit(pk.y, zhi, lower), layer_hit(pk.z, zhi, lower),
                      layer_hit(pk.w, zhi, lower));
            // Crossing rule: the ray was in front of a layer's surface at the previous
            // step and is behind it now, and that surface is continuous between the two
            // texels (depth jump <= u_continuity of its depth): a steep surface (seen at
            // a grazing angle from e_c) crossed within one step, not a silhouette the ray
            // passes behind.
            xing = bvec4(false);
#ifdef CROSSING
            if (pok) {
                xing = bvec4(vec4(greaterThan(pd, vec4(pz))) * vec4(lessThan(pk, vec4(zc)))
                             * vec4(greaterThanEqual(pk, vec4(zfirst)))
                             * vec4(lessThanEqual(abs(pk - pd), u_continuity * min(pk, pd))));
                h = bvec4(vec4(h) + vec4(xing));
            }
#endif
#ifdef SURFACE_CROSSING
            // Surface crossing: the ray is in front of a layer's interpolated surface at
            // the previous step and behind it now, that surface continuous around both
            // points: a steep surface crossed between texel centres.
            sx = bvec4(false);
            sxa = vec4(0.0);
            // Cheap pre-test on the nearest texels (a continuous 2×2 footprint spans at
            // most a factor 1 + sc_rel): the ray not far behind the previous texel's
            // surface and not far in front of this one's.
            bvec4 cand = bvec4(vec4(lessThanEqual(pk, vec4(zc * (1.0 + sc_rel))))
                               * (pok ? vec4(greaterThanEqual(pd * (1.0 + sc_rel), vec4(pz))) : vec4(1.0)));
            if (k > 0 && any(cand)) {
                bvec4 ck;
                vec4 gk = vec4(mix(is2, ie2, ac)) - surface_inv(org, top, pix, sc_rel, ck);
                float ap = float(k - 1) / float(steps);
                if (!sc_ok) sc_g = vec4(mix(is2, ie2, ap)) - surface_inv(org, top, mix(s2, e2, ap), sc_rel, sc_c);
                sx = bvec4(vec4(cand) * vec4(sc_c) * vec4(ck) * vec4(greaterThanEqual(sc_g, vec4(0.0)))
                           * vec4(lessThan(gk, vec4(0.0))));
                sxa = ap + (ac - ap) * sc_g / max(sc_g - gk, vec4(1e-30));
                sc_g = gk; sc_c = ck; sc_ok = true;
            } else sc_ok = false;
            h = bvec4(vec4(h) + vec4(sx));
#endif
            if (!any(h)) continue;
            // The own triangle's plane is never a hit (checked only on candidate hits).
            vec2 uv = mix(F.rect.xy, F.rect.zw, (vec2(tx) + 0.5) / wh);
            float slope = g_plane.y + uv.x * g_plane.z + uv.y * g_plane.w;
            vec2 off = abs(vec2(g_plane.x) + pk.yz * slope);
            h.yz = bvec2(h.y && off.x > SELF_PLANE * pk.y, h.z && off.y > SELF_PLANE * pk.z);
            if (!any(h)) continue;
            found = true;
            break;
        }
        if (!found) return false;
        float dtol;
        vec4 ars = vec4(-2.0);  // refined crossings, computed here only near the origin
#ifdef NEAR_CROSSING
        // Near the ray's origin (its first u_near_steps texels) the ray lies on or
        // next to its reflector, whose texels (and those of surfaces touching it) are
        // within the thin-surface tolerance of the ray: there a hit needs the ray to
        // cross the interpolated surface inside the step (a refined crossing).
        if (a0 <= 0.0 && k <= u_near_steps) {
            for (int l = 0; l < 4; ++l) {
#ifdef SURFACE_CROSSING
                if (sx[l]) continue;
#endif
                if (!h[l] || xing[l]) continue;
                dtol = max(2.0 * tol, 5e-3 * pk[l]);
                ars[l] = refine(l, org, top, s2, e2, is2, ie2, alo, ahi, pk[l], dtol);
                if (ars[l] < 0.0) h[l] = false;
            }
            if (!any(h)) { ++k; continue; }
        }
#endif
        // Several layers hit in this step: the surface met first along the ray.
        bool away = ie2 < is2;  // depth grows along the ray
        int layer = -1;
        float D = 0.0;
        for (int l = 0; l < 4; ++l) {
            float Dl = pk[l];
#ifdef SURFACE_CROSSING
            if (sx[l]) Dl = 1.0 / mix(is2, ie2, sxa[l]);
#endif
            if (h[l] && (layer < 0 || (away ? Dl < D : Dl > D))) { layer = l; D = Dl; }
        }
        if (!exact_hit) {  // a lobe ray: its hit texel's colour
            col = layer_colour(layer, org + tx);
            t_hit = hit_distance(t0, t1, zs, ze, a0, a1, ac, D);
            return true;
        }
        dtol = max(2.0 * tol, 5e-3 * D);
        // Where in the step the hit lies (image parameter ac, depth D), by the rule
        // that found it; then one colour lookup for all three rules.
        bool surface_xing = false;
#ifdef SURFACE_CROSSING
        surface_xing = sx[layer];
#endif
        if (surface_xing) {
#ifdef SURFACE_CROSSING
            ac = sxa[layer]; pix = mix(s2, e2, ac);
            dtol = max(5e-3 * D, sc_rel * D);
#endif
        }
#ifdef CROSSING
        else if (xing[layer] && !layer_hit(D, zhi, lower)) {
            // Crossed between the previous step's centre and this one: the crossing of
            // the ray's and the surface's inverse depths, both linear between them.
            float gp = 1.0 / pz - 1.0 / pd[layer], gk = 1.0 / zc - 1.0 / D;
            float ax = gp > gk ? pa + (ac - pa) * clamp(gp / (gp - gk), 0.0, 1.0) : ac;
            ac = ax; pix = mix(s2, e2, ax); D = 1.0 / mix(is2, ie2, ax);
            dtol = max(dtol, u_continuity * D);
        }
#endif
        else {
            float ar = ars[layer] > -2.0 ? ars[layer] : refine(layer, org, top, s2, e2, is2, ie2, alo, ahi, D, dtol);
            if (ar >= 0.0) { ac = ar; pix = mix(s2, e2, ar); D = 1.0 / mix(is2, ie2, ar); }
        }
        col = surface_at(layer, org, top, pix, D, dtol, true).rgb;
        t_hit = hit_distance(t0, t1, zs, ze, a0, a1, ac, D);
        return true;
    }
    return false;
}

void main() {
    if (gl_GlobalInvocationID.x >= n_samples) return;
    ivec2 p = list_sample(gl_GlobalInvocationID.x);
    uint bin = texelFetch(u_bins, p, 0).r;  // listed: never 0 (the resolve reads reflective samples only)
    int cid = remap[bin - 1u];
    ClusterFrame F = frames[max(cid, 0)];
    vec3 P = texelFetch(u_position, p, 0).xyz;
    vec3 n = normalize(texelFetch(u_normal, p, 0).xyz);
    vec3 ng = geom_normal(texelFetch(u_tri, p, 0).r);
    g_plane = vec4(dot(F.c_near.xyz - P, ng), dot(F.fwd_half.xyz, ng), dot(F.right_far.xyz, ng), dot(F.up_len.xyz, ng));
    vec3 r = mirror_dir(normalize(P - u_eye), n, ng);
    float g = texelFetch(u_material, p, 0).g;
    vec3 diff = texelFetch(u_color, p, 0).rgb;
    float half_angle = F.fwd_half.w, far_len = F.up_len.w;
    vec3 refl = vec3(0.0);
    float len = f_inf();
    if (u_mode == 1) {
        if (g <= 0.0) refl = sky(r);
        else { for (int k = 0; k < u_rays; ++k) refl += sky(lift_above(lobe_dir(r, half_angle, u_lobe[k]), ng));
               refl /= float(u_rays); }
    } else {
        vec3 hc; float th;
        bool h = trace(P, r, F, hc, th, true);
        len = h ? th : f_inf();
        if (g <= 0.0) refl = h ? hc : sky(r);
        else {
            for (int k = 0; k < u_rays; ++k) {
                vec3 dk = lift_above(lobe_dir(r, half_angle, u_lobe[k]), ng);
                h = trace(P, dk, F, hc, th, false);  // a lobe ray: its hit texel's colour
                float w = h ? clamp((far_len - th) / (FADE_FRACTION * far_len), 0.0, 1.0) : 0.0;
                refl += w * hc + (1.0 - w) * diff;
            }
            refl /= float(u_rays);
        }
    }
    imageStore(u_out, p, vec4(refl, len));
}
