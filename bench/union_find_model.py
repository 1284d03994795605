"""Lock-step model of the clustering's union-find on a GPU (issue 17; §4.3 components).

On the lent H200 the clustering with the per-sample union grew faster than linearly
in the samples, where llvmpipe's grew about linearly (timings:
bench/results/reflections_gpu.json and reflections.md). This script counts, on the
real G-buffers of the rooms, the global memory accesses and lock-step rounds of the
two union-finds that gl_passes.clustering has had, under a simple model of a GPU:

- work groups of 16×16 invocations start in launch order (x fastest) and at most
  `resident_groups` of them run at once (an H200: 132 SMs × 8 groups of 256);
- every running invocation makes one access to the labels array per round; loads see
  the array as the round began, stores and atomics apply at its end, atomics in
  launch order (so an atomicMin returns what a sequential order would);
- a group retires when all its invocations are done; rounds are the critical path.

Per-sample union (before e62a543): every reflective sample unites itself with its
left, then its upper neighbour (find without compression, link by atomicMin), then
`compress` walks every sample to its root. Block union-find (e62a543,
cluster_labels.glsl): tiles are labelled in shared memory (one store per sample,
not modelled further), `border` unites the local roots across tile borders (one
invocation per run of equal label pairs along a tile side, finds with path
halving), `roots` points every local root at its root, `compress` walks every
sample (two hops). Both models are checked: their final labels equal scipy's
components (least linear index) on the same edges.

The model ignores memory latency and atomic contention, so it does not predict
milliseconds; it shows how the chained accesses grow. Beside each row: the GPU
clustering time measured with the per-sample union (bench/results/reflections_gpu.json,
kept in this script's json when it is computed).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from bench.common import RESULTS_DIR, git_revision, load_named_scene, md_table, write_json, write_text

TILE = 16
NONE = np.int64(1) << 62  # not reflective: never a label of a union
SHIFT = np.int64(1) << 26  # > any linear index of a 4096² G-buffer: group offsets for a segmented running min


@dataclass(frozen=True)
class GPUModel:
    """resident_groups: work groups of TILE² invocations running at once."""

    resident_groups: int = 132 * 8


@dataclass
class PassCost:
    """accesses: loads, stores and atomics on the labels array; rounds: lock-step rounds."""

    accesses: int = 0
    rounds: int = 0


def run_groups(model: GPUModel, group: np.ndarray, step: Callable[[np.ndarray], tuple[np.ndarray, int]]) -> PassCost:
    """Run invocations 0..n−1 (launch order; group (n,) non-decreasing work group of
    each) under `model`: step(active indices) makes one round and returns (done mask
    over them, accesses made)."""
    cost = PassCost()
    n = len(group)
    if n == 0:
        return cost
    starts = np.r_[0, np.nonzero(np.diff(group))[0] + 1]
    ends = np.r_[starts[1:], n]
    done = np.zeros(n, bool)
    resident: list[int] = []
    launched = 0
    while launched < len(starts) or resident:
        while len(resident) < model.resident_groups and launched < len(starts):
            resident.append(launched)
            launched += 1
        act = np.concatenate([np.arange(starts[g], ends[g]) for g in resident])
        act = act[~done[act]]
        if len(act):
            fin, accesses = step(act)
            done[act[fin]] = True
            cost.accesses += accesses
            cost.rounds += 1
        resident = [g for g in resident if not done[starts[g]:ends[g]].all()]
    return cost


def atomic_min(labels: np.ndarray, hi: np.ndarray, lo: np.ndarray) -> np.ndarray:
    """atomicMin(labels[hi[i]], lo[i]) for i in order: each one's returned old value;
    all applied."""
    order = np.argsort(hi, kind="stable")
    h, v = hi[order], lo[order]
    first = np.r_[True, h[1:] != h[:-1]]
    gid = np.cumsum(first) - 1
    running = np.minimum.accumulate(v - gid * SHIFT) + gid * SHIFT  # min of the group's lo up to each
    earlier = np.r_[NONE, running[:-1]]
    earlier[first] = NONE
    old = np.empty_like(lo)
    old[order] = np.minimum(labels[h], earlier)
    np.minimum.at(labels, hi, lo)
    return old


def find_step(labels: np.ndarray, x: np.ndarray, halving: bool) -> tuple[np.ndarray, np.ndarray, int]:
    """One find step from nodes x: (parent, at-root mask, accesses); with halving
    x is pointed at its grandparent (atomicMin, applied now)."""
    y = labels[x]
    root = y == x
    accesses = len(x)
    if halving:
        z = labels[y]
        skip = ~root & (z != y)
        np.minimum.at(labels, x[skip], z[skip])
        accesses += int(skip.sum())
    return y, root, accesses


def unite_pass(labels: np.ndarray, edges: np.ndarray, valid: np.ndarray, group: np.ndarray, halving: bool,
               model: GPUModel) -> PassCost:
    """Every invocation i unites edges[i, k] (a pair of nodes) for k = 0.. where
    valid[i, k], in turn (cluster_labels.glsl unite: find both roots, link the larger
    below the smaller by atomicMin, retry from the old value when it was linked)."""
    n, n_edges = valid.shape
    a = np.zeros(n, np.int64)
    b = np.zeros(n, np.int64)
    k = np.zeros(n, np.int64)
    state = np.zeros(n, np.int8)  # 0 next edge, 1 find a, 2 find b, 3 link

    def step(act: np.ndarray) -> tuple[np.ndarray, int]:
        for _ in range(n_edges + 1):  # take the next valid edge (no access)
            t = act[state[act] == 0]
            has = (k[t] < n_edges) & valid[t, np.minimum(k[t], n_edges - 1)]
            a[t[has]], b[t[has]] = edges[t[has], k[t[has]], 0], edges[t[has], k[t[has]], 1]
            state[t[has]] = 1
            k[t[~has & (k[t] < n_edges)]] += 1
        begin = state[act].copy()
        accesses = 0
        for s, node in ((1, a), (2, b)):
            t = act[begin == s]
            parent, root, made = find_step(labels, node[t], halving)
            accesses += made
            node[t[~root]] = parent[~root]
            state[t[root]] = s + 1
        linked = act[begin == 3]
        if len(linked):
            hi, lo = np.maximum(a[linked], b[linked]), np.minimum(a[linked], b[linked])
            old = atomic_min(labels, hi, lo)
            accesses += len(linked)
            ok = old == hi
            state[linked[ok]] = 0
            k[linked[ok]] += 1
            retry = linked[~ok]
            a[retry], b[retry], state[retry] = old[~ok], lo[~ok], 1
        same = act[(state[act] == 3) & (a[act] == b[act])]  # both roots found: one set already
        state[same] = 0
        k[same] += 1
        left_edges = (valid[act] & (np.arange(n_edges)[None, :] >= k[act][:, None])).any(1)
        return (state[act] == 0) & ~left_edges, accesses  # done once no valid edge is left

    return run_groups(model, group, step)


def find_pass(labels: np.ndarray, start: np.ndarray, group: np.ndarray, halving: bool, model: GPUModel) -> PassCost:
    """Every invocation walks from start[i] to its root and points start[i] at it
    (cluster_compress.comp; cluster_roots.comp with halving)."""
    x = start.copy()

    def step(act: np.ndarray) -> tuple[np.ndarray, int]:
        parent, root, accesses = find_step(labels, x[act], halving)
        x[act[~root]] = parent[~root]
        np.minimum.at(labels, start[act[root]], x[act[root]])
        return root, accesses + int(root.sum())

    return run_groups(model, group, step)


def launch(h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """(sample linear indices in launch order, their work group), GL rows."""
    gy, gx, ly, lx = np.meshgrid(*(np.arange(m) for m in (h // TILE, w // TILE, TILE, TILE)), indexing="ij")
    return ((gy * TILE + ly) * w + gx * TILE + lx).reshape(-1), (gy * (w // TILE) + gx).reshape(-1)


def in_group_order(p: np.ndarray, w: int) -> tuple[np.ndarray, np.ndarray]:
    """Samples p (linear indices, GL rows of width w) sorted by work group (stable),
    and their groups."""
    g = (p // w // TILE) * (w // TILE) + (p % w) // TILE
    o = np.argsort(g, kind="stable")
    return o, g[o]


def components(n: int, pairs: np.ndarray) -> np.ndarray:
    """(n,) each node's least node index in its component of the (2, m) edge list."""
    _, lab = connected_components(coo_matrix((np.ones(pairs.shape[1]), (pairs[0], pairs[1])), shape=(n, n)),
                                  directed=False)
    least = np.full(lab.max() + 1, n)
    np.minimum.at(least, lab, np.arange(n))
    return least[lab]


