"""The prose of the sampling reports (bench.sampling): what issue 3's criteria show
and why our numbers differ from the thesis.

The prose discusses the canonical runs in bench/results (sampling.json at 512²,
sampling_1024/, sampling_2048/, the 1024²/1000-view target sampling_1024_1000v/,
tessellation.json, rig_spread.json, peeling_sides.json). Every number it quotes is
computed from those JSON files when a report is written (`criteria_notes`,
`discussion`), so a regenerated run updates the prose of every report; one-off
measurements that no benchmark stores, and run history, live in
bench/results/sampling_notes.json, each with how it was measured. The templates
below hold words and placeholders only.
"""

from __future__ import annotations

import json
import math
import textwrap
from collections.abc import Callable, Iterable, Sequence
from functools import cached_property
from pathlib import Path

import numpy as np

from bench.common import RESULTS_DIR, span
from bench.sampling_report import (
    CRITERIA_SCENES,
    THESIS_T2,
    THESIS_T4,
    THESIS_T5,
    THESIS_T7,
    conv_gap,
    criteria_rows,
    granularity_loss,
    layer_table,
    lead_ranges,
    reference_gap,
    thesis_granularity_loss,
    useful_table,
    view_independent_table,
    visibility_drift,
)

#: The canonical runs the prose discusses, relative to bench/results.
FILES = {"main": "sampling.json", "s1024": "sampling_1024/sampling.json", "s2048": "sampling_2048/sampling.json",
         "target": "sampling_1024_1000v/sampling.json", "tess": "tessellation.json", "spread": "rig_spread.json",
         "peel": "peeling_sides.json", "notes": "sampling_notes.json"}
