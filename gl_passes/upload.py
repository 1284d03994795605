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
from gl_passes.releasable import Releasable
from scenes.model import Scene


class SceneGPU(Releasable):
    """GPU copy of a Scene. Call `release()` when done (frees buffers and VAOs), or
    use it as a context manager: `with SceneGPU(gl, scene) as sg: ...`."""

    def __init__(self, gl: GLContext, scene: Scene) -> None:
        gl.check_thread()
        self.gl = gl
        self.scene = scene
        interleaved = np.hstack([scene.vertices, scene.normals]).astype(np.float32)
        self.vbo = gl.ctx.buffer(interleaved.tobytes())
        self.ibo = gl.ctx.buffer(scene.faces.astype(np.uint32).tobytes())
        self._vaos: dict[int, moderngl.VertexArray] = {}
        off = scene.face_offsets
        self.ranges = [(int(off[k]), int(off[k + 1] - off[k])) for k in range(len(scene.objects))]
        self.object_bounds = np.array(
            [[o.vertices.min(axis=0), o.vertices.max(axis=0)] for o in scene.objects], dtype=np.float64
        )

    def vao(self, prog: moderngl.Program) -> moderngl.VertexArray:
        """Vertex array binding this scene's buffers to `prog` (cached per program)."""
        key = prog.glo
        if key not in self._vaos:
            attrs = [a for a in ("in_position", "in_normal") if a in prog]
            fmt = "3f 3f" if len(attrs) == 2 else "3f 12x"
            self._vaos[key] = self.gl.ctx.vertex_array(
                prog, [(self.vbo, fmt, *attrs)], index_buffer=self.ibo, index_element_size=4
            )
        return self._vaos[key]

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

    def release(self) -> None:
        self.gl.check_thread()
        for v in self._vaos.values():
            v.release()
        self._vaos.clear()
        self.vbo.release()
        self.ibo.release()
