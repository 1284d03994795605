"""Scene upload to the GPU and per-object drawing (DESIGN.md: triangle ids).

One interleaved vertex buffer (position, normal: float32) and one index buffer
(uint32) hold every object; object k is drawn with its own index range, so the
geometry shader's primitive id + the object's base face offset is the global
triangle index.
"""

from __future__ import annotations

from collections.abc import Iterable
from functools import cached_property

import moderngl
import numpy as np

from gl_passes.chunks import ChunkTable, boxes_in_frustum, chunk_table, facing_away, nearest_first, runs
from gl_passes.context import GLContext
from gl_passes.indexed import IndexedBuffers
from scenes.model import Scene


class SceneGPU(IndexedBuffers):
    """GPU copy of a Scene. Call `release()` when done (frees buffers and VAOs), or
    use it as a context manager: `with SceneGPU(gl, scene) as sg: ...`."""

    def __init__(self, gl: GLContext, scene: Scene) -> None:
        gl.check_thread()
        self.scene = scene
        interleaved = np.hstack([scene.vertices, scene.normals]).astype(np.float32)
        super().__init__(gl, gl.ctx.buffer(interleaved.tobytes()),
                         gl.ctx.buffer(scene.faces.astype(np.uint32).tobytes()))
        off = scene.face_offsets
        self.ranges = [(int(off[k]), int(off[k + 1] - off[k])) for k in range(len(scene.objects))]
        self.object_bounds = np.array(
            [[o.vertices.min(axis=0), o.vertices.max(axis=0)] for o in scene.objects], dtype=np.float64
        )

    def vertex_format(self, prog: moderngl.Program) -> tuple[str, ...]:
        """Interleaved position and normal; the normal skipped when `prog` has no in_normal."""
        attrs = [a for a in ("in_position", "in_normal") if a in prog]
        return ("3f 3f" if len(attrs) == 2 else "3f 12x", *attrs)

    @cached_property
    def chunks(self) -> ChunkTable:
        """The scene's triangle chunks (gl_passes.chunks), built on first use."""
        return chunk_table(self.scene.vertices, self.scene.faces, self.ranges)

    def draw(self, prog: moderngl.Program, objects: Iterable[int] | None = None, materials: bool = True,
             instances: int = 1, view_proj: np.ndarray | None = None, eye: np.ndarray | None = None,
             near_first: np.ndarray | None = None) -> int:
        """Draw the given objects (0-based indices; all by default) with `prog`,
        setting u_base (first global face of each draw), u_object (1-based id) and,
        when the program has them, the material uniforms. With `view_proj` (4×4) the
        triangle chunks outside its frustum are skipped, with `eye` (world point;
        only where GL culls back faces) those facing away from it: neither changes
        a pixel (gl_passes.chunks). With `near_first` (world point) the chunks are
        drawn in the order of their boxes' distance from it, nearest first, so that
        a depth-tested pass shades fewer hidden fragments (a rasteriser tests depth
        before shading); the pixels change only where two surfaces tie in depth.
        Returns the triangles drawn per instance."""
        self.gl.check_thread()
        vao = self.vao(prog)
        objs = range(len(self.ranges)) if objects is None else objects
        if view_proj is None and eye is None and near_first is None:
            pieces: Iterable[tuple[int, int, int]] = ((k, *self.ranges[k]) for k in objs)
        else:
            t = self.chunks
            keep = np.zeros(len(self.ranges), bool)
            keep[list(objs)] = True
            v = keep[t.obj]
            if view_proj is not None:
                v &= boxes_in_frustum(view_proj, t.bounds, t.corners)
            if eye is not None:
                v &= ~facing_away(eye, t.cones)
            sel = np.nonzero(v)[0]
            pieces = runs(t, sel if near_first is None else nearest_first(t.bounds, sel, near_first))
        drawn, current = 0, -1
        for k, first, count in pieces:
            if count == 0:
                continue
            if "u_base" in prog:
                prog["u_base"].value = first
            if k != current:
                current = k
                if "u_object" in prog:
                    prog["u_object"].value = k + 1
                if materials:
                    m = self.scene.objects[k].material
                    for name, value in (("u_albedo", m.albedo), ("u_specular", m.specular),
                                        ("u_glossiness", m.glossiness)):
                        if name in prog:
                            prog[name].value = value
            vao.render(moderngl.TRIANGLES, vertices=3 * count, first=3 * first, instances=instances)
            drawn += count
        return drawn
