"""Cross-check of the reflection clustering on this machine's GL driver (issue 17):
the block union-find's labels against scipy's connected components on the same
raw-bin and mirror-normal images, and every reflective sample's segment against
the per-segment statistics (a lost sample: its segment out of range, or counted in
no segment). Prints one line per check and the passes' milliseconds; for a lent GPU
(bench/gpu/run.sh), where llvmpipe's answers need not hold.

    python -m bench.gpu.clustering_check --scene living_room --res 512 2048
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from bench.common import load_named_scene
from bench.reflections import view_camera
from gl_passes.cluster_units import UNITS
from gl_passes.clustering import STATS_STRIDE, bins_per_reflector
from gl_passes.context import create_gl_context
from gl_passes.readback import read_buffer, read_texture
from gl_passes.reflections import DEFAULT_SETTINGS, ClusterReflections
from gl_passes.upload import SceneGPU


def components(bins: np.ndarray, normals: np.ndarray, cos_break: float) -> np.ndarray:
    """scipy's components (4-neighbours, same raw bin, mirror normals within the break)."""
    h, w = bins.shape
    idx = np.arange(h * w).reshape(h, w)
    edges = []
    for a, b in ((np.s_[:, 1:], np.s_[:, :-1]), (np.s_[1:, :], np.s_[:-1, :])):
        ok = (bins[a] > 0) & (bins[a] == bins[b]) & (np.sum(normals[a] * normals[b], axis=-1) >= cos_break)
        edges.append(np.stack([idx[a][ok], idx[b][ok]]))
    e = np.concatenate(edges, axis=1)
    return connected_components(coo_matrix((np.ones(e.shape[1], np.int8), (e[0], e[1])), shape=(h * w, h * w)),
                                directed=False)[1]


def analyse(refl: ClusterReflections, n_objects: int) -> None:
    """The last clustering's results read back and checked: every reflective sample's
    segment against the per-segment counts, and its label against scipy's components
    (raw bins rebuilt from the segments and the split list)."""
    st = refl.settings
    cp = refl.clustering
    obj = read_buffer(cp.buffer("obj_count"), np.uint32, n_objects + 1)
    n_bins = int(np.prod(bins_per_reflector(obj, st.bin_scale, st.bin_rule), axis=1).sum())
    seg = read_texture(cp.bins_tex, gl_rows=True).ravel().astype(np.int64)  # linear index W·y + x
    n = seg.size
    n_split = int(read_buffer(cp.buffer("split"), np.uint32, 1)[0])
    split = read_buffer(cp.buffer("split"), np.uint32, 3 * n_split, offset=4).reshape(-1, 3)
    n_seg = n_bins + n_split
    raw = read_buffer(cp.buffer("bin_stats"), np.uint32, n_seg * STATS_STRIDE)
    got = raw.reshape(n_seg, STATS_STRIDE)[:, 0]
    refl_mask = seg > 0
    s = seg[refl_mask] - 1
    print(f"  reflective {int(refl_mask.sum())} (objects' count {int(obj[1:].sum())}), n_bins {n_bins}, "
          f"split {n_split}, segments out of range {int((s >= n_seg).sum())}, stats total {int(got.sum())}")
    hist = np.bincount(s[s < n_seg], minlength=n_seg)
    diff = np.nonzero(hist != got)[0]
    print(f"  segments whose count differs from the bin image: {len(diff)} "
          f"{[(int(i), int(hist[i]), int(got[i])) for i in diff[:6]]}", flush=True)
    labels = read_buffer(cp.buffer("labels"), np.uint32, n).astype(np.int64)
    lab = labels[refl_mask]
    ok = lab < n
    print(f"  labels NONE/out of range {int((~ok).sum())}, not a root {int((labels[lab[ok]] != lab[ok]).sum())}")
    rawbin = np.where(s < n_bins, s, split[np.clip(s - n_bins, 0, max(n_split - 1, 0)), 1] if n_split else s)
    bins = np.zeros(n, np.int64)
    bins[refl_mask] = rawbin + 1
    w, h = cp.bins_tex.size
    normals = read_texture(cp.mnormal_tex, gl_rows=True)[..., :3]
    truth = components(bins.reshape(h, w), normals, float(np.cos(np.radians(st.normal_break))))[refl_mask]
    least = np.full(truth.max() + 1, n, np.int64)
    np.minimum.at(least, truth, np.nonzero(refl_mask)[0])
    print(f"  components: gpu {len(np.unique(lab))}, scipy {len(np.unique(truth))}; labels equal to scipy's "
          f"least index: {int((lab == least[truth]).sum())} of {len(lab)}", flush=True)


def check(gl, refl: ClusterReflections, sg: SceneGPU, res: int) -> None:
    """The clustering passes alone, each waited for (their milliseconds), then analyse."""
    st = refl.settings
    scene = sg.scene
    cam = view_camera(scene, res)
    cam = cam.fit_clip(scene.bounds) if cam.near is None else cam
    ss_cam = cam.with_size(cam.width * st.supersample, cam.height * st.supersample)
    tex = refl.gbuffer.draw(sg, ss_cam).textures
    UNITS.bind_storage("MeshVerts", sg.vbo)
    UNITS.bind_storage("MeshFaces", sg.ibo)
    cp = refl.clustering
    min_samples = max(1, round(st.min_component * ss_cam.width * ss_cam.height))
    try:
        stats = cp.run(tex, scene.bounds, len(scene.objects), np.asarray(cam.eye), st.bin_scale, st.bin_rule,
                       st.normal_break, min_samples, st.split_curved, timed=True)
        print(f"res {res}: {stats.n} clusters", flush=True)
    except RuntimeError as exc:
        print(f"res {res}: FAILED {exc}", flush=True)
    print("  passes ms", {k: round(v, 2) for k, v in cp.pass_ms.items()}, flush=True)
    analyse(refl, len(scene.objects))


def check_frames(gl, refl: ClusterReflections, sg: SceneGPU, res: int, frames: int) -> None:
    """Whole frames as the benchmark renders them (no wait between the passes),
    analyse after each."""
    cam = view_camera(sg.scene, res)
    for f in range(frames):
        try:
            refl.render(sg, cam, diagnostics=f == frames - 1)
            print(f"res {res} frame {f}: ok", flush=True)
        except RuntimeError as exc:
            print(f"res {res} frame {f}: FAILED {exc}", flush=True)
        analyse(refl, len(sg.scene.objects))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="living_room")
    ap.add_argument("--res", type=int, nargs="+", default=[512, 2048])
    ap.add_argument("--frames", type=int, default=0, help="whole frames per resolution instead of the passes")
    args = ap.parse_args()
    gl = create_gl_context()
    print("GL", gl.renderer, flush=True)
    scene = load_named_scene(args.scene)
    with ClusterReflections(gl, DEFAULT_SETTINGS) as refl, SceneGPU(gl, scene) as sg:
        for res in args.res:
            if args.frames:
                check_frames(gl, refl, sg, res, args.frames)
            else:
                check(gl, refl, sg, res)


if __name__ == "__main__":
    main()
