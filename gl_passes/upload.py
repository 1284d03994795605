"""Scene upload to the GPU and per-object drawing (DESIGN.md: triangle ids).

One interleaved vertex buffer (position, normal: float32) and one index buffer
(uint32) hold every object; object k is drawn with its own index range, so the
geometry shader's primitive id + the object's base face offset is the global
triangle index.
"""

from __future__ import annotations

from collections.abc import Iterable

import moderngl
import numpy as np

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

    def draw(self, prog: moderngl.Program, objects: Iterable[int] | None = None, materials: bool = True,
             instances: int = 1) -> None:
        """Draw the given objects (0-based indices; all by default) with `prog`,
        setting u_base (first global face), u_object (1-based id) and, when the
        program has them, the material uniforms."""
        self.gl.check_thread()
        vao = self.vao(prog)
        for k in range(len(self.ranges)) if objects is None else objects:
            first, count = self.ranges[k]
            if count == 0:
                continue
            if "u_base" in prog:
                prog["u_base"].value = first
            if "u_object" in prog:
                prog["u_object"].value = k + 1
            if materials:
                m = self.scene.objects[k].material
                for name, value in (("u_albedo", m.albedo), ("u_specular", m.specular),
                                    ("u_glossiness", m.glossiness)):
                    if name in prog:
                        prog[name].value = value
            vao.render(moderngl.TRIANGLES, vertices=3 * count, first=3 * first, instances=instances)

