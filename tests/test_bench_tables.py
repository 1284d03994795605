"""Benchmark report helpers (bench.sampling_report: the tables of bench.peeling_sides,
bench.rig_spread, bench.sampling, bench.tessellation) on hand-made numbers and a small scene."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from bench.sampling_report import layer_table, useful_table
from scenes.camera import Camera
from scenes.depth_image import DepthImage


def _m(useful: int, useful_earlier: int = 0, occ=(0.1, 0.5, 0.6), use=(0.9, 0.02, 0.7), avail: float = 0.9) -> dict:
    return {"total": {"useful": useful, "useful_earlier": useful_earlier}, "occluded_frac": list(occ),
            "useful_frac_of_occluded": list(use), "available_avg": avail}


def _result(scene: str, nr: tuple[int, int], culled: int, two: int, two_use=(0.9, 0.02, 0.7)) -> dict:
    metrics = {}
    for red in ("pixel", "visibility"):
        metrics[f"{red}/non_redundant"] = _m(*nr)
        metrics[f"{red}/peeling"] = _m(culled, use=(0.9, 0.5, 0.5))
        metrics[f"{red}/peeling_two_sided"] = _m(two, use=two_use)
    return {"scene": scene, "triangles": 1, "metrics": metrics}


def test_useful_table_counts_scenes_where_nr_is_ahead():
    results = [_result("nest", (100, 300), culled=200, two=100), _result("city", (50, 60), culled=40, two=70)]
    table, wins = useful_table(results, "pixel")
    # issue reading: nest 100 < 200 culled, = 100 two-sided; city 50 ≥ 40, < 70
    assert wins == {"issue/peeling": 1, "issue/peeling_two_sided": 1,
                    "thesis/peeling": 2, "thesis/peeling_two_sided": 1}
    assert "0.50 **<1**" in table and "| 1.00 |" in table and "| 1.25 |" in table


def test_layer_table_gap_to_the_thesis():
    # thesis nest peel useful L1, L2 (Table 2): 2 %, 71 %
    results = [_result("nest", (1, 1), culled=1, two=1, two_use=(0.9, 0.02, 0.71))]
    table, gaps = layer_table(results, "pixel")
    assert gaps["peeling_two_sided"] == 0.0
    assert abs(gaps["peeling"] - (abs(50 - 2) + abs(50 - 71)) / 2) < 1e-9
    assert "| nest | L1 | 50 (50) | 50 (2) | 46 (2) |" in table


def test_rig_spread_conventional_gap_is_the_mean_over_i1_i2():
    from bench.sampling_report import conv_gap

    # thesis nest, conventional redundant I1, I2: 70, 80 % (Table 2); 80, 87 % (Table 5)
    nest = {"scene": "nest", "metrics": {"pixel/conventional": {"redundant_frac": [0.0, 0.60, 0.90]},
                                         "visibility/conventional": {"redundant_frac": [0.0, 0.80, 0.87]}}}
    assert abs(conv_gap([nest], "pixel") - 10.0) < 1e-9
    assert abs(conv_gap([nest], "visibility")) < 1e-9
    other = {"scene": "diorama", "metrics": {"pixel/conventional": {"redundant_frac": [0.0, 0.0, 0.0]}}}
    assert abs(conv_gap([nest, other], "pixel") - 10.0) < 1e-9  # scenes the thesis has no row for are skipped


def test_verdict_counts_counts_scenes_per_criterion():
    from bench.sampling_report import verdict_counts

    rows = [{"b": True, "c": False, "c_earlier": True}, {"b": False, "c": False, "c_earlier": True},
            {"b": True, "c": True, "c_earlier": None}]
    assert verdict_counts(rows) == ("2 / 3", "1 / 3", "2 / 3")


def test_granularity_loss_is_pixel_minus_visibility_availability():
    from bench.sampling_report import granularity_loss, thesis_granularity_loss

    r = {"metrics": {"pixel/conventional": {"available_avg": 0.785},
                     "visibility/conventional": {"available_avg": 0.925}}}
    assert abs(granularity_loss(r) - (-14.0)) < 1e-9
    assert abs(thesis_granularity_loss("grass") - (86 - 86.61)) < 1e-9  # Tables 4 and 6, conventional average
    assert thesis_granularity_loss("diorama") is None


def test_subdivided_scene_keeps_its_surfaces():
    from bench.tessellation import subdivided
    from reference.raycast import RayCaster
    from scenes.builtin import make_builtin
    from scenes.camera import look_at_scene

    scene = make_builtin("cornell")
    fine = subdivided(scene, 2)
    assert fine.n_triangles == 16 * scene.n_triangles
    for a, b in zip(scene.objects, fine.objects, strict=True):
        assert a.name == b.name and a.material == b.material
        area = [float(np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1).sum())
                for v, f in ((a.vertices, a.faces), (b.vertices, b.faces))]
        assert abs(area[1] - area[0]) <= 1e-6 * area[0]  # float32 vertices
        assert np.allclose(np.linalg.norm(b.normals, axis=1), 1.0)
    cam = look_at_scene(scene.bounds, width=64, height=64)
    coarse_buf, fine_buf = RayCaster(scene).gbuffer(cam), RayCaster(fine).gbuffer(cam)
    hit = np.isfinite(coarse_buf.depth)
    assert hit.mean() > 0.2 and np.array_equal(hit, np.isfinite(fine_buf.depth))
    assert np.allclose(coarse_buf.depth[hit], fine_buf.depth[hit], rtol=1e-5)
    assert not np.array_equal(coarse_buf.tri_id, fine_buf.tri_id)  # same surfaces, other triangle ids


def _tess_run(scene: str, nr: float, conv: float, ref: float, vis: float) -> dict:
    m = {"pixel/non_redundant": {"available_avg": nr, "available_min": nr - 0.01},
         "pixel/conventional": {"available_avg": conv, "available_min": conv - 0.01},
         "pixel/non_redundant_reference": {"available_avg": ref, "available_min": ref - 0.01}}
    for method in ("conventional", "non_redundant", "peeling"):
        m[f"visibility/{method}"] = {"available_avg": vis, "available_min": vis}
    return {"scene": scene, "metrics": m}


def test_tessellation_summaries_on_hand_made_runs():
    from bench.sampling_report import lead_ranges, reference_gap, visibility_drift

    runs = {0: [_tess_run("nest", 0.90, 0.89, 0.9004, 0.95), _tess_run("tree", 0.80, 0.81, 0.80, 0.96)],
            1: [_tess_run("nest", 0.84, 0.85, 0.84, 0.951), _tess_run("tree", 0.70, 0.72, 0.7002, 0.96)]}
    ranges = lead_ranges(runs)
    assert np.allclose(ranges[0], (-1.0, 1.0)) and np.allclose(ranges[1], (-2.0, -1.0))
    assert abs(reference_gap(runs) - 0.04) < 1e-9  # nest L0: 0.9004 vs 0.90
    assert abs(visibility_drift(runs) - 0.1) < 1e-9  # nest L1: 0.951 vs 0.95


def test_tessellation_redundant_counts_add_up_over_levels():
    from bench.sampling_report import redundant_counts

    def run(gl: int, ties: list[int], ref: int) -> dict:
        return {"metrics": {"pixel/non_redundant": {"total": {"redundant": gl}, "redundant_edge_ties": ties},
                            "pixel/non_redundant_reference": {"total": {"redundant": ref}}}}

    assert redundant_counts({0: [run(5, [0, 3, 2], 0), run(2, [0, 1, 0], 1)], 1: [run(4, [0, 4, 0], 0)]}) == (11, 10, 1)


def _copy_results(dst):
    """The canonical results the sampling prose reads (bench.sampling_notes.FILES and
    the target run's parts) copied under dst."""
    import shutil

    from bench.common import RESULTS_DIR
    from bench.sampling_notes import FILES

    for rel in [*FILES.values(), *(f"sampling_1024_1000v/{s}/sampling.json"
                                   for s in ("nest", "grass", "city", "tree", "diorama"))]:
        (dst / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(RESULTS_DIR / rel, dst / rel)


def test_sampling_prose_numbers_follow_the_results(tmp_path):
    """The reports' prose is computed from the JSON results: no placeholder is left,
    a changed result changes the quoted number, and without the results it says so."""
    import json
    import re

    from bench.sampling_notes import criteria_notes, discussion

    _copy_results(tmp_path)
    before = criteria_notes(tmp_path) + discussion(tmp_path)
    assert not re.search(r"\{[a-z_0-9]+\}", before)
    assert "80 / 99 / 46 / 75 %" in before and "(80, 99, 46 % at" in before
    main = json.loads((tmp_path / "sampling.json").read_text())
    nest = next(r for r in main["scenes"] if r["scene"] == "nest")
    nest["metrics"]["pixel/peeling"]["useful_frac_of_occluded"][1] = 0.123
    (tmp_path / "sampling.json").write_text(json.dumps(main))
    after = " ".join((criteria_notes(tmp_path) + discussion(tmp_path)).split())
    assert "12 / 99 / 46 / 75 %" in after and "(12, 99, 46 % at" in after
    (tmp_path / "rig_spread.json").unlink()
    assert "missing (rig_spread.json)" in criteria_notes(tmp_path)


def test_sampling_merge_names_each_scenes_reference_revision(tmp_path):
    """Per-scene parts of the target run measured against different reference
    revisions: the merged report says which scenes measured the older one."""
    import json
    import shutil

    from bench.sampling import main, revision_note
    from reference import REVISION
    from tests.helpers import ROOT

    assert revision_note({"nest": REVISION, "city": REVISION}) == ""
    assert "revision 1," in revision_note({"nest": 1, "city": 1}) and "other scenes" not in revision_note({"nest": 1})
    parts = []
    for scene, rev in (("nest", REVISION - 1), ("city", REVISION)):
        src = ROOT / "bench/results/sampling_1024_1000v" / scene
        shutil.copytree(src, tmp_path / scene)
        data = json.loads((tmp_path / scene / "sampling.json").read_text())
        data["config"]["reference_revision"] = rev
        (tmp_path / scene / "sampling.json").write_text(json.dumps(data))
        parts.append(str(tmp_path / scene / "sampling.json"))
    assert main(["--merge", *parts, "--out", str(tmp_path / "merged")]) == 0
    merged = json.loads((tmp_path / "merged" / "sampling.json").read_text())
    assert [(r["scene"], r["reference_revision"]) for r in merged["scenes"]] == [("nest", REVISION - 1),
                                                                                 ("city", REVISION)]
    assert merged["config"]["reference_revision"] == REVISION - 1
    md = " ".join((tmp_path / "merged" / "sampling.md").read_text().split())
    assert (f"nest measured against reference revision {REVISION - 1}, before revision {REVISION}'s rules "
            f"(`reference.REVISION`); the other scenes against revision {REVISION}") in md


def test_reflection_step_breakdown_from_the_timing_rows():
    from bench.reflections import step_breakdown

    def row(scene, res, clusters, trace, intersection):
        return {"scene": scene, "res": res, "clusters": clusters, "embree_trace_ms": trace,
                "ours_ms": {"intersection": intersection}}

    text = step_breakdown([row("living_room", 512, 60, 100.0, 50.0), row("living_room", 2048, 61, 1500.0, 740.0),
                           row("bathroom", 512, 110, 80.0, 40.0), row("bathroom", 2048, 115, 1440.0, 730.0),
                           row("mirror", 512, 1, 10.0, 1.0)])
    assert "(about 15–18× from 512² to 2048²)" in text and "(60–115 clusters)" in text
    assert "costs about half of Embree's trace" in text


def test_reflection_sweeps_merge_keeps_the_tables_not_measured_again():
    from bench.reflection_sweeps import merge_sweeps
    from bench.reflections import UNSTAMPED_SWEEPS, sweeps_measured

    old = [{"scene": "a", "res": 512, "table15": [1], "tablelayers": [2]}, {"scene": "b", "res": 512, "table15": [3]}]
    new = [{"scene": "a", "res": 512, "tablelayers": [20], "tablelod": [30]},
           {"scene": "c", "res": 512, "table15": [4]}]
    merged = merge_sweeps(old, new, "2026-11-25 abc")
    assert merged == [
        {"scene": "a", "res": 512, "table15": [1], "tablelayers": [20], "tablelod": [30],
         "measured": {"tablelayers": "2026-11-25 abc", "tablelod": "2026-11-25 abc"}},
        {"scene": "b", "res": 512, "table15": [3]},
        {"scene": "c", "res": 512, "table15": [4], "measured": {"table15": "2026-11-25 abc"}}]
    assert old[0]["tablelayers"] == [2]  # the earlier run's records are not modified
    assert sorted(sweeps_measured(merged)) == sorted([
        f"- 15 (a, b): {UNSTAMPED_SWEEPS}", "- 15, layers, lod (a, c): 2026-11-25 abc"])


def test_temporal_keyframe_intervals():
    from bench.temporal import intervals

    assert intervals([True, False, False, True, False]) == [3, 2]
    assert intervals([True]) == [1]


def test_temporal_report_states_why_runs_are_smaller_than_the_thesis():
    from bench.temporal import SMALLER_RUNS, run_groups

    def row(scene, seed, tracer, frames, res):
        return {"scene": scene, "path": f"fly-through {seed}", "tracer": tracer, "frames": frames, "res": res,
                "path_frames": 500}

    lines = run_groups([row("a", 0, "embree", 500, 1024), row("b", 1, "embree", 500, 1024),
                        row("a", 1, "clusters", 100, 512), row("a", 0, "clusters", 100, 512)])
    assert lines == ["embree: 500 · 1024² on a, b, fly-through paths 0, 1.",
                     f"clusters: 100 of 500 · 512² on a, fly-through paths 0, 1: {SMALLER_RUNS['clusters']}."]


def test_temporal_bench_smoke_writes_its_tables():
    """bench.temporal end to end (tables, JSON, pictures)."""
    from tests.helpers import run_isolated, temporal_bench_scenario

    res = run_isolated(temporal_bench_scenario)
    runs = res["json"]["runs"]
    assert [(r["tracer"], r["path"]) for r in runs] == [
        ("embree", "fly-through 0"), ("clusters", "fly-through 0"), ("embree", "fly-through 1"),
        ("clusters", "fly-through 1")]
    for r in runs:
        assert r["per_frame"]["keyframe"][0] and len(r["per_frame"]["mae_ours"]) == 4
        assert r["full_fps"][0] > 0 and r["ours_fps"][0] > 0
    md = res["md"]
    # Table 22 and 23: a row per run; the criteria: one row per scene (both paths, Embree);
    # the breakdown behind the speedup: a row per run
    assert "## Table 22" in md and "## Table 23" in md and md.count("| mirror |") == 4 + 4 + 1 + 4
    assert "| mirror | 2 |" in md.split("## Criteria")[1]
    assert "temporal_mae.png" in res["files"] and "temporal_mirror_path0_embree_triplet.png" in res["files"]


def test_temporal_sweeps_smoke_writes_its_tables():
    """bench.temporal_sweeps end to end: threshold 0 makes every frame after any
    recomputation a keyframe, threshold 1 never a second one; the 8-frame path is
    recorded at both speeds."""
    from tests.helpers import run_isolated, temporal_sweeps_scenario

    res = run_isolated(temporal_sweeps_scenario)
    (run,) = res["json"]["runs"]
    never = next(t for t in run["thresholds"] if t["threshold"] == 1.0)
    always = next(t for t in run["thresholds"] if t["threshold"] == 0.0)
    assert never["keyframe_interval_max"] == 8 and always["keyframe_interval_mean"] < 8
    assert all(t["speedup"] > 0 and t["mae_mean"] >= 0 for t in run["thresholds"])
    assert [s["path_frames"] for s in run["speeds"]] == [4, 8] and [s["frames"] for s in run["speeds"]] == [4, 8]
    assert "## Keyframe threshold" in res["md"] and "## Camera speed" in res["md"]


def _jump(kind, step, tracer, mae, ratio=0.5, recomputed=0.1, scene="a", **kw):
    """A stream_jumps sample: MAE `mae` over the whole frame and (unless `reused_mae`)
    over its 100 reused pixel-channels."""
    reused_n = kw.pop("reused_n", 100)
    return {"scene": scene, "path": 0, "frame": kw.pop("frame", 0), "kind": kind, "step": step, "tracer": tracer,
            "mae": mae, "reused_err_sum": kw.pop("reused_mae", mae) * reused_n, "reused_n": reused_n,
            "recomputed": recomputed, "disoccluded": 0.0, "unreliable": recomputed, "reflective": 0.3,
            "reused_ms": kw.pop("reused_ms", 100.0 * ratio), "keyframe_ms": kw.pop("keyframe_ms", 100.0),
            "turn_deg": 0.0, "move": 0.0, "zoom": 1.0, "roll_deg": 0.0, "start_repeat_mae": 0.0, **kw}


def test_stream_jumps_cells_baselines_and_verdicts_by_hand():
    """bench.stream_jumps: cells average over keyframe cameras (time ratio = mean over
    mean, reused-pixel MAE = mean error sum over mean count), the steady state is the
    mean of the path steps after 0, and each kind fails, for the tracer asked, at its
    first step whose reused-pixel MAE exceeds 2× the steady state or whose reused frame
    takes as long as a keyframe."""
    from bench.stream_jumps import baselines, cells, verdicts

    samples = [_jump("path", 0.0, "embree", 0.0, reused_n=0), _jump("path", 1.0, "embree", 0.1),
               _jump("path", 5.0, "embree", 0.3), _jump("path", 1.0, "clusters", 0.4),
               _jump("turn", 5.0, "embree", 0.2, reused_ms=30.0, keyframe_ms=100.0),
               _jump("turn", 5.0, "embree", 0.4, reused_ms=70.0, keyframe_ms=300.0, frame=1, reused_n=300),
               _jump("turn", 5.0, "clusters", 0.5, ratio=1.2),  # another tracer: not embree's verdict
               _jump("turn", 15.0, "embree", 0.39, recomputed=0.3), _jump("turn", 30.0, "embree", 0.41),
               _jump("zoom_out", 1.05, "embree", 0.1), _jump("zoom_in", 1.05, "embree", 0.1),
               _jump("zoom_out", 1.1, "embree", 0.1), _jump("zoom_in", 1.1, "embree", 0.1, ratio=1.0),
               _jump("roll", 90.0, "embree", 0.2), _jump("roll", 90.0, "clusters", 0.7)]
    cs = cells(samples)
    turn5 = next(c for c in cs if (c["kind"], c["step"], c["tracer"]) == ("turn", 5.0, "embree"))
    assert turn5["n"] == 2 and turn5["mae"] == pytest.approx(0.3) and turn5["time_ratio"] == pytest.approx(0.25)
    assert turn5["mae_reflective"] == pytest.approx(0.3 / 0.3)  # over the 30 % of reflective pixels
    assert turn5["mae_reused"] == pytest.approx((20 + 120) / (100 + 300))  # pooled: weighs by reused pixels
    # over all the cameras' reflective pixels: a view left with a few badly reused ones weighs little
    (few,) = cells([_jump("roll", 10.0, "embree", 0.3), _jump("roll", 10.0, "embree", 0.1, reflective=0.01, frame=1)])
    assert few["mae_reflective"] == pytest.approx(0.2 / 0.155)
    assert baselines(cs, "mae") == {("a", "embree"): pytest.approx(0.2), ("a", "clusters"): pytest.approx(0.4)}
    assert baselines(cs, "mae_reflective") == {("a", "embree"): pytest.approx(0.2 / 0.3),
                                               ("a", "clusters"): pytest.approx(0.4 / 0.3)}
    base = baselines(cs)  # over the reused pixels
    assert base == {("a", "embree"): pytest.approx(0.2), ("a", "clusters"): pytest.approx(0.4)}
    vd = verdicts(cs, base, policy=0.2)
    assert {k: vd["turn"][k] for k in ("error_at", "cost_at", "policy_at", "keep", "policy_keep", "margin",
                                       "tested", "exact")} == {
        "error_at": 30.0, "cost_at": None, "policy_at": 15.0, "keep": 15.0, "policy_keep": 5.0, "margin": 15.0,
        "tested": [5.0, 15.0, 30.0], "exact": {5.0: False, 15.0: False, 30.0: False}}
    assert vd["turn"]["saving_at_keep"] == pytest.approx(0.5) and vd["turn"]["worst_ratio"][5.0] == pytest.approx(0.25)
    assert vd["turn"]["worst_error"][30.0] == pytest.approx(0.41 / 0.2)
    assert vd["zoom"]["cost_at"] == 1.1 and vd["zoom"]["keep"] == 1.05 and vd["zoom"]["error_at"] is None
    # the recommendation keeps a margin: the reused frame at most MARGIN_RATIO of a keyframe
    margin = verdicts(cells([*samples, _jump("roll", 10.0, "embree", 0.2, ratio=0.85)]), base, policy=0.2)["roll"]
    assert margin["keep"] == 90.0 and margin["margin"] is None  # 10° already costs 0.85 of a keyframe
    assert vd["roll"]["keep"] == 90.0 and vd["roll"]["error_at"] is None
    cluster = verdicts(cs, base, policy=0.2, tracer="clusters")
    assert cluster["turn"]["cost_at"] == 5.0 and cluster["turn"]["tested"] == [5.0]  # its own cells only
    assert cluster["roll"]["error_at"] is None  # 0.7 < 2 × 0.4


def test_stream_jumps_leaves_near_empty_views_out_of_the_time_ratio():
    """Views under MIN_REFLECTIVE reflective stay out of the time ratio (counted by
    untimed); a cell with none left has no ratio and fails no cost criterion."""
    from bench.stream_jumps import MIN_REFLECTIVE, baselines, cells, untimed, verdicts

    samples = [_jump("path", 1.0, "embree", 0.2), _jump("turn", 90.0, "embree", 0.0),
               _jump("turn", 90.0, "embree", 0.0, reflective=MIN_REFLECTIVE / 2, ratio=3.0, frame=1),
               _jump("turn", 60.0, "embree", 0.0, reflective=MIN_REFLECTIVE / 2, ratio=3.0)]
    cs = cells(samples)
    by = {c["step"]: c for c in cs if c["kind"] == "turn"}
    assert by[90.0]["n"] == 2 and by[90.0]["n_timed"] == 1 and by[90.0]["time_ratio"] == pytest.approx(0.5)
    assert by[60.0]["n_timed"] == 0 and by[60.0]["time_ratio"] is None
    v = verdicts(cs, baselines(cs), policy=0.2)["turn"]
    assert v["cost_at"] is None and v["worst_ratio"] == {60.0: None, 90.0: pytest.approx(0.5)}
    assert untimed(samples) == {"a turn 90°": 1, "a turn 60°": 1}


def test_stream_jumps_error_on_reused_pixels():
    """A step that recomputes everything it got wrong has a whole-frame MAE near 0 but
    fails (a) on the pixels it did reuse; a cell reusing nothing has no reused-pixel
    MAE and fails nothing."""
    from bench.stream_jumps import baselines, cells, verdicts

    samples = [_jump("path", 1.0, "embree", 0.2), _jump("turn", 45.0, "embree", 0.01, reused_mae=0.5, reused_n=10),
               _jump("turn", 90.0, "embree", 0.0, reused_n=0)]
    cs = cells(samples)
    by = {c["step"]: c for c in cs if c["kind"] == "turn"}
    assert by[45.0]["mae_reused"] == pytest.approx(0.5) and by[90.0]["mae_reused"] is None
    v = verdicts(cs, baselines(cs), policy=0.2)["turn"]
    assert v["error_at"] == 45.0 and v["worst_error"] == {45.0: pytest.approx(2.5), 90.0: None}


def _rec_v(worst, margin=0.1, error_at=None, cost_at=None):
    tested = [0.05, 0.1, 0.125, 0.15, 0.2, 0.25, 0.5]
    return {"margin": margin, "error_at": error_at, "cost_at": cost_at, "tested": tested,
            "worst_ratio": dict(zip(tested, worst, strict=True))}


def test_stream_jumps_recommended_keeps_the_margin_above_the_floor():
    """recommended: the margin step where it lies above the fly-throughs' largest step;
    else the smallest tested step above it that passes (a) and (b) and whose reused
    frame costs at most MARGIN_RATIO of a keyframe — never one costing more (the old
    fallback took move 0.25 at 0.98 of a keyframe); None where no step does."""
    from bench.stream_jumps import recommended

    floor = 0.101
    assert recommended(_rec_v([0.4, 0.5, 0.6, 0.7, 0.75, 0.85, 1.1], margin=0.2, cost_at=0.5), floor) == 0.2
    # the margin step 0.1 fires on the fly-throughs: 0.125 costs 0.85, 0.15 0.78
    assert recommended(_rec_v([0.4, 0.5, 0.85, 0.78, 0.9, 0.98, 1.1], cost_at=0.5), floor) == 0.15
    assert recommended(_rec_v([0.4, 0.5, 0.7, 0.85, 0.9, 0.98, 1.1], cost_at=0.5), floor) == 0.125
    # nothing above the floor keeps the margin: None (not 0.25 at 0.98)
    assert recommended(_rec_v([0.4, 0.5, 0.85, 0.9, 0.95, 0.98, 1.1], cost_at=0.5), floor) is None
    # 0.15 keeps the margin but fails the error, as every larger step then counts as failing
    assert recommended(_rec_v([0.4, 0.5, 0.85, 0.78, 0.7, 0.7, 0.7], error_at=0.15), floor) is None
    assert recommended(_rec_v([0.9] * 7, margin=None), floor) is None


def test_stream_jumps_cluster_thresholds_when_reuse_is_never_cheap():
    """recommended_for: a method whose reused frame costs over MARGIN_RATIO of a
    keyframe at every step above the fly-throughs takes the smallest tested step at
    least FLOOR_MARGIN × their largest (the zoom: on its logarithm) below its error
    failure, no looser than raytrace's; otherwise the raytrace rule."""
    from bench.stream_jumps import recommended_for

    turns = [2.0, 5.0, 10.0, 15.0, 20.0, 30.0, 45.0]
    v = {"margin": None, "error_at": None, "cost_at": 30.0, "tested": turns,
         "worst_ratio": dict.fromkeys(turns, 0.95)}
    assert recommended_for("cluster", v, 7.13, "turn", cap=30.0) == 15.0  # ≥ 1.5 × 7.13
    assert recommended_for("cluster", v, 7.13, "turn", cap=10.0) == 10.0
    assert recommended_for("cluster", {**v, "error_at": 15.0}, 7.13, "turn") is None
    assert recommended_for("raytrace", v, 7.13, "turn") is None
    zooms = [1.05, 1.1, 1.25]
    z = {"margin": None, "error_at": None, "cost_at": None, "tested": zooms, "worst_ratio": dict.fromkeys(zooms, 1.0)}
    assert recommended_for("cluster", z, 1.0, "zoom") == 1.05
    cheap = {**v, "margin": 20.0, "worst_ratio": {**v["worst_ratio"], 10.0: 0.5, 15.0: 0.6, 20.0: 0.7}}
    assert recommended_for("cluster", cheap, 7.13, "turn") == 20.0  # reuse is cheap there: the margin rule


def test_stream_jumps_current_limits_per_method(monkeypatch):
    """The report reads service.stream's thresholds per method (JUMP_LIMITS)."""
    import service.stream as stream
    from bench.stream_jumps import current_limits

    monkeypatch.setattr(stream, "JUMP_LIMITS", {"raytrace": stream.JumpLimits(turn_deg=30.0, move=0.2, zoom=1.5),
                                                "cluster": stream.JumpLimits(turn_deg=15.0, move=0.15, zoom=1.1)})
    assert current_limits() == {"raytrace": {"turn": 30.0, "move": 0.2, "zoom": 1.5},
                                "cluster": {"turn": 15.0, "move": 0.15, "zoom": 1.1}}


def test_stream_jumps_path_floor_once_per_scene_set():
    """path_floor: the largest step between consecutive frames of the fly-throughs (the
    shortest paths are the fastest), no zoom; computed once per set of scenes."""
    import itertools

    from bench.common import load_named_scene
    from bench.stream_jumps import PATH_LENGTHS, _path_floor, path_floor
    from bench.temporal import PATH_SEEDS
    from scenes.camera import camera_step, flythrough_path

    fl = path_floor(["cornell"])
    before = _path_floor.cache_info().hits
    assert path_floor(("cornell",)) == fl and _path_floor.cache_info().hits == before + 1
    bounds = load_named_scene("cornell").bounds
    fastest = [camera_step(a, b) for seed in PATH_SEEDS
               for a, b in itertools.pairwise(flythrough_path(bounds, min(PATH_LENGTHS), seed=seed))]
    assert fl["move"] == pytest.approx(max(st.move for st in fastest))
    assert fl["turn"] == pytest.approx(max(st.turn_deg for st in fastest)) and fl["zoom"] == 1.0


def test_stream_jumps_smoke_writes_its_tables():
    """bench.stream_jumps end to end: a sample per target and tracer, the targets a
    known step from their keyframe camera, the report's tables and plot."""
    from tests.helpers import run_isolated, stream_jumps_scenario

    res = run_isolated(stream_jumps_scenario)
    samples = res["json"]["samples"]
    assert len(samples) == 2 * 8 and {s["tracer"] for s in samples} == {"embree", "clusters"}
    turn = next(s for s in samples if s["kind"] == "turn" and s["step"] == 30.0)
    assert turn["turn_deg"] == pytest.approx(30.0) and turn["move"] == pytest.approx(0.0, abs=1e-9)
    roll = next(s for s in samples if s["kind"] == "roll")
    assert abs(roll["roll_deg"]) == pytest.approx(90.0) and roll["turn_deg"] == pytest.approx(0.0, abs=1e-6)
    still = [s for s in samples if s["kind"] == "path" and s["step"] == 0.0]
    assert all(s["start_repeat_mae"] == 0.0 and s["reused_ms"] > 0 for s in samples)
    assert len(still) == 2 and all(s["mae"] < 1e-3 for s in still)  # at the keyframe's own camera: the keyframe
    # a quarter roll of a square frame maps pixels onto pixels: Embree's reuse is exact
    assert next(s for s in samples if s["kind"] == "roll" and s["tracer"] == "embree")["mae"] < 1e-3
    assert all("keyframe_mae_vs_embree" in s for s in samples if s["tracer"] == "clusters")
    md = res["md"]
    assert "## Steady state" in md and "## Every cell" in md and "## Reading" in md and "JumpLimits.turn_deg" in md
    assert "### raytrace" in md and "### cluster" in md and "MAE reused px" in md
    assert "jumps_mae.png" in res["files"]
    # the reused pixels' error, and the order of the timed frames alternating between targets
    assert all(s["reused_n"] % 3 == 0 and s["reused_err_sum"] >= 0 for s in samples)
    assert {s["key_first"] for s in samples if s["tracer"] == "embree"} == {True, False}


def test_service_load_smoke_writes_its_tables(tmp_path):
    """bench.service_load end to end at tiny sizes: real server processes (one render
    worker), frames under 1 and 2 clients, the stream with reuse, full trace and no
    reflections; the JSON, the report and the plot."""
    import json

    from bench.service_load import main

    out = tmp_path / "service"
    assert main(["--smoke", "--no-progress", "--out", str(out)]) == 0
    data = json.loads(out.with_suffix(".json").read_text())
    assert [(r["workers"], r["clients"]) for r in data["frames"]] == [(1, 1), (1, 2)]
    for r in data["frames"]:
        assert r["ok"] > 0 and r["statuses"] == {"200": r["ok"]} and r["throughput_fps"] > 0
        assert 0 < r["p50_ms"] <= r["p99_ms"]
    stream = {s["label"]: s for s in data["stream"]}
    assert set(stream) == {"no reflections", "cluster, reuse", "cluster, full trace"}
    assert all(s["frames"] > 0 and s["latency"]["p50_ms"] > 0 for s in stream.values())
    assert stream["cluster, full trace"]["keyframes"] == stream["cluster, full trace"]["answered"]
    assert stream["cluster, full trace"]["reused_ratio_mean"] == 0
    assert stream["cluster, reuse"]["reused_ratio_mean"] > 0.3  # a slow orbit: most reflections reused
    md = out.with_suffix(".md").read_text()
    assert "## Frames" in md and "## Stream" in md and md.count("\n| 1 | ") == 2
    assert "| cluster, reuse |" in md and (tmp_path / "service_frames.png").stat().st_size > 0


def _flat_image(tri: np.ndarray, depth: np.ndarray) -> DepthImage:
    """A 1×n depth image of the camera below: sample x on pixel x's centre ray at eye depth
    depth[x], normal facing the camera, triangle tri[x] (0 = no sample)."""
    n = len(tri)
    cam = Camera((0.0, 0.0, 0.0), (0.0, 0.0, -1.0), fov=10.0, width=n, height=1, near=0.1, far=100.0)
    d = cam.pixel_directions()[0]
    z = depth / (d @ np.array([0.0, 0.0, -1.0]))
    pos = (d * z[:, None]).astype(np.float32)[None]
    normal = np.tile(np.array([0, 0, 1], np.float32), (1, n, 1))
    return DepthImage(cam, np.zeros((1, n, 3), np.float32), np.where(tri > 0, depth, np.inf).astype(np.float32)[None],
                      normal, pos, np.asarray(tri, np.uint32)[None])


def test_drop_redundant_by_hand():
    """Two images from one camera, 5 pixels. I_0 holds a wall at depth 5 (triangles
    1, 2) in pixels 0–3 and nothing in pixel 4. I_1 holds: pixel 0 the wall's other
    triangle (same surface), pixel 1 a sample in front of the wall (depth 3: V_0's
    ray would have met it first, yet I_0's texel shows the wall: a gap I_0's ray passed
    by), pixel 2 one behind the wall (depth 8: occluded from V_0), pixel 3 nothing,
    pixel 4 a sample where I_0 saw nothing (V_0 saw past it)."""
    from bench.soft_shadows import drop_redundant

    i0 = _flat_image(np.array([1, 1, 2, 2, 0]), np.array([5.0, 5, 5, 5, 0]))
    i1 = _flat_image(np.array([2, 7, 8, 0, 9]), np.array([5.0, 3, 8, 0, 4]))
    same = drop_redundant([i0, i1], "same_surface")
    visible = drop_redundant([i0, i1], "visible")
    assert same[0] is i0 and visible[0] is i0
    assert same[1].tri_id[0].tolist() == [0, 7, 8, 0, 9]  # only the wall's other triangle goes
    assert visible[1].tri_id[0].tolist() == [0, 0, 8, 0, 0]  # only the occluded sample stays
    assert i1.tri_id[0].tolist() == [2, 7, 8, 0, 9]  # the input is not changed


def test_unpack_visibility_by_hand():
    from bench.shadow_stage import unpack_visibility

    words = np.array([[1 | (1 << 31), 1 << 1], [0, 1 << 3]], np.uint32)  # samples 0, 31, 33 / 35 of 36
    got = unpack_visibility(words, 36)
    assert got.shape == (2, 36) and got.dtype == bool
    assert np.flatnonzero(got[0]).tolist() == [0, 31, 33] and np.flatnonzero(got[1]).tolist() == [35]


def test_per_sample_errors_by_hand():
    from bench.soft_shadows import per_sample_errors

    truth = np.array([[[0b1111]], [[0b1111]]], np.uint32)  # 2 pixels, k = 2: all 4 samples visible
    approx = np.array([[[0b1110]], [[0b0110]]], np.uint32)  # sample 0 wrong twice, sample 3 once
    np.testing.assert_allclose(per_sample_errors(approx, truth, np.ones((2, 1), bool), 2), [1.0, 0, 0, 0.5])


def _errors(geometry: tuple[float, float], exact: tuple[float, float]) -> dict:
    return {"vs_geometry": {"intensity_mean": geometry[0], "visibility_mean": geometry[1]},
            "vs_exact": {"intensity_mean": exact[0], "visibility_mean": exact[1]}}


def test_soft_shadow_criteria_against_both_truths():
    from bench.soft_shadows import criteria

    def scene(nr, conv, peel):  # (geometry, exact) pairs of (intensity, visibility)
        grid = _errors((9, 9), (9, 9))
        return {"methods": {m: {"hybrid": _errors(*e), "grid": grid, "compact": _errors(*e)}
                            for m, e in (("non_redundant", nr), ("conventional", conv), ("peeling", peel))}}

    t8 = {"a": scene(((1, 1), (1, 1)), ((2, 2), (2, 2)), ((1, 1), (1, 1))),
          # b: NR above conventional in visibility against the geometry truth only, above peeling against exact only
          "b": scene(((1, 3), (1, 1)), ((2, 2), (2, 2)), ((2, 3), (0.5, 1)))}
    text = "\n".join(criteria({"table8": t8, "fig20": {}}))
    assert "| NR + hybrid: lower mean intensity and visibility error than conventional | 1/2 | a; not b: " \
           "1.00 vs 2.00 · 3.00 vs 2.00 |" in text
    assert "| NR + hybrid: no higher than peeling (both errors) | 2/2 | a, b |" in text
    assert "| NR + hybrid: lower than conventional (against the exact Embree truth, reported beside) | 2/2 |" in text
    assert "| NR + hybrid: no higher than peeling (against the exact Embree truth, reported beside) | 1/2 | a; " \
           "not b: 1.00 vs 0.50 · 1.00 vs 1.00 |" in text


def test_reflection_report_names_failed_frames():
    from bench.reflections import failed_lines

    assert failed_lines(None) == [] and failed_lines([]) == []
    assert failed_lines([{"scene": "living_room", "res": 2048, "error": "clustering lost reflective samples"}]) == [
        "- living_room 2048²: the frame failed: clustering lost reflective samples", ""]


def test_shadow_holes_occluder_classes_and_ray_hits_by_hand():
    """A wall at eye depth 5 seen by a 1×7 image. I_0 holds it in pixels 0–1, a
    later image in pixel 3. Rays from behind the wall meet it on the centre rays of
    pixels 0 (at I_0's texel), 2 (next to I_0's pixel 1), 4 (next to the later
    image's pixel 3) and 6 (no sample within 1.5 footprints); a fifth ray passes
    beside the wall and is not counted."""
    from bench.shadow_holes import classify_occluders, reconstruction_hits
    from reference.raycast import RayCaster
    from scenes.model import Scene, SceneObject

    i0 = _flat_image(np.array([1, 1, 0, 0, 0, 0, 0]), np.array([5.0, 5, 0, 0, 0, 0, 0]))
    i1 = _flat_image(np.array([0, 0, 0, 9, 0, 0, 0]), np.array([0.0, 0, 0, 5, 0, 0, 0]))
    wall_v = np.array([[-3, -1, -5], [3, -1, -5], [3, 1, -5], [-3, 1, -5]], np.float32)
    wall = SceneObject("wall", wall_v, np.array([[0, 1, 2], [0, 2, 3]], np.uint32))
    caster = RayCaster(Scene([wall], name="wall"))
    x = i0.camera.pixel_directions()[0][[0, 2, 4, 6]]
    targets = np.concatenate([x * (5.0 / -x[:, 2:3]), [[10.0, 0.0, -5.0]]])  # the last: beside the wall
    origins = targets + np.array([0.0, 0.0, -5.0])
    rays = (origins, np.tile([0.0, 0.0, 1.0], (5, 1)), np.full(5, 10.0))
    shares = classify_occluders(caster, rays, [i0, i1])
    assert shares["rays"] == 4
    assert [shares[c] for c in ("at I_0", "next to I_0", "later image", "none")] == [0.25] * 4
    assert reconstruction_hits(rays, [(wall_v, wall.faces)]) == 0.8
    assert reconstruction_hits(rays, [(wall_v, np.zeros((0, 3), np.uint32))]) == 0.0


def test_recapture_gaps_fills_exactly_a_hole_of_the_first_reconstruction(gl):
    """Two images from one camera of a wall filling its view: NR's second image is
    empty (every fragment is pixel-redundant). With a 4×3 block of the first image's
    samples removed, its reconstruction leaves exactly those pixels open (each quad
    covers its own pixel), so the second image gets the conventional image's samples
    there and nowhere else."""
    from bench.shadow_holes import recapture_gaps
    from gl_passes.reconstruction import ReconstructionSettings, Reconstructor, render_set
    from gl_passes.upload import SceneGPU
    from scenes.model import Scene, SceneObject

    cam = Camera((0.0, 0.0, 5.0), (0.0, 0.0, 0.0), fov=40.0, width=24, height=20, near=1.0, far=20.0)
    wall = SceneObject("wall", np.array([[-9, -9, 0], [9, -9, 0], [9, 9, 0], [-9, 9, 0]], np.float32),
                       np.array([[0, 1, 2], [0, 2, 3]], np.uint32))
    with SceneGPU(gl, Scene([wall], name="wall")) as sg:
        nr = render_set(gl, sg, "non_redundant", [cam, cam])
        conv = render_set(gl, sg, "conventional", [cam, cam], offsets=False)
    assert nr.images[0].n_samples == 24 * 20 and nr.images[1].n_samples == 0
    hole = np.zeros((20, 24), bool)
    hole[8:11, 5:9] = True
    first = nr.images[0]
    cut = replace(first, tri_id=np.where(hole, 0, first.tri_id).astype(np.uint32),
                  depth=np.where(hole, np.inf, first.depth).astype(np.float32))
    rec = Reconstructor(gl)
    try:
        out, added = recapture_gaps(gl, replace(nr, images=[cut, nr.images[1]]), conv, ReconstructionSettings(), rec)
        whole, none_added = recapture_gaps(gl, nr, conv, ReconstructionSettings(), rec)
    finally:
        rec.release()
    assert added == hole.sum() and out.images[0] is cut
    np.testing.assert_array_equal(out.images[1].mask, hole)
    np.testing.assert_array_equal(out.images[1].position[hole], conv.images[1].position[hole])
    assert none_added == 0 and whole.images[1].n_samples == 0


def _budget_run(res: int, samples: int, vis: float, inten: float) -> dict:
    e = {"intensity_mean": inten, "visibility_mean": vis, "intensity_max": 1.0, "visibility_max": 1.0}
    return {"vs_geometry": e, "vs_exact": e, "too_dark_mean": 0.1, "too_bright_mean": 0.2, "resolution": res,
            "samples": samples, "triangles": 2 * samples}


def test_equal_sample_resolution_and_budget_tables_by_hand():
    from bench.shadow_budget import budget_criterion_row, budget_report, equal_sample_resolution

    # samples grow with the pixel count: a quarter of the samples at half the side
    assert equal_sample_resolution(1024, 1_000_000, 250_000) == 512
    assert equal_sample_resolution(1024, 1_212_133, 544_664) == 686  # grass's counts: 1024·√0.4493
    args = {"sweep_k": 4, "ref_res": 1024}
    budget = {
        "a": {"args": args, "runs": {"non_redundant": _budget_run(1024, 500, 1.0, 0.5),
                                     "conventional": _budget_run(1024, 1000, 0.9, 0.6),
                                     "conventional_equal_samples": _budget_run(724, 500, 1.2, 0.7)}},
        "b": {"args": args, "runs": {"non_redundant": _budget_run(1024, 500, 1.0, 0.8),
                                     "conventional": _budget_run(1024, 1000, 0.9, 0.6),
                                     "conventional_equal_samples": _budget_run(724, 500, 1.2, 0.7)}},
    }
    row = budget_criterion_row(budget)
    assert row[1] == "1/2"  # b: NR's intensity 0.8 is above 0.7
    assert row[2] == "a 0.500 · 1.000 vs 0.700 · 1.200, b 0.800 · 1.000 vs 0.700 · 1.200"
    assert budget_criterion_row({}) == [] and budget_report({}, {}) == []
    widths = {"grass": {"args": args, "runs": {
        "1": {m: _budget_run(1024, 9, v, 0.5) for m, v in (("non_redundant", 1.1), ("conventional", 1.0),
                                                           ("peeling", 1.3))},
        "subpixel": {"C_0": _budget_run(1024, 9, 1.0, 0.5),
                     "C_0 shifted": {**_budget_run(1024, 9, 1.0, 0.5), "too_bright_mean": 0.05}}}}}
    text = "\n".join(budget_report(budget, widths))
    assert "| a | conventional, NR's samples | 724² | 500 | 0.700 · 1.200 (0.100 / 0.200; 0.00 M) | 0.700 · 1.200 |" \
        in text
    assert "| × 1 | 0.500 · 1.100 (0.100 / 0.200; 0.00 M) |" in text and "| +10.0% |" in text
    assert "× subpixel" not in text and "| C_0 shifted | 0.500 · 1.000 (0.100 / 0.050; 0.00 M) |" in text
    assert "conventional's at × 1: +0.100)" in text and "falls 0.200 → 0.050" in text
    assert "(a 2.0×, b 2.0×)" in text and "exceeds NR's on every scene: a +20%, b +20%." in text
    assert "last row per scene" not in text  # runs from before the break-even search
    budget["a"]["runs"]["conventional_break_even"] = _budget_run(1100, 600, 1.005, 0.6)
    budget["b"]["runs"]["conventional_break_even"] = _budget_run(1536, 1100, 1.1, 0.6)
    text = "\n".join(budget_report(budget, {}))
    assert "| a | conventional, NR's visibility error | 1100² | 600 | 0.600 · 1.005 (0.100 / 0.200; 0.00 M) |" in text
    assert ("(within 1%; searched up to 1.5× the reference resolution, last row per scene): a at 1100² (1.2× NR's "
            "samples), b not by 1536² (2.2× NR's samples, 1.100 against NR's 1.000).") in text


def test_break_even_resolution_by_hand():
    from bench.shadow_budget import break_even_resolution

    calls: list[int] = []

    def inverse(res: int) -> float:  # err = 800 / res: the fit through two points is exact
        calls.append(res)
        return 800.0 / res

    points = {512: 800 / 512, 1024: 800 / 1024}
    assert break_even_resolution(inverse, 1.0, points, max_res=1536) == 800 and calls == [800]
    calls.clear()  # already within 1 % of the target: nothing measured
    assert break_even_resolution(inverse, 0.785, {512: 1.5625, 1024: 0.78125}, max_res=1536) == 1024 and calls == []

    def floor(res: int) -> float:  # never reaches 0.5: one step to max_res, then the fit repeats it
        calls.append(res)
        return 1.0 + 100.0 / res

    points = {512: floor(512), 1024: floor(1024)}
    calls.clear()
    assert break_even_resolution(floor, 0.5, points, max_res=1536) == 1536 and calls == [1536]
    # an error that rises with resolution between the two: the bracket's geometric mean (√(512·2048))
    calls.clear()
    assert break_even_resolution(inverse, 1.0, {512: 1.5, 2048: 1.6}, max_res=4096, steps=1) == 1024
    assert calls == [1024]


def test_subpixel_shifted_moves_the_image_centre_by_the_shift():
    from bench.shadow_budget import subpixel_shifted

    cam = Camera((1.0, 2.0, 5.0), (0.0, 0.5, 0.0), fov=40.0, width=64, height=48)
    target = np.array([cam.target])
    np.testing.assert_allclose(cam.project(target)[0], [[32.0, 24.0]], atol=1e-6)
    for (dx, dy), moved in (((0.5, 0.0), (31.5, 24.0)), ((0.0, 0.5), (32.0, 24.5)), ((0.5, 0.5), (31.5, 24.5))):
        np.testing.assert_allclose(subpixel_shifted(cam, dx, dy).project(target)[0], [moved], atol=0.01)


def test_shadow_bias_choice_by_hand():
    """bench.shadow_bias.choose: the least worst ratio to each scene's lowest
    visibility error over the grid, among settings without acne."""
    from bench.shadow_bias import bias_report, choose, setting_key
    from gl_passes.shadows import ShadowSettings

    def sweep(values: dict[str, float], acne: dict[str, list[int]]) -> dict:
        return {"sweep_k": 4, "k": 16, "final": {},
                "sweep": {k: {"visibility_mean": v, "intensity_mean": v / 2, "acne_degrees": acne.get(k, [])}
                          for k, v in values.items()}}

    x, y, z = "0.5/1/0", "0.25/1/0", "0.25/1/0.5"
    acne = {x: [80, 88]}
    bias = {"a": sweep({x: 1.0, y: 1.2, z: 1.1}, acne), "b": sweep({x: 2.0, y: 2.0, z: 3.0}, acne)}
    # x is best on both scenes but has acne; y: worst 1.2 / 1.0; z: 3.0 / 2.0 = 1.5
    assert choose(bias) == (y, 1.2)
    assert choose({s: sweep({x: 1.0}, acne) for s in "ab"}) is None
    default = setting_key(ShadowSettings())
    assert setting_key(ShadowSettings(normal_offset=0.125, depth_bias=1.0, depth_slope=0.5)) == "0.125/1/0.5"
    part = {s: {"runs": r} for s, r in bias.items()}
    text = "\n".join(bias_report(part))
    assert f"is NOT the choice of this sweep ({y}, worst 1.20)" in text and "80°, 88°" in text
    chosen = {s: {"runs": sweep({default: v, x: v * 0.9}, acne)} for s, v in (("a", 1.0), ("b", 2.0))}
    assert f"bias ({default}) is the choice" in "\n".join(bias_report(chosen))


def test_soft_shadow_parts_name_their_shadow_bias():
    """A saved part names the shadow-map bias it ran with; runs saved before the
    bias was recorded ran with bench.shadow_bias.PREVIOUS."""
    from bench.soft_shadows import _bias_key

    assert _bias_key({"args": {}}) == "0.75/1/0"
    assert _bias_key({"args": {"shadow_bias": {"normal_offset": 0.125, "depth_bias": 1.0,
                                               "depth_slope": 0.5}}}) == "0.125/1/0.5"


def test_shadow_frames_report_by_hand(tmp_path):
    """bench.shadow_frames: later frames are the median of all but the first, the
    ratio is remade over kept."""
    from argparse import Namespace

    from bench.shadow_frames import write_report

    run = {"setting": "thin client", "scene": "city", "k": 6, "res": 256, "sides": "both", "width": 640, "height": 480,
           "seconds": {"kept": [2.0, 1.0, 3.0, 1.0], "remade": [2.5, 2.0, 2.0, 9.0]}}
    write_report(tmp_path, Namespace(frames=4, http_frames=3), {}, [run], 60.0)
    text = (tmp_path / "shadow_frames.md").read_text()
    assert "| thin client | city | 6² · 256² both · 640×480 | 4 | 2.00 / 2.50 | 1.00 | 2.00 | 2.00× |" in text


def test_speedup_ranges_say_faster_or_slower_by_sign():
    """The report words a range of time savings (1 − t_new / t_old) by its signs."""
    from bench.soft_shadows import _speedup_range

    assert _speedup_range([0.03, 0.16]) == "3–16 % faster"
    assert _speedup_range([-0.09, -0.02]) == "2–9 % slower"
    assert _speedup_range([-0.13, 0.02, 0.0]) == "13 % slower to 2 % faster"


def test_crossover_and_compact_bound_table_by_hand():
    """bench.shadow_compact: the crossover interpolates where the original's time
    reaches the reconstruction's; the bound table names the bounds that keep both
    of the issue's limits (+10 % visibility error on every scene, crossover < 1 M)."""
    from bench.shadow_compact import compact_report, crossover_of

    # differences −2 at 0.5 M and +2 at 1.5 M: they meet half way
    assert crossover_of([(0.5e6, 1.0, 3.0), (1.5e6, 4.0, 2.0)]) == 1.0e6
    assert crossover_of([(0.5e6, 3.0, 3.0)]) == 0.5e6  # already there at the first level
    assert crossover_of([(0.5e6, 1.0, 3.0), (1.5e6, 2.0, 3.0)]) is None

    def run(hybrid: float, errs: dict[str, float]) -> dict:
        runs = {n: {"triangles": 100, "vs_geometry": {"visibility_mean": v}} for n, v in errs.items()}
        return {"args": {"ref_res": 1024}, "runs": {"k": 16, "runs": {
            "hybrid": {"triangles": 300, "vs_geometry": {"visibility_mean": hybrid}}, **runs}}}

    def level(tri: int, geometry: float, default: float, other: float) -> dict:
        return {"detail": 20 if tri == 2_000_000 else 1, "triangles": tri, "geometry_seconds_per_map": geometry,
                "compact": {"triangles": 7, "seconds_per_map": default},
                "compact_bounds": {"0.6": {"triangles": 5, "seconds_per_map": other}}}

    compact = {"a": run(1.0, {"0.4": 1.05, "0.6": 1.2}), "b": run(2.0, {"0.4": 2.1, "0.6": 2.1})}
    # default 0.4: differences −2, +2: crosses at 1.25 M (too late); 0.6: −1, +3: at 0.875 M, but +20 % on a
    levels = [level(500_000, 1.0, 3.0, 2.0), level(2_000_000, 4.0, 2.0, 1.0)]
    text = "\n".join(compact_report(compact, levels, 0.4))
    assert "| 0.4 (default) | 100 · +5.0 % | 100 · +5.0 % | +5.0 % | 7 | 1,250,000 |" in text
    assert "| 0.6 | 100 · +20.0 % | 100 · +5.0 % | +20.0 % | 5 | 875,000 |" in text
    assert "on this machine: none." in text
    compact["a"] = run(1.0, {"0.4": 1.05, "0.6": 1.08})
    assert "on this machine: 0.6." in "\n".join(compact_report(compact, levels, 0.4))
    levels[1]["hybrid"] = {"triangles": 40, "pieces": 9, "small_piece_triangles": 30}
    levels[1]["compact"].update(triangles=20, pieces=9, small_piece_triangles=5)
    text = "\n".join(compact_report(compact, levels, 0.4))
    assert "the NR hybrid meshes are 9 separate pieces, 75 % of their triangles" in text
    assert "9 pieces, 25 % of their triangles in small ones" in text


def test_fig20_crossover_against_the_faster_original_by_hand():
    """bench.soft_shadows: Fig. 20's crossover against the original drawn as
    triangles, and against the faster of that and its triangles through the splat
    rasteriser at each level (the stricter one when the latter is faster)."""
    from bench.soft_shadows import crossover, crossover_lines, original_seconds

    def level(tri: float, drawn: float, as_splats: float, rec: float) -> dict:
        kind = {"triangles": 9, "seconds_per_map": rec}
        return {"triangles": tri, "geometry_seconds_per_map": drawn, "geometry_splats_seconds_per_map": as_splats,
                "hybrid": kind, "compact": dict(kind)}

    levels = [level(0.5e6, 1.0, 0.5, 3.0), level(1.5e6, 4.0, 5.0, 2.0)]
    assert [original_seconds(lv, fastest=True) for lv in levels] == [0.5, 4.0]
    assert crossover(levels, "compact") == 1.0e6  # differences −2, +2
    # the faster original: −2.5 at 0.5 M, +2 at 1.5 M
    assert crossover(levels, "compact", fastest=True) == pytest.approx(0.5e6 + 1e6 * 2.5 / 4.5)
    text = "\n".join(crossover_lines(levels))
    assert ("- Crossover, NR compact: 1,000,000 original triangles (against the original drawn the faster of its two "
            "ways at each level: 1,055,556 original triangles).") in text
    del levels[0]["geometry_splats_seconds_per_map"]
    assert crossover(levels, "compact", fastest=True) == 1.0e6 and "faster" not in "\n".join(crossover_lines(levels))


def test_pieces_by_hand(gl):
    """bench.shadow_compact.pieces: pieces joined through shared vertex indices; a
    quad is a small piece, a strip of 5 quads (10 triangles) is not."""
    from bench.shadow_compact import pieces
    from gl_passes.mesh_gpu import MeshGPU

    quad = np.array([[0, 1, 2], [0, 2, 3]])
    xs = np.arange(6, dtype=np.float32)
    strip_pos = np.array([(x, y, 0) for x in xs for y in (0, 1)], np.float32)  # 12 vertices, column pairs
    strip = np.array([t for i in range(5) for t in ([2 * i, 2 * i + 2, 2 * i + 3], [2 * i, 2 * i + 3, 2 * i + 1])])
    pos = np.concatenate([np.array([(0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)], np.float32), strip_pos])
    meshes = [MeshGPU.from_arrays(gl, pos, np.concatenate([quad, strip + 4])),
              MeshGPU.from_arrays(gl, pos[:4], quad)]
    try:
        assert pieces(meshes) == {"pieces": 3, "small_piece_triangles": 4}
    finally:
        for m in meshes:
            m.release()


def test_splat_raster_crossings_and_default_by_hand():
    """bench.splat_raster: a sweep's crossings are linear between neighbours (gains
    −20 ms at 10,000 splats and +30 ms at 20,000 cross at 14,000; back to −10 ms at
    30,000 crosses again at 27,500), none where the gain never changes sign; a set is
    faster one way only below (1 − NOISE) of the other's time; the default is said
    to separate the sets only when it lies above every triangles-faster density and
    at or below every splats-faster one."""
    from bench.splat_raster import NOISE, SPLAT_RASTER_MIN, _choice, crossings, faster_way

    def row(n: int, splats_ms: float, triangles_ms: float) -> dict:
        return {"splats": n, "seconds": {"splats": splats_ms / 1e3, "triangles": triangles_ms / 1e3}}

    rows = [row(5_000, 200, 150), row(10_000, 220, 200), row(20_000, 240, 270), row(30_000, 280, 270)]
    assert crossings(rows) == pytest.approx([14_000, 27_500])
    assert crossings(rows[:2]) == []
    assert faster_way({"splats": 0.94, "triangles": 1.0}) == "splats" and NOISE == 0.05
    assert faster_way({"splats": 0.96, "triangles": 1.0}) == "tie"
    assert faster_way({"splats": 1.0, "triangles": 0.94}) == "triangles"
    below, above = SPLAT_RASTER_MIN / 2, SPLAT_RASTER_MIN * 2
    said = _choice([0.02], {"triangles": [below], "splats": [above], "tie": [below]})
    assert said.endswith("drawn that way.") and f"between {below:.3f} and {above:.3f} (" in said
    assert _choice([0.02], {"triangles": [above], "splats": [above], "tie": []}).endswith("does not separate them.")
    assert _choice([], {"triangles": [], "splats": [below], "tie": []}).endswith("does not separate them.")


def test_soft_shadow_parts_name_how_their_splats_were_drawn():
    """bench.soft_shadows' stale-run check: a part saved before the splat rule
    (no splat_raster_min), with another rule, with the compute rasteriser's
    predecessors or without splats is told apart from one timed as now."""
    from bench.soft_shadows import SPLAT_RASTER, _splat_raster_key
    from gl_passes.shadows import SPLAT_RASTER_MIN

    def key(**args: object) -> str:
        return _splat_raster_key({"args": {"quad_splats": True, **args}})

    assert key(splat_raster="compute", splat_raster_min=SPLAT_RASTER_MIN) == SPLAT_RASTER
    assert key(splat_raster="compute") == "compute in every batch"
    assert key(splat_raster="compute", splat_raster_min=0.5) == "compute from 0.5 splats per texel"
    assert key() == "point sprites"
    assert _splat_raster_key({"args": {"quad_splats": False}}) == "triangles"


def test_time_side_by_side_turns_the_order_each_round():
    """bench.common.time_side_by_side: warm-up rounds in the given order, then with
    rotate=True timed round r starts at function r mod n; without, always the given order."""
    from bench.common import time_side_by_side

    calls: list[str] = []
    fns = {name: (lambda name=name: calls.append(name)) for name in "abc"}
    times = time_side_by_side(fns, repeat=4, warmup=1, rotate=True)
    assert "".join(calls) == "abc" + "abc" + "bca" + "cab" + "abc"
    assert all(len(t.samples_ms) == 4 for t in times.values())
    calls.clear()
    time_side_by_side(fns, repeat=2, warmup=0)
    assert "".join(calls) == "abcabc"
