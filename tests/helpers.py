"""Scene builders and helpers shared by the test modules: tests import this module
(as `tests.helpers`), never each other nor conftest.

* the repository: `ROOT`; real models: `shared_scene` (../shared/scenes, skips when absent);
* checks: `assert_depth_close`, `assert_images_equal`, `MEAN_ONLY`, `face_normals`,
  `unpack_bits` (shadow visibility words), `wait_until` (poll with a hang guard);
* GL core: `sphere_on_slab`, `quad_scene`;
* depth images: `box` (flat-faced), `figure11_scene`;
* reflections: `props`, `planar_mirror_scene`, `mirror_object_scene`, `sphere_mesh`,
  `vase_mesh`, `mirror_camera`;
* service: `obj_text`, `service` (a TestClient of a fresh app), `service_client` (a
  module-scoped `client` fixture of one), `live_server` (uvicorn on a loopback port),
  `frame_camera`;
* the plugin: `write_small_glb`;
* GL scenarios that could take the process down (another context type, a lost
  context) or open their own context (a bench script's main) run in a fresh
  interpreter: `run_isolated(scenario)`.
"""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import trimesh

from scenes import Camera, Material, Scene, SceneObject
from scenes.builtin import make_builtin, mirror
from scenes.camera import look_at_scene
from service.image_check import assert_images_close
from service.testing import wait_ready  # noqa: F401  (tests import it from here)

ROOT = Path(__file__).resolve().parents[1]
SHARED_SCENES = Path(os.environ.get("DEPTHVIEW_SHARED_SCENES", ROOT.parent / "shared" / "scenes"))


def shared_scene(relpath: str) -> Path:
    """Path of a real model in ../shared/scenes; skips the test when absent."""
    p = SHARED_SCENES / relpath
    if not p.exists():
        pytest.skip(f"{p} not present")
    return p


