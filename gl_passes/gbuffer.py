"""G-buffer pass (DESIGN.md §"Conventions"; thesis §4.2 step 1).

One pass writes local-shaded colour (alpha: the specular factor s, 0 on the
background), linear depth, world normal, world position,
triangle id (gl_PrimitiveID in the fragment shader), object id and material (s, g);
the background gets the sky colour and ids 0.
"""

from __future__ import annotations

import moderngl
import numpy as np

from gl_passes.context import GLContext
from gl_passes.readback import read_texture
from gl_passes.releasable import Releasable, release_framebuffer
from gl_passes.shaders import program
from gl_passes.uniforms import set_camera
from gl_passes.upload import SceneGPU
from scenes.buffers import FrameBuffers
from scenes.camera import Camera

#: The G-buffer's read-back layout (shared with the Embree reference).
GBuffer = FrameBuffers


# (name, components, dtype) of the colour attachments, in shader location order.
_ATTACHMENTS = (("color", 4, "f4"), ("depth", 1, "f4"), ("normal", 4, "f4"), ("position", 4, "f4"),
                ("tri_id", 1, "u4"), ("obj_id", 1, "u4"), ("material", 2, "f4"))


class RenderTarget:
    """The G-buffer's framebuffer for one size; reused until the size changes."""

    def __init__(self, ctx: moderngl.Context, size: tuple[int, int]) -> None:
        self.size = size
        self.textures = {n: ctx.texture(size, c, dtype=d) for n, c, d in _ATTACHMENTS}
        for t in self.textures.values():
            t.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.depth = ctx.depth_texture(size)
        self.fbo = ctx.framebuffer([self.textures[n] for n, _, _ in _ATTACHMENTS], self.depth)

    def release(self) -> None:
        release_framebuffer(self.fbo)
        self.depth.release()
        for t in self.textures.values():
            t.release()


class GBufferPass(Releasable):
    """Renders G-buffers on `gl`'s thread; holds one RenderTarget per size in use."""

    def __init__(self, gl: GLContext) -> None:
        gl.check_thread()
        self.gl = gl
        self.prog = program(gl, "scene.vert", "gbuffer.frag")
        self.sky_prog = program(gl, "fullscreen.vert", "gbuffer_sky.frag")
        self.sky_vao = gl.ctx.vertex_array(self.sky_prog, [])
        self.target: RenderTarget | None = None
        self.drawn = 0  # triangles the last draw() sent (culled chunks skipped)

    def draw(self, scene_gpu: SceneGPU, camera: Camera, cull_back_faces: bool = True,
             objects: list[int] | None = None) -> RenderTarget:
        """Render into the (reused) target without reading back; returns it. The
        scene's chunks are drawn nearest the eye first (SceneGPU.draw's near_first),
        so that the depth test rejects most hidden fragments before they are shaded
        into seven attachments (bench/results/reflections_notes.json)."""
        self.gl.check_thread()
        ctx = self.gl.ctx
        size = (camera.width, camera.height)
        if self.target is None or self.target.size != size:
            if self.target is not None:
                self.target.release()
            self.target = RenderTarget(ctx, size)
        cam = camera if camera.near is not None else camera.fit_clip(scene_gpu.scene.bounds)
        sun = scene_gpu.scene.sun_direction
        fbo = self.target.fbo
        fbo.use()
        fbo.viewport = (0, 0, *size)
        fbo.clear(depth=1.0)
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.depth_func = "<"
        if cull_back_faces:
            ctx.enable(moderngl.CULL_FACE)
            ctx.front_face = "ccw"
            ctx.cull_face = "back"
        set_camera(self.prog, cam, sun)
        eye = np.asarray(cam.eye, np.float64)
        self.drawn = scene_gpu.draw(self.prog, objects, view_proj=cam.view_projection(),
                                    eye=eye if cull_back_faces else None, near_first=eye)
        # the background last, at the far plane (depth 1.0, the clear value): the depth
        # test leaves it only the pixels no triangle covered, instead of shading and
        # storing every attachment of every pixel under the geometry
        ctx.disable(moderngl.CULL_FACE)
        ctx.depth_func = "<="
        set_camera(self.sky_prog, cam, sun)
        self.sky_vao.render(moderngl.TRIANGLES, vertices=3)
        ctx.depth_func = "<"
        ctx.disable(moderngl.DEPTH_TEST)
        return self.target

    def render(self, scene_gpu: SceneGPU, camera: Camera, cull_back_faces: bool = True,
               objects: list[int] | None = None) -> GBuffer:
        """Render and read back a GBuffer for `camera` (near/far fitted to the
        scene bounds when the camera has none)."""
        t = self.draw(scene_gpu, camera, cull_back_faces, objects).textures
        tri = read_texture(t["tri_id"])
        depth = read_texture(t["depth"])
        material = read_texture(t["material"])
        return GBuffer(
            color=read_texture(t["color"])[..., :3].copy(),
            depth=np.where(tri > 0, depth, np.float32(np.inf)).astype(np.float32),
            normal=read_texture(t["normal"])[..., :3].copy(),
            position=read_texture(t["position"])[..., :3].copy(),
            tri_id=tri,
            obj_id=read_texture(t["obj_id"]).astype(np.uint16),
            specular=material[..., 0].copy(),
            glossiness=material[..., 1].copy(),
        )

    def release_target(self) -> None:
        """Release the render target (the next `draw` makes one of its size)."""
        self.gl.check_thread()
        if self.target is not None:
            self.target.release()
            self.target = None

    def release(self) -> None:
        self.release_target()
        self.sky_vao.release()
