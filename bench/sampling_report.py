"""The Ch. 2 sampling benchmarks' report arithmetic and tables, on their JSON results
only (no rendering): the thesis's numbers (§2.3.3), the Tables 2-7 cells, issue 3's
criteria (a)-(d), and the derived quantities of bench.rig_spread, bench.peeling_sides
and bench.tessellation. The measuring scripts (bench.sampling and those three) and
the report prose (bench.sampling_notes) import it; it imports none of them."""

from __future__ import annotations

import numpy as np

from bench.common import md_table

METHODS = ("conventional", "non_redundant", "peeling")


METHOD_LABEL = {"conventional": "conventional", "non_redundant": "non-redundant", "peeling": "depth peeling"}


# --- the thesis's numbers (§2.3.3), percent ------------------------------------------
# Tables 2 / 5: conventional redundant per image; NR and peeling (occluded, useful).
THESIS_T2 = {
    "nest": {"conv": [0, 70, 80], "nr": [(0, 0), (62, 89), (76, 86)], "peel": [(10, 99), (46, 2), (52, 71)]},
    "grass": {"conv": [0, 54, 69], "nr": [(0, 0), (56, 85), (75, 80)], "peel": [(15, 99), (51, 4), (71, 79)]},
    "city": {"conv": [0, 82, 84], "nr": [(0, 0), (73, 40), (80, 23)], "peel": [(1, 100), (78, 7), (88, 8)]},
    "tree": {"conv": [0, 23, 35], "nr": [(0, 0), (84, 99), (88, 98)], "peel": [(44, 99), (63, 98), (72, 97)]},
}


THESIS_T5 = {
    "nest": {"conv": [0, 80, 87], "nr": [(0, 0), (55, 66), (66, 61)], "peel": [(10, 99), (39, 38), (45, 55)]},
    "grass": {"conv": [0, 58, 74], "nr": [(0, 0), (48, 80), (73, 85)], "peel": [(15, 99), (48, 81), (69, 76)]},
    "city": {"conv": [0, 87, 87], "nr": [(0, 0), (74, 29), (80, 9)], "peel": [(1, 100), (75, 10), (88, 6)]},
    "tree": {"conv": [0, 49, 67], "nr": [(0, 0), (36, 92), (54, 96)], "peel": [(44, 99), (30, 95), (45, 94)]},
}


# Tables 4 / 6: available samples (avg, min) for conventional, NR, peeling.
THESIS_T4 = {
    "nest": [(90, 89), (93, 92), (92, 89)], "grass": [(86, 81), (96, 91), (93, 88)],
    "city": [(97, 96), (98, 97), (96, 91)], "tree": [(55, 53), (59, 57), (55, 48)],
}


THESIS_T6 = {
    "nest": [(95.25, 94.46), (99.84, 99.73), (99.50, 98.82)], "grass": [(86.61, 83.61), (99.72, 99.35), (99.57, 98.15)],
    "city": [(98.91, 97.64), (99.82, 99.32), (99.37, 94.23)], "tree": [(85.36, 83.63), (98.61, 97.78), (97.65, 93.94)],
}


# Table 7: milliseconds for three 1024² images (GTX 570).
THESIS_T7 = {"nest": (1.8, 3.6, 3.3), "grass": (1.7, 3.0, 3.2), "city": (1.6, 3.3, 2.7), "tree": (2.1, 6.4, 6.5)}
#: The view-independent tables per redundancy definition (Table 2: pixel, Table 5: visibility).
THESIS_BY_DEFINITION = {"pixel": THESIS_T2, "visibility": THESIS_T5}


def _cell(ours: float, thesis: float | None, digits: int = 0) -> str:
    s = f"{100 * ours:.{digits}f}"
    return s if thesis is None else f"{s} ({thesis:g})"


def _pair(occ: float, use: float, thesis: tuple | None) -> str:
    s = f"{100 * occ:.0f} ({100 * use:.0f})"
    return s if thesis is None else f"{s} · thesis {thesis[0]:g} ({thesis[1]:g})"