WIDTH = 78  # the prose's line width in the .md
CRITERIA_HEADER = '### What the criteria show, and why (measured)'
CRITERIA_BULLETS = (
    ("* **The issue's target configuration, 1024² with 1000 intermediate views** (`sampling_1024_1000v/`: "
     '{target_total} min on this 2-core machine, {target_per_scene} min per scene, with the Embree '
     'reference caster split across threads), gives the {target_same} (a) {target_a}; (b) with visibility '
     '{target_b_vis}, with pixel {target_b_px} ({target_b_px_scenes}; NR trails the conventional set on '
     "average by {target_trail_avg}, and on the minimum by {target_trail_min}); (c) with the thesis's "
     "reading {target_c_thesis} (NR {target_ratio}× peeling's useful occluded samples), with the issue's "
     'reading {target_c_issue}. From 60 to 1000 views the averages moved by at most {moved_avg} points; '
     'the minima fell by up to {fell_min} points for NR and the conventional set and by {fell_peel} points'
     " for peeling (views near the rig's corners see past the centroid's layers); useful counts grew by "
     '{useful_growth} % (a sample needed only by a rare view), for NR and peeling alike.'),
    ('* **(a) holds.** The visibility NR sets (Embree) have no visibility-redundant sample. The GL pixel '
     'NR sets show {a_redundant} pixel-redundant samples out of {a_samples} when the reference re-tests '
     'them, and every one is a texel-edge tie: its projection lies within {tie_texels} texel of a texel '
     "edge (measured on {tie_measured}), where GL's float32 Alg. 3 and the reference's float64 projection "
     'fall on neighbouring texels; at 2048² ({views_2048} views) {off_edge} lies {off_edge_texels} texel '
     'from the edge (not counted as a tie: the float32 error in texel units grows with the resolution); '
     'the same sets rendered by Embree in float64 (`reference.visibility.non_redundant_reference`, '
     '`bench/results/tessellation.md`) have none. (Until this run the visibility NR sets also showed '
     '{old_visibility} such sample: `non_redundant_visibility` tested the float64 hit point but stored it '
     'as float32, and an occlusion ray grazing an edge could answer differently for the two; it now tests '
     'the stored point.)'),
    ('* **(b) holds with the visibility definition on {b_vis_scenes}** at 512² and 1024² (NR ahead of '
     'conventional by {b_vis_conv_avg} points and of peeling by {b_vis_peel_avg} points on average; on the'
     ' minimum by {b_vis_conv_min} and {b_vis_peel_min} points). **With the pixel definition NR stays '
     'ahead of peeling but falls {b_px_below} points below the conventional set** on {b_px_fail}. The '
     'mechanism, measured on {mech_run}: per view NR loses {mech_lost} of the samples the conventional set'
     ' makes available and gains {mech_gained}; {mech_dropped} % of the lost samples are on a triangle '
     'that C1 or C2 holds at their texel and that NR dropped there as pixel-redundant with an earlier '
     "image, while the frame sample's own projection into that earlier image lands on a texel of another "
     'triangle (silhouettes of thin blades, twigs and leaves, and building edges). Alg. 3 forces this, '
     'whatever the implementation: it keeps or drops a whole texel by its centre, and in an 8×8 case '
     'counted by hand (offset scene, `tests/test_sampling_metrics.py`) the NR set, with no redundant '
     "sample, makes 6 of a frame's 8 columns available where the conventional set makes all 8 (visibility "
     "definition: 8 and 8). It is the pixel definition's texel granularity: the gap shrinks from 512² to "
     '1024² ({shrink}) as pixel redundancy converges to visibility redundancy, and at 2048² ({views_2048} '
     'views, `sampling_2048/`) (b) holds with the pixel definition on {b_2048_scenes} (NR ahead of '
     'conventional by {b_2048_lead} points){b_2048_rest}. The gap belongs to Alg. 3, not to our GL pass, '
     "and it follows the triangles' size against the texel (`bench/results/tessellation.md`, `python -m "
     'bench.tessellation`, 1024², 60 views): the same NR sets rendered by Embree '
     "(`reference.visibility.non_redundant_reference`) give the GL sets' availability to ≤ {tess_ref_gap} "
     'point; splitting every triangle into 4 and 16, with the surfaces unchanged (visibility metrics move '
     '≤ {tess_drift} point), takes (b) with the pixel definition from {tess_b_first} scenes to '
     "{tess_b_last}, and NR's average lead over the conventional set from {tess_lead_first} points (as "
     'tessellated) to {tess_lead_last} ({tess_last_factor} triangles each). Finer triangles do not '
     "reproduce the thesis's tree row either (its conventional set loses {thesis_tree_loss} points from "
     "Table 6 to Table 4, yet NR is {thesis_tree_nr_lead} points ahead): our tree's conventional set loses"
     ' {tess_tree_loss} points that way ({tess_factors}) and NR trails more the finer it gets.'),
    ('* **(c) holds with the thesis\'s reading of "occluded" on {c_thesis} scenes, under both redundancy '
     'definitions, at 512² and at 1024² (NR ahead of peeling by {c_ratio}× in useful occluded samples); '
     "with the issue's reading it fails ({c_issue}).** The two readings (`reference/sampling_metrics.py`, "
     'both computed in every run): the issue summarises occluded samples as "not captured by the '
     'conventional images of V0..Vn-1"; §2.3.2 item 2 says, for an NR image from PPC_i, "not captured by '
     'the conventional images of PPC_j, j = 0..i-1", and for peeling "by any conventional image". We '
     "report both and judge (c) on the thesis's text, which is the spec, for three measured reasons: (1) "
     "the thesis's own tree row (conventional I1 23 % redundant, NR I1 84 % occluded) is impossible under "
     "the issue's reading, where NR I1's first-layer samples (≥ 77 % of C1's pixels) are captured by C1; "
     "(2) its NR cells are reproduced far better under the literal reading, with percentages of C_i's "
     'samples: mean gap over the NR occluded/useful cells {gap_px_512} points (pixel, 512²), {gap_px_1024}'
     ' (pixel, 1024²), {gap_vis_512} and {gap_vis_1024} (visibility), e.g. nest NR I1 {nest_i1} against '
     "the thesis's {nest_i1_thesis} at 1024²; (3) under the issue's reading, an NR image's first-layer "
     "samples, seen from V_i and thus needed by the views near V_i, never count, while peeling's layer L0 "
     "counts in full although it is itself a conventional image of an intermediate view. Why the issue's "
     'reading goes against NR on our scenes (measured, per-image table above): *L0 is an intermediate '
     'view*, so its occluded samples are ~100 % useful, and with the pixel definition it is inflated by '
     'reprojection misses on sub-pixel triangles (L0 has {l0_ratio}× more occluded samples under the pixel'
     ' than the visibility definition on nest, tree and grass); *our peeling layers 1-2 are far more '
     "useful than the thesis's* (useful share of L1's occluded samples {l1_useful} % on nest, grass, city,"
     ' tree, pixel, 512², against {l1_useful_thesis} %): our occluders (twigs 4-10 mm, blades, leaves) are'
     " thin against the rig's eye baseline; and *NR images spend most samples on first-layer surfaces* V0 "
     '(or V0, V1) does not see. Ground, framing and borders are not the cause (variant without ground: '
     "{no_ground} change; every view holds the content). The rig's spread, which Fig. 8 does not give, "
     'moves the issue-reading verdict but does not rescue it (`bench/results/rig_spread.md`, `python -m '
     'bench.rig_spread`, spreads {spreads}, {spread_res}², {spread_views} views): with the pixel '
     'definition (c) holds on {spread_c_px}; with the visibility definition on {spread_c_vis}; with the '
     "thesis's reading on {spread_c_thesis}. (b) with the pixel definition {spread_b_px}. The thesis's "
     'conventional redundancy does not pin the spread down (mean gap {spread_gap_vis} points over the '
     'spreads, visibility; {spread_gap_px}, pixel), so we keep 20° rather than pick the value that favours'
     ' NR.'),
    ('* **(d) {d_verdict}**: NR/conventional {d_conv} and NR/peeling {d_peel} at {d_res}² with either '
     'triangle-id source (llvmpipe, {d_rounds} interleaved rounds; Table 7). With {spread_rounds} rounds '
     'one reading ({spread_outlier}) came out at NR/peeling {spread_outlier_ratio}: single ratios on this '
     'shared 2-core machine move by ±{spread_pct} %.'),
)

