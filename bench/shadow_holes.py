"""Where NR's extra too-bright light samples come from (soft-shadow benchmark, part `holes`).

On grass the NR + hybrid shadows are too bright more often than the conventional
images' (gap part). Per scene, at k = --sweep-k, against the geometry-shadow-map
truth, this part measures:

- the light samples per pixel that one set gets wrong and the other right, split
  into too bright and too dark, counting only the pairs (pixel, light sample) where
  the exact Embree truth agrees with the geometry truth;
- for the pairs NR alone lights (and, the other way round, the conventional set
  alone), the occluder point: where the shadow ray from the pixel to the light
  sample meets the scene (Embree), classified by the NR images' samples near it —
  at the point's texel of the first image I_0 (NR and conventional share it), next
  to it (3 × 3 texels), at or next to a later NR image's texel, or none — a sample
  "near" when within HOLE_REACH pixel footprints of the point;
- two ways to give NR back re-captures where its earlier images leave a surface
  open, tried and not kept: footprint redundancy limited to occlusion seams
  (`DepthImageRenderer(footprint=½, occluded_margin=SEAM_MARGIN)`), and
  reconstruction-aware redundancy (`recapture_gaps`): a later image keeps its first
  hit where the reconstructions of the images before it, seen from its eye, do not
  hold that surface at the pixel centre;
- NR's and the conventional images' errors again in shadow maps FINER_MAPS times
  finer per side (the geometry truth is itself a shadow map; the exact truth stays).
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from typing import Any

import numpy as np

from bench.common import md_table
from bench.shadow_stage import Stage, errors, iv, iv_sign_triangles, truths, unpack_visibility
from gl_passes.context import GLContext
from gl_passes.depth_images import DepthImageRenderer
from gl_passes.reconstruction import (
    ReconstructionSettings,
    Reconstructor,
    SampledSet,
    mesh_arrays,
    reconstruct_set,
    render_set,
)
from gl_passes.shadows import ShadowSettings, SoftShadowPass
from reference.raycast import RayCaster
from reference.shadows import shadow_errors, surface_offset
from scenes.depth_image import DepthImage
from scenes.lights import default_area_light, reference_cameras
from scenes.model import AreaLight, Scene, SceneObject

#: Relative depth margin of the occlusion-seam rule (a nearer surface by more than 0.3 % of the depth).
SEAM_MARGIN = 0.003
#: A reconstruction holds a later image's first hit when its surface along the pixel-centre ray is within
#: this many pixel footprints of the hit (recapture_gaps).
RECAPTURE_TOLERANCE = 2.0
#: A sample is near an occluder point within this many pixel footprints (occluder classification).
HOLE_REACH = 1.5
#: Occluder points classified per kind of disagreement (a seeded random subset of the pairs).
HOLE_RAYS = 20000
#: The shadow maps of the resolution check are this many times finer per side than --shadow-res.
FINER_MAPS = 2
#: The kinds of (pixel, light sample) pairs whose occluders are classified, with their report labels.
OCCLUDER_PAIRS = {"nr_bright": "NR alone too bright", "conv_bright": "conventional alone too bright",
                  "both_shadowed": "both right, shadowed"}
#: The occluder classes, in the order they are tried.
HOLE_CLASSES = ("at I_0", "next to I_0", "later image", "none")


def mesh_caster(parts: list[tuple[np.ndarray, np.ndarray]]) -> RayCaster | None:
    """Embree over reconstructed meshes (positions, triangles) as `mesh_arrays`
    returns them; None when they hold no triangle."""
    objs = [SceneObject(f"image_{j}", p, t) for j, (p, t) in enumerate(parts) if len(t)]
    return RayCaster(Scene(objs, name="reconstruction")) if objs else None


def recapture_gaps(gl: GLContext, nr: SampledSet, conv: SampledSet, settings: ReconstructionSettings,
                   rec: Reconstructor, tolerance: float = RECAPTURE_TOLERANCE) -> tuple[SampledSet, int]:
    """NR images whose later images I_i also keep the first hit (conventional image
    C_i's sample of the same camera) at the pixels where Alg. 3 dropped it and the
    reconstructions of I_0..I_{i−1} (as modified) leave its surface open: the ray
    from V_i through the pixel centre meets them nowhere within `tolerance` pixel
    footprints of C_i's depth. Returns the set (I_i's offset images unchanged: a
    kept first hit takes tangent-plane corners) and the number of samples added."""
    images = [nr.images[0]]
    added = 0
    for i in range(1, len(nr.images)):
        meshes = reconstruct_set(gl, SampledSet(nr.method, images, (nr.offsets or [])[:i] or None), settings, rec)
        try:
            parts = [mesh_arrays(m) for m in meshes]
        finally:
            for m in meshes:
                m.release()
        first, own = conv.images[i], nr.images[i]
        rows, cols = np.nonzero((first.tri_id > 0) & (first.tri_id != own.tri_id))
        open_ = np.ones(len(rows), bool)
        caster = mesh_caster(parts)
        if len(rows) and caster is not None:
            eye = np.asarray(first.camera.eye, np.float64)
            d = first.position[rows, cols].astype(np.float64) - eye
            dist = np.linalg.norm(d, axis=1)
            hits = caster.intersect(np.broadcast_to(eye, d.shape), d / dist[:, None], 2 * dist,
                                    cull_back_faces=False)
            open_ = ~(np.abs(hits.t - dist) <= tolerance * first.camera.pixel_footprint * dist)
        r, c = rows[open_], cols[open_]
        fields = {f: getattr(own, f).copy() for f in ("color", "depth", "normal", "position", "tri_id")}
        for f, a in fields.items():
            a[r, c] = getattr(first, f)[r, c]
        images.append(replace(own, **fields))
        added += len(r)
    return SampledSet(nr.method, images, nr.offsets), added


def shadow_rays(st: Stage, light: AreaLight, k: int, pairs: np.ndarray,
                rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(origins, unit directions, lengths) of the exact truth's occlusion rays for
    (pixel index into the mask's pixels, light sample) pairs, at most HOLE_RAYS of
    them (drawn with rng)."""
    pix, smp = np.nonzero(pairs)
    if len(pix) > HOLE_RAYS:
        pick = rng.choice(len(pix), HOLE_RAYS, replace=False)
        pix, smp = pix[pick], smp[pick]
    n = st.normals[st.mask][pix].astype(np.float64)
    o = st.points[st.mask][pix].astype(np.float64) + n / np.linalg.norm(n, axis=1, keepdims=True) \
        * surface_offset(st.caster)
    d = light.samples(k)[smp] - o
    dist = np.linalg.norm(d, axis=1)
    return o, d / np.maximum(dist, 1e-30)[:, None], dist