def _earlier_fracs(m: dict, red: str) -> tuple[list[float], list[float]] | None:
    """NR occluded samples under the thesis's literal reading (I_i vs C_0..C_{i-1})
    as fractions of the conventional image C_i's samples (the view's scene
    samples), and their useful share; None for runs without those counts."""
    nr, cv = m[f"{red}/non_redundant"], m[f"{red}/conventional"]
    if nr.get("occluded_earlier") is None:
        return None
    occ = [o / c if c else 0.0 for o, c in zip(nr["occluded_earlier"], cv["samples"], strict=True)]
    use = [u / o if o else 0.0 for u, o in zip(nr["useful_earlier"], nr["occluded_earlier"], strict=True)]
    return occ, use


def view_independent_table(results: list[dict], red: str, thesis: dict) -> tuple[str, dict[str, list[float]]]:
    """Table 2/5 with ours (thesis) cells; also |ours − thesis| in points: "all"
    over every comparable cell (conventional redundancy; occluded and useful of
    NR, issue reading, and peeling), "nr_all" / "nr_earlier" over NR's occluded
    and useful cells of I1, I2 under each reading of "occluded" (issue: fractions
    of the image's samples; thesis, literal item 2: fractions of C_i's samples).
    """
    diffs: dict[str, list[float]] = {"all": [], "nr_all": [], "nr_earlier": []}
    rows = []
    for r in results:
        t = thesis.get(r["scene"])
        m = r["metrics"]
        conv = m[f"{red}/conventional"]["redundant_frac"]
        cells = []
        for i in range(3):
            cells.append(_cell(conv[i], t["conv"][i] if t else None))
            if t:
                diffs["all"].append(abs(100 * conv[i] - t["conv"][i]))
        rows.append([r["scene"], "conventional: redundant", *cells])
        nr, pe = m[f"{red}/non_redundant"], m[f"{red}/peeling"]
        # (row label, thesis key, gap lists: "all" over I0-I2, "nr_*" over I1-I2, occluded, useful)
        variants = [("non-redundant: occluded (useful), issue reading", "nr", ("all", "nr_all"),
                     nr["occluded_frac"], nr["useful_frac_of_occluded"])]
        lit = _earlier_fracs(m, red)
        if lit is not None:
            variants.append(("non-redundant: occluded (useful), thesis reading ¹", "nr", ("nr_earlier",), *lit))
        variants.append(("depth peeling: occluded (useful)", "peel", ("all",), pe["occluded_frac"],
                         pe["useful_frac_of_occluded"]))
        for label, key, gap_keys, occ, use in variants:
            cells = []
            for i in range(3):
                th = t[key][i] if t else None
                cells.append(_pair(occ[i], use[i], th))
                if th:
                    for k in gap_keys:
                        if k == "all" or i > 0:
                            diffs[k] += [abs(100 * occ[i] - th[0]), abs(100 * use[i] - th[1])]
            rows.append([r["scene"], label, *cells])
    return md_table(["scene", "metric [%]", "I0 (V0 / peel layer 0)", "I1", "I2"], rows), diffs


EARLIER_NOTE = ("¹ Thesis reading (§2.3.2 item 2 read literally, `reference/sampling_metrics.py`): NR image I_i's "
                "samples not captured by C_0..C_{i-1}, in percent of the conventional image C_i's samples (the "
                "view's scene samples), useful in percent of those; the issue reading tests every image against "
                "all of C_0..C_2 and divides by the image's own samples. Peeling layers are tested against all "
                "of C_0..C_2 in both readings.")


def view_dependent_table(results: list[dict], red: str, thesis: dict, digits: int) -> tuple[str, list[float]]:
    diffs: list[float] = []
    rows = []
    for r in results:
        t = thesis.get(r["scene"])
        row = [r["scene"]]
        for k, method in enumerate(METHODS):
            mm = r["metrics"][f"{red}/{method}"]
            th = t[k] if t else (None, None)
            row += [_cell(mm["available_avg"], th[0], digits), _cell(mm["available_min"], th[1], digits)]
            if t:
                diffs += [abs(100 * mm["available_avg"] - th[0]), abs(100 * mm["available_min"] - th[1])]
        rows.append(row)
    head = ["scene"] + [f"{METHOD_LABEL[m]} {s}" for m in METHODS for s in ("avg", "min")]
    return md_table(head, rows), diffs