DISCUSSION_HEADER = '### Why our numbers differ from the thesis'
DISCUSSION_BULLETS = (
    ("* **Scenes.** The thesis's bird's nest, grass, city and tree models are not available; ours are "
     'procedural stand-ins with the same triangle budgets (`scenes/builtin`) but a different depth '
     'complexity. All metrics depend on how much hidden, front-facing geometry lies behind what V0..V2 '
     'see, so per-cell gaps of tens of points are expected; the orderings are what can be compared '
     '(section "The thesis\'s claims, checked").'),
    ('* **Ground.** The nest and the tree stand on modest ground discs (1.4 × their footprint); grass and '
     'city grounds are the patch and the street grid the content covers. (Earlier runs used 1.5 m / 12 m '
     'ground quads around the nest / tree: the plane filled the image corners with ground that NR images '
     'mostly drop as redundant or keep as non-occluded, and lowered the NR occluded fractions; the counts '
     'of useful occluded samples barely changed.)'),
    ("* **Tiny triangles and resolution.** The nest's twigs and the tree's leaves are a few pixels or less"
     ' at 512²: pixel redundancy (same triangle id at the reprojected texel) then misses much of the true '
     'redundancy, so conventional redundancy is lower, NR images keep visible samples that only differ by '
     'triangle, and pixel-definition availability is low. The sweep (Figs 13-15) shows pixel-definition '
     'values converging toward the visibility-definition ones as the resolution grows, as §2.3.3 states; '
     '{sweep_overtake}'),
    ('* **Rig.** Fig. 8 gives no numbers: we use `scenes.rig.fig8_rig` (eyes 20° off a common axis at '
     "elevation 25°, fov 45°) framed on the scene without its ground: the content box's bounding sphere "
     'just fits the narrowest view of the rig (`scenes.rig.fit_distance`, {rig_distance} × the content '
     'diagonal), so every reference, peeling and intermediate view holds the whole content. Clip planes '
     "are fitted to the whole scene. Only the tree's ground disc reaches past the peeling view: "
     "{outside_tree} % of the tree's intermediate-view samples lie outside the peeling camera's frustum "
     "(inside all of V0..V2's), which lowers peeling's available fraction on the tree by at most that much"
     ' (measured at {outside_measured}; {outside_others}). A wider spread makes V1/V2 less redundant and '
     'NR images less deep.'),
    ("* **Views.** Fewer intermediate views than the thesis's 1000 lower the useful fraction slightly (a "
     'sample needed by a rare view can be missed) and raise the minimum available fraction.'),
    ('* **Depth peeling.** Its first layer comes from the centroid, itself an intermediate view, so its '
     'occluded samples are almost all useful; its deeper layers are complete images of the hidden layers, '
     'so in absolute counts peeling often collects more occluded samples than our sparse NR images. The '
     "thesis's layer 1 is nearly useless on the nest, grass and city ({thesis_l1} % of its occluded "
     'samples, Table 2) where ours is not ({ours_l1} % at {main_res}², {main_views} views): peeling '
     '*without* back-face culling gives {two_sided_l1} % on our closed nest and city models, its layer 1 '
     "being their inside (`bench/results/peeling_sides.md`, `python -m bench.peeling_sides`). The thesis's"
     ' Table 5 layer-1 and layer-2 shares fit our culled peeling better (mean gap {peel_gap_culled} '
     'against {peel_gap_two} points), so no single peeling matches both tables; we keep the culled peeling'
     ' the issue asks for (it has more useful occluded samples on every scene). Against the two-sided '
     "peeling, NR's useful occluded samples under the issue's reading still trail on {trail_px} scenes "
     '(pixel) and {trail_vis} (visibility).'),
    ('* **Definitions.** Where §2.3.2 is not precise we chose (see `reference/sampling_metrics.py`): '
     "occluded is computed under both readings (the issue's: not captured by any of the n conventional "
     "images, fraction of the image's samples; the thesis's literal item 2: NR I_i against C_0..C_{{i-1}},"
     " fraction of C_i's samples); visibility-definition availability compares with the *layer* of what "
     'each image stores within one texel. Background pixels are not samples. GL samples tested with Embree'
     ' are not exactly consistent at silhouettes: conventional images show ~{conv_occluded} "occluded" '
     'samples and peeling layers ~{peel_redundant} % visibility-redundant ones (float32 positions on thin '
     "twigs and leaves, whose occlusion ray grazes the occluder's edge)."),
    ('* **Timing.** Table 7 in the thesis is a GTX 570; ours is Mesa llvmpipe on a shared 2-core CPU, so '
     'absolute times are ~{times_larger}× larger and only the ratios are comparable. On llvmpipe the NR '
     "pass's extra cost (one reprojection and texture fetch per previous image per fragment) is small "
     'against rasterising and shading {triangles}k triangles on the CPU, so NR/conventional is lower than '
     "the thesis's {thesis_nr_conv}; NR/peeling is close to the thesis's (≈1). The thesis blames its "
     "geometry shader for the tree's cost; the geometry-shader variant rows measure that set-up here. The "
     'machine is shared: with {spread_rounds} rounds single ratios moved by ±{spread_pct} % between runs, '
     'hence the interleaved rounds stated under "What was run" (compare the two variants of a scene).'),
)


