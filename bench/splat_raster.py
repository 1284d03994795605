"""When the compute splat rasteriser pays: shadow maps of a reconstruction's small
pieces rasterised as splats (`gl_passes.quad_splats.SplatRaster`) against the same
pieces drawn as triangles (thesis Alg. 5 over Alg. 4's meshes; beyond the thesis).

The rasteriser costs a fixed pass per batch of maps (its resolve over the tile rows
the batch fills) and saves a part of each splat's triangle cost in every map, so it
pays above some splats × maps per resolved texel: `ShadowSettings.splat_raster_min`.

1. Sweeps: N splats taken at random (fixed seed, kept in the mesh's order) from the NR + hybrid
   reconstruction of grass (reference images from the light's 4 corners at the
   HTTP default's 1024², front faces, and at the thin client's 256², both sides:
   splats of a pixel or so there are about 4× as wide in the maps), alone in one
   batch of 16 shadow maps of 1024² (the service's), as splats and as triangles,
   interleaved round by round; the break-even N (where the times cross,
   interpolated between the measured N) over the batch's texels is the density.
2. Sets: the whole reconstructions the service draws (the thin client's k = 6 from
   256² images, both sides; the HTTP default's 1024² images, front faces, at k = 4
   here: one full batch, the rule being per batch): all their maps with every batch
   as splats, as triangles, and by the default rule.

    python -m bench.splat_raster [--repeat 5] [--out bench/results]
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

from bench.common import md_table, measure_with_gl, progress, report_head, time_side_by_side, write_json, write_text
from gl_passes.mesh_gpu import MeshGPU, pack_vertices
from gl_passes.reconstruction import ReconstructionSettings, reconstruct_set, render_set
from gl_passes.shadows import SPLAT_RASTER_MIN, ShadowSettings, SoftShadowPass
from gl_passes.upload import SceneGPU
from scenes.builtin import make_builtin
from scenes.lights import default_area_light, reference_cameras

#: (reference resolution, sides, splat counts) of the sweeps, on grass.
SWEEPS = ((1024, "front", (2_000, 5_000, 10_000, 15_000, 20_000, 40_000, 80_000, 160_000, 300_000)),
          (256, "both", (2_000, 5_000, 10_000, 15_000, 20_000, 25_000, 31_000)))
MAP_RES = 1024  # the service's shadow maps (ShadowSettings' default)
#: (label, k, reference resolution, sides, scenes) of the sets (bench.shadow_frames' settings).
SETS = (("thin client", 6, 256, "both", ("city", "grass", "nest", "tree", "cornell")),
        ("HTTP default", 4, 1024, "front", ("city", "grass", "nest", "tree")))
WAYS = {"splats": 0.0, "triangles": float("inf"), "default": SPLAT_RASTER_MIN}
#: A way is faster than the other when it takes less than (1 − NOISE) of its time;
#: closer, the two are a tie (the default's own column, the same path as one of the
#: two, strays by about this much on this shared machine).
NOISE = 0.05


def light_meshes(gl: Any, name: str, res: int, sides: str) -> tuple[Any, list[MeshGPU]]:
    """(scene, NR + hybrid meshes of the light's 4 corners at res², as the service makes them)."""
    scene = make_builtin(name)
    light = default_area_light(scene.bounds, scene.sun_direction)
    with SceneGPU(gl, scene) as sg:
        sampled = render_set(gl, sg, "non_redundant", reference_cameras(light, scene.bounds, "non_redundant", res),
                             cull_back_faces=sides == "front")
    return scene, reconstruct_set(gl, sampled, ReconstructionSettings(kind="hybrid"))


def splat_arrays(meshes: list[MeshGPU]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(positions (V,3), quads (Q,2,3), lone triangles (L,3)) of the meshes' splats."""
    pos, quads, singles, base = [], [], [], 0
    for m in meshes:
        if m.splats is None:
            continue
        p, _, tri = m.read()
        n, count = m.splats.triangles, m.splats.count
        q = n - count
        last = np.asarray(tri, np.int64)[len(tri) - n:] + base
        quads.append(last[:2 * q].reshape(-1, 2, 3))
        singles.append(last[2 * q:])
        pos.append(p)
        base += len(p)
    return np.concatenate(pos), np.concatenate(quads), np.concatenate(singles)


def timed_maps(gl: Any, meshes: list[MeshGPU], scene: Any, k: int, repeat: int, ways: tuple[str, ...] = tuple(WAYS)
               ) -> dict[str, float]:
    """Fastest seconds of `repeat` rounds for all k² maps of `meshes` (render_maps)
    each of `ways` (WAYS), after one untimed round; the ways' order turns by one each
    round (no way always runs after the same other)."""
    light = default_area_light(scene.bounds, scene.sun_direction)
    passes = {w: SoftShadowPass(gl, ShadowSettings(samples=k, shadow_map_resolution=MAP_RES,
                                                   splat_raster_min=WAYS[w])) for w in ways}
    try:
        fns = {w: (lambda sp=sp: sp.render_maps(meshes, scene.bounds, light).release()) for w, sp in passes.items()}
        times = time_side_by_side(fns, repeat=repeat, warmup=1, sync=gl.ctx.finish, rotate=True)
    finally:
        for sp in passes.values():
            sp.release()
    return {w: t.min_ms / 1e3 for w, t in times.items()}


def sweep(gl: Any, res: int, sides: str, counts: tuple[int, ...], repeat: int, show: bool
          ) -> dict[str, Any]:
    """One batch's seconds each way for each of `counts` splats of grass's
    reconstruction from res² images (`sides`)."""
    scene, meshes = light_meshes(gl, "grass", res, sides)
    try:
        pos, quads, singles = splat_arrays(meshes)
    finally:
        for m in meshes:
            m.release()
    rng = np.random.default_rng(0)
    total = len(quads) + len(singles)
    out = []
    for n in progress([n for n in counts if n <= total], show, desc=f"sweep {res}²"):
        q = round(n * len(quads) / total)
        # a random subset in the mesh's own order, over its own vertices in first-use
        # order (a shuffled order would cost the triangles their vertex locality)
        pick = [np.sort(rng.choice(len(a), m, replace=False)) for a, m in ((quads, q), (singles, n - q))]
        used, tri = np.unique(np.concatenate([quads[pick[0]].reshape(-1, 3), singles[pick[1]]]), return_inverse=True)
        mesh = MeshGPU.from_records(gl, pack_vertices(pos[used]), tri.reshape(-1, 3), quads=q, singles=n - q)
        try:
            t = timed_maps(gl, [mesh], scene, 4, repeat, ("splats", "triangles"))
        finally:
            mesh.release()
        out.append({"splats": n, "quads": q, "triangles": len(tri), "seconds": t})
    return {"res": res, "sides": sides, "available": total, "rows": out}


def crossings(rows: list[dict[str, Any]]) -> list[float]:
    """Splats where the splat and triangle times of one batch cross, either way
    (linear between the sweep's neighbours; more than one where noise crosses back)."""
    gain = [(r["splats"], r["seconds"]["triangles"] - r["seconds"]["splats"]) for r in rows]
    return [n0 + (n1 - n0) * -g0 / (g1 - g0) for (n0, g0), (n1, g1) in zip(gain, gain[1:], strict=False)
            if (g0 < 0) != (g1 < 0)]


def faster_way(seconds: dict[str, float]) -> str:
    """"splats", "triangles", or "tie" when neither takes less than (1 − NOISE) of the other's time."""
    s, t = seconds["splats"], seconds["triangles"]
    return "splats" if s < (1 - NOISE) * t else "triangles" if t < (1 - NOISE) * s else "tie"


def sets(gl: Any, repeat: int, show: bool) -> list[dict[str, Any]]:
    jobs = [(label, k, res, sides, name) for label, k, res, sides, names in SETS for name in names]
    out = []
    for label, k, res, sides, name in progress(jobs, show, desc="sets"):
        scene, meshes = light_meshes(gl, name, res, sides)
        try:
            splats = sum(m.splats.count for m in meshes if m.splats)
            with SoftShadowPass(gl, ShadowSettings(samples=k, shadow_map_resolution=MAP_RES)) as sp:
                raster = sp.splat_raster
                counts = [min(sp.batch, k * k - first) for first in range(0, k * k, sp.batch)]
                batches = [(c, raster.pays(splats, c, SPLAT_RASTER_MIN),
                            splats * c / (raster.rows(c) * raster.tiles * MAP_RES**2)) for c in counts]
            out.append({"setting": label, "scene": name, "k": k, "res": res, "sides": sides, "splats": splats,
                        "triangles": sum(m.n_triangles for m in meshes), "batches": batches,
                        "seconds": timed_maps(gl, meshes, scene, k, repeat)})
        finally:
            for m in meshes:
                m.release()
    return out


def write_report(out: Path, args: argparse.Namespace, info: dict[str, Any], runs: dict[str, Any],
                 seconds: float) -> None:
    texels = MAP_RES**2  # per map of a full batch: splats × maps / texels = splats / MAP_RES²
    sweep_text, crossed = [], []
    for sw in runs["sweeps"]:
        rows = []
        for r in sw["rows"]:
            t = r["seconds"]
            rows.append([f"{r['splats']:,}", f"{r['splats'] / texels:.3f}", f"{t['splats'] * 1e3:.0f}",
                         f"{t['triangles'] * 1e3:.0f}", f"{t['triangles'] / t['splats']:.2f}×"])
        at = crossings(sw["rows"])
        crossed += [n / texels for n in at]
        even = ("The times cross at " + ", ".join(f"**{n:,.0f} splats** ({n / texels:.4f} per texel)" for n in at)
                + ("" if len(at) < 2 else ": noise crosses them back and forth") + "."
                if at else "The times do not cross within the sweep.")
        sweep_text += [f"### Grass, {sw['res']}² reference images, {sw['sides']} ({sw['available']:,} splats)", "",
                       md_table(["splats", "density", "ms as splats", "ms as triangles", "triangles / splats"], rows),
                       "", even, ""]
    set_rows, faster = [], {"splats": [], "triangles": [], "tie": []}
    for r in runs["sets"]:
        t = r["seconds"]
        way = faster_way(t)
        faster[way] += [d for _, _, d in r["batches"]]
        ways = ", ".join(f"{count}: {'splats' if pays else 'triangles'} ({d:.3f})" for count, pays, d in r["batches"])
        set_rows.append([r["setting"], r["scene"], f"{r['k']}² · {r['res']}² {r['sides']}", f"{r['triangles']:,}",
                         f"{r['splats']:,}", ways, f"{t['splats'] * 1e3:.0f}", f"{t['triangles'] * 1e3:.0f}", way,
                         f"{t['default'] * 1e3:.0f}", f"{t['default'] / min(t['splats'], t['triangles']):.2f}×"])
    text = report_head(
        "Splat rasteriser: where it pays (`ShadowSettings.splat_raster_min`)",
        f"python -m bench.splat_raster --repeat {args.repeat}",
        [f"Shadow maps of {MAP_RES}² in batches of 16 (an atlas of 4 × 4 tiles; `SoftShadowPass.render_maps`), "
         "the mesh drawn with its small pieces as splats (`gl_passes.quad_splats.SplatRaster`: a compute pass, "
         "then a resolve over the tile rows the batch fills) and as the triangles they stand for, interleaved "
         f"round by round (the order turning each round), the fastest of {args.repeat} rounds after one untimed "
         "round."],
        seconds, info) + [
        "## Sweeps: one batch of 16 maps, splats alone",
        "",
        "N splats drawn at random from grass's NR + hybrid reconstruction (images from the light's 4 corners), in "
        "the mesh's order; density = splats × maps per texel of the tile rows resolved (N / 1024² for a full batch).",
        "",
        *sweep_text,
        "## The service's reconstructions",
        "",
        "NR + hybrid reconstructions of the light's 4 corners as the service makes them; all k² maps. Batches: "
        "maps of each batch, the way the default rule picks and the batch's density. Faster: the way taking less "
        f"than {1 - NOISE:.2f} of the other's time, else a tie. Last column: the default rule against the faster "
        "of the two ways.",
        "",
        md_table(["setting", "scene", "k² · images", "triangles", "splats", "batches", "ms splats",
                  "ms triangles", "faster", "ms default", "default / faster"], set_rows),
        "",
        "## The default",
        "",
        _choice(crossed, faster),
        "",
    ]
    write_text(out / "splat_raster.md", "\n".join(text))


def _choice(crossed: list[float], faster: dict[str, list[float]]) -> str:
    """The default `splat_raster_min` against what was measured: the sweeps'
    crossings (densities) and the densities of the sets' batches by the way that
    drew them faster ("splats", "triangles", "tie")."""
    said = ["The sweeps (splats alone) cross at " + (", ".join(f"{c:.4f}" for c in sorted(crossed)) or "no density")
            + " splats per texel."]
    tri, spl = max(faster["triangles"], default=None), min(faster["splats"], default=None)
    if tri is not None:
        said.append(f"Drawn with the rest of their meshes, sets were faster as triangles up to {tri:.3f}.")
    if spl is not None:
        said.append(f"Sets were faster as splats from {spl:.3f}.")
    if faster["tie"]:
        said.append(f"Ties (within {100 * NOISE:.0f} %) at {min(faster['tie']):.3f}–{max(faster['tie']):.3f}.")
    between = (tri is None or tri < SPLAT_RASTER_MIN) and (spl is None or SPLAT_RASTER_MIN <= spl)
    gap = (f" {tri:.3f} and {spl:.3f} (between them the sets measured are ties or there are none: where the two "
           "ways meet with a mesh's body is not pinned down)" if tri is not None and spl is not None and between
           else "")
    said.append(f"The default, {SPLAT_RASTER_MIN}, " + (f"lies between{gap}: every set one way draws faster is "
                                                         "drawn that way." if between else "does not separate them."))
    return " ".join(said)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=5, help="timed rounds (interleaved) per measurement")
    ap.add_argument("--out", type=Path, default=Path("bench/results"))
    ap.add_argument("--report-only", action="store_true", help="rewrite the report from the saved json")
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)
    path = args.out / "splat_raster.json"
    if args.report_only:
        import json

        saved = json.loads(path.read_text())
        write_report(args.out, args, saved["machine"], saved["runs"], saved["seconds"])
        return 0
    show = not args.no_progress
    runs, info, seconds = measure_with_gl(lambda gl: {
        "sweeps": [sweep(gl, res, sides, counts, args.repeat, show) for res, sides, counts in SWEEPS],
        "sets": sets(gl, args.repeat, show)})
    write_json(path, {"args": vars(args), "machine": info, "seconds": seconds, "runs": runs})
    write_report(args.out, args, info, runs, seconds)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
