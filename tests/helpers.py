"""Scene builders and helpers shared by the test modules (tests import this module,
never each other nor conftest)."""

from __future__ import annotations

from pathlib import Path

import trimesh


def write_small_glb(path: Path, ball_radius: float = 0.5) -> Path:
    """A small GLB (≈ 1.3k triangles): a grey slab under a ball of `ball_radius`."""
    scene = trimesh.Scene()
    slab = trimesh.creation.box((2.0, 0.2, 2.0))
    slab.apply_translation((0.0, -0.6, 0.0))
    scene.add_geometry(slab, "slab")
    scene.add_geometry(trimesh.creation.icosphere(3, radius=ball_radius), "ball")
    scene.export(path)
    return path