def edge_pairs(left: np.ndarray, up: np.ndarray, w: int, keep: np.ndarray | None = None) -> np.ndarray:
    ids = np.arange(left.size).reshape(left.shape)
    lm, um = (left, up) if keep is None else (left & keep[0], up & keep[1])
    return np.concatenate([np.stack([ids[lm], ids[lm] - 1]), np.stack([ids[um], ids[um] - w])], axis=1)


def per_sample_union(refl: np.ndarray, left: np.ndarray, up: np.ndarray, model: GPUModel
                     ) -> tuple[dict[str, PassCost], np.ndarray]:
    h, w = refl.shape
    order, group = launch(h, w)
    flat = refl.reshape(-1)
    labels = np.where(flat, np.arange(h * w), NONE).astype(np.int64)
    edges = np.stack([np.stack([order, order - 1], -1), np.stack([order, order - w], -1)], 1)
    valid = np.stack([left.reshape(-1)[order], up.reshape(-1)[order]], 1)
    use = valid.any(1)
    cost = {"merge": unite_pass(labels, edges[use], valid[use], group[use], False, model)}
    r = flat[order]
    cost["compress"] = find_pass(labels, order[r], group[r], False, model)
    return cost, labels


def block_union(refl: np.ndarray, left: np.ndarray, up: np.ndarray, model: GPUModel
                ) -> tuple[dict[str, PassCost], np.ndarray]:
    h, w = refl.shape
    order, group = launch(h, w)
    flat = refl.reshape(-1)
    inner = (np.broadcast_to((np.arange(w) % TILE != 0)[None, :], (h, w)),
             np.broadcast_to((np.arange(h) % TILE != 0)[:, None], (h, w)))
    local = components(h * w, edge_pairs(left, up, w, inner))  # cluster_merge.comp, in shared memory
    labels = np.where(flat, local, NONE).astype(np.int64)
    cost = {"merge": PassCost(accesses=int(flat.sum()), rounds=1)}  # the local labels' stores
    pairs, where = [], []
    for mask, off, prev in ((left & ~inner[0], 1, w), (up & ~inner[1], w, 1)):  # left columns, top rows
        p = np.nonzero(mask.reshape(-1))[0]
        pair = np.stack([labels[p], labels[p - off]], 1)
        # an invocation whose predecessor along the tile side unites the same pair leaves it to it
        side_pos = (p // w) % TILE if prev == w else (p % w) % TILE
        q = p - prev
        at = np.searchsorted(p, q)
        found = (at < len(p)) & (p[np.minimum(at, len(p) - 1)] == q)
        same = found & (pair[np.minimum(at, len(p) - 1)] == pair).all(1) & (side_pos > 0)
        pairs.append(pair[~same])
        where.append(p[~same])
    pair, p = np.concatenate(pairs), np.concatenate(where)
    o, g = in_group_order(p, w)
    cost["border"] = unite_pass(labels, pair[o][:, None, :], np.ones((len(p), 1), bool), g, True, model)
    roots = np.nonzero(flat & (local == np.arange(h * w)))[0]
    o, g = in_group_order(roots, w)
    cost["roots"] = find_pass(labels, roots[o], g, True, model)
    r = flat[order]
    cost["compress"] = find_pass(labels, order[r], group[r], False, model)
    return cost, labels


def scene_edges(gl, name: str, res: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(reflective, left-connected, up-connected) (H, W) bool masks of the Table 12 view's
    supersampled G-buffer, GL rows (row 0 = bottom): two 4-neighbours are connected
    when they lie in one cluster and their mirror normals differ by at most
    normal_break (the same edges as one raw bin: a cluster joins segments of one bin
    only, and neighbouring connected samples share a segment)."""
    from bench.reflections import view_camera
    from gl_passes.readback import read_texture
    from gl_passes.reflections import DEFAULT_SETTINGS, ClusterReflections
    from gl_passes.upload import SceneGPU

    scene = load_named_scene(name)
    with ClusterReflections(gl, DEFAULT_SETTINGS) as refl, SceneGPU(gl, scene) as sg:
        res_ = refl.render(sg, view_camera(scene, res), diagnostics=True)
        cluster = res_.diagnostics.cluster_of_sample[::-1].astype(np.int64)  # rows as the shaders index them
        normal = read_texture(refl.clustering.mnormal_tex, gl_rows=True)[:, :, :3].astype(np.float64)
        cos_break = np.cos(np.radians(refl.settings.normal_break))
    left = np.zeros(cluster.shape, bool)
    up = np.zeros(cluster.shape, bool)
    left[:, 1:] = (cluster[:, 1:] >= 0) & (cluster[:, 1:] == cluster[:, :-1]) \
        & (np.sum(normal[:, 1:] * normal[:, :-1], -1) >= cos_break)
    up[1:] = (cluster[1:] >= 0) & (cluster[1:] == cluster[:-1]) & (np.sum(normal[1:] * normal[:-1], -1) >= cos_break)
    return cluster >= 0, left, up


def model_row(gl, name: str, res: int, model: GPUModel) -> dict:
    refl, left, up = scene_edges(gl, name, res)
    h, w = refl.shape
    truth = components(h * w, edge_pairs(left, up, w))[refl.reshape(-1)]
    row: dict = {"scene": name, "res": res, "samples": h * w, "reflective": int(refl.sum())}
    for key, algorithm in (("per_sample", per_sample_union), ("block", block_union)):
        cost, labels = algorithm(refl, left, up, model)
        if not np.array_equal(labels[refl.reshape(-1)], truth):
            raise AssertionError(f"{key} union-find model disagrees with scipy's components ({name} {res}²)")
        row[key] = {k: asdict(v) for k, v in cost.items()}
    return row


#: The commit that replaced the per-sample union by the block union-find.
BLOCK_UNION_COMMIT = "e62a543"


def per_sample_gpu_ms() -> dict[tuple[str, int], float]:
    """The clustering step's GPU times (ms) per (scene, res) from
    bench/results/reflections_gpu.json when that run predates the block union-find
    (its stamped commit an ancestor of BLOCK_UNION_COMMIT's parent), else none."""
    path = RESULTS_DIR / "reflections_gpu.json"
    if not path.exists():
        return {}
    data = json.loads(path.read_text())
    commit = data.get("measured", {}).get("commit", "").rstrip("+")
    older = subprocess.run(["git", "merge-base", "--is-ancestor", commit, BLOCK_UNION_COMMIT + "^"],
                           cwd=RESULTS_DIR, capture_output=True).returncode == 0 if commit else False
    return {(t["scene"], t["res"]): t["ours_ms"]["clustering"] for t in data["timings"]} if older else {}


def report(rows: list[dict], model: GPUModel, measured: dict) -> str:
    gpu = {(r["scene"], r["res"]): r["gpu_per_sample_ms"] for r in rows if r.get("gpu_per_sample_ms") is not None}

    def cell(c: dict) -> str:
        return f"{c['accesses'] / 1e6:.2f} M ({c['rounds']})"

    def total(costs: dict) -> int:
        return sum(c["accesses"] for c in costs.values())

    def measured_cells(r: dict) -> list[str]:
        ms = gpu.get((r["scene"], r["res"]))
        if ms is None:
            return ["—", "—", "—"]
        ns = ms * 1e6 / total(r["per_sample"])
        return [f"{ms:.0f}", f"{ns:.1f}", f"{total(r['block']) * ns / 1e6:.0f}"]

    table = md_table(
        ["scene", "res", "reflective samples", "per-sample: merge", "compress", "block: merge", "border", "roots",
         "compress", "accesses per-sample / block", "GPU clustering ms (per-sample union, measured)",
         "ns per per-sample access", "block's accesses at that rate, ms"],
        [[r["scene"], r["res"], f"{r['reflective']:,}", cell(r["per_sample"]["merge"]),
          cell(r["per_sample"]["compress"]), cell(r["block"]["merge"]), cell(r["block"]["border"]),
          cell(r["block"]["roots"]), cell(r["block"]["compress"]),
          f"{total(r['per_sample']) / total(r['block']):.0f}×", *measured_cells(r)] for r in rows])
    doc = (__doc__ or "").split("\n\n")
    return "\n".join([
        "# The clustering's union-find under a lock-step GPU model (issue 17)", "",
        f"Computed {measured['date']} at commit {measured['commit']}: `{measured['command']}` "
        f"({model.resident_groups} resident work groups of {TILE}×{TILE}). A model, not a GPU measurement.", "",
        *doc[1:], "",
        "Cells: accesses to the labels array (millions) and, in brackets, lock-step rounds. The block "
        "union-find's merge pass makes one store per reflective sample in one round (its unions run in "
        "shared memory). The last three columns hold the whole clustering step measured on the GPU with the "
        "per-sample union, that time per modelled access of its union-find, and the block union-find's "
        "modelled accesses at the same rate: a projection, not a measurement (its compress loads are "
        "streaming, the per-sample merge's chained).", "", table, ""])


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=["living_room", "bathroom"])
    ap.add_argument("--res", type=int, nargs="+", default=[256, 512, 1024, 2048])
    ap.add_argument("--resident-groups", type=int, default=GPUModel().resident_groups)
    ap.add_argument("--out", default=str(RESULTS_DIR / "union_find_model"))
    ap.add_argument("--report-only", action="store_true", help="rewrite the .md from the existing .json")
    args = ap.parse_args(argv)
    if args.report_only:
        data = json.loads(Path(args.out + ".json").read_text())
        write_text(args.out + ".md", report(data["rows"], GPUModel(**data["model"]), data["measured"]))
        return
    from gl_passes.context import create_gl_context

    model = GPUModel(args.resident_groups)
    gl = create_gl_context()
    rows = []
    gpu = per_sample_gpu_ms()
    for name in args.scenes:
        for res in args.res:
            t0 = time.perf_counter()
            rows.append({**model_row(gl, name, res, model), "gpu_per_sample_ms": gpu.get((name, res))})
            print(rows[-1], f"{time.perf_counter() - t0:.0f} s", flush=True)
    measured = {"date": time.strftime("%Y-%m-%d", time.gmtime()), "commit": git_revision(),
                "command": "python -m bench.union_find_model " + " ".join(argv if argv is not None else sys.argv[1:])}
    write_json(args.out + ".json", {"model": asdict(model), "measured": measured, "rows": rows})
    text = report(rows, model, measured)
    write_text(args.out + ".md", text)
    print(text)


if __name__ == "__main__":
    main()