def classify_occluders(caster: RayCaster, rays: tuple[np.ndarray, ...], images: list[DepthImage]) -> dict[str, float]:
    """Shares of HOLE_CLASSES among the occluder points of `rays` (where they meet
    the scene of `caster`) by the samples of `images` near them."""
    o, d, dist = rays
    hits = caster.intersect(o, d, dist, cull_back_faces=False)
    x = o[hits.hit] + d[hits.hit] * hits.t[hits.hit, None]
    label = np.full(len(x), len(HOLE_CLASSES) - 1)
    for j, img in enumerate(images):
        cam = img.camera
        px, z = cam.project(x)
        foot = cam.pixel_footprint * z
        col, row = np.floor(px[:, 0]).astype(np.int64), np.floor(px[:, 1]).astype(np.int64)
        for reach, cls in ((0, 0 if j == 0 else 2), (1, 1 if j == 0 else 2)):
            near = np.zeros(len(x), bool)
            for dy in range(-reach, reach + 1):
                for dx in range(-reach, reach + 1):
                    c, r = (col + dx).clip(0, cam.width - 1), (row + dy).clip(0, cam.height - 1)
                    q = img.position[r, c].astype(np.float64)
                    near |= (img.tri_id[r, c] > 0) & (np.linalg.norm(q - x, axis=1) <= HOLE_REACH * foot)
            label = np.where(near & (z > 0), np.minimum(label, cls), label)
    counts = np.bincount(label, minlength=len(HOLE_CLASSES))
    return {"rays": int(len(x)), **{c: float(counts[i] / max(len(x), 1)) for i, c in enumerate(HOLE_CLASSES)}}


def reconstruction_hits(rays: tuple[np.ndarray, ...], parts: list[tuple[np.ndarray, np.ndarray]]) -> float:
    """Share of `rays` that meet any of the meshes (positions, triangles)."""
    caster = mesh_caster(parts)
    if caster is None or not len(rays[0]):
        return 0.0
    o, d, dist = rays
    return float(caster.intersect(o, d, dist, cull_back_faces=False).hit.mean())