# --- formatting -----------------------------------------------------------------------

def num(x: float, fmt: str) -> str:
    """x formatted, with a true minus sign."""
    return format(x, fmt).replace("-", "−")


def signed(x: float, fmt: str) -> str:
    """x with its sign always shown, e.g. "+1.50", "−0.25"."""
    return ("+" if x >= 0 else "") + num(x, fmt)


def ceil_to(x: float, digits: int) -> str:
    """x rounded up at `digits` decimals (an upper bound that stays one)."""
    return f"{math.ceil(x * 10 ** digits - 1e-9) / 10 ** digits:.{digits}f}"


def sci(x: float) -> str:
    """123456 → '1e5'."""
    mantissa, exp = f"{x:.0e}".split("e")
    return f"{mantissa}e{int(exp)}"


def and_list(items: Sequence[str]) -> str:
    """'a', 'a and b', 'a, b and c'."""
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]


def count(rows: list[dict], key: str) -> str:
    """'k / n': rows where `key` holds."""
    return f"{sum(bool(r[key]) for r in rows)} / {len(rows)}"


def holding(rows: list[dict], key: str) -> list[str]:
    return [r["scene"] for r in rows if r[key]]


def runs_of(keys: Sequence[float], value: Callable[[float], object]) -> list[tuple[list[float], object]]:
    """Consecutive keys with equal value(key), in order: [(keys, value)]."""
    out: list[tuple[list[float], object]] = []
    for k in keys:
        v = value(k)
        if out and out[-1][1] == v:
            out[-1][0].append(k)
        else:
            out.append(([k], v))
    return out


def degrees(ks: Sequence[float]) -> str:
    """'5°' or '10-15°'."""
    return f"{ks[0]:g}°" if len(ks) == 1 else f"{ks[0]:g}-{ks[-1]:g}°"


def lead(rows: list[dict], what: str, other: int) -> dict[str, float]:
    """Scene → NR's lead over method `other` (1 conventional, 2 peeling) in the
    average or minimum available samples (what: avg | min), in points between the
    report's two-decimal cells."""
    return {r["scene"]: round(100 * r[f"avail_{what}"][0], 2) - round(100 * r[f"avail_{what}"][other], 2)
            for r in rows}


def points_on(values: dict[str, float]) -> str:
    """E.g. 'a / b points on grass / city' for {"grass": a, "city": b} (gaps, printed positive, 2 decimals)."""
    return f"{' / '.join(f'{abs(v):.2f}' for v in values.values())} points on {' / '.join(values)}"


# --- the runs -------------------------------------------------------------------------

class Runs:
    """The canonical results under `root` (bench/results), loaded on first use."""

    def __init__(self, root: Path = RESULTS_DIR) -> None:
        self.root = Path(root)

    def missing(self) -> list[str]:
        return [rel for rel in FILES.values() if not (self.root / rel).exists()]

    @cached_property
    def data(self) -> dict[str, dict]:
        return {k: json.loads((self.root / rel).read_text()) for k, rel in FILES.items()}

    def rows(self, key: str, red: str) -> list[dict]:
        """Issue 3's criteria rows of one run and definition (the four thesis scenes)."""
        return [r for r in criteria_rows(self.data[key]["scenes"], key) if r["definition"] == red]

    @property
    def notes(self) -> dict:
        """bench/results/sampling_notes.json: the one-off measurements."""
        return self.data["notes"]

    def scenes(self, key: str) -> list[dict]:
        return [r for r in self.data[key]["scenes"] if r["scene"] in CRITERIA_SCENES]

    def config(self, key: str, name: str) -> object:
        return self.data[key]["config"][name]

    def target_minutes(self, scenes: Iterable[str] | None = None) -> list[float]:
        """Wall minutes of the target's per-scene runs (all, or those of `scenes`)."""
        folder = self.root / Path(FILES["target"]).parent
        parts = [json.loads((folder / rel).read_text()) for rel in self.data["target"]["merged_from"]]
        return [p["wall_s"] / 60 for p in parts if scenes is None or p["scenes"][0]["scene"] in scenes]