def timing_table(results: list[dict]) -> str:
    rows = []
    for r in results:
        tm = r.get("timing")
        if not tm:
            continue
        th = THESIS_T7.get(r["scene"])
        for label in ("prim_id", "geom_shader"):
            if label not in tm:
                continue
            t = tm[label]
            thr = f"{th[1] / th[0]:.2f} / {th[1] / th[2]:.2f}" if th else "—"
            rows.append([r["scene"], "gl_PrimitiveID" if label == "prim_id" else "geometry shader",
                         f"{t['conventional_ms']:.1f}", f"{t['non_redundant_ms']:.1f}", f"{t['peeling_ms']:.1f}",
                         f"{t['nr_over_conventional']:.2f}", f"{t['nr_over_peeling']:.2f}",
                         f"{th[0]} / {th[1]} / {th[2]}" if th else "—", thr])
    return md_table(["scene", "triangle id from", "conventional [ms]", "NR [ms]", "peeling [ms]", "NR/conv",
                     "NR/peel", "thesis ms (conv / NR / peel)", "thesis NR/conv / NR/peel"], rows)


def ranking_table(results: list[dict]) -> str:
    """The thesis's qualitative claims, checked per scene and definition: NR
    images hold more useful occluded samples than peeling, and more available
    samples per view than conventional images and peeling."""
    rows = []
    for r in results:
        for red in ("pixel", "visibility"):
            m = r["metrics"]
            nr, pe, cv = (m[f"{red}/{k}"] for k in METHODS[1:] + METHODS[:1])
            rows.append([
                r["scene"], red,
                f"{nr['total']['occluded']:,} / {pe['total']['occluded']:,}",
                f"{nr['total']['useful']:,} / {pe['total']['useful']:,}",
                yes_no(nr["total"]["useful"] > pe["total"]["useful"]),
                f"{100 * nr['available_avg']:.1f} / {100 * cv['available_avg']:.1f} / {100 * pe['available_avg']:.1f}",
                yes_no(nr["available_avg"] >= max(cv["available_avg"], pe["available_avg"])),
            ])
    return md_table(["scene", "definition", "occluded samples NR / peel", "useful samples NR / peel",
                     "NR more useful", "available avg NR / conv / peel [%]", "NR most available"], rows)


#: Issue 3, criterion (d): at 1024², NR time ≤ 2.5 × conventional and ≤ 1.3 × peeling.
MAX_NR_OVER_CONV, MAX_NR_OVER_PEEL = 2.5, 1.3


CRITERIA_SCENES = ("nest", "grass", "city", "tree")


def yes_no(ok: bool) -> str:
    """A criterion's verdict cell: "yes", or "**no**" in bold."""
    return "yes" if ok else "**no**"


def criteria_rows(results: list[dict], run: str) -> list[dict]:
    """Criteria (a)-(c) per scene and redundancy definition of one run: (a) the
    NR set has no redundant sample; (b) NR's available samples, average and
    minimum over the intermediate views, ≥ conventional's and ≥ peeling's; (c) NR
    holds at least as many useful occluded samples (totals over the 3 images)
    as peeling."""
    rows = []
    for r in results:
        if r["scene"] not in CRITERIA_SCENES:
            continue
        for red in ("pixel", "visibility"):
            m = r["metrics"]
            cv, nr, pe = (m[f"{red}/{k}"] for k in METHODS)
            rows.append({
                "scene": r["scene"], "run": run, "definition": red,
                "a_nr_redundant": nr["total"]["redundant"],
                "a_edge_ties": sum(nr.get("redundant_edge_ties") or [0]),
                "a": nr["total"]["redundant"] == sum(nr.get("redundant_edge_ties") or [0]),
                "avail_avg": (nr["available_avg"], cv["available_avg"], pe["available_avg"]),
                "avail_min": (nr["available_min"], cv["available_min"], pe["available_min"]),
                "b": (nr["available_avg"] >= max(cv["available_avg"], pe["available_avg"])
                      and nr["available_min"] >= max(cv["available_min"], pe["available_min"])),
                "useful": (nr["total"]["useful"], pe["total"]["useful"]),
                "c": nr["total"]["useful"] >= pe["total"]["useful"],
                # The thesis's literal reading of "occluded" (None for runs made before it was counted).
                "useful_earlier": ((nr["total"]["useful_earlier"], pe["total"]["useful_earlier"])
                                   if nr["total"].get("useful_earlier") is not None else None),
                "c_earlier": (nr["total"]["useful_earlier"] >= pe["total"]["useful_earlier"]
                              if nr["total"].get("useful_earlier") is not None else None),
                "nr_images": {k: nr.get(k) for k in ("samples", "occluded", "useful", "occluded_earlier",
                                                      "useful_earlier")},
                "peel_images": {k: pe[k] for k in ("samples", "occluded", "useful")},
            })
    return rows


