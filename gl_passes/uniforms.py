"""Uniform helpers shared by passes (matrices are numpy row-major, GL wants column-major)."""

from __future__ import annotations

import moderngl
import numpy as np

from scenes.camera import Camera


def set_uniform(prog: moderngl.Program, name: str, value: object) -> None:
    """Set `name` if the program uses it (the GLSL compiler drops unused uniforms)."""
    if name not in prog:
        return
    u = prog[name]
    if isinstance(value, np.ndarray) and value.ndim == 2:
        u.write(np.ascontiguousarray(value.T, dtype=np.float32).tobytes())
    elif isinstance(value, np.ndarray):
        u.value = tuple(float(x) for x in value.ravel())
    else:
        u.value = value


def set_camera(prog: moderngl.Program, cam: Camera, sun: tuple[float, float, float] | None = None) -> None:
    """u_view, u_view_proj, u_eye and the sky basis u_cam_right/up/forward
    (scaled so that NDC (x, y) maps to the direction f + x·r + y·u)."""
    r, u, f = cam.basis()
    t = np.tan(np.radians(cam.fov) / 2)
    set_uniform(prog, "u_view", cam.view_matrix())
    set_uniform(prog, "u_view_proj", cam.view_projection())
    set_uniform(prog, "u_eye", np.asarray(cam.eye))
    set_uniform(prog, "u_cam_right", r * t * cam.aspect)
    set_uniform(prog, "u_cam_up", u * t)
    set_uniform(prog, "u_cam_forward", f)
    if sun is not None:
        set_uniform(prog, "u_sun", np.asarray(sun))