def target_minutes_per_scene(root: Path = RESULTS_DIR) -> str | None:
    """The span of the target run's minutes per scene, e.g. 'lo-hi' (None without that run)."""
    runs = Runs(root)
    if (runs.root / FILES["target"]).exists():
        return span(runs.target_minutes(), ".0f")
    return None


# --- the values of the criteria notes -------------------------------------------------------

def _target(runs: Runs) -> dict[str, str]:
    px, vis = runs.rows("target", "pixel"), runs.rows("target", "visibility")
    same = all(a["scene"] == b["scene"] and all(a[k] == b[k] for k in ("a", "b", "c", "c_earlier"))
               for red in ("pixel", "visibility")
               for a, b in zip(runs.rows("s1024", red), runs.rows("target", red), strict=True))
    avg, low = lead(px, "avg", 1), lead(px, "min", 1)
    moved, fell, fell_peel, grew = [], [], [], []
    for red in ("pixel", "visibility"):
        for a, b in zip(runs.rows("s1024", red), runs.rows("target", red), strict=True):
            moved += [abs(100 * (y - x)) for x, y in zip(a["avail_avg"], b["avail_avg"], strict=True)]
            drop = [100 * (x - y) for x, y in zip(a["avail_min"], b["avail_min"], strict=True)]
            fell += drop[:2]
            fell_peel.append(drop[2])
            grew += [100 * (y / x - 1) for key in ("useful", "useful_earlier")
                     for x, y in zip(a[key], b[key], strict=True)]
    c_px, c_vis = count(px, "c_earlier"), count(vis, "c_earlier")
    issue_scenes = [s for s in CRITERIA_SCENES if s in holding(px, "c") + holding(vis, "c")]
    minutes = runs.target_minutes(CRITERIA_SCENES)
    return {
        "target_total": f"{sum(minutes):.0f}", "target_per_scene": span(minutes, ".0f"),
        "target_same": ("same verdicts as the 1024²/60-view run on every scene and definition:" if same
                        else "verdicts (not all those of the 1024²/60-view run):"),
        "target_a": count(px, "a"), "target_b_vis": count(vis, "b"), "target_b_px": count(px, "b"),
        "target_b_px_scenes": and_list(holding(px, "b")) if holding(px, "b") else "no scene",
        "target_trail_avg": points_on({s: v for s, v in avg.items() if v < 0}),
        "target_trail_min": points_on({s: v for s, v in low.items() if v < 0}),
        "target_c_thesis": f"{c_px} under both definitions" if c_px == c_vis else f"pixel {c_px}, visibility {c_vis}",
        "target_ratio": span((r["useful_earlier"][0] / r["useful_earlier"][1] for r in px + vis), ".2f"),
        "target_c_issue": f"pixel {count(px, 'c')}, visibility {count(vis, 'c')}"
                          + (f" ({and_list(issue_scenes)})" if issue_scenes else ""),
        "moved_avg": f"{max(moved):.1f}", "fell_min": f"{max(fell):.1f}", "fell_peel": span(fell_peel, ".1f"),
        "useful_growth": span(grew, ".0f"),
    }


def _criterion_a(runs: Runs) -> dict[str, str]:
    counts, samples = [], []
    for key in ("main", "s1024", "target"):
        for r in runs.scenes(key):
            nr = r["metrics"]["pixel/non_redundant"]
            counts.append(nr["total"]["redundant"])
            samples.append(sum(nr["samples"][1:]))  # I1, I2: the images that can be redundant
    ties = runs.notes["edge_ties"]
    off = [(r["scene"], r["metrics"]["pixel/non_redundant"]) for r in runs.scenes("s2048")]
    off = [(s, m["total"]["redundant"] - sum(m["redundant_edge_ties"] or [0]), sum(m["samples"][1:]))
           for s, m in off]
    off = [x for x in off if x[1] > 0]
    words = {1: "one", 2: "two", 3: "three"}
    off_text = " and ".join(f"{words.get(k, k)} {s} sample{'s' if k > 1 else ''} in {sci(n)}" for s, k, n in off)
    return {"a_redundant": span(counts, "d"), "a_samples": f"{sci(min(samples))}-{sci(max(samples))}",
            "tie_texels": ties["max_texel_distance"],
            "tie_measured": ties["measured_on"], "views_2048": str(runs.config("s2048", "views")),
            "off_edge": off_text or "no sample", "off_edge_texels": runs.notes["tree_2048_off_edge_texels"]["value"],
            "old_visibility": runs.notes["old_visibility_redundant"]["value"]}