def part_holes(gl: GLContext, st: Stage, args: argparse.Namespace) -> dict[str, Any]:
    """The measurements of the module docstring for one staged scene."""
    k = args.sweep_k
    bounds = st.scene.bounds
    light = default_area_light(bounds, st.scene.sun_direction)
    settings = ReconstructionSettings()
    rec = Reconstructor(gl)
    out: dict[str, Any] = {"runs": {}}
    try:
        with SoftShadowPass(gl, ShadowSettings(samples=k, shadow_map_resolution=args.shadow_res)) as sp:
            geo, exact, _ = truths(st, sp, light, k)

            def measure(sampled: SampledSet, keep: list | None = None, pass_: SoftShadowPass = sp,
                        truth: np.ndarray = geo) -> tuple[dict[str, Any], np.ndarray]:
                """Errors and bits of the set's reconstruction in `pass_`'s shadow maps
                against `truth` and the exact truth; `keep` gets the meshes' arrays."""
                meshes = reconstruct_set(gl, sampled, settings, rec)
                try:
                    bits = pass_.visibility(meshes, bounds, st.points, st.normals, st.mask, light).bits
                    tris = sum(m.n_triangles for m in meshes)
                    if keep is not None:
                        keep += [mesh_arrays(m) for m in meshes]
                finally:
                    for m in meshes:
                        m.release()
                return {**errors(bits, truth, exact, st.mask), "triangles": tris}, bits

            cams = {m: reference_cameras(light, bounds, m, args.ref_res) for m in ("non_redundant", "conventional")}
            sets = {m: render_set(gl, st.gpu, m, c) for m, c in cams.items()}
            bits, parts = {}, {}
            for m, sampled in sets.items():
                parts[m] = []
                out["runs"][m], bits[m] = measure(sampled, parts[m])
            with DepthImageRenderer(gl, footprint=0.5, occluded_margin=SEAM_MARGIN) as r:
                seams = render_set(gl, st.gpu, "non_redundant", cams["non_redundant"], renderer=r)
            out["runs"]["seams"], _ = measure(seams)
            regained, added = recapture_gaps(gl, sets["non_redundant"], sets["conventional"], settings, rec)
            out["runs"]["recapture"], _ = measure(regained)
            out["runs"]["recapture"]["samples_added"] = added
        out["maps"] = {str(args.shadow_res): {"geometry_vs_exact": shadow_errors(geo, exact, st.mask),
                                              **{m: out["runs"][m] for m in sets}}}
        fine = FINER_MAPS * args.shadow_res  # the same images and meshes in finer shadow maps
        with SoftShadowPass(gl, ShadowSettings(samples=k, shadow_map_resolution=fine)) as sp_fine:
            geo_fine = sp_fine.visibility([st.gpu], bounds, st.points, st.normals, st.mask, light).bits
            out["maps"][str(fine)] = {"geometry_vs_exact": shadow_errors(geo_fine, exact, st.mask),
                                      **{m: measure(sets[m], None, sp_fine, geo_fine)[0] for m in sets}}
    finally:
        rec.release()
    g, x, nr, cv = (unpack_visibility(b[st.mask], k * k)
                    for b in (geo, exact, bits["non_redundant"], bits["conventional"]))
    agree = g == x
    pixels = max(int(st.mask.sum()), 1)
    only = {"nr_bright": nr & ~cv & ~g, "conv_bright": cv & ~nr & ~g,
            "nr_dark": ~nr & cv & g, "conv_dark": ~cv & nr & g}
    out["only"] = {name: float((sel & agree).sum() / pixels) for name, sel in only.items()}
    only["both_shadowed"] = ~nr & ~cv & ~g  # both right where the truth is shadowed: the rays' baseline
    rng = np.random.default_rng(0)
    out["occluders"] = {}
    for name in OCCLUDER_PAIRS:
        rays = shadow_rays(st, light, k, only[name] & agree, rng)
        out["occluders"][name] = {**classify_occluders(st.caster, rays, sets["non_redundant"].images),
                                  **{f"hits_{m}": reconstruction_hits(rays, parts[m]) for m in parts}}
    return out


