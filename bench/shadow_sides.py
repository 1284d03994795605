"""Which sides of the surfaces the light's depth images keep (soft-shadow benchmark,
part `sides`; the service's ``soft_shadows.sides``).

The thesis's depth images cull back faces (§2.3), so an occluder the light sees from
behind — a single-sided surface facing away from it, such as a room's walls and
ceiling under a light outside the room — is in none of the light's images and casts
no shadow, while the geometry shadow maps (drawn without culling) and the exact
Embree truth see it. Per scene, at k = --sweep-k with reference images of --ref-res²
and the hybrid reconstruction, this part measures NR, conventional and peeling images
with back faces culled (``front``, the default) and with both sides drawn
(``both``, `render_set(cull_back_faces=False)`), against both truths.
Run it on the Table 8 scenes and on the rooms (cornell, bathroom).
"""

from __future__ import annotations

import argparse
from typing import Any

from bench.common import cpu_model, md_table
from bench.shadow_stage import Stage, set_errors, truths
from gl_passes.context import GLContext
from gl_passes.reconstruction import SAMPLING_METHODS
from gl_passes.shadows import ShadowSettings, SoftShadowPass
from scenes.lights import default_area_light, reference_cameras

#: The two settings of ``sides`` (service ``soft_shadows.sides``): back faces culled or not.
SIDES = ("front", "both")


def part_sides(gl: GLContext, st: Stage, args: argparse.Namespace) -> dict[str, Any]:
    """{"methods": {method: {sides: errors (both truths) and triangles}} under the
    default light, "cpu": the machine's CPU (the report's header names the machine of
    the other parts)}."""
    k = args.sweep_k
    light = default_area_light(st.scene.bounds, st.scene.sun_direction)
    out: dict[str, Any] = {}
    with SoftShadowPass(gl, ShadowSettings(samples=k, shadow_map_resolution=args.shadow_res)) as sp:
        geo, exact, _ = truths(st, sp, light, k)
        for method in SAMPLING_METHODS:
            out[method] = {}
            cams = reference_cameras(light, st.scene.bounds, method, args.ref_res)
            for sides in SIDES:
                out[method][sides] = set_errors(gl, st, sp, light, method, cams, geo, exact,
                                                cull_back_faces=sides == "front")
    return {"methods": out, "cpu": cpu_model()}


def _cell(e: dict[str, Any], truth: str) -> str:
    return f"{e[truth]['intensity_mean']:.2f} / {e[truth]['visibility_mean']:.2f}"


def sides_report(data: dict[str, Any]) -> list[str]:
    """The part's section of soft_shadows.md (empty without runs)."""
    if not data:
        return []
    first = next(iter(data.values()))
    rows, changed = [], []
    for scene, r in data.items():
        for method, runs in r["runs"]["methods"].items():
            rows.append([scene, method, *(_cell(runs[s], t) for t in ("vs_geometry", "vs_exact") for s in SIDES),
                         *(f"{runs[s]['triangles']:,}" for s in SIDES)])
            front, both = (runs[s]["vs_exact"]["visibility_mean"] for s in SIDES)
            if abs(both - front) > 0.1 * max(front, 1e-9):
                changed.append(f"{scene} {method} {front:.2f} → {both:.2f}")
    headers = ["scene", "images", *(f"{s} vs {t}" for t in ("geometry", "exact") for s in SIDES),
               *(f"triangles {s}" for s in SIDES)]
    cpus = sorted({r["runs"]["cpu"] for r in data.values()})
    return [f"## Sides of the light's depth images (hybrid, k = {first['args']['sweep_k']}, reference "
            f"{first['args']['ref_res']}², default light)", "",
            "Mean intensity / visibility error (light samples per pixel) with back faces culled (`front`, the "
            "thesis's images and the service's default) and with both sides drawn (`both`, the service's "
            "`soft_shadows.sides`), measured on " + ", ".join(cpus) + ". Culled, a single-sided occluder the "
            "light sees from behind casts no shadow; the geometry shadow maps and the Embree truth see both "
            "sides. Mean visibility error against the exact truth changed by more than 10 %: "
            + ("; ".join(changed) or "nowhere") + ". On closed objects both sides add nothing to conventional "
            "images (their nearest surface faces the light) but triangles to NR and peeling: a later NR image "
            "keeps the nearest surface not captured before, which behind a captured front face is now the "
            "object's inside, and a peeling layer may be one.", "",
            md_table(headers, rows), ""]