def _criterion_b(runs: Runs) -> dict[str, str]:
    vis = runs.rows("main", "visibility") + runs.rows("s1024", "visibility")
    below = [-v for key in ("main", "s1024") for v in lead(runs.rows(key, "pixel"), "avg", 1).values() if v < 0]
    fail = {key: [r["scene"] for r in runs.rows(key, "pixel") if not r["b"]] for key in ("main", "s1024")}
    extra = [s for s in fail["main"] if s not in fail["s1024"]]
    b_px_fail = and_list(fail["s1024"]) + (f" (and on {and_list(extra)} at 512²; at 1024² {and_list(extra)} holds)"
                                           if extra else "")
    all_vis = all(r["b"] for r in vis)

    def vis_lead(what: str, other: int) -> list[float]:
        return [v for key in ("main", "s1024") for v in lead(runs.rows(key, "visibility"), what, other).values()]

    mech = runs.notes["availability_mechanism"]
    lost, gained = mech["lost_pct"], mech["gained_pct"]
    shrink = []
    a512, a1024 = lead(runs.rows("main", "pixel"), "avg", 1), lead(runs.rows("s1024", "pixel"), "avg", 1)
    for s in CRITERIA_SCENES:  # the gap (conventional − NR) where NR trails at 1024², else NR's signed lead
        if a1024[s] < 0:
            shrink.append(f"{s} {-a512[s]:.2f} → {-a1024[s]:.2f}")
    tail = [f"{s} {signed(a512[s], '.2f')} → {signed(a1024[s], '.2f')}" for s in CRITERIA_SCENES if a1024[s] >= 0]
    px2048 = runs.rows("s2048", "pixel")
    lead2048, low2048 = lead(px2048, "avg", 1), lead(px2048, "min", 1)
    held = [r["scene"] for r in px2048 if r["b"]]
    rest = [r["scene"] for r in px2048 if not r["b"]]
    rest_text = "".join(
        f" and the {s} {'ties' if abs(lead2048[s]) < 0.05 else 'trails'} (average {signed(lead2048[s], '.2f')}"
        f" point, minimum {signed(low2048[s], '.1f')})" for s in rest)
    return {
        "b_vis_scenes": "all four scenes" if all_vis else and_list(sorted({r["scene"] for r in vis if r["b"]})),
        "b_vis_conv_avg": span(vis_lead("avg", 1), ".1f"), "b_vis_peel_avg": span(vis_lead("avg", 2), ".1f"),
        "b_vis_conv_min": span(vis_lead("min", 1), ".1f"), "b_vis_peel_min": span(vis_lead("min", 2), ".1f"),
        "b_px_below": f"{min(below):.2g}-{max(below):.2g}", "b_px_fail": b_px_fail,
        "mech_run": mech["run"],
        "mech_lost": " / ".join(f"{v:g} % ({s})" for s, v in lost.items()),
        "mech_gained": " / ".join(f"{v:g} %" for v in gained.values()),
        "mech_dropped": f"{mech['lost_on_dropped_triangle_pct']:g}",
        "shrink": ", ".join(shrink) + " points" + ("; " + "; ".join(tail) if tail else ""),
        "b_2048_scenes": and_list(held), "b_2048_lead": span([lead2048[s] for s in held], ".1f"),
        "b_2048_rest": rest_text,
    }


def _tessellation(runs: Runs) -> dict[str, str]:
    levels = {int(k): v for k, v in runs.data["tess"]["runs"].items()}
    first, last = min(levels), max(levels)
    b = {lvl: count([r for r in criteria_rows(res, str(lvl)) if r["definition"] == "pixel"], "b")
         for lvl, res in levels.items()}
    leads = lead_ranges(levels)
    tree = [-granularity_loss(next(r for r in levels[lvl] if r["scene"] == "tree")) for lvl in sorted(levels)]
    t4 = THESIS_T4["tree"]
    return {
        "tess_ref_gap": ceil_to(reference_gap(levels), 2), "tess_drift": ceil_to(visibility_drift(levels), 2),
        "tess_b_first": b[first], "tess_b_last": b[last],
        "tess_lead_first": f"{signed(leads[first][0], '.2f')} … {signed(leads[first][1], '.2f')}",
        "tess_lead_last": f"{num(leads[last][0], '.2f')} … {num(leads[last][1], '.2f')}",
        "tess_last_factor": f"{4 ** last}", "tess_factors": f"1× to {4 ** last}×",
        "thesis_tree_loss": f"{-thesis_granularity_loss('tree'):.0f}",
        "thesis_tree_nr_lead": f"{t4[1][0] - t4[0][0]:g}",
        "tess_tree_loss": span(tree, ".0f"),
    }


