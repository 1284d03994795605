"""The staging the soft-shadow benchmark's parts share (bench.soft_shadows,
bench.shadow_holes, bench.shadow_budget): a scene with the receivers of its output
view, its two truths (geometry shadow maps, exact Embree rays), Alg. 5 with a set's
reconstructions (`approximate`), the §3.4.2 errors against both truths and the
report's cell formats of them."""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from gl_passes.context import GLContext
from gl_passes.gbuffer import GBufferPass
from gl_passes.reconstruction import ReconstructionSettings, reconstruct_set, render_set
from gl_passes.shadows import SoftShadowPass
from gl_passes.upload import SceneGPU
from reference.raycast import RayCaster
from reference.shadows import error_maps, light_visibility, shadow_errors
from scenes.camera import Camera, look_at_scene
from scenes.lights import PEEL_LAYERS, reference_cameras
from scenes.model import AreaLight, Scene

#: Output view resolution (square), the receivers of every part.
OUTPUT_RES = 512


@dataclass
class Stage:
    """One scene ready for shadow queries: its GPU copy, the receivers of the
    output view (G-buffer points, normals, mask, albedo) and the Embree caster."""

    scene: Scene
    gpu: SceneGPU
    caster: RayCaster
    view: Camera
    points: np.ndarray
    normals: np.ndarray
    mask: np.ndarray
    albedo: np.ndarray


def stage_scene(gl: GLContext, scene: Scene) -> Stage:
    gpu = SceneGPU(gl, scene)
    view = look_at_scene(scene.bounds, width=OUTPUT_RES, height=OUTPUT_RES)
    gb = GBufferPass(gl)
    try:
        buf = gb.render(gpu, view)
    finally:
        gb.release()
    albedo = scene.materials[buf.obj_id, :3]
    return Stage(scene, gpu, RayCaster(scene), view, buf.position, buf.normal, buf.mask, albedo)


def truths(st: Stage, sp: SoftShadowPass, light: AreaLight, k: int) -> tuple[np.ndarray, np.ndarray, dict]:
    """(geometry-shadow-map bits, exact Embree bits, their seconds)."""
    t0 = time.perf_counter()
    geo = sp.visibility([st.gpu], st.scene.bounds, st.points, st.normals, st.mask, light).bits
    t1 = time.perf_counter()
    exact = light_visibility(st.caster, st.points, st.normals, st.mask, light, k)
    return geo, exact, {"geometry_shadows": t1 - t0, "exact_embree": time.perf_counter() - t1}


def approximate(gl: GLContext, st: Stage, sp: SoftShadowPass, light: AreaLight, method: str,
                kinds: tuple[str, ...], res: int, cameras: list[Camera] | None = None) -> dict[str, dict[str, Any]]:
    """Alg. 5 with each reconstruction kind of `method`'s images, taken from Alg. 5's
    reference cameras at res² unless `cameras`: bits, triangles, samples and the time
    of step 1 (reference images), 2 (reconstruction), 3 (shadows)."""
    bounds = st.scene.bounds
    t0 = time.perf_counter()
    sampled = render_set(gl, st.gpu, method, cameras or reference_cameras(light, bounds, method, res),
                         layers=PEEL_LAYERS)
    gl.ctx.finish()
    step1 = time.perf_counter() - t0
    out = {}
    for kind in kinds:
        t0 = time.perf_counter()
        meshes = reconstruct_set(gl, sampled, ReconstructionSettings(kind=kind))
        gl.ctx.finish()
        step2 = time.perf_counter() - t0
        try:
            t0 = time.perf_counter()
            res_ = sp.visibility(meshes, bounds, st.points, st.normals, st.mask, light)
            step3 = time.perf_counter() - t0
            out[kind] = {"bits": res_.bits, "triangles": sum(m.n_triangles for m in meshes),
                         "samples": sum(img.n_samples for img in sampled.images),
                         "seconds": {"reference_images": step1, "reconstruction": step2, "shadows": step3}}
        finally:
            for m in meshes:
                m.release()
    return out


def unpack_visibility(words: np.ndarray, n_samples: int) -> np.ndarray:
    """(..., n_samples) bool: bit s % 32 of word s // 32 of visibility words
    (..., ceil(n_samples/32)) uint32 (the layout of `ShadowResult.bits`)."""
    s = np.arange(n_samples)
    return ((words[..., s >> 5] >> (s & 31).astype(np.uint32)) & 1).astype(bool)


def errors(bits: np.ndarray, geo: np.ndarray, exact: np.ndarray, mask: np.ndarray) -> dict[str, Any]:
    """§3.4.2 errors against both truths, and the mean wrong decisions against the
    geometry truth split by sign (too dark: samples shadowed that the truth lights)."""
    _, signed = error_maps(bits, geo)
    s = signed[mask].astype(np.float64)
    return {"vs_geometry": shadow_errors(bits, geo, mask), "vs_exact": shadow_errors(bits, exact, mask),
            "too_dark_mean": float(np.clip(-s, 0, None).mean()) if s.size else 0.0,
            "too_bright_mean": float(np.clip(s, 0, None).mean()) if s.size else 0.0}


def set_errors(gl: GLContext, st: Stage, sp: SoftShadowPass, light: AreaLight, method: str,
               cameras: list[Camera], geo: np.ndarray, exact: np.ndarray, **images: Any) -> dict[str, Any]:
    """`errors` and the triangle count of the default (hybrid) reconstruction of the
    `method` images of `cameras` (`render_set` with `images`: a renderer, or
    cull_back_faces) as occluders; the meshes are released."""
    sampled = render_set(gl, st.gpu, method, cameras, layers=PEEL_LAYERS, **images)
    meshes = reconstruct_set(gl, sampled, ReconstructionSettings())
    try:
        r = sp.visibility(meshes, st.scene.bounds, st.points, st.normals, st.mask, light)
        return {**errors(r.bits, geo, exact, st.mask), "triangles": sum(m.n_triangles for m in meshes)}
    finally:
        for m in meshes:
            m.release()


def iv(x: dict[str, Any]) -> str:
    """'intensity · visibility' mean errors of one set of §3.4.2 errors (`shadow_errors`)."""
    return f"{x['intensity_mean']:.3f} · {x['visibility_mean']:.3f}"


def iv_sign_triangles(e: dict[str, Any]) -> str:
    """'intensity · visibility (too dark / too bright; triangles)' of an `errors` run, against the geometry truth."""
    return (f"{iv(e['vs_geometry'])} ({e['too_dark_mean']:.3f} / {e['too_bright_mean']:.3f}; "
            f"{e['triangles'] / 1e6:.2f} M)")