def verdict_counts(rows: list[dict]) -> tuple[str, str, str]:
    """'k / n' scenes where (b), (c) with the issue's reading and (c) with the
    thesis's reading hold, over `criteria_rows` of one definition."""
    n = len(rows)
    return (f"{sum(bool(x['b']) for x in rows)} / {n}", f"{sum(bool(x['c']) for x in rows)} / {n}",
            f"{sum(bool(x['c_earlier']) for x in rows)} / {n}")


def criteria_tables(runs: list[tuple[str, list[dict]]], timing_results: list[dict]) -> tuple[str, dict]:
    """Markdown for issue 3's criteria over several runs (label, results) and the
    Table 7 timing, plus a JSON-ready summary."""
    rows = [row for label, res in runs for row in criteria_rows(res, label)]
    def useful_cell(pair: tuple[int, int] | None, ok: bool | None) -> str:
        return "—" if pair is None else f"{pair[0]:,} / {pair[1]:,} · {yes_no(bool(ok))}"

    table = md_table(
        ["scene", "run", "definition", "(a) NR redundant", "available avg NR / conv / peel [%]",
         "available min NR / conv / peel [%]", "(b) holds", "(c) useful occluded NR / peel, thesis reading",
         "(c) useful occluded NR / peel, issue reading"],
        [[r["scene"], r["run"], r["definition"],
          f"{r['a_nr_redundant']:,}" + (f" ({r['a_edge_ties']:,} ties)" if r["a_edge_ties"] else "")
          + f" · {yes_no(r['a'])}",
          " / ".join(f"{100 * x:.2f}" for x in r["avail_avg"]), " / ".join(f"{100 * x:.2f}" for x in r["avail_min"]),
          yes_no(r["b"]), useful_cell(r["useful_earlier"], r["c_earlier"]), useful_cell(r["useful"], r["c"])]
         for r in rows])
    counts = []
    summary: dict = {"rows": [{k: v for k, v in r.items() if not k.endswith("_images")} for r in rows]}

    def verdict(n: int | None, total: int) -> str:
        return "—" if n is None else f"{n} / {total} ({'holds' if n >= 3 else '**fails**'}: needs ≥ 3)"

    for label, _ in runs:
        for red in ("pixel", "visibility"):
            sel = [r for r in rows if r["run"] == label and r["definition"] == red]
            nc, nb = sum(r["c"] for r in sel), sum(r["b"] for r in sel)
            ne = None if any(r["c_earlier"] is None for r in sel) else sum(r["c_earlier"] for r in sel)
            counts.append([label, red, f"{sum(r['a'] for r in sel)} / {len(sel)}", f"{nb} / {len(sel)}",
                           verdict(ne, len(sel)), verdict(nc, len(sel))])
            summary[f"{label}/{red}"] = {"a": sum(r["a"] for r in sel), "b": nb, "c": nc, "c_earlier": ne,
                                         "scenes": len(sel)}
    count_table = md_table(["run", "definition", "(a) scenes", "(b) scenes", "(c) scenes, thesis reading",
                            "(c) scenes, issue reading"], counts)
    trows = []
    for r in timing_results:
        tm = r.get("timing")
        if r["scene"] not in CRITERIA_SCENES or not tm:
            continue
        for label in ("prim_id", "geom_shader"):
            if label in tm:
                t = tm[label]
                ok = t["nr_over_conventional"] <= MAX_NR_OVER_CONV and t["nr_over_peeling"] <= MAX_NR_OVER_PEEL
                trows.append([r["scene"], "gl_PrimitiveID" if label == "prim_id" else "geometry shader",
                              f"{tm['res']}²", f"{t['nr_over_conventional']:.2f}", f"{t['nr_over_peeling']:.2f}",
                              yes_no(ok)])
                summary.setdefault("d", {})[f"{r['scene']}/{label}"] = ok
    ttable = md_table(["scene", "triangle id from", "res", "NR / conv (≤ 2.5)", "NR / peel (≤ 1.3)", "(d) holds"],
                      trows)
    drows = []
    for r in rows:
        n, p = r["nr_images"], r["peel_images"]
        def pair(xs: list[int] | None) -> str:
            return "—" if xs is None else " / ".join(f"{x:,}" for x in xs[1:])

        drows.append([r["scene"], r["run"], r["definition"], pair(n["samples"]), pair(n["occluded_earlier"]),
                      pair(n["useful_earlier"]), pair(n["occluded"]), pair(n["useful"]),
                      " / ".join(f"{x:,}" for x in p["samples"]), " / ".join(f"{x:,}" for x in p["occluded"]),
                      " / ".join(f"{x:,}" for x in p["useful"])])
    dtable = md_table(["scene", "run", "definition", "NR samples I1 / I2", "NR occluded I1 / I2 (thesis r.)",
                       "NR useful I1 / I2 (thesis r.)", "NR occluded I1 / I2 (issue r.)",
                       "NR useful I1 / I2 (issue r.)",
                       "peel samples L0 / L1 / L2", "peel occluded L0 / L1 / L2", "peel useful L0 / L1 / L2"], drows)
    md = ["Criteria (a)-(c) per scene and redundancy definition; (a) counts the NR set's samples redundant "
          "with an earlier image of the set, and in parentheses those of them that are texel-edge float ties "
          "(pixel definition: the projection is within 1e-3 texel of a texel edge, where GL's float32 Alg. 3 "
          "and the reference's float64 test may pick neighbouring texels; `reference.sampling_metrics`); (a) "
          "holds when every redundant sample is such a tie. Available samples in percent of the "
          "intermediate view's samples (average and minimum over the views); useful occluded samples are "
          "totals over the three images.", "", table, "", count_table, "",
          *(["Criterion (d), Table 7 timing (median of interleaved rounds):", "", ttable, ""] if trows else
            ["Criterion (d), Table 7 timing: not timed in this run.", ""]),
          "Where the useful occluded samples come from (per image; NR I0 = C0 has none by construction; "
          "peeling layer L0 is the conventional image of the centroid view):", "", dtable, ""]
    return "\n".join(md), summary