def triangle_rows(pos: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """(M,9) the triangles' vertex positions, rows sorted: a mesh's triangles whatever
    the order of its vertices and triangles (each triangle's own vertex order kept)."""
    t = pos[tri].reshape(len(tri), 9)
    return t[np.lexsort(t.T[::-1])]


def assert_depth_close(actual: np.ndarray, expected: np.ndarray, rtol: float, mask: np.ndarray | None = None,
                       name: str = "log_depth") -> None:
    """Depth maps (H,W) equal within the relative tolerance rtol on every (masked)
    pixel, through assert_images_close on ln(depth) (error images on failure):
    |ln a − ln b| ≤ ln(1 + rtol) admits a/b in [1/(1 + rtol), 1 + rtol], no more
    than |a − b| ≤ rtol·b does; +inf = +inf (background) is no error."""
    __tracebackhide__ = True
    with np.errstate(divide="ignore", invalid="ignore"):
        la, lb = np.log(np.asarray(actual, np.float64)), np.log(np.asarray(expected, np.float64))
    assert_images_close(la, lb, tolerance=float(np.log1p(rtol)), max_bad_fraction=0.0, mask=mask, name=name)


#: assert_images_close keywords for a bound on the mean error only (single pixels may be
#: far off: silhouettes, where two renderers pick different surfaces).
MEAN_ONLY = {"max_bad_fraction": 1.0}

#: The built-in mirror scene seen obliquely (JSON camera), and the same view moved 5 cm.
MIRROR_CAMERA = {"eye": list(mirror.VIEW_EYE), "target": list(mirror.VIEW_TARGET)}
MIRROR_CAMERA_MOVED = {**MIRROR_CAMERA, "eye": [2.45, 1.6, 3.02]}


def face_normals(vertices: np.ndarray, faces: np.ndarray, unit: bool = False) -> np.ndarray:
    """(M,3) float64 geometric normals (p1 − p0) × (p2 − p0) of the triangles (CCW
    front): length twice the triangle's area, or 1 with unit=True."""
    p = np.asarray(vertices, np.float64)[np.asarray(faces, np.int64)]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    return n / np.linalg.norm(n, axis=1, keepdims=True) if unit else n


def unpack_bits(bits: np.ndarray, k: int) -> np.ndarray:
    """(...,k²) bool from (...,n_words) uint32 shadow visibility words by the documented
    layout (sample s = bit s % 32 of word s // 32), written out independently of the
    modules under test."""
    s = np.arange(k * k)
    return ((bits[..., s // 32] >> (s % 32).astype(np.uint32)) & 1).astype(bool)


def wait_until(cond: Callable[[], Any], timeout: float = 30.0, what: str = "condition") -> None:
    """Poll cond() every 10 ms until it is true; fail after `timeout` s. The timeout is
    a hang guard, not a performance bound: keep it far above the expected wait."""
    __tracebackhide__ = True
    deadline = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < deadline, f"{what} not reached within {timeout:g} s"
        time.sleep(0.01)


def assert_images_equal(actual: np.ndarray, expected: np.ndarray, name: str | None = None,
                        mask: np.ndarray | None = None) -> None:
    """Images equal pixel for pixel (+inf = +inf and NaN = NaN count as equal),
    through assert_images_close (error images on failure)."""
    __tracebackhide__ = True
    assert_images_close(actual, expected, tolerance=0.0, max_bad_fraction=0.0, mask=mask, name=name)


# --- GL core ---------------------------------------------------------------------------

def sphere_on_slab() -> Scene:
    s = trimesh.creation.icosphere(4)
    b = trimesh.creation.box((3, 0.2, 3))
    b.apply_translation((0, -1.2, 0))
    return Scene([SceneObject("sphere", s.vertices, s.faces, material=Material((0.8, 0.2, 0.2), 0.5, 0.1)),
                  SceneObject("slab", b.vertices, b.faces, material=Material((0.3, 0.6, 0.3)))], name="t")


def quad_scene(facing_camera: bool) -> Scene:
    """A 2×2 quad in the plane z = 0, front face toward +z when facing_camera."""
    v = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float32)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    if not facing_camera:
        f = f[:, ::-1]
    return Scene([SceneObject("quad", v, f, normals=np.tile([0, 0, 1.0], (4, 1)))])


# --- depth images ------------------------------------------------------------------------

def box(name: str, lo: tuple, hi: tuple, albedo: tuple = (0.7, 0.7, 0.7)) -> SceneObject:
    """Axis-aligned box with flat faces; every face is split along the diagonal
    from its (min, min) to its (max, max) corner (CCW seen from outside)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    verts, faces, normals = [], [], []
    for k in range(3):
        u, v = (k + 1) % 3, (k + 2) % 3
        for sign in (1, -1):
            uv = [(0, 0), (1, 0), (1, 1), (0, 1)] if sign > 0 else [(0, 0), (0, 1), (1, 1), (1, 0)]
            base = len(verts)
            for a, b in uv:
                p = np.where(np.arange(3) == k, hi[k] if sign > 0 else lo[k], 0.0)
                p[u] = hi[u] if a else lo[u]
                p[v] = hi[v] if b else lo[v]
                verts.append(p)
                normals.append(np.eye(3)[k] * sign)
            faces += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
    return SceneObject(name, np.array(verts), np.array(faces), normals=np.array(normals),
                       material=Material(albedo))


def figure11_scene() -> Scene:
    """The thesis's Fig. 11 scene: boxes A (objects id 1), B, C, D (4), seen by
    cameras on the line z = 10 (tests/test_depth_images.py, Figs 11-12)."""
    return Scene([
        box("A", (-0.3, -1.5, 4.9), (0.3, 1.5, 5.1), (0.8, 0.3, 0.3)),
        box("B", (-0.2, -1.5, 1.9), (1.2, 3.5, 2.1), (0.3, 0.8, 0.3)),
        box("C", (-0.2, -0.5, -0.3), (0.2, 0.5, 0.0), (0.3, 0.3, 0.8)),
        box("D", (-2.2, -1.5, 4.9), (-1.2, 1.5, 5.1), (0.8, 0.8, 0.3)),
    ], name="figure11")


# --- reflections -----------------------------------------------------------------------

MIRROR = Material((0.9, 0.9, 0.9), 1.0, 0.0)
FLOOR = Material((0.6, 0.58, 0.55))


def prop_box(name: str, center, size, mat: Material) -> SceneObject:
    """An axis-aligned box of `size` centred at `center` (trimesh's, outward faces)."""
    b = trimesh.creation.box(size)
    b.apply_translation(center)
    return SceneObject(name, b.vertices, b.faces, material=mat)


def props() -> list[SceneObject]:
    """A floor and a few coloured objects around the origin."""
    s = trimesh.creation.icosphere(3, radius=0.3)
    s.apply_translation((-0.9, 0.3, 0.8))
    return [prop_box("floor", (0, -0.05, 0), (6, 0.1, 6), FLOOR),
            prop_box("red", (1.2, 0.4, 0.4), (0.5, 0.8, 0.5), Material((0.7, 0.1, 0.1))),
            prop_box("green", (0.2, 0.5, -1.6), (1.6, 1.0, 0.3), Material((0.1, 0.6, 0.1))),
            SceneObject("ball", s.vertices, s.faces, material=Material((0.15, 0.25, 0.75)))]


def planar_mirror_scene() -> Scene:
    """A 2.4 × 1.6 mirror quad (s = 1, g = 0) in the plane z = −1.2 facing +z."""
    v = np.array([[-1.2, 0.1, -1.2], [1.2, 0.1, -1.2], [1.2, 1.7, -1.2], [-1.2, 1.7, -1.2]], np.float32)
    quad = SceneObject("mirror", v, [[0, 1, 2], [0, 2, 3]], normals=np.tile([0, 0, 1.0], (4, 1)), material=MIRROR)
    others = [o for o in props() if o.name != "green"]
    return Scene([quad, *others], name="planar_mirror")


def bevelled_mirror_scene(bevel_deg: float = 45.0, width: float = 0.25) -> Scene:
    """planar_mirror_scene's 2.4 × 1.6 mirror face (faces 0 and 1, normal +z) with a
    bevelled frame of the same object and material: four flat strips `width` wide
    falling back from the face's edges at `bevel_deg` to it (a normal-field break
    at every edge; no vertex shared between face and bevel, flat normals)."""
    x0, x1, y0, y1, z = -1.2, 1.2, 0.1, 1.7, -1.2
    d, dz = width * np.cos(np.radians(bevel_deg)), width * np.sin(np.radians(bevel_deg))
    X0, X1, Y0, Y1, Z = x0 - d, x1 + d, y0 - d, y1 + d, z - dz
    quads = [[(x0, y0, z), (x1, y0, z), (x1, y1, z), (x0, y1, z)],  # the face
             [(X0, Y0, Z), (X1, Y0, Z), (x1, y0, z), (x0, y0, z)],  # bottom bevel
             [(x0, y1, z), (x1, y1, z), (X1, Y1, Z), (X0, Y1, Z)],  # top
             [(X0, Y0, Z), (x0, y0, z), (x0, y1, z), (X0, Y1, Z)],  # left
             [(x1, y0, z), (X1, Y0, Z), (X1, Y1, Z), (x1, y1, z)]]  # right
    v = np.asarray(quads, np.float64).reshape(-1, 3)
    faces = [f for q in range(5) for f in ([4 * q, 4 * q + 1, 4 * q + 2], [4 * q, 4 * q + 2, 4 * q + 3])]
    n = np.cross(v[1::4] - v[0::4], v[2::4] - v[0::4])
    n = np.repeat(n / np.linalg.norm(n, axis=1, keepdims=True), 4, axis=0)
    mirror = SceneObject("mirror", v.astype(np.float32), faces, normals=n.astype(np.float32), material=MIRROR)
    return Scene([mirror, *[o for o in props() if o.name != "green"]], name="bevelled_mirror")


def tap_scene() -> Scene:
    """A small chrome tap (MIRROR material; post r = 0.05, 0.5 high, a spout r = 0.035,
    0.3 long, a ball cap; one object, 32 sections) among the props, and the camera
    that sees it from 1 unit (tap_camera)."""
    post = trimesh.creation.cylinder(radius=0.05, height=0.5, sections=32)
    post.apply_translation((0, 0.25, 0))
    spout = trimesh.creation.cylinder(radius=0.035, height=0.3, sections=32)
    spout.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, (0, 0, 1)))
    spout.apply_translation((0.15, 0.46, 0))
    cap = trimesh.creation.icosphere(3, radius=0.05)
    cap.apply_translation((0, 0.5, 0))
    m = trimesh.util.concatenate([post, spout, cap])
    m.apply_translation((0.0, 0.0, 0.3))
    return Scene([SceneObject("tap", m.vertices, m.faces, material=MIRROR), *props()], name="tap")


def tap_camera(size: int = 96) -> Camera:
    """tap_scene's view: the tap fills about a fifth of the frame."""
    return Camera((0.5, 0.8, 1.3), (0.05, 0.35, 0.3), fov=40, width=size, height=size)


def mirror_object_scene(mesh: trimesh.Trimesh, name: str, material: Material = MIRROR) -> Scene:
    """`mesh` scaled to ~1.2 units, standing on the floor at the origin, among the props."""
    m = mesh.copy()
    ext = m.bounds[1] - m.bounds[0]
    m.apply_scale(1.2 / float(ext.max()))
    lo, hi = m.bounds
    m.apply_translation((-(lo[0] + hi[0]) / 2, -lo[1], -(lo[2] + hi[2]) / 2))
    return Scene([SceneObject(name, m.vertices, m.faces, material=material), *props()], name=name)


def sphere_mesh() -> trimesh.Trimesh:
    """An icosphere (level 4, 5120 triangles) of radius 0.6 at the origin."""
    return trimesh.creation.icosphere(4, radius=0.6)


def vase_mesh(n_around: int = 64, n_up: int = 48) -> trimesh.Trimesh:
    """Closed surface of revolution about +Y with a bulge and a neck (outward CCW faces)."""
    t = np.linspace(0.0, 1.0, n_up)
    radius = 0.25 + 0.22 * np.sin(np.pi * t * 1.2) ** 2 - 0.1 * t
    y = 1.4 * t
    a = np.linspace(0, 2 * np.pi, n_around, endpoint=False)
    verts = np.stack([np.outer(radius, np.cos(a)), np.repeat(y[:, None], n_around, 1),
                      np.outer(radius, np.sin(a))], -1).reshape(-1, 3)
    faces = []
    for i in range(n_up - 1):
        for j in range(n_around):
            p, q = i * n_around + j, i * n_around + (j + 1) % n_around
            faces += [[p, p + n_around, q], [q, p + n_around, q + n_around]]
    bottom, top = len(verts), len(verts) + 1
    verts = np.vstack([verts, [[0, 0, 0], [0, y[-1], 0]]])
    for j in range(n_around):
        faces += [[bottom, j, (j + 1) % n_around]]
        k = (n_up - 1) * n_around
        faces += [[top, k + (j + 1) % n_around, k + j]]
    m = trimesh.Trimesh(verts, np.asarray(faces), process=True)
    trimesh.repair.fix_normals(m)
    return m


def mirror_camera(size: int = 96) -> Camera:
    """The reflection tests' view of the mirror scenes, size × size pixels."""
    return Camera((1.0, 1.6, 3.2), (0.0, 0.55, 0.0), fov=40, width=size, height=size)


# --- service -----------------------------------------------------------------------------

def obj_text(n_quads: int = 1, z: float = 0.0) -> bytes:
    """A strip of n unit quads (2 triangles each) in the plane z, front faces toward +z."""
    lines = []
    for i in range(n_quads):
        lines += [f"v {i} 0 {z}", f"v {i + 1} 0 {z}", f"v {i + 1} 1 {z}", f"v {i} 1 {z}"]
    for i in range(n_quads):
        b = 4 * i + 1
        lines += [f"f {b} {b + 1} {b + 2}", f"f {b} {b + 2} {b + 3}"]
    return ("\n".join(lines) + "\n").encode()


@contextlib.contextmanager
def service(data_dir: Path, ready: bool = True, **overrides) -> Iterator[Any]:
    """A TestClient of a fresh app on `data_dir` (settings overridden), ready unless
    ready=False. Its render worker is the in-process thread (workers=0) unless
    `workers` is given: the tests look inside it (its thread, jobs that are closures,
    patched classes); tests/test_service_workers.py covers the worker processes, and
    `live_server` runs the default."""
    from fastapi.testclient import TestClient

    from service.app import create_app
    from service.config import Settings

    app = create_app(Settings(data_dir=data_dir, **{"workers": 0, **overrides}))
    with TestClient(app) as client:
        if ready:
            wait_ready(client)
        yield client


def service_client(builtin: str | None = None, **overrides: Any) -> Any:
    """A module-scoped `client` fixture: `service` on a fresh data folder (settings
    overridden) yielding its TestClient, or (client, scene id) with the built-in scene
    `builtin` registered. Use as `client = service_client(...)` in a test module."""

    @pytest.fixture(scope="module")
    def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Any]:
        with service(tmp_path_factory.mktemp("data"), **overrides) as c:
            if builtin is None:
                yield c
            else:
                r = c.post("/scenes", json={"builtin": builtin})
                assert r.is_success, r.text
                yield c, r.json()["id"]

    return client


@contextlib.contextmanager
def live_server(data_dir: Path, **overrides) -> Iterator[tuple[str, int]]:
    """The real uvicorn server of `depthview serve` on a free loopback port (settings
    overridden); yields (host, port)."""
    import threading

    import uvicorn

    from service.cli import server_config
    from service.config import Settings

    settings = Settings(data_dir=data_dir, host="127.0.0.1", port=0, **overrides)
    server = uvicorn.Server(server_config(settings, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    t0 = time.monotonic()
    while not server.started and time.monotonic() - t0 < 30:
        time.sleep(0.02)
    assert server.started
    try:
        yield "127.0.0.1", server.servers[0].sockets[0].getsockname()[1]
    finally:
        server.should_exit = True
        thread.join(30)


def frame_camera(scene_name: str = "cornell") -> dict:
    """A camera (JSON) looking at a built-in scene from outside its bounds."""
    scene = make_builtin(scene_name)
    cam = look_at_scene(scene.bounds, azimuth=20.0, elevation=15.0, distance=1.0, fov=50.0)
    return {"eye": list(cam.eye), "target": list(cam.target), "up": [0.0, 1.0, 0.0], "fov": 50.0}


# --- the plugin --------------------------------------------------------------------------

def write_small_glb(path: Path, ball_radius: float = 0.5) -> Path:
    """A small GLB (≈ 1.3k triangles): a grey slab under a ball of `ball_radius`."""
    scene = trimesh.Scene()
    slab = trimesh.creation.box((2.0, 0.2, 2.0))
    slab.apply_translation((0.0, -0.6, 0.0))
    scene.add_geometry(slab, "slab")
    scene.add_geometry(trimesh.creation.icosphere(3, radius=ball_radius), "ball")
    scene.export(path)
    return path


# --- GL scenarios in their own process -----------------------------------------------------

def run_isolated(scenario: Callable[[], dict], env: dict[str, str] | None = None, timeout: float = 120.0) -> dict:
    """Run scenario() — a module-level function returning a JSON-able dict — in a
    fresh interpreter (environment overrides `env`), so a scenario that crashes
    the process fails this test instead of ending the run. Returns its dict."""
    code = (f"import json\nfrom {scenario.__module__} import {scenario.__qualname__} as s\n"
            "print(json.dumps(s()))\n")
    out = subprocess.run([sys.executable, "-c", code], env={**os.environ, **(env or {})}, cwd=ROOT,
                         capture_output=True, text=True, timeout=timeout)
    if out.returncode != 0:
        how = f"killed by signal {-out.returncode}" if out.returncode < 0 else f"exit status {out.returncode}"
        raise AssertionError(f"{scenario.__qualname__} failed in its process ({how}):\n{out.stderr[-4000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def osmesa_render_agreement() -> dict:
    """Scenario: the G-buffer of sphere_on_slab on a fresh context (run with
    DEPTHVIEW_GL=osmesa) against Embree: {"backend", "agree": share of equal ids}."""
    from gl_passes.context import create_gl_context
    from gl_passes.gbuffer import GBufferPass
    from gl_passes.upload import SceneGPU
    from reference.raycast import RayCaster

    sc = sphere_on_slab()
    gl = create_gl_context()
    cam = look_at_scene(sc.bounds, width=96, height=64)
    with GBufferPass(gl) as gp, SceneGPU(gl, sc) as sg:
        g = gp.render(sg, cam)
    r = RayCaster(sc).gbuffer(cam)
    backend = gl.backend
    gl.release()
    return {"backend": backend, "agree": float((g.tri_id == r.tri_id).mean())}


def worker_context_loss() -> dict:
    """Scenario: the render worker's context is lost (released under it) between
    two frames: {"first": coverage of the frame before, "error": what the frame
    after raised (None if it did not), "alive": worker thread alive after,
    "stopped": stop() finished}."""
    from service.jobs import FrameJob
    from service.worker import RenderWorker

    sc = make_builtin("cornell")
    cam = look_at_scene(sc.bounds, width=32, height=24).fit_clip(sc.bounds)
    w = RenderWorker(queue_size=4).start()
    assert w.wait_ready(60), w.startup_error
    first = w.submit(FrameJob("a", sc, cam)).result(60)
    w.submit(lambda state: state.gl.ctx.release()).result(60)  # the context is gone
    try:
        w.submit(FrameJob("b", sc, cam)).result(60)
        error = None
    except Exception as exc:  # noqa: BLE001 - reported to the test
        error = f"{type(exc).__name__}: {exc}"
    alive = w.alive
    w.stop()
    return {"first": float(first.mask.mean()), "error": error, "alive": alive, "stopped": not w.alive}


def temporal_bench_scenario() -> dict:
    """Scenario (own process: the bench opens its own GL context on its thread):
    bench.temporal on the small mirror scene, 4 frames at 32², both tracers."""
    import json
    import tempfile
    from pathlib import Path

    from bench.temporal import main

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "temporal"
        main(["--scenes", "mirror", "--frames", "4", "--res", "32", "--out", str(out)])
        return {"json": json.loads(out.with_suffix(".json").read_text()), "md": out.with_suffix(".md").read_text(),
                "files": sorted(p.name for p in Path(tmp).iterdir())}


def temporal_sweeps_scenario() -> dict:
    """Scenario (own process): bench.temporal_sweeps on the mirror scene, 8-frame
    paths at 32², two thresholds, two camera speeds."""
    import json
    import tempfile
    from pathlib import Path

    from bench.temporal_sweeps import main

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "sweeps"
        main(["--scenes", "mirror", "--frames", "8", "--res", "32", "--thresholds", "0.0", "1.0",
              "--speeds", "4", "8", "--no-progress", "--out", str(out)])
        return {"json": json.loads(out.with_suffix(".json").read_text()), "md": out.with_suffix(".md").read_text()}


def stream_jumps_scenario() -> dict:
    """Scenario (own process): bench.stream_jumps on the bathroom, one keyframe camera
    on a 40-frame path at 32², one step of each kind, both tracers."""
    import json
    import tempfile
    from pathlib import Path

    from bench.stream_jumps import main

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "jumps"
        main(["--scenes", "bathroom", "--res", "32", "--frames", "40", "--per-path", "1", "--seeds", "0",
              "--turns", "5", "30", "--moves", "0.1", "--zooms", "1.25", "--rolls", "90", "--path-steps", "0", "1",
              "--no-progress", "--out", str(out)])
        return {"json": json.loads(out.with_suffix(".json").read_text()), "md": out.with_suffix(".md").read_text(),
                "files": sorted(p.name for p in Path(tmp).iterdir())}