def holes_report(holes: dict[str, Any]) -> list[str]:
    """The part's section of bench/results/soft_shadows.md ([] without runs)."""
    if not holes:
        return []
    k = next(iter(holes.values()))["args"]["sweep_k"]
    rows = [[s, *(f"{r['runs']['only'][n]:.3f}" for n in ("nr_bright", "conv_bright", "nr_dark", "conv_dark"))]
            for s, r in holes.items()]
    lines = [f"### Where NR's extra too-bright light samples come from (hybrid, k = {k}, reference 1024²)", "",
             "Light samples per pixel that one set gets wrong and the other right, against the geometry truth, "
             "where the exact Embree truth agrees with it (`bench/shadow_holes.py`):", "",
             md_table(["scene", "NR alone too bright", "conventional alone too bright", "NR alone too dark",
                       "conventional alone too dark"], rows), "",
             f"The occluder point of each such pair (where the shadow ray meets the scene; at most {HOLE_RAYS:,} "
             f"per cell), by the NR images' samples within {HOLE_REACH:g} pixel footprints of it: at its texel of "
             "the first image I_0 (the same image in both sets), in the 3 × 3 texels around it, at or next to a "
             "later NR image's texel, or none; and the share of the same rays that meet each set's reconstruction "
             "(Embree on the meshes, not the shadow maps). The last row per scene, pairs both sets get right "
             "where the truth is shadowed, is the baseline:", ""]
    rows = [[s, label, *(f"{o[c]:.2f}" for c in HOLE_CLASSES), f"{o['hits_non_redundant']:.2f}",
             f"{o['hits_conventional']:.2f}", f"{o['rays']:,}"]
            for s, r in holes.items() for name, label in OCCLUDER_PAIRS.items()
            for o in (r["runs"]["occluders"].get(name),) if o]
    lines += [md_table(["scene", "pairs", *HOLE_CLASSES, "ray meets NR's meshes", "ray meets conventional's meshes",
                        "rays"], rows), "",
              "Re-captures for NR where its earlier images leave the surface open (tried, not kept): footprint "
              f"redundancy at the pixel corners limited to occlusion seams (`occluded_margin={SEAM_MARGIN:g}`: a "
              "straddling pixel keeps its surface only where the earlier image saw a nearer surface there), and "
              "reconstruction-aware redundancy (`recapture_gaps`: a later image keeps its first hit where the "
              "reconstructions of the images before it, seen from its eye, miss that surface at the pixel centre "
              f"by more than {RECAPTURE_TOLERANCE:g} footprints). Cells: mean intensity · visibility error "
              "against the geometry truth (too dark / too bright; triangles).", ""]
    rows = [[s, *(iv_sign_triangles(r["runs"]["runs"][n])
                  for n in ("non_redundant", "seams", "recapture", "conventional"))] for s, r in holes.items()]
    lines += [md_table(["scene", "NR (default)", "NR, occlusion seams", "NR, reconstruction-aware",
                        "conventional"], rows), ""]
    lines += _reading(holes)
    rows = [[s, f"{res}²", iv(m["geometry_vs_exact"]), *(f"{iv(m[n]['vs_geometry'])} / {iv(m[n]['vs_exact'])}"
                                                        for n in ("non_redundant", "conventional"))]
            for s, r in holes.items() for res, m in r["runs"].get("maps", {}).items()]
    if rows:
        lines += ["The same images and meshes in shadow maps of two resolutions (the geometry truth is itself a "
                  "shadow map of that resolution; the exact truth does not change). Cells: mean intensity · "
                  "visibility error, against the geometry truth / against the exact truth:", "",
                  md_table(["scene", "shadow maps", "geometry maps vs exact", "NR", "conventional"], rows), ""]
    return lines


def _reading(holes: dict[str, Any]) -> list[str]:
    """What the tables say about the scene where NR's visibility error exceeds conventional's the most."""
    def gap(r: dict[str, Any]) -> float:
        return r["runs"]["runs"]["non_redundant"]["vs_geometry"]["visibility_mean"] \
            - r["runs"]["runs"]["conventional"]["vs_geometry"]["visibility_mean"]

    scene, r = max(holes.items(), key=lambda item: gap(item[1]))
    if gap(r) <= 0 or "hits_non_redundant" not in r["runs"]["occluders"]["nr_bright"]:
        return []
    runs, only, o = r["runs"]["runs"], r["runs"]["only"], r["runs"]["occluders"]["nr_bright"]
    b = r["runs"]["occluders"].get("both_shadowed", o)
    base = runs["non_redundant"]["vs_geometry"]["visibility_mean"]
    regained = max(base - runs[n]["vs_geometry"]["visibility_mean"] for n in ("seams", "recapture"))
    return [f"Reading ({scene}, where NR's mean visibility error exceeds conventional's by {gap(r):.3f}): "
            f"NR alone is too bright in {only['nr_bright']:.3f} light samples per pixel, conventional alone in "
            f"{only['conv_bright']:.3f}. {o['at I_0'] + o['next to I_0']:.0%} of the occluder points of NR's lie "
            f"at or next to a sample of I_0, the image both sets share, and {o['hits_non_redundant']:.0%} of those "
            "shadow rays meet NR's meshes, about as for the pairs both sets shadow rightly "
            f"({b['at I_0'] + b['next to I_0']:.0%}, {b['hits_non_redundant']:.0%}): NR's extra too-bright "
            "samples are not at missing surfaces or seams but where a shadow map's texel centre misses a "
            "reconstructed outline that the ray through the pixel meets (not only on blades narrower than a "
            "texel: grass with wider blades below). Conventional images hold up to four outlines of each "
            "blade, each rounded to its own pixel grid (the later ones trimmed by the evidence rule); "
            f"their union meets {o['hits_conventional']:.0%} of these rays ({b['hits_conventional']:.0%} of the "
            "baseline's) and covers more of the truth's texel centres, at the price of more too-dark samples. "
            f"Re-capturing where NR's earlier images leave a surface open takes back at most {regained:.3f} of "
            f"the {gap(r):.3f}.", ""]