def conv_gap(results: list[dict], red: str) -> float:
    """Mean |ours − thesis| of the conventional images' redundant share of I1, I2 [points]."""
    gaps = [abs(100 * r["metrics"][f"{red}/conventional"]["redundant_frac"][i]
                - THESIS_BY_DEFINITION[red][r["scene"]]["conv"][i])
            for r in results if r["scene"] in THESIS_BY_DEFINITION[red] for i in (1, 2)]
    return float(np.mean(gaps)) if gaps else float("nan")


PEELINGS = ("peeling", "peeling_two_sided")


def _share(m: dict, i: int) -> tuple[float, float]:
    """(occluded % of layer i's samples, useful % of its occluded samples)."""
    return 100 * m["occluded_frac"][i], 100 * m["useful_frac_of_occluded"][i]


def layer_table(results: list[dict], red: str) -> tuple[str, dict[str, float]]:
    """Per scene and layer: occluded (useful) % of both peelings and the thesis's;
    also the mean |ours − thesis| of the useful share over layers 1-2 per peeling."""
    rows, gaps = [], {p: [] for p in PEELINGS}
    for r in results:
        t = THESIS_BY_DEFINITION[red].get(r["scene"], {}).get("peel")
        for i in range(3):
            cells = []
            for p in PEELINGS:
                occ, use = _share(r["metrics"][f"{red}/{p}"], i)
                cells.append(f"{occ:.0f} ({use:.0f})")
                if t and i:
                    gaps[p].append(abs(use - t[i][1]))
            rows.append([r["scene"], f"L{i}", *cells, f"{t[i][0]:g} ({t[i][1]:g})" if t else "—"])
    table = md_table(["scene", "layer", "culled (the issue's)", "two-sided", "thesis"], rows)
    return table, {p: float(np.mean(g)) if g else float("nan") for p, g in gaps.items()}


