"""Depth-image sets (thesis Ch. 2): conventional, non-redundant, depth peeling.

* `conventional`: one ordinary depth image per camera.
* `non_redundant`: Alg. 1 (non-redundant rendering) with the pixel-redundancy
  test of Alg. 3 in the fragment shader (shaders/depth_image.frag, NON_REDUNDANT):
  image i is rendered with the triangle-id textures and view-projection matrices
  of images j < i bound; a fragment that reprojects into some I_j onto a texel
  holding its own triangle id is discarded before it writes depth, so the depth
  test keeps the nearest *non-redundant* fragment. Visibility redundancy
  (Alg. 2) is Embree's: `reference.visibility.non_redundant_visibility` (this
  package never imports `reference`; callers pick the definition).
* `depth_peeling`: classic depth peeling from one viewpoint (§2.3.1: the same
  shader, the test being "strictly behind the previous layer at this pixel").

All three render through the same shaders (depth_image.vert/.frag; the
triangle id comes from gl_PrimitiveID, no geometry shader), with back-face
culling on, so image 0 of `non_redundant` equals image 0 of `conventional`
bit for bit. Outputs are `scenes.depth_image.DepthImage` (row 0 = top):
color (H,W,3) float32 linear local shading (0 where there is no sample — the
sky is not part of a depth image), depth (H,W) float32 positive eye-space z
(+inf = no sample), normal/position (H,W,3) float32 world space (0 = no
sample), tri_id (H,W) uint32 (0 = no sample).

Every function takes the owning GLContext and a SceneGPU. Render targets live
in a `DepthImageRenderer`; pass one in to reuse them across calls (release()
it when done), otherwise a temporary one is made and freed before returning.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from functools import lru_cache

import moderngl
import numpy as np

from gl_passes.bindings import Units
from gl_passes.context import GLContext
from gl_passes.readback import read_texture
from gl_passes.releasable import Releasable, release_framebuffer
from gl_passes.shaders import program
from gl_passes.uniforms import set_camera, set_uniform
from gl_passes.upload import SceneGPU
from scenes.camera import Camera
from scenes.depth_image import DepthImage

#: Most previous images the non-redundant shader tests against (n ≤ MAX_IMAGES).
MAX_IMAGES = 16

#: Sizes whose render targets a renderer keeps between calls: a set's images and
#: its offset images (Alg. 4) are rendered by two calls at two sizes.
KEPT_SIZES = 2

#: Sampler units of a peeling layer's shader: the previous layer's ids and depths.
PEEL_UNITS = Units(textures=("u_peel_id", "u_peel_depth"))


@lru_cache(maxsize=2 * MAX_IMAGES)
def nr_units(n_prev: int, depths: bool) -> Units:
    """Sampler units of the non-redundant shader testing against n_prev previous
    images: its arrays u_prev_id[N_PREV] (and u_prev_depth[N_PREV] with depths)
    take consecutive units from their element 0's (`layout(binding = …)` on an
    array), so the table lists one name per element, u_prev_id0…, in that order."""
    names = [f"u_prev_id{j}" for j in range(n_prev)]
    if depths:
        names += [f"u_prev_depth{j}" for j in range(n_prev)]
    return Units(textures=tuple(names))


# Shared (overwritten per image) colour attachments: (name, components, dtype).
_SHARED = (("color", 4, "f4"), ("normal", 4, "f4"), ("position", 4, "f4"))


class _SizeTargets:
    """Render targets of one size: shared colour/normal/position/z-buffer, and per
    image slot its own linear-depth (R32F) and triangle-id (R32UI) textures, which
    later images (non-redundant) or layers (peeling) sample."""

    def __init__(self, ctx: moderngl.Context, size: tuple[int, int]) -> None:
        self.ctx = ctx
        self.size = size
        self.shared = {n: ctx.texture(size, c, dtype=d) for n, c, d in _SHARED}
        self.zbuffer = ctx.depth_texture(size)
        self.slots: list[tuple[moderngl.Texture, moderngl.Texture, moderngl.Framebuffer]] = []
        for t in self.shared.values():
            t.filter = (moderngl.NEAREST, moderngl.NEAREST)

    def slot(self, k: int) -> tuple[moderngl.Texture, moderngl.Texture, moderngl.Framebuffer]:
        """(linear depth, triangle id, framebuffer) of image slot k (made on demand)."""
        while len(self.slots) <= k:
            depth = self.ctx.texture(self.size, 1, dtype="f4")
            tri = self.ctx.texture(self.size, 1, dtype="u4")
            for t in (depth, tri):
                t.filter = (moderngl.NEAREST, moderngl.NEAREST)
            s = self.shared
            fbo = self.ctx.framebuffer([s["color"], depth, s["normal"], s["position"], tri], self.zbuffer)
            self.slots.append((depth, tri, fbo))
        return self.slots[k]

    def release(self) -> None:
        for depth, tri, fbo in self.slots:
            release_framebuffer(fbo)
            depth.release()
            tri.release()
        self.slots.clear()
        self.zbuffer.release()
        for t in self.shared.values():
            t.release()


class DepthImageRenderer(Releasable):
    """Programs and per-size render targets for depth-image sets on `gl`'s thread.

    vs_project: where the non-redundant test projects a fragment into the
    previous images — True: per vertex, interpolated as varyings (cheaper on
    llvmpipe); False: per fragment, one matrix product per previous image;
    None (default): per vertex while the varyings fit the implementation's
    GL_MAX_VERTEX_OUTPUT_COMPONENTS, else per fragment.
    tri_from_geom: take the triangle id from a geometry shader
    (depth_image.geom, as the thesis and the G-buffer do) instead of
    gl_PrimitiveID in the fragment shader — only to measure its cost.
    The images are the same either way (up to float rounding at texel edges).
    cull_back_faces: False draws both sides of every triangle — not a method of
    the thesis (every image of §2.3 culls back faces): the benchmark's two-sided
    peeling variant, which measures what the thesis's peeling numbers suggest
    (bench/peeling_sides.py), and soft shadows' `sides="both"` (a single-sided
    surface seen from behind by the light still occludes; bench/soft_shadows.py's
    sides part).
    footprint: 0 (default) is Alg. 3's test at the fragment's pixel centre; f > 0
    (at most ½) also requires the points ±f pixel from the centre along both screen
    axes (the pixel's corners at ½) to land on texels of the same earlier image
    holding the fragment's triangle — a pixel straddling an earlier image's outline
    of its surface then keeps that surface, which a reconstruction needs: its quad
    covers the whole pixel. occluded_margin m > 0 narrows it to occlusion seams: a
    point off I_j's triangle then keeps the fragment only where I_j's texel holds
    another surface nearer to V_j than the point by more than m of its depth (I_j's
    view of the surface was blocked there), not where I_j saw past it or saw
    nothing. Diagnostics of the soft-shadow benchmark's gap part, not methods of
    the thesis."""

    def __init__(self, gl: GLContext, vs_project: bool | None = None, tri_from_geom: bool = False,
                 cull_back_faces: bool = True, footprint: float = 0.0, occluded_margin: float = 0.0) -> None:
        gl.check_thread()
        if not 0.0 <= footprint <= 0.5:
            raise ValueError(f"footprint must be in [0, 0.5] pixels, got {footprint!r}")
        if occluded_margin < 0.0 or (occluded_margin and not footprint):
            raise ValueError(f"occluded_margin must be ≥ 0 and needs footprint > 0, got {occluded_margin!r}")
        self.gl = gl
        self.footprint = float(footprint)
        self.occluded_margin = float(occluded_margin)
        self.cull_back_faces = cull_back_faces
        self.vs_project = vs_project
        self.tri_from_geom = tri_from_geom
        self.max_vs_outputs = int(gl.ctx.info.get("GL_MAX_VERTEX_OUTPUT_COMPONENTS", 64))
        self.conv_prog = self._program()
        self.peel_prog = self._program(PEEL="1", **PEEL_UNITS.defines())
        self._targets: dict[tuple[int, int], _SizeTargets] = {}

    def _program(self, **defines: str) -> moderngl.Program:
        geom = None
        if self.tri_from_geom:
            geom = "depth_image.geom"
            defines = {**defines, "TRI_FROM_GEOM": "1"}
        return program(self.gl, "depth_image.vert", "depth_image.frag", geom, defines=defines)

    def nr_program(self, n_prev: int) -> moderngl.Program:
        """The non-redundant program testing against n_prev ≥ 1 previous images.
        One variant per n_prev (cached on the context): the test loop then has a
        constant trip count and constant sampler indices, which llvmpipe needs
        to unroll it (a dynamically indexed sampler array costs a switch over
        every sampler per fetch)."""
        vs = self.vs_project
        if vs is None:  # position, normal, depth + one vec4 per previous image
            vs = 7 + 4 * n_prev <= self.max_vs_outputs
        defines = {"NON_REDUNDANT": "1", "N_PREV": str(n_prev)}
        if vs:
            defines["VS_PROJECT"] = "1"
        if self.footprint:
            defines["FOOTPRINT"] = repr(float(self.footprint))
        if self.occluded_margin:
            defines["OCCLUDED_MARGIN"] = repr(self.occluded_margin)
        units = nr_units(n_prev, bool(self.occluded_margin))
        limit = int(self.gl.ctx.info.get("GL_MAX_TEXTURE_IMAGE_UNITS", 16))
        if len(units.textures) > limit:
            raise ValueError(f"{n_prev} previous images need {len(units.textures)} texture units; "
                             f"this GL has {limit}")
        return self._program(**defines, **units.defines())

    # --- targets -------------------------------------------------------------------
    def _size_targets(self, size: tuple[int, int]) -> _SizeTargets:
        if size not in self._targets:
            self._targets[size] = _SizeTargets(self.gl.ctx, size)
        return self._targets[size]

    def _keep_sizes(self, cameras: Iterable[Camera]) -> None:
        """Free the targets of sizes that neither the cameras of this call nor the
        last calls have, so that a renderer kept for a worker's lifetime holds at
        most KEPT_SIZES sizes' targets (more only where one call needs more),
        whatever sizes its requests ask for."""
        need = {(c.width, c.height) for c in cameras}
        for size in need & self._targets.keys():  # most recently used last
            self._targets[size] = self._targets.pop(size)
        others = [s for s in self._targets if s not in need]
        for size in others[:max(0, len(others) - (KEPT_SIZES - len(need)))]:
            self._targets.pop(size).release()

    def release(self) -> None:
        """Free every render target (the programs are cached on the context)."""
        self.gl.check_thread()
        for t in self._targets.values():
            t.release()
        self._targets.clear()

    # --- drawing -------------------------------------------------------------------
    def _draw(self, prog: moderngl.Program, scene_gpu: SceneGPU, camera: Camera, slot: int) -> _SizeTargets:
        """Render the scene with `prog` into image slot `slot` of the camera's size."""
        ctx = self.gl.ctx
        size = (camera.width, camera.height)
        targets = self._size_targets(size)
        _, _, fbo = targets.slot(slot)
        fbo.use()
        fbo.viewport = (0, 0, *size)
        fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        ctx.enable((moderngl.DEPTH_TEST | moderngl.CULL_FACE) if self.cull_back_faces else moderngl.DEPTH_TEST)
        ctx.depth_func = "<"
        ctx.front_face = "ccw"
        ctx.cull_face = "back"
        set_camera(prog, camera, scene_gpu.scene.sun_direction)
        scene_gpu.draw(prog)
        ctx.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        return targets

    def _read(self, targets: _SizeTargets, camera: Camera, slot: int) -> DepthImage:
        depth_tex, tri_tex, _ = targets.slot(slot)
        tri = read_texture(tri_tex)
        mask = tri > 0
        depth = read_texture(depth_tex)
        depth[~mask] = np.inf
        # Pixels without a sample keep the clear value 0; the RGB views of the
        # RGBA readbacks are kept as they are (no further copy).
        color, normal, position = (read_texture(targets.shared[n])[..., :3] for n in ("color", "normal", "position"))
        return DepthImage(camera, color, depth, normal, position, tri)

    def conventional(self, scene_gpu: SceneGPU, cameras: Sequence[Camera], read: bool = True) -> list[DepthImage]:
        """One ordinary depth image per (prepared) camera; read=False renders only."""
        self.gl.check_thread()
        self._keep_sizes(cameras)
        out = []
        for i, cam in enumerate(cameras):
            slot = i % 2  # alternate, so no draw waits for the previous image's readback
            t = self._draw(self.conv_prog, scene_gpu, cam, slot)
            if read:
                out.append(self._read(t, cam, slot))
        return out

    def non_redundant(self, scene_gpu: SceneGPU, cameras: Sequence[Camera], read: bool = True) -> list[DepthImage]:
        """Alg. 1 + Alg. 3 over (prepared) cameras; read=False renders only."""
        return self._non_redundant(scene_gpu, cameras, read)[0]

    def non_redundant_with_offsets(self, scene_gpu: SceneGPU, cameras: Sequence[Camera],
                                   offset_cameras: Sequence[Camera]) -> tuple[list[DepthImage], list[DepthImage]]:
        """Alg. 1 + Alg. 3 as `non_redundant`, plus per image I_i the image of
        offset_cameras[i] rendered with the same previous images I_0..I_{i−1}
        bound (the offset image H of Alg. 4; its size may differ from I_i's)."""
        return self._non_redundant(scene_gpu, cameras, True, offset_cameras)

    def _non_redundant(self, scene_gpu: SceneGPU, cameras: Sequence[Camera], read: bool,
                       offset_cameras: Sequence[Camera] | None = None) -> tuple[list[DepthImage], list[DepthImage]]:
        self.gl.check_thread()
        if len(cameras) > MAX_IMAGES:
            raise ValueError(f"non_redundant supports at most {MAX_IMAGES} images, got {len(cameras)}")
        self._keep_sizes([*cameras, *(offset_cameras or ())])
        texel = np.stack([_texel_matrix(c).T for c in cameras]).astype(np.float32)  # column-major for GL
        sizes = np.array([(c.width, c.height) for c in cameras], np.float32)
        out: list[DepthImage] = []
        offsets: list[DepthImage] = []
        for i, cam in enumerate(cameras):
            prog = self.nr_program(i) if i else self.conv_prog
            if i:
                units = nr_units(i, bool(self.occluded_margin))
                for j in range(i):  # I_j's ids (and depths) as element j of the sampler arrays
                    prev = cameras[j]
                    depth_tex, tri_tex, _ = self._size_targets((prev.width, prev.height)).slot(j)
                    units.bind_texture(f"u_prev_id{j}", tri_tex)
                    if self.occluded_margin:
                        units.bind_texture(f"u_prev_depth{j}", depth_tex)
                prog["u_prev_texel"].write(texel[:i].tobytes())
                prog["u_prev_size"].write(sizes[:i].tobytes())
            t = self._draw(prog, scene_gpu, cam, i)
            if read:
                out.append(self._read(t, cam, i))
            if offset_cameras is not None:  # same program, same previous images bound
                off = offset_cameras[i]
                offsets.append(self._read(self._draw(prog, scene_gpu, off, i), off, i))
        return out, offsets

    def depth_peeling(self, scene_gpu: SceneGPU, camera: Camera, layers: int, eps: float = 1e-6,
                      read: bool = True) -> list[DepthImage]:
        """`layers` peeled layers from one (prepared) camera; read=False renders only."""
        self.gl.check_thread()
        prog = self.peel_prog
        set_uniform(prog, "u_peel_eps", float(eps))
        self._keep_sizes([camera])
        targets = self._size_targets((camera.width, camera.height))
        out = []
        for k in range(layers):
            slot = k % 2  # ping-pong: layer k reads layer k-1's textures
            if k:
                prev_depth, prev_tri, _ = targets.slot(1 - slot)
                PEEL_UNITS.bind_texture("u_peel_id", prev_tri)
                PEEL_UNITS.bind_texture("u_peel_depth", prev_depth)
            self._draw(prog if k else self.conv_prog, scene_gpu, camera, slot)
            if read:
                out.append(self._read(targets, camera, slot))
        return out


def _texel_matrix(camera: Camera) -> np.ndarray:
    """(4,4) world → clip space of `camera` with x, y rescaled so that x/w, y/w are
    GL texel coordinates in [0, width] × [0, height] (origin bottom-left)."""
    w, h = camera.width, camera.height
    s = np.array([[w / 2, 0, 0, w / 2], [0, h / 2, 0, h / 2], [0, 0, 1, 0], [0, 0, 0, 1]], np.float64)
    return s @ camera.view_projection()


# --- public functional API -----------------------------------------------------------

def prepare_cameras(scene_gpu: SceneGPU, cameras: Sequence[Camera], res: int | None = None) -> list[Camera]:
    """Cameras resized to res×res when `res` is given, with near/far fitted to the
    scene bounds when missing."""
    out = []
    for cam in cameras:
        if res is not None:
            cam = cam.with_size(int(res), int(res))
        if cam.near is None or cam.far is None:
            cam = cam.fit_clip(scene_gpu.scene.bounds)
        out.append(cam)
    return out


def _run(gl: GLContext, renderer: DepthImageRenderer | None, fn_name: str, *args: object, **kw: object) -> list:
    gl.check_thread()
    own = renderer is None
    r = DepthImageRenderer(gl) if own else renderer
    try:
        return getattr(r, fn_name)(*args, **kw)
    finally:
        if own:
            r.release()


def conventional(gl: GLContext, scene_gpu: SceneGPU, cameras: Sequence[Camera], res: int | None = None,
                 renderer: DepthImageRenderer | None = None) -> list[DepthImage]:
    """Conventional depth images (the baseline of §2.3): one per camera, nearest
    front-facing surface at every pixel centre.

    cameras: n pinhole cameras; res: square res×res override of their sizes.
    Returns n DepthImages of shape (H,W[,3]) (see the module docstring for units)."""
    cams = prepare_cameras(scene_gpu, cameras, res)
    return _run(gl, renderer, "conventional", scene_gpu, cams)


def non_redundant(gl: GLContext, scene_gpu: SceneGPU, cameras: Sequence[Camera], res: int | None = None,
                  renderer: DepthImageRenderer | None = None) -> list[DepthImage]:
    """Non-redundant depth images (thesis Alg. 1) with pixel redundancy (Alg. 3),
    rendered in camera order: a fragment of image i is discarded when its world
    position, projected with PPC_j into I_j (j < i, inside I_j's frustum), lands
    on a texel whose triangle id is the fragment's own; the z-buffer then keeps
    the nearest non-redundant fragment. Image 0 is the conventional image.
    (Visibility redundancy, Alg. 2, is the Embree reference's:
    `reference.visibility.non_redundant_visibility`.)

    cameras: n ≤ MAX_IMAGES (16) pinhole cameras; res: square res×res override.
    Returns n DepthImages (H,W[,3]); tri_id 0 / depth +inf where image i has no
    non-redundant sample."""
    cams = prepare_cameras(scene_gpu, cameras, res)
    return _run(gl, renderer, "non_redundant", scene_gpu, cams)


def depth_peeling(gl: GLContext, scene_gpu: SceneGPU, camera: Camera, layers: int, res: int | None = None,
                  eps: float = 1e-6, renderer: DepthImageRenderer | None = None) -> list[DepthImage]:
    """Depth peeling from one viewpoint (the baseline of §2.3; the peeling camera
    of Fig. 8 sits at the reference eyes' centroid).

    Layer 0 is the conventional image; layer k keeps, per pixel, the nearest
    front-facing fragment that is neither layer k−1's triangle nor at a linear
    depth ≤ layer k−1's depth·(1 + eps); pixels empty in layer k−1 stay empty.
    Returns `layers` DepthImages (H,W[,3]) whose depths strictly increase per pixel."""
    if layers < 1:
        raise ValueError("layers must be ≥ 1")
    cam = prepare_cameras(scene_gpu, [camera], res)[0]
    return _run(gl, renderer, "depth_peeling", scene_gpu, cam, int(layers), eps=eps)
