"""Soft shadows from shadow maps (thesis §3.3, Alg. 5; DESIGN.md technique 2).

`SoftShadowPass(gl, settings).visibility(occluders, bounds, points, normals, mask,
light)` answers, for every receiver point P of a G-buffer and every light sample s
of a rectangular area light's k×k grid (`AreaLight.samples(k)`, row s = sample s),
whether s sees P:

1. one shadow map per light sample (k² maps), rendered from the light camera
   `scenes.lights.shadow_map_camera(light, s, bounds, res)` — the same cameras for every
   occluder kind, so the original geometry (ground truth of Alg. 5) and its
   reconstruction (several meshes) are judged through identical maps. Every
   occluder (a `SceneGPU`, a `MeshGPU`, anything whose `draw(prog)` draws
   triangles reading `in_position`) is drawn into every map: depth only, with a
   position-only vertex shader (shadow_map.vert), no back-face culling (a
   reconstruction is a one-sided surface whose back faces cast shadows too), and
   depth clamping (an occluder in front of a light camera's near plane, e.g. a
   reconstruction quad slightly outside `bounds`, still occludes). A mesh's
   small pieces (`MeshGPU.splats`) are rasterised by a compute pass instead, with
   their triangles' texels and depths (`gl_passes.quad_splats.SplatRaster`), in
   batches with enough of them to pay for its fixed cost (`splat_raster_min`);
2. `maps_per_draw` maps per draw call: one instance per map into its own tile of a
   depth atlas (clip distances keep each instance in its tile), one batch of
   maps after another;
3. after each batch, a compute pass over the receiver points (shadow_lookup.comp)
   compares each point with each map of the batch and sets bit s of the point's
   visibility words in a storage buffer, read back once at the end.

The maps depend on the light and the occluders only, not on the receivers:
`render_maps` keeps all k² of them (one atlas per batch, `ShadowMaps`) and `lookup`
answers any receivers from them, with the same bits as `visibility`, which reuses
one atlas batch after batch.

Visibility rule (shared with the Embree reference): a light sample on or behind
P's tangent plane (dot(n, s − P) ≤ 0) is not visible. Depth bias: P is moved
`normal_offset` texels along its normal n, and is lit when that point's depth along
the light camera's axis is at most the map's linear depth + `depth_bias` +
`depth_slope`·tan t texels, t the angle between n and the direction to s (a surface
tilted by t changes depth by tan t texels across a texel; tan t clamped at 100);
a texel is the world size of one shadow-map texel at P's depth (2·tan(fov/2)·z/res),
so the bias follows the map's quantisation at every depth and is the same for
every occluder. Points outside a map or in front of an empty texel are lit. The
default bias is the one whose geometry shadow maps come nearest the exact Embree
truth on the benchmark's scenes without acne on a tilted plane (`bench.shadow_bias`).
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Protocol

import moderngl
import numpy as np

from gl_passes.bindings import Units
from gl_passes.context import GLContext
from gl_passes.laps import LapClock
from gl_passes.quad_splats import QuadSplats, SplatRaster
from gl_passes.readback import read_buffer
from gl_passes.releasable import Releasable, ReleasedOnError, Scratch, grown_buffer, release_framebuffer
from gl_passes.shaders import compute_program, program
from scenes.lights import shadow_map_camera
from scenes.model import AreaLight

GL_CLIP_DISTANCE0 = 0x3000
GL_DEPTH_CLAMP = 0x864F
#: Clip distances written by shadow_map.vert with MAPS_PER_DRAW (the tile's four sides).
N_CLIP_DISTANCES = 4
#: local_size_x of shadow_lookup.comp, and the most work groups per dispatch row.
LOOKUP_GROUP = 64
MAX_GROUPS_X = 65535
#: Units of shadow_lookup.comp (compiled in as `UNIT_<name>` #defines; gl_passes.bindings).
LOOKUP_UNITS = Units(storage=("points", "normals", "bits"), textures=("depth",))
#: Default `ShadowSettings.splat_raster_min`, splats × maps per resolved texel: between
#: the densities where the service's reconstructions draw faster as triangles and
#: where as splats (bench.splat_raster).
SPLAT_RASTER_MIN = 0.05
STEPS = ("upload", "shadow_maps", "lookup", "readback")  # ShadowResult.timings_ms
#: Most light samples per side: ShadowResult.counts (0..k²) is uint16.
MAX_SAMPLES = 255


@dataclass(frozen=True)
class ShadowSettings:
    """Shadow-map settings of Alg. 5 (§3.3).

    samples: k, the light is sampled on a k×k grid of cell centres (k² maps).
    shadow_map_resolution: texels per side of each (square) shadow map.
    normal_offset: receiver offset along its unit normal, in shadow-map texels.
    depth_bias: tolerance on the light-space depth comparison, in texels.
    depth_slope: more tolerance per unit tan t (t: the angle between the receiver's
    normal and the direction to the light sample), in texels.
    maps_per_draw: shadow maps rendered per draw call (instanced into a square
    atlas of ceil(√min(maps_per_draw, k²))² tiles); 1 = one draw per map.
    splat_raster_min: a batch's splats (`MeshGPU.splats`) go through the compute
    rasteriser when splats × maps are at least this many per texel of the atlas's
    tile rows the batch fills (`SplatRaster.pays`), else they are drawn as the
    triangles they stand for: below it the rasteriser's fixed pass over those
    texels costs more than it saves (0 = always; the default: bench.splat_raster,
    measured on llvmpipe; a GPU's break-even is its own)."""

    samples: int = 16
    shadow_map_resolution: int = 1024
    normal_offset: float = 0.125
    depth_bias: float = 1.0
    depth_slope: float = 0.5
    maps_per_draw: int = 16
    splat_raster_min: float = SPLAT_RASTER_MIN

    def __post_init__(self) -> None:
        if self.samples < 1 or self.shadow_map_resolution < 1 or self.maps_per_draw < 1:
            raise ValueError("samples, shadow_map_resolution and maps_per_draw must be ≥ 1")
        if self.samples > MAX_SAMPLES:
            raise ValueError(f"samples must be ≤ {MAX_SAMPLES}: a pixel's count of visible samples is 16-bit")
        if not all(np.isfinite(x) for x in (self.normal_offset, self.depth_bias, self.depth_slope)):
            raise ValueError("normal_offset, depth_bias and depth_slope must be finite")
        if not self.splat_raster_min >= 0:
            raise ValueError("splat_raster_min must be ≥ 0")

    @property
    def n_samples(self) -> int:
        """k², the number of light samples and shadow maps."""
        return self.samples * self.samples

    @property
    def words(self) -> int:
        """uint32 visibility words per receiver point, ceil(k²/32)."""
        return (self.n_samples + 31) // 32


@dataclass
class ShadowResult:
    """Per-pixel light-sample visibility (Alg. 5).

    bits: (H,W,ceil(k²/32)) uint32, bit s % 32 of word s // 32 set when light
    sample s (row s of light.samples(k)) sees the pixel's point; 0 outside the mask.
    counts: (H,W) uint16 visible samples per pixel (0..k²).
    timings_ms: milliseconds per step ("upload", "shadow_maps", "lookup", "readback")."""

    bits: np.ndarray
    counts: np.ndarray
    timings_ms: dict[str, float]


def _atlas_bytes(atlas: moderngl.Texture) -> int:
    """GPU bytes of a depth atlas (32-bit depth texels)."""
    return atlas.width * atlas.height * 4


@dataclass
class ShadowMaps:
    """The k² shadow maps of one light over fixed occluders (`SoftShadowPass.render_maps`),
    for `SoftShadowPass.lookup` from any receivers: `atlases[i]` holds maps
    i·maps_per_draw … in its tiles, as `settings` (the pass's that made them) lay
    them out. Owns the atlases: call `release()`."""

    cams: ShadowCameras
    atlases: list[moderngl.Texture]
    settings: ShadowSettings

    @property
    def nbytes(self) -> int:
        """GPU bytes of the atlases."""
        return sum(_atlas_bytes(a) for a in self.atlases)

    def release(self) -> None:
        for a in self.atlases:
            a.release()
        self.atlases.clear()


class Occluder(Protocol):
    """Anything that draws its triangles with `prog`, reading `in_position` (vec3).
    When its draw() also takes `instances` (SceneGPU, MeshGPU) one call draws a
    whole batch of maps; `materials=False` is passed where accepted (SceneGPU)."""

    def draw(self, prog: moderngl.Program) -> None: ...


@dataclass(frozen=True)
class ShadowCameras:
    """The k² light cameras as the shaders read them (S = k², sample order).

    view_proj: (S,4,4) float32 world → clip, column-major (GL layout).
    light: (S,4) float32 sample position (world units) and texel size per unit
    depth, 2·tan(fov/2)/res. clip: (S,2) float32 near, far (world units).
    forward: (S,4) float32 each camera's unit view axis (xyz; w unused): the light's
    −normal, or toward the scene box for a sample far off the light's axis."""

    view_proj: np.ndarray
    light: np.ndarray
    clip: np.ndarray
    forward: np.ndarray


def shadow_cameras(light: AreaLight, bounds: tuple[np.ndarray, np.ndarray], samples: int,
                   resolution: int) -> ShadowCameras:
    """The light cameras of the k×k light samples (`scenes.lights.shadow_map_camera`)."""
    cams = [shadow_map_camera(light, s, bounds, resolution) for s in light.samples(samples)]
    view_proj = np.stack([c.view_projection().T for c in cams]).astype(np.float32)
    texel = np.array([2 * np.tan(np.radians(c.fov) / 2) / resolution for c in cams])
    light_rows = np.column_stack([[c.eye for c in cams], texel]).astype(np.float32)
    clip = np.array([(c.near, c.far) for c in cams], np.float32)
    forward = np.array([np.append(c.basis()[2], 0.0) for c in cams], np.float32)
    return ShadowCameras(np.ascontiguousarray(view_proj), light_rows, clip, forward)


def atlas_tiles(n: int) -> tuple[int, np.ndarray]:
    """(t, (n,4) float32): a t×t tile grid (t = ceil(√n)) and, per tile i (column
    i % t, row i // t from the bottom), the NDC scale (x, y) and offset (x, y) that
    map a full-viewport NDC position into the tile."""
    t = int(np.ceil(np.sqrt(n)))
    i = np.arange(n)
    tiles = np.empty((n, 4), np.float32)
    tiles[:, :2] = 1.0 / t
    tiles[:, 2] = (2 * (i % t) + 1) / t - 1
    tiles[:, 3] = (2 * (i // t) + 1) / t - 1
    return t, tiles


def _padded(rows: np.ndarray, first: int, count: int, size: int) -> bytes:
    """rows[first:first+count] zero-padded to `size` rows, as bytes for a uniform array."""
    out = np.zeros((size, *rows.shape[1:]), rows.dtype)
    out[:count] = rows[first:first + count]
    return out.tobytes()


#: Set bits of each byte value (popcount where numpy < 2 has no bitwise_count).
_BYTE_BITS = np.array([bin(i).count("1") for i in range(256)], np.uint8)


def popcount_words(bits: np.ndarray) -> np.ndarray:
    """(..., words) uint32 → (...) uint16 number of set bits."""
    b = np.ascontiguousarray(bits, np.uint32)
    if hasattr(np, "bitwise_count"):
        return np.bitwise_count(b).sum(axis=-1, dtype=np.uint16)
    return _BYTE_BITS[b.view(np.uint8)].sum(axis=-1, dtype=np.uint16)


def _draw(occluder: Occluder, prog: moderngl.Program, instances: int, set_first: Callable[[int], None],
          splats_apart: bool) -> None:
    """Draw `occluder` `instances` times with `prog`, in one instanced call when its
    draw() takes `instances`, else once per instance (set_first(i) before each);
    a SceneGPU is told to skip its material uniforms; splats_apart: a mesh with
    splats draws only the triangles they do not stand for (the splats are the
    compute pass's: `_splats`)."""
    params = inspect.signature(occluder.draw).parameters
    kw = {"materials": False} if "materials" in params else {}
    if splats_apart:
        kw["quads"] = False
    if "instances" in params or instances == 1:
        if instances > 1:
            kw["instances"] = instances
        set_first(0)
        occluder.draw(prog, **kw)
        return
    for i in range(instances):
        set_first(i)
        occluder.draw(prog, **kw)


def _splats(occluder: Occluder) -> QuadSplats | None:
    """The occluder's quad splats (a `MeshGPU` with splats whose draw() can leave
    their triangles out), else None."""
    splats = getattr(occluder, "splats", None)
    return splats if splats is not None and "quads" in inspect.signature(occluder.draw).parameters else None


class SoftShadowPass(Releasable):
    """Shadow maps of an area light's k×k samples and per-point visibility bits
    (Alg. 5) on `gl`'s thread. Owns a depth atlas and the point buffers (reused
    across calls, grown when needed): call `release()` or use it as a context
    manager. Programs are cached on the context."""

    def __init__(self, gl: GLContext, settings: ShadowSettings = ShadowSettings()) -> None:
        gl.check_thread()
        self.gl = gl
        self.settings = settings
        res = settings.shadow_map_resolution
        self.batch = min(settings.maps_per_draw, settings.n_samples)
        self.tiles, self.tile_ndc = atlas_tiles(self.batch)
        size = res * self.tiles
        limit = int(gl.ctx.info["GL_MAX_TEXTURE_SIZE"])
        if size > limit:
            raise ValueError(f"shadow-map atlas {size}² exceeds GL_MAX_TEXTURE_SIZE {limit}: "
                             "lower maps_per_draw or shadow_map_resolution")
        instanced = {"MAPS_PER_DRAW": str(self.batch)} if self.batch > 1 else {}
        self.map_prog = program(gl, "shadow_map.vert", "shadow_map.frag", defines=instanced)
        self.lookup_prog = compute_program(gl, "shadow_lookup.comp", defines={
            "MAPS_PER_DRAW": str(self.batch), "WORDS": str(settings.words), **LOOKUP_UNITS.defines()})
        self.splat_raster = SplatRaster(gl, self.batch, self.tiles, res)  # its image is made at first use
        self.atlas, self.fbo = self._new_atlas()
        self._buffers: dict[str, moderngl.Buffer] = {}

    # --- resources -------------------------------------------------------------------
    def _new_atlas(self) -> tuple[moderngl.Texture, moderngl.Framebuffer]:
        """A depth atlas of `tiles`² maps, read unfiltered, and its framebuffer."""
        size = self.settings.shadow_map_resolution * self.tiles
        with ReleasedOnError() as made:
            atlas = made(self.gl.ctx.depth_texture((size, size)))
            atlas.filter = (moderngl.NEAREST, moderngl.NEAREST)
            atlas.compare_func = ""
            return atlas, self.gl.ctx.framebuffer(depth_attachment=atlas)

    @property
    def maps_nbytes(self) -> int:
        """GPU bytes of the `ShadowMaps` that `render_maps` makes (one atlas per batch)."""
        return self._n_batches * _atlas_bytes(self.atlas)

    def _buffer(self, name: str, nbytes: int) -> moderngl.Buffer:
        """The storage buffer `name`, at least `nbytes` long (replaced when smaller)."""
        buf = self._buffers[name] = grown_buffer(self.gl.ctx, self._buffers.get(name), nbytes, max(nbytes, 16))
        return buf

    def release(self) -> None:
        """Free the atlas, its framebuffer, the splat depth image and the point buffers."""
        self.gl.check_thread()
        self.splat_raster.release()
        for buf in self._buffers.values():
            buf.release()
        self._buffers.clear()
        release_framebuffer(self.fbo)
        self.atlas.release()


    # --- steps -----------------------------------------------------------------------
    def _upload(self, points: np.ndarray, normals: np.ndarray, mask: np.ndarray) -> int:
        """Masked receivers → the `points`/`normals` buffers as (N,4) float32; zeroed
        bits (N × words uint32). Returns N."""
        sel = np.flatnonzero(mask.ravel())
        n = len(sel)
        for name, arr in (("points", points), ("normals", normals)):
            rows = np.zeros((n, 4), np.float32)
            rows[:, :3] = arr.reshape(-1, 3)[sel]
            self._buffer(name, rows.nbytes).write(rows.tobytes())
        self._buffer("bits", n * self.settings.words * 4).clear()
        return n

    @contextmanager
    def _map_state(self, tiles: bool = True) -> Iterator[None]:
        """Depth test ("<"), no culling, depth clamp and (tiles, for shaders that write
        them) the tile clip distances while shadow maps are drawn; afterwards the depth
        test, depth clamp and clip distances are off (as every pass leaves them)."""
        ctx = self.gl.ctx
        clips = [GL_CLIP_DISTANCE0 + i for i in range(N_CLIP_DISTANCES)] if self.batch > 1 and tiles else []
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.disable(moderngl.CULL_FACE)
        ctx.depth_func = "<"
        for e in [GL_DEPTH_CLAMP, *clips]:
            ctx.enable_direct(e)
        try:
            yield
        finally:
            for e in [GL_DEPTH_CLAMP, *clips]:
                ctx.disable_direct(e)
            ctx.disable(moderngl.DEPTH_TEST)

    @property
    def _n_batches(self) -> int:
        return -(-self.settings.n_samples // self.batch)

    def _batches(self) -> Iterator[tuple[int, int]]:
        """(first, count) of each batch of maps."""
        n = self.settings.n_samples
        for first in range(0, n, self.batch):
            yield first, min(self.batch, n - first)

    def _render_maps(self, occluders: Sequence[Occluder], cams: ShadowCameras, first: int, count: int,
                     fbo: moderngl.Framebuffer) -> None:
        """Maps first..first+count−1 into tiles 0..count−1 of `fbo`'s atlas: the
        occluders' triangles, then their splats (`SplatRaster`, where it pays)."""
        prog = self.map_prog
        fbo.use()
        fbo.viewport = (0, 0, *fbo.size)
        fbo.clear(depth=1.0)
        light_vp = _padded(cams.view_proj, first, count, self.batch)
        prog["u_light_vp"].write(light_vp)
        if "u_tile" in prog:
            prog["u_tile"].write(self.tile_ndc.tobytes())

        def set_first(i: int) -> None:
            if "u_map0" in prog:
                prog["u_map0"].value = i

        held = [_splats(occ) for occ in occluders]
        total = sum(sp.count for sp in held if sp is not None)
        if not self.splat_raster.pays(total, count, self.settings.splat_raster_min):
            held = [None] * len(held)  # too few: drawn as their triangles
        with self._map_state():
            for occ, sp in zip(occluders, held, strict=True):
                _draw(occ, prog, count, set_first, sp is not None)
        splats = [sp for sp in held if sp is not None and sp.count]
        if splats:
            self.splat_raster.begin(light_vp, count)
            for sp in splats:
                self.splat_raster.draw(sp)
            with self._map_state(tiles=False):
                self.splat_raster.resolve(fbo)

    def _lookup(self, cams: ShadowCameras, first: int, count: int, n_points: int, atlas: moderngl.Texture) -> None:
        """Set the bits of samples first..first+count−1 (in `atlas`) for every receiver point."""
        prog = self.lookup_prog
        LOOKUP_UNITS.bind_texture("depth", atlas)
        for name in LOOKUP_UNITS.storage:
            LOOKUP_UNITS.bind_storage(name, self._buffers[name])
        for name, rows in (("u_light_vp", cams.view_proj), ("u_light", cams.light), ("u_clip", cams.clip),
                           ("u_forward", cams.forward)):
            prog[name].write(_padded(rows, first, count, self.batch))
        s = self.settings
        for name, value in (("u_first", first), ("u_count", count), ("u_tiles", self.tiles),
                            ("u_res", s.shadow_map_resolution), ("u_n_points", n_points),
                            ("u_normal_offset", float(s.normal_offset)), ("u_depth_bias", float(s.depth_bias)),
                            ("u_depth_slope", float(s.depth_slope))):
            prog[name].value = value
        groups = -(-n_points // LOOKUP_GROUP)
        gx = min(groups, MAX_GROUPS_X)
        prog.run(gx, -(-groups // gx))
        self.gl.ctx.memory_barrier()

    def _receivers(self, points: np.ndarray, normals: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, int]:
        """Check the shapes, upload the masked receivers: (mask (H,W) bool, their count)."""
        mask = np.asarray(mask, bool)
        if np.shape(points) != (*mask.shape, 3) or np.shape(normals) != (*mask.shape, 3):
            raise ValueError(f"points and normals must be (H,W,3) with mask (H,W) = {mask.shape}")
        return mask, self._upload(np.asarray(points, np.float32), np.asarray(normals, np.float32), mask)

    def _result(self, mask: np.ndarray, n: int, clock: LapClock) -> ShadowResult:
        """Read the receivers' bits back into (H,W,words)."""
        words = self.settings.words
        bits = np.zeros((*mask.shape, words), np.uint32)
        if n:
            flat = read_buffer(self._buffers["bits"], np.uint32, n * words)
            bits.reshape(-1, words)[np.flatnonzero(mask.ravel())] = flat.reshape(n, words)
        clock.lap("readback")
        return ShadowResult(bits=bits, counts=popcount_words(bits), timings_ms=clock.ms)

    # --- public ----------------------------------------------------------------------
    def visibility(self, occluders: Sequence[Occluder], bounds: tuple[np.ndarray, np.ndarray],
                   points: np.ndarray, normals: np.ndarray, mask: np.ndarray, light: AreaLight) -> ShadowResult:
        """Visibility of k×k light samples at the receiver points (Alg. 5).

        occluders: everything that casts shadows, all drawn into every map.
        bounds: (lo, hi) (3,) world box of the scene; it fixes the light cameras.
        points, normals: (H,W,3) float32 world positions and unit normals of the
        receivers (row 0 = top); mask: (H,W) bool receivers to evaluate.
        Returns a ShadowResult (bits, counts; 0 outside the mask). Raises
        ValueError on mismatched shapes, or when `bounds` is not entirely in front
        of the light (scenes.lights.light_camera)."""
        self.gl.check_thread()
        clock = LapClock(self.gl.ctx, sync=True, ms=dict.fromkeys(STEPS, 0.0))
        cams = shadow_cameras(light, bounds, self.settings.samples, self.settings.shadow_map_resolution)
        mask, n = self._receivers(points, normals, mask)
        clock.lap("upload")
        for first, count in self._batches() if n else ():
            self._render_maps(occluders, cams, first, count, self.fbo)
            clock.lap("shadow_maps")
            self._lookup(cams, first, count, n, self.atlas)
            clock.lap("lookup")
        return self._result(mask, n, clock)

    def render_maps(self, occluders: Sequence[Occluder], bounds: tuple[np.ndarray, np.ndarray],
                    light: AreaLight) -> ShadowMaps:
        """All k² shadow maps of `light` over `occluders` (as `visibility` draws
        them), kept in `maps_nbytes` of atlases for `lookup`."""
        self.gl.check_thread()
        cams = shadow_cameras(light, bounds, self.settings.samples, self.settings.shadow_map_resolution)
        with ReleasedOnError() as made:
            maps = made(ShadowMaps(cams, [], self.settings))
            for first, count in self._batches():
                atlas, fbo = self._new_atlas()
                maps.atlases.append(atlas)
                with Scratch() as temp:
                    self._render_maps(occluders, cams, first, count, temp(fbo))
            return maps

    def lookup(self, maps: ShadowMaps, points: np.ndarray, normals: np.ndarray, mask: np.ndarray) -> ShadowResult:
        """`visibility` of the receivers (shapes as there) from maps that
        `render_maps` of this pass made."""
        self.gl.check_thread()
        if maps.settings != self.settings:
            raise ValueError(f"the maps were made with other settings ({maps.settings}) than this pass's "
                             f"({self.settings})")
        if len(maps.atlases) != self._n_batches:
            raise ValueError(f"{len(maps.atlases)} atlases are not the maps of this pass's {self.settings.samples}² "
                             "light samples (released)")
        clock = LapClock(self.gl.ctx, ms=dict.fromkeys(STEPS, 0.0))
        mask, n = self._receivers(points, normals, mask)
        clock.lap("upload")
        for (first, count), atlas in zip(self._batches(), maps.atlases, strict=True) if n else ():
            self._lookup(maps.cams, first, count, n, atlas)
        clock.lap("lookup", finish=True)
        return self._result(mask, n, clock)