def useful_table(results: list[dict], red: str) -> tuple[str, dict[str, int]]:
    """Useful occluded samples, totals over the three images: NR (issue reading and
    thesis reading) against both peelings; counts of scenes where NR ≥ peeling."""
    rows, wins = [], {f"{reading}/{p}": 0 for reading in ("issue", "thesis") for p in PEELINGS}
    for r in results:
        m = r["metrics"]
        nr = m[f"{red}/non_redundant"]["total"]
        peel = [m[f"{red}/{p}"]["total"]["useful"] for p in PEELINGS]
        cells = []
        for reading, key in (("issue", "useful"), ("thesis", "useful_earlier")):
            for p, u in zip(PEELINGS, peel, strict=True):
                ok = nr[key] >= u
                wins[f"{reading}/{p}"] += ok
                cells.append(f"{nr[key] / u:.2f}" + ("" if ok else " **<1**") if u else "—")
        avail = [f"{100 * m[f'{red}/{p}']['available_avg']:.2f}" for p in PEELINGS]
        rows.append([r["scene"], f"{nr['useful']:,}", f"{nr['useful_earlier']:,}", *(f"{u:,}" for u in peel),
                     *cells, " / ".join(avail)])
    headers = ["scene", "NR, issue reading", "NR, thesis reading", "peel culled", "peel two-sided",
               "NR/culled (issue r.)", "NR/two-sided (issue r.)", "NR/culled (thesis r.)",
               "NR/two-sided (thesis r.)", "available avg culled / two-sided [%]"]
    return md_table(headers, rows), wins


def granularity_loss(result: dict) -> float:
    """Conventional set's available samples, pixel minus visibility definition,
    average over the views [points]: what triangle ids against texels cost."""
    m = result["metrics"]
    return 100 * (m["pixel/conventional"]["available_avg"] - m["visibility/conventional"]["available_avg"])


def thesis_granularity_loss(scene: str) -> float | None:
    """The same for the thesis's scene: Table 4 − Table 6, conventional average [points]."""
    if scene not in THESIS_T4:
        return None
    return THESIS_T4[scene][0][0] - THESIS_T6[scene][0][0]


def visibility_drift(runs: dict[int, list[dict]]) -> float:
    """Largest change of any visibility-definition available sample (average or
    minimum, any method, any scene) from level 0 [points]: ≈ 0 when the
    subdivision kept the surfaces."""
    base = {r["scene"]: r["metrics"] for r in runs[min(runs)]}
    drift = 0.0
    for results in runs.values():
        for r in results:
            for method in ("conventional", "non_redundant", "peeling"):
                a, b = r["metrics"][f"visibility/{method}"], base[r["scene"]][f"visibility/{method}"]
                for key in ("available_avg", "available_min"):
                    drift = max(drift, 100 * abs(a[key] - b[key]))
    return drift


def redundant_counts(runs: dict[int, list[dict]]) -> tuple[int, int, int]:
    """Criterion (a) over every scene and level, pixel definition: (redundant
    samples of the GL NR sets, of them texel-edge ties, redundant samples of the
    Embree NR sets)."""
    gl = ties = ref = 0
    for results in runs.values():
        for r in results:
            m = r["metrics"]
            gl += m["pixel/non_redundant"]["total"]["redundant"]
            ties += sum(m["pixel/non_redundant"].get("redundant_edge_ties") or [0])
            ref += m.get("pixel/non_redundant_reference", {}).get("total", {}).get("redundant", 0)
    return gl, ties, ref


def lead_ranges(runs: dict[int, list[dict]]) -> dict[int, tuple[float, float]]:
    """Per level: (min, max) over the scenes of NR − conventional available
    samples, pixel definition, average over the views [points]."""
    out = {}
    for k, results in runs.items():
        lead = [100 * (r["metrics"]["pixel/non_redundant"]["available_avg"]
                       - r["metrics"]["pixel/conventional"]["available_avg"]) for r in results]
        out[k] = (min(lead), max(lead))
    return out


def reference_gap(runs: dict[int, list[dict]]) -> float:
    """Largest |GL − Embree| NR availability under the pixel definition (average or
    minimum, any scene and level) [points]; NaN without the reference set."""
    gaps = [100 * abs(r["metrics"]["pixel/non_redundant"][key] - r["metrics"]["pixel/non_redundant_reference"][key])
            for results in runs.values() for r in results if "pixel/non_redundant_reference" in r["metrics"]
            for key in ("available_avg", "available_min")]
    return max(gaps) if gaps else float("nan")