def _criterion_c(runs: Runs) -> dict[str, str]:
    both = [r for key in ("main", "s1024") for red in ("pixel", "visibility") for r in runs.rows(key, red)]
    c_thesis = {count(runs.rows(k, red), "c_earlier") for k in ("main", "s1024") for red in ("pixel", "visibility")}
    px, vis = runs.rows("s1024", "pixel"), runs.rows("s1024", "visibility")
    issue = [s for s in CRITERIA_SCENES if s in holding(px, "c") + holding(vis, "c")]

    def gap(key: str, red: str) -> str:
        _, d = view_independent_table(runs.scenes(key), red, THESIS_T2 if red == "pixel" else THESIS_T5)
        return f"{np.mean(d['nr_all']):.1f} → {np.mean(d['nr_earlier']):.1f}"

    nest = next(r for r in runs.scenes("s1024") if r["scene"] == "nest")["metrics"]
    nr, cv = nest["pixel/non_redundant"], nest["pixel/conventional"]
    occ = nr["occluded_earlier"][1] / cv["samples"][1]
    use = nr["useful_earlier"][1] / nr["occluded_earlier"][1]
    th = THESIS_T2["nest"]["nr"][1]
    main = {r["scene"]: r["metrics"] for r in runs.scenes("main")}
    l0 = [main[s]["pixel/peeling"]["occluded"][0] / main[s]["visibility/peeling"]["occluded"][0]
          for s in ("nest", "tree", "grass")]
    return {
        "c_thesis": " / ".join(sorted(c_thesis)) if len(c_thesis) > 1 else c_thesis.pop(),
        "c_ratio": span((r["useful_earlier"][0] / r["useful_earlier"][1] for r in both), ".3g"),
        "c_issue": f"pixel {count(px, 'c')}, visibility {count(vis, 'c')}" + (f", {and_list(issue)}" if issue else ""),
        "gap_px_512": gap("main", "pixel"), "gap_px_1024": gap("s1024", "pixel"),
        "gap_vis_512": gap("main", "visibility"), "gap_vis_1024": gap("s1024", "visibility"),
        "nest_i1": f"{100 * occ:.0f} % ({100 * use:.0f} %)", "nest_i1_thesis": f"{th[0]} % ({th[1]} %)",
        "l0_ratio": span(l0, ".1f"),
        "l1_useful": " / ".join(f"{100 * main[s]['pixel/peeling']['useful_frac_of_occluded'][1]:.0f}"
                                for s in CRITERIA_SCENES),
        "l1_useful_thesis": " / ".join(f"{THESIS_T2[s]['peel'][1][1]:g}" for s in CRITERIA_SCENES),
        "no_ground": runs.notes["no_ground_change"]["value"],
    }


def _rig_spread(runs: Runs) -> dict[str, str]:
    spread = runs.data["spread"]
    by = {float(k): v for k, v in spread["runs"].items()}
    keys = sorted(by)
    rows = {s: {red: [r for r in criteria_rows(by[s], f"{s:g}") if r["definition"] == red]
                for red in ("pixel", "visibility")} for s in keys}

    def phrase(red: str, key: str) -> str:
        parts = runs_of(keys, lambda s: count(rows[s][red], key))
        if len(parts) == 1:
            return f"{parts[0][1]} scenes at every spread"
        return and_list([f"{v} at {degrees(ks)}" for ks, v in parts])

    full = [s for s in keys if all(r["c_earlier"] for red in rows[s] for r in rows[s][red])]
    n = len(rows[keys[0]]["pixel"])
    b_px = {count(rows[s]["pixel"], "b") for s in keys}
    a = spread["args"]
    return {
        "spreads": degrees([keys[0], keys[-1]]), "spread_res": str(a["res"]), "spread_views": str(a["views"]),
        "spread_c_px": phrase("pixel", "c"), "spread_c_vis": phrase("visibility", "c"),
        "spread_c_thesis": f"{n} / {n} at {degrees(full)}" if full else "no spread",
        "spread_b_px": "fails at 512² at every spread" if b_px == {f"0 / {n}"} else
                       "holds on " + ", ".join(f"{count(rows[s]['pixel'], 'b')} at {s:g}°" for s in keys),
        "spread_gap_vis": span([conv_gap(by[s], "visibility") for s in keys], ".1f"),
        "spread_gap_px": span([conv_gap(by[s], "pixel") for s in keys], ".1f"),
    }


def _timing(runs: Runs) -> dict[str, str]:
    timed = [r["timing"] for r in runs.scenes("main") if r.get("timing")]
    ratios = [t[v] for t in timed for v in ("prim_id", "geom_shader") if v in t]
    conv = [x["nr_over_conventional"] for x in ratios]
    peel = [x["nr_over_peeling"] for x in ratios]
    holds = max(conv) <= 2.5 and max(peel) <= 1.3
    sp = runs.notes["timing_spread"]
    return {"d_verdict": "holds" if holds else "does not hold", "d_conv": span(conv, ".2f"),
            "d_peel": span(peel, ".2f"), "d_res": str(timed[0]["res"]), "d_rounds": str(timed[0]["repeat"]),
            "spread_rounds": str(sp["rounds"]), "spread_outlier": sp["outlier"],
            "spread_outlier_ratio": f"{sp['outlier_nr_over_peeling']:g}", "spread_pct": f"{sp['spread_pct']:g}"}


