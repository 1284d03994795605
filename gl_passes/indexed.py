"""A vertex buffer, a uint32 index buffer (or none) and their vertex arrays, one
per program (cached): the GPU side shared by scene uploads (SceneGPU) and
reconstructed meshes (MeshGPU)."""

from __future__ import annotations

import moderngl

from gl_passes.context import GLContext
from gl_passes.releasable import Releasable


class IndexedBuffers(Releasable):
    """Owns `vbo` and `ibo` (None: draws are not indexed); subclasses say how a
    program reads the vertices (`vertex_format`). `release()` frees the buffers and
    every vertex array."""

    def __init__(self, gl: GLContext, vbo: moderngl.Buffer, ibo: moderngl.Buffer | None) -> None:
        gl.check_thread()
        self.gl = gl
        self.vbo, self.ibo = vbo, ibo
        self._vaos: dict[int, moderngl.VertexArray] = {}

    def vertex_format(self, prog: moderngl.Program) -> tuple[str, ...]:
        """(moderngl buffer format, attribute names…) of the vertex buffer for `prog`."""
        raise NotImplementedError

    def vao(self, prog: moderngl.Program) -> moderngl.VertexArray:
        """Vertex array binding the buffers to `prog` (cached per program)."""
        key = prog.glo
        if key not in self._vaos:
            self._vaos[key] = self.gl.ctx.vertex_array(
                prog, [(self.vbo, *self.vertex_format(prog))], index_buffer=self.ibo, index_element_size=4)
        return self._vaos[key]

    @property
    def nbytes(self) -> int:
        """Bytes of GPU buffers held (the vertex and index buffers)."""
        return self.vbo.size + (self.ibo.size if self.ibo is not None else 0)

    def release(self) -> None:
        self.gl.check_thread()
        for v in self._vaos.values():
            v.release()
        self._vaos.clear()
        self.vbo.release()
        if self.ibo is not None:
            self.ibo.release()