def _discussion(runs: Runs) -> dict[str, str]:
    sweep = runs.data["main"]["sweep"]
    over = [res for res, m in zip(sweep["res"], sweep["metrics"], strict=True)
            if m["pixel/non_redundant"]["available_avg"] >= m["pixel/conventional"]["available_avg"]]
    res_list = sweep["res"]
    if not over:
        overtake = (f"it also shows NR staying below the conventional set in pixel-definition availability up "
                    f"to {res_list[-1]}².")
    else:
        overtake = (f"it also shows NR overtaking the conventional set in pixel-definition availability only "
                    f"from {over[0]}² up.")
    main = {r["scene"]: r for r in runs.scenes("main")}
    out = runs.notes["tree_outside_peeling_frustum"]
    peel = runs.data["peel"]["results"]
    two = {r["scene"]: r["metrics"]["pixel/peeling_two_sided"]["useful_frac_of_occluded"][1] for r in peel}
    two_closed = sorted({f"{100 * two[s]:.0f}" for s in ("nest", "city")})
    gaps = layer_table(peel, "visibility")[1]
    wins = {red: useful_table(peel, red)[1]["issue/peeling_two_sided"] for red in ("pixel", "visibility")}
    n = len(peel)
    conv_occ = np.mean([x for r in main.values() for x in r["metrics"]["visibility/conventional"]["occluded_frac"]])
    peel_red = [r["metrics"]["visibility/peeling"]["redundant_frac"][1] * 100 for r in main.values()]
    timing = [(r["timing"]["prim_id"], THESIS_T7[s]) for s, r in main.items() if r.get("timing")]
    ratio = math.exp(np.mean([math.log(t[f"{m}_ms"] / th[k]) for t, th in timing
                              for k, m in enumerate(("conventional", "non_redundant", "peeling"))]))
    tris = [r["triangles"] for r in main.values()]
    t7 = [THESIS_T7[s][1] / THESIS_T7[s][0] for s in CRITERIA_SCENES]
    sp = runs.notes["timing_spread"]
    return {
        "sweep_overtake": overtake,
        "rig_distance": span((r["rig"]["distance_x_content_diagonal"] for r in main.values()), ".2f"),
        "outside_tree": f"{out['tree_pct']:g}", "outside_measured": out["measured_at"],
        "outside_others": out["others"],
        "thesis_l1": ", ".join(f"{THESIS_T2[s]['peel'][1][1]:g}" for s in ("nest", "grass", "city")),
        "ours_l1": ", ".join(f"{100 * main[s]['metrics']['pixel/peeling']['useful_frac_of_occluded'][1]:.0f}"
                             for s in ("nest", "grass", "city")),
        "main_res": str(runs.config("main", "res")), "main_views": str(runs.config("main", "views")),
        "two_sided_l1": " / ".join(two_closed),
        "peel_gap_culled": f"{gaps['peeling']:.0f}", "peel_gap_two": f"{gaps['peeling_two_sided']:.0f}",
        "trail_px": f"{n - wins['pixel']} / {n}", "trail_vis": f"{n - wins['visibility']} / {n}",
        "conv_occluded": f"1e{round(math.log10(conv_occ))}", "peel_redundant": span(peel_red, ".1f"),
        "times_larger": f"{10 ** round(math.log10(ratio)):g}",
        "triangles": f"{min(tris) / 1000:.0f}-{max(tris) / 1000:.0f}", "thesis_nr_conv": span(t7, ".1f"),
        "spread_rounds": str(sp["rounds"]), "spread_pct": f"{sp['spread_pct']:g}",
    }


# --- the sections ---------------------------------------------------------------------------

def _render(header: str, bullets: Sequence[str], values: dict[str, str]) -> str:
    body = [textwrap.fill(b.format(**values), WIDTH, subsequent_indent="  ", break_long_words=False,
                          break_on_hyphens=False) for b in bullets]
    return "\n".join([header, "", *body]) + "\n"


def _unavailable(header: str, runs: Runs) -> str:
    return f"{header}\n\nNot written: the canonical results are missing ({', '.join(runs.missing())}).\n"


def criteria_notes(root: Path = RESULTS_DIR) -> str:
    """The "What the criteria show, and why (measured)" section, from the results in `root`."""
    runs = Runs(root)
    if runs.missing():
        return _unavailable(CRITERIA_HEADER, runs)
    values = {**_target(runs), **_criterion_a(runs), **_criterion_b(runs), **_tessellation(runs),
              **_criterion_c(runs), **_rig_spread(runs), **_timing(runs)}
    return _render(CRITERIA_HEADER, CRITERIA_BULLETS, values)


def discussion(root: Path = RESULTS_DIR) -> str:
    """The "Why our numbers differ from the thesis" section, from the results in `root`."""
    runs = Runs(root)
    if runs.missing():
        return _unavailable(DISCUSSION_HEADER, runs)
    return _render(DISCUSSION_HEADER, DISCUSSION_BULLETS, _discussion(runs))
