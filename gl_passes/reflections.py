"""Reflections with cluster depth images (thesis Ch. 4, Alg. 6/7; DESIGN.md technique 3).

`ClusterReflections(gl, settings).render(scene_gpu, camera)`; every parameter of the
method lives in one frozen `ClusterSettings` (DEFAULT_SETTINGS: what the service
renders and the benchmarks measure); every texture, image and storage unit of its
shaders comes from gl_passes.cluster_units.UNITS.

0. per-scene records that do not depend on the camera (cached for CHUNK_CACHE
   scenes, step "scene_setup", ~0 on a scene's later frames): every triangle's
   geometric normal (face_normals.comp, read by the later passes' geom_normal),
   triangle chunks with AABBs and normal cones, and the levels of detail
   (meshoptimizer) with theirs;
1. G-buffer at ss×ss supersampling (GBufferPass at ss·W × ss·H);
2. clustering of the reflective samples on the GPU (gl_passes.clustering, §4.3):
   bins of the mirror normal and reflector, split into the connected components of
   continuous normal field (planar ones sharing a cluster per plane);
3. one cluster camera per cluster (gl_passes.cluster_camera, §4.4): per-cluster
   statistics and ray extents by compute passes with atomics, the per-cluster
   camera algebra in numpy on those few numbers;
4. cluster depth images (local-shaded colour + linear depth) rendered into one
   atlas texture, one viewport per cluster (over `atlas_budget` the images shrink
   but planar mirrors'; those keep their texel = sample grid, on which their rays
   are exact: shrinking them raised the occlusion error, measured in
   bench/results/reflections_notes.json, planar_grid_under_budget), with
   frustum culling of triangle
   chunks (gl_passes.chunks; finer than SceneGPU.object_bounds, so large floors and walls are mostly
   culled), back-face culling of whole chunks (cluster_camera.backfacing_chunks:
   exact, GL would cull every triangle of them), the other objects of non-planar
   clusters at a level of detail within `lod_texels` texels (ClusterSettings), and
   the fitting plane as a clip plane. Four layers per cluster image:
   every object except the cluster's own reflector; the reflector alone (its
   self-reflections) — otherwise the reflector's far side, which faces e_c, hides
   what its rays see; and the reflector's second surface (one depth peel,
   cluster_peel.frag), for self-reflections behind its nearest surface (thick rims,
   the inside of a bathtub or a bowl); and, for non-planar clusters
   (`others_peel`), the other objects' second surface (one depth peel of the first
   layer): a curved cluster's shifted centre e_c does not lie on its rays, so what
   a ray meets can be hidden from e_c behind another object (its cost and its
   effect on the occlusion error: the reflections report's cluster-image layers
   sweep; planar clusters: e_c = e0 lies on every ray, nothing on a ray is hidden
   from it, so they skip this layer). Each
   layer's fragment shader also writes its depth into that layer's channel of one
   pack texture (a colour mask per framebuffer) and its colour (11/11/10 bits)
   into its channel of a colour pack; per frame only the pack (to the background)
   and the depth attachments are cleared: a layer's colour is read only where the
   pack says this frame drew it;
5. intersection (Alg. 7, reflect_trace.comp) per reflective sample (the list of
   gl_passes.reflective_list, as for the clustering's per-sample passes and the
   cluster cameras' extent passes: llvmpipe runs a pass's code for invocations
   whose lanes are all masked off): the reflected ray's
   projection is marched one texel per step with perspective-correct depth (1/z
   linear in the image) over all layers at once (their depths packed in one
   texel, written by the layers' fragment shaders); the first surface met along
   the ray wins. Hit rules:
   (a) thin surface: the step whose ray-depth span reaches the stored depth,
   unless the surface lies in front of the span by more than `thickness` spans
   (the ray passes behind it) or in front of the ray's entry point, refined inside
   the step where the ray's inverse depth crosses the bilinearly interpolated
   surface's; (b) surface crossing (`slope` > 0): the ray is in front of a layer's
   surface interpolated at its exact image point (bilinear in 1/z over the 2×2
   texels around it) at the previous step and behind it now, both 2×2 footprints
   continuous (depths within a factor 1 + 1.5·slope·texel angle: surfaces up to
   tan θ = slope to the view ray); hit where the inverse depths cross. It catches
   steep surfaces crossed between texel centres, which (a) reads as the ray
   passing behind; (c) optional (`near_steps` > 0): near the origin (the ray's
   first `near_steps` texels, where the ray lies on its reflector and the
   reflector's texels are within (a)'s tolerance) an (a) hit needs that refined
   crossing, else marching goes on (false self-hits on finely tessellated curved
   reflectors). The sample's own triangle is never a hit, nor is any reflector
   texel whose stored point lies on its plane (a reflected ray leaves that plane;
   a geometric test, so the cluster images store no triangle ids). The mirror ray's
   hit is refined and its colour filtered; a glossy sample's lobe rays take their
   hit texel's colour, as Alg. 7 does. A stretch of the ray
   inside one 8×8-texel block is skipped when, in every layer, the block's stored
   depths all lie behind the ray there or all in front of the lowest depth rule (a)
   accepts there (cluster_block_depth.comp; exact: frames are bit-identical to
   marching every texel; with (b) or the crossing rule, behind only). The march
   loop holds only the per-step test and the hit processing runs after it:
   llvmpipe executes a branch's body under a lane mask even when no lane takes it,
   so refinement code inside the loop cost every step
   (bench/results/reflections_notes.json, "march_loop_refinement_cost"),
   and the hit processing reads each layer's depth and colour from the packs
   (one fetch whatever the layer) rather than choosing among per-layer textures.
   (b) and (c) are opt-in: (b), and (b) with (c), lowered the strict occlusion
   error a little for much more intersection time, which dominates the frame,
   and (c) without (b) raised the error (bench/results/reflections_notes.json, "opt_in_hit_rules").
   Optional crossing rule (`continuity`
   > 0, compiled in only then; superseded by (b)): a surface the ray was in front of at
   the previous step and is behind now is hit when its texel-centre depth jumps by
   at most `continuity` of itself between the two texels. For glossy reflectors
   `glossy_rays` lobe rays (scenes.glossy) with fade to diffuse;
   misses read the sky (mirrors) or the diffuse colour (glossy, as the reference);
6. colour = mix(diffuse, reflected, s) and ss×ss averages (reflect_resolve.comp,
   the same aggregation rules as reference.reflections).

Only small per-cluster records cross the bus: per-object sample counts, per-bin
statistics and per-cluster extents (a few dozen uints each) and the final images.

`method="envmap"` is the environment-map baseline (reflected = sky(r), lobe mean
for glossy samples, ray length +inf). Results follow reference.reflections'
ReflectionResult layout, plus the cluster cameras and per-step timings.
render(..., diagnostics=True) also reads back, after the timed steps, each sample's
cluster and the cluster images' stored depths (ClusterDiagnostics), for the
thesis's occlusion-error test (§4.7.1, reference.occlusion.captured_mask).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import moderngl
import numpy as np

from gl_passes import cluster_camera as cc
from gl_passes.chunks import chunk_table, runs
from gl_passes.cluster_camera import ClusterCamera, ClusterExtentPass
from gl_passes.cluster_units import UNITS
from gl_passes.clustering import ClusteringPass
from gl_passes.context import GLContext
from gl_passes.gbuffer import GBufferPass
from gl_passes.laps import LapClock
from gl_passes.lod import lod_faces
from gl_passes.readback import read_planes, read_texture
from gl_passes.releasable import Releasable, grown_buffer, release_framebuffer
from gl_passes.shaders import compute_program, program
from gl_passes.uniforms import set_uniform
from gl_passes.upload import SceneGPU
from scenes.buffers import ClusterDiagnostics, ReflectionBuffers
from scenes.camera import Camera
from scenes.glossy import FADE_FRACTION, lobe_offsets

MAX_RAYS = 64
RESOLVED_PLANES = 12  # reflect_resolve.comp's output channels (colour, s, reflected, length, diffuse, count)
CHUNK_CACHE = 4  # scenes whose chunk records (bounds, normal cones) are kept
BLOCK = 8    # atlas texels per side of a depth-bounds block (march skipping)
TRACE_GROUP = 64  # intersection work group (invocations, one per listed reflective sample)
GL_CLIP_DISTANCE0 = 0x3000
BACKGROUND_DEPTH = 1e30
# Cluster image layers: other objects, the reflector, the reflector's 2nd surface,
# the other objects' 2nd surface (non-planar clusters only).
N_LAYERS = 4
CONTINUITY = 0.0  # crossing rule (off by default): max relative depth jump between texels of one surface
SLOPE = 0.0  # surface-crossing rule (opt-in, e.g. 10): steepest surface, tan of its angle to the view ray
NEAR_STEPS = 0  # near-origin rule (opt-in, e.g. 4): in the ray's first texels a hit needs a refined crossing
STEPS = ("scene_setup", "gbuffer", "clustering", "cluster_cameras", "depth_images", "intersection", "resolve")


@dataclass
class ClusterReflectionResult(ReflectionBuffers):
    """ReflectionBuffers (same aggregation rules as the reference) plus: cameras:
    the cluster cameras; timings_ms: per step (STEPS) plus "total"; atlas_size:
    (w, h) texels; drawn_chunks: triangle chunks drawn into the cluster images
    (after culling); diagnostics: ClusterDiagnostics when render(diagnostics=True),
    else None; cache_hits: per cached step whether it hit its cache ("scene_setup":
    the scene's camera-independent records, chunk bounds and normal cones, came
    from the per-scene cache; callers may add theirs, e.g. the service's "upload");
    clustering_ms: with diagnostics, the clustering step's passes (each waited for,
    so their sum exceeds the untimed step)."""

    method: str = "clusters"
    supersample: int = 2
    n_clusters: int = 0
    cameras: list[ClusterCamera] = field(default_factory=list)
    timings_ms: dict[str, float] = field(default_factory=dict)
    atlas_size: tuple[int, int] = (0, 0)
    drawn_chunks: int = 0
    diagnostics: ClusterDiagnostics | None = None
    cache_hits: dict[str, bool] = field(default_factory=dict)
    clustering_ms: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class ClusterSettings:
    """Every parameter of the cluster-depth-image method (thesis Ch. 4, Alg. 6/7), one
    frozen object shared by the pass, the service (service.jobs) and the benchmarks
    (bench/reflections.py, bench/reflection_sweeps.py), so that the service renders
    what the benchmark measures.

    Clustering (§4.3, gl_passes.clustering): bin_scale multiplies the bin counts,
    bin_rule picks how they follow the reflector's sample count, bin_normal the normal
    binned ("mirror": the one the mirror ray is reflected about; "shading": the
    interpolated normal whatever the ray). normal_break > 0 splits each bin into the
    components of its samples whose neighbours' mirror normals differ by at most that
    many degrees (0 = off: clusters are the bins); a component of at least
    min_component × the G-buffer's samples is split off (planar ones grouped per
    plane, curved ones each a cluster when split_curved, else back in their bin).
    Cluster cameras (§4.4): a cluster of at least stage0_dense G-buffer samples places
    e_c (eq. 6's d_n, d_f) from one sample per output pixel, its first sub-sample (None:
    every sample; a small cluster's d_n, d_f would move by a larger fraction of
    themselves, the default is measured in bench/results/reflections_notes.json);
    max_shift clamps the e0 → P_c shift 1 − f; resolution_scale
    multiplies the texel density derived from the cluster's projected sample spacing;
    max_resolution caps an image's side (texels).
    Cluster depth images (§4.5): atlas_max caps the atlas side (texels); atlas_budget
    caps the total image area at that many texels per G-buffer sample (None = no cap;
    the images shrink uniformly but planar mirrors', which keep their exact texel =
    sample grid, cluster_camera.pack_atlas; the default is chosen by the budget sweep
    of bench/reflection_sweeps.py); others_peel adds the other objects' second surface
    to non-planar images (module docstring, step 4).
    Intersection (Alg. 7): thickness is the hit tolerance in units of a step's depth
    span; continuity > 0 enables the crossing rule; slope > 0 the surface-crossing rule
    (continuous surfaces up to that tan of their angle to the view ray); near_steps > 0
    the near-origin rule (module docstring, step 5); block_skip False marches every
    texel (the block skip changes no hit; for tests).
    backface_chunks skips, per cluster camera, the triangle chunks whose every
    triangle faces away from e_c (cluster_camera.backfacing_chunks): back-face
    culling would discard them all, so the images are unchanged (False: for tests).
    Level of detail (§4.5, beyond the thesis): lod_errors are the absolute error
    bounds of the simplified levels (meshoptimizer, built once per scene) as
    fractions of the scene diagonal, finest first (() = full detail only); per
    non-planar cluster image (planar ones stay exact) each object other than the
    reflector is drawn at the coarsest
    level whose error is at most lod_texels texels of that image at the object's
    nearest depth (meshoptimizer's error measure: the surface moves by about that
    many texels' width, up to about twice it, tests/test_lod.py).
    Sampling (§4.2, §4.6): supersample is the G-buffer's ss×ss samples per output
    pixel; glossy_rays the lobe rays per G-buffer sample of a glossy reflector (1 to
    MAX_RAYS; Embree's reference traces the same lobe)."""

    max_resolution: int = 1024
    resolution_scale: float = 1.0
    bin_scale: float = 1.0
    bin_rule: str = "relative"
    bin_normal: str = "mirror"
    normal_break: float = 10.0
    min_component: float = 1 / 1024
    split_curved: bool = True
    thickness: float = 1.0
    atlas_max: int = 4096
    atlas_budget: float | None = 4.0
    max_shift: float = cc.MAX_SHIFT
    stage0_dense: int | None = 4096
    continuity: float = CONTINUITY
    slope: float = SLOPE
    near_steps: int = NEAR_STEPS
    block_skip: bool = True
    others_peel: bool = True
    glossy_rays: int = 8
    supersample: int = 2
    backface_chunks: bool = True
    lod_errors: tuple[float, ...] = (0.0001, 0.00025, 0.001, 0.004)
    lod_texels: float = 1.0

    def __post_init__(self) -> None:
        if not 1 <= self.glossy_rays <= MAX_RAYS:
            raise ValueError(f"glossy_rays must be in [1, {MAX_RAYS}]")
        if self.supersample < 1:
            raise ValueError("supersample must be >= 1")
        if self.max_resolution < 1 or self.atlas_max < 1:
            raise ValueError("max_resolution and atlas_max must be >= 1")
        if self.stage0_dense is not None and self.stage0_dense < 1:
            raise ValueError("stage0_dense must be >= 1 or None")
        if self.atlas_budget is not None and self.atlas_budget <= 0:
            raise ValueError("atlas_budget must be > 0 or None")
        if any(e <= 0 for e in self.lod_errors) or list(self.lod_errors) != sorted(self.lod_errors):
            raise ValueError("lod_errors must be positive and increasing")
        if self.lod_texels <= 0:
            raise ValueError("lod_texels must be > 0")
        if self.bin_normal not in ("mirror", "shading"):
            raise ValueError("bin_normal must be 'mirror' or 'shading'")
        if not 0 <= self.normal_break < 180 or not 0 <= self.min_component <= 1:
            raise ValueError("normal_break must be in [0, 180) degrees and min_component in [0, 1]")

    def replace(self, **changes) -> ClusterSettings:
        """A copy with `changes` applied (validated again)."""
        return replace(self, **changes)


#: The settings the service renders with and the benchmarks measure.
DEFAULT_SETTINGS = ClusterSettings()


class ClusterReflections(Releasable):
    """Reflection renderer on `gl`'s thread with one ClusterSettings (defaults:
    DEFAULT_SETTINGS)."""

    def __init__(self, gl: GLContext, settings: ClusterSettings = DEFAULT_SETTINGS) -> None:
        gl.check_thread()
        self.gl = gl
        self.settings = settings
        self.gbuffer = GBufferPass(gl)
        self._resolved: moderngl.Buffer | None = None  # the frame's outputs (reflect_resolve.comp's planes)
        self.clustering = ClusteringPass(gl, settings.bin_normal)
        self.extent = ClusterExtentPass(gl)
        units = {**UNITS.defines(), "BACKGROUND_DEPTH": repr(BACKGROUND_DEPTH)}
        defines = {**units, "FADE_FRACTION": repr(float(FADE_FRACTION)), "MAX_RAYS": str(MAX_RAYS),
                   "BLOCK": str(BLOCK), "TRACE_GROUP": str(TRACE_GROUP)}
        if settings.continuity > 0:  # the crossing rule is compiled in only when enabled (it costs every step)
            defines["CROSSING"] = "1"
        if settings.slope > 0:  # likewise the surface-crossing and near-origin rules
            defines["SURFACE_CROSSING"] = "1"
        if settings.near_steps > 0:
            defines["NEAR_CROSSING"] = "1"
        if not settings.block_skip:  # exact either way (tests compare the two)
            defines["NO_BLOCK_SKIP"] = "1"
        # Per cluster-image layer: the depth program (layers 0, 1), the peel program (2, 3).
        self.depth_prog = program(gl, "cluster_depth.vert", "cluster_depth.frag", defines=units)
        self.peel_prog = program(gl, "cluster_depth.vert", "cluster_peel.frag", defines=units)
        self.layer_progs = (self.depth_prog, self.depth_prog, self.peel_prog, self.peel_prog)
        self.trace_prog = compute_program(gl, "reflect_trace.comp", defines)
        self._units = units  # the resolve is compiled per supersampling factor, in render()
        self.block_prog = compute_program(gl, "cluster_block_depth.comp", {**units, "BLOCK": str(BLOCK)})
        self.face_normal_prog = compute_program(gl, "face_normals.comp", units)
        self._atlas: list[tuple[moderngl.Framebuffer, moderngl.Texture]] = []  # per layer: framebuffer, depth
        self._owns: list[moderngl.Texture] = []  # layers 0 and 1's own depths, then the peel layers' (unwritten)
        self._pack: moderngl.Texture | None = None  # the layers' depths, written with them
        self._colour_pack: moderngl.Texture | None = None  # the layers' colours, likewise
        self._pack_fbo: moderngl.Framebuffer | None = None
        self._outputs: dict[str, moderngl.Texture] = {}
        self._chunk_cache: dict = {}

    # --- GPU resources -------------------------------------------------------------
    def _atlas_target(self, size: tuple[int, int]) -> list[moderngl.Framebuffer]:
        """The framebuffers of the N_LAYERS atlas layers of the same layout: the other
        objects, the cluster's own reflector, the reflector's second surface and the
        others' second surface. Each layer writes its depth into its own texture (the
        peel layers' u_prev) and into its own channel of one shared pack (self._pack:
        the layers' depths in one texel) and its colour into its channel of one shared
        colour pack (self._colour_pack: pack_colour, common.glsl), so that the march
        reads any layer's depth or colour with one fetch."""
        need = (max(256, -(-size[0] // 256) * 256), max(256, -(-size[1] // 256) * 256))
        have = self._pack.size if self._atlas else (0, 0)
        if not self._atlas or have[0] < need[0] or have[1] < need[1]:
            self._release_atlas()
            ctx = self.gl.ctx
            need = (max(need[0], have[0]), max(need[1], have[1]))
            self._pack = ctx.texture(need, 4, dtype="f4")
            self._pack_fbo = ctx.framebuffer([self._pack])
            self._colour_pack = ctx.texture(need, 4, dtype="u4")
            # The layers' own depths: layers 0 and 1 are peeled (u_prev of layers 3 and
            # 2); the peel layers share one target with writes masked off (on llvmpipe
            # every written colour output costs its fragments).
            self._owns = [ctx.texture(need, 1, dtype="f4") for _ in range(3)]
            for tex in (self._pack, self._colour_pack, *self._owns):
                tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
            for layer in range(N_LAYERS):
                depth = ctx.depth_texture(need)
                # Fragment outputs: 0 the layer's depth, 1 the pack, 2 the colour pack;
                # the framebuffer keeps the layer's channel of both packs.
                fbo = ctx.framebuffer([self._owns[min(layer, 2)], self._pack, self._colour_pack], depth)
                channel = tuple(c == layer for c in range(4))
                fbo.color_mask = ((layer < 2,) * 4, channel, channel)
                self._atlas.append((fbo, depth))
        return [fbo for fbo, _ in self._atlas]

    def _release_atlas(self) -> None:
        for fbo, depth in self._atlas:
            release_framebuffer(fbo)
            depth.release()
        if self._atlas:
            release_framebuffer(self._pack_fbo)
            for tex in (self._pack, self._colour_pack, *self._owns):
                tex.release()
        self._atlas, self._owns = [], []

    def _block_bounds(self, used: tuple[int, int]) -> tuple[moderngl.Texture, moderngl.Texture]:
        """Per BLOCK×BLOCK block of the pack and per layer, the minimum and the
        maximum stored (non-background) depth."""
        csize = (-(-self._pack.size[0] // BLOCK), -(-self._pack.size[1] // BLOCK))
        block_min = self._texture("block_min", csize)
        block_max = self._texture("block_max", csize)
        if used[0] > 0 and used[1] > 0:
            UNITS.bind_image("u_block_min_image", block_min, read=False, write=True)
            UNITS.bind_image("u_block_max_image", block_max, read=False, write=True)
            UNITS.bind_texture("u_pack", self._pack)
            p = self.block_prog
            set_uniform(p, "u_size", tuple(int(x) for x in used))
            p.run((-(-used[0] // BLOCK) + 7) // 8, (-(-used[1] // BLOCK) + 7) // 8, 1)
            self.gl.ctx.memory_barrier()
        return block_min, block_max

    @staticmethod
    def _bind_gbuffer(bins: moderngl.Texture, tex: dict[str, moderngl.Texture]) -> None:
        """Bind the sample → bin map and the G-buffer textures to their samplers."""
        UNITS.bind_texture("u_bins", bins)
        for name, key in (("u_tri", "tri_id"), ("u_normal", "normal"), ("u_position", "position"),
                          ("u_color", "color"), ("u_material", "material")):
            UNITS.bind_texture(name, tex[key])

    def _texture(self, key: str, size: tuple[int, int], components: int = 4) -> moderngl.Texture:
        tex = self._outputs.get(key)
        if tex is None or tex.size != size:
            if tex is not None:
                tex.release()
            tex = self.gl.ctx.texture(size, components, dtype="f4")
            tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
            self._outputs[key] = tex
        return tex

    # --- the technique -------------------------------------------------------------
    def render(self, scene_gpu: SceneGPU, camera: Camera, glossy_rays: int | None = None,
               supersample: int | None = None, method: str = "clusters", sync_timings: bool = True,
               diagnostics: bool = False) -> ClusterReflectionResult:
        """Reflections for `camera` (near/far fitted to the scene when absent).
        method: "clusters" (Alg. 6) or "envmap" (baseline); glossy_rays and supersample
        default to the settings'. diagnostics=True also reads back what the cluster
        images hold (result.diagnostics, ClusterDiagnostics; after the timed steps,
        not in timings_ms)."""
        self.gl.check_thread()
        if method not in ("clusters", "envmap"):
            raise ValueError(f"method must be 'clusters' or 'envmap', got {method!r}")
        st = self.settings.replace(
            glossy_rays=self.settings.glossy_rays if glossy_rays is None else int(glossy_rays),
            supersample=self.settings.supersample if supersample is None else int(supersample))
        glossy_rays, ss = st.glossy_rays, st.supersample
        ctx = self.gl.ctx
        scene = scene_gpu.scene
        cam = camera if camera.near is not None else camera.fit_clip(scene.bounds)
        W, H = cam.width, cam.height
        ss_cam = cam.with_size(W * ss, H * ss)
        clock = LapClock(ctx, sync=sync_timings)
        lap = clock.lap

        # 0. camera-independent per-scene records (cached: a later frame of the scene pays nothing)
        cache_hit = self._chunk_cache_hit(scene_gpu)
        records = self._chunks(scene_gpu, lods=method == "clusters")
        lap("scene_setup")
        # 1. supersampled G-buffer
        tex = self.gbuffer.draw(scene_gpu, ss_cam).textures
        lap("gbuffer")
        # 2. clustering
        eye = np.asarray(cam.eye, np.float64)
        UNITS.bind_storage("FaceNormals", records["face_normals"])
        min_samples = max(1, round(st.min_component * ss_cam.width * ss_cam.height))
        stats = self.clustering.run(tex, scene.bounds, len(scene.objects), eye, st.bin_scale, st.bin_rule,
                                    st.normal_break, min_samples, st.split_curved, timed=diagnostics)
        lap("clustering")
        # 3. cluster cameras
        bins = self.clustering.bins_tex
        size = bins.size
        self._bind_gbuffer(bins, tex)
        cams = cc.initial_cameras(stats, cam, scene.materials, scene.diagonal)
        atlas_size = (0, 0)
        drawn = 0
        if method == "clusters" and cams:
            ext0 = self.extent.run(0, cc.stage0_frames(cams, st.stage0_dense), self.clustering.samples, eye, ss)
            cc.place_centers(cams, ext0, stats, scene.diagonal, st.max_shift)
            ext1 = self.extent.run(1, cc.stage1_frames(cams), self.clustering.samples, eye, ss)
            cc.finish_cameras(cams, ext1, cam, ss, st.resolution_scale, st.max_resolution)
            budget = st.atlas_budget * size[0] * size[1] if st.atlas_budget else None
            atlas_size = cc.pack_atlas(cams, st.atlas_max, budget)
        lap("cluster_cameras")
        # 4. cluster depth images
        layers = self._atlas_target(atlas_size if atlas_size[0] else (1, 1))
        if method == "clusters" and cams:
            drawn = self._draw_atlas(scene_gpu, cams, layers, atlas_size)
        lap("depth_images")
        # 5. intersection
        frames = np.asarray([c.frame() for c in cams], np.float32).reshape(-1, cc.FRAME_FLOATS)
        self.extent.upload_frames(frames if len(frames) else np.zeros((1, cc.FRAME_FLOATS), np.float32))
        samples = self._texture("samples", size)
        pack = self._pack
        block_min, block_max = self._block_bounds(atlas_size)
        UNITS.bind_image("u_out", samples, read=False, write=True)  # after the block-bounds pass (shared unit)
        self._bind_gbuffer(bins, tex)
        for name, layers_tex in (("u_pack", pack), ("u_colour_pack", self._colour_pack), ("u_block_min", block_min),
                                 ("u_block_max", block_max)):
            UNITS.bind_texture(name, layers_tex)
        p = self.trace_prog
        set_uniform(p, "u_eye", eye)
        set_uniform(p, "u_sun", np.asarray(scene.sun_direction))
        set_uniform(p, "u_mode", 1 if method == "envmap" else 0)
        set_uniform(p, "u_rays", int(glossy_rays))
        set_uniform(p, "u_thickness", st.thickness)
        set_uniform(p, "u_continuity", st.continuity)
        set_uniform(p, "u_slope", st.slope)
        set_uniform(p, "u_near_steps", st.near_steps)
        if "u_lobe" in p:
            lobe = np.zeros((MAX_RAYS, 2), np.float32)
            lobe[:glossy_rays] = lobe_offsets(glossy_rays)
            p["u_lobe"].write(lobe.tobytes())
        self.clustering.samples.dispatch(p, TRACE_GROUP)
        ctx.memory_barrier()
        lap("intersection")
        # 6. blend + ss×ss resolve + readback
        self._resolved = grown_buffer(ctx, self._resolved, RESOLVED_PLANES * 4 * W * H)
        UNITS.bind_storage("Resolved", self._resolved)
        UNITS.bind_texture("u_reflected", samples)
        p = compute_program(self.gl, "reflect_resolve.comp", {**self._units, "SS": str(ss)})  # cached per ss
        set_uniform(p, "u_size", (W, H))
        p.run((W + 7) // 8, (H + 7) // 8, 1)
        ctx.memory_barrier()
        color, specular, reflected, ray_length, diffuse, coverage = read_planes(
            self._resolved, [(H, W, 3), (H, W), (H, W, 3), (H, W), (H, W, 3), (H, W)])
        lap("resolve")
        timings = clock.ms
        timings["total"] = clock.total_ms()
        diag = self._diagnostics(cams, pack, atlas_size) if diagnostics else None
        return ClusterReflectionResult(
            color=color, reflected=reflected, diffuse=diffuse, specular=specular, reflective=coverage > 0,
            ray_length=ray_length.astype(np.float64),
            method=method, supersample=ss, n_clusters=len(cams), cameras=cams, timings_ms=timings,
            atlas_size=atlas_size, drawn_chunks=drawn, diagnostics=diag, cache_hits={"scene_setup": cache_hit},
            clustering_ms=dict(self.clustering.pass_ms) if diagnostics else {})

    def _diagnostics(self, cams: list[ClusterCamera], pack: moderngl.Texture,
                     atlas_size: tuple[int, int]) -> ClusterDiagnostics:
        """Read back the sample → cluster map and the cluster images' stored depths
        (ClusterDiagnostics; from the packed layers) of the frame just rendered."""
        aw, ah = (int(atlas_size[0]), int(atlas_size[1])) if atlas_size[0] > 0 else (0, 0)
        if aw > 0 and ah > 0:
            depths = np.moveaxis(read_texture(pack, (0, 0, aw, ah)), -1, 0)
        else:
            depths = np.full((N_LAYERS, 1, 1), BACKGROUND_DEPTH, np.float32)
        k = len(cams)
        vps = np.zeros((k, 4), np.int64)
        for i, c in enumerate(cams):
            x, y, w, h = (int(v) for v in c.atlas)
            if c.valid and w > 0 and h > 0 and aw > 0:
                vps[i] = (x, ah - (y + h), w, h)  # GL bottom-left → top row of the flipped read-back
        return ClusterDiagnostics(
            cluster_of_sample=self.clustering.cluster_of_samples(), layer_depths=depths.astype(np.float32),
            viewports=vps, view_proj=np.asarray([c.view_projection() for c in cams], np.float64).reshape(k, 4, 4),
            clip_planes=np.asarray([[*c.plane_normal, c.clip_offset] for c in cams], np.float64).reshape(k, 4))

    def render_envmap(self, scene_gpu: SceneGPU, camera: Camera, glossy_rays: int = 8,
                      supersample: int = 2) -> ClusterReflectionResult:
        """Environment-map baseline (the service's method="envmap")."""
        return self.render(scene_gpu, camera, glossy_rays, supersample, method="envmap")

    def _chunk_cache_hit(self, scene_gpu: SceneGPU) -> bool:
        cached = self._chunk_cache.get(id(scene_gpu))
        return cached is not None and cached["scene"] is scene_gpu.scene and cached["vbo"] is scene_gpu.vbo

    def _lod_table(self, scene_gpu: SceneGPU, error: float) -> dict:
        """The scene's objects simplified (meshoptimizer, absolute error ≤ `error`
        scene units, welded and sided: gl_passes.lod) in one index buffer over the
        scene's vertex buffer: its chunk table, `error`, the buffer and its VAOs for
        the depth and peel programs."""
        scene = scene_gpu.scene
        parts, ranges, f0 = [], [], 0
        for o, off in zip(scene.objects, scene.vertex_offsets[:-1], strict=True):
            tri = lod_faces(o.vertices, o.normals, o.faces, error).astype(np.int64) + int(off)
            parts.append(tri.astype(np.uint32))
            ranges.append((f0, len(tri)))
            f0 += len(tri)
        faces = np.concatenate(parts) if parts else np.zeros((0, 3), np.uint32)
        table = chunk_table(scene.vertices, faces, ranges)
        ibo = self.gl.ctx.buffer(np.ascontiguousarray(faces, np.uint32).tobytes() or bytes(12))
        vaos = tuple(self.gl.ctx.vertex_array(prog, [(scene_gpu.vbo, *scene_gpu.vertex_format(prog))],
                                              index_buffer=ibo, index_element_size=4)
                     for prog in (self.depth_prog, self.peel_prog))
        return {"table": table, "error": float(error), "ibo": ibo, "vaos": vaos, "triangles": len(faces)}

    @staticmethod
    def _release_entry(entry: dict) -> None:
        for lod in entry["lods"] or ():
            for vao in lod["vaos"]:
                vao.release()
            lod["ibo"].release()
        if entry["face_normals"] is not None:
            entry["face_normals"].release()

    def _face_normals(self, scene_gpu: SceneGPU) -> moderngl.Buffer:
        """(3·F,) float32 storage buffer: every triangle's unit geometric normal
        (face_normals.comp, from the scene's vertex and index buffers)."""
        n = len(scene_gpu.scene.faces)
        buf = self.gl.ctx.buffer(reserve=max(12 * n, 12))
        UNITS.bind_storage("MeshVerts", scene_gpu.vbo)
        UNITS.bind_storage("MeshFaces", scene_gpu.ibo)
        UNITS.bind_storage("FaceNormals", buf)
        groups = -(-n // 256)
        row = min(groups, 65535)  # GL's guaranteed work-group count per dimension
        set_uniform(self.face_normal_prog, "u_faces", n)
        set_uniform(self.face_normal_prog, "u_row_groups", row)
        if n:
            self.face_normal_prog.run(row, -(-groups // row), 1)
            self.gl.ctx.memory_barrier()
        return buf

    def _chunks(self, scene_gpu: SceneGPU, lods: bool = True) -> dict:
        """The camera-independent records of a scene (cached per SceneGPU, CHUNK_CACHE
        scenes): under "face_normals" every triangle's geometric normal
        (_face_normals); the unit of frustum culling for the cluster images, per-object runs of
        at most chunks.CHUNK triangles (finer than SceneGPU.object_bounds, so large objects,
        floors and walls, are mostly culled) with AABBs and normal cones (SceneGPU.chunks); under "lods"
        the same for each level of detail of settings.lod_errors (× scene diagonal), built
        on the first call that asks for them (lods=True: the cluster method)."""
        key = id(scene_gpu)
        if not self._chunk_cache_hit(scene_gpu):
            old = self._chunk_cache.pop(key, None)
            if old is not None:
                self._release_entry(old)
            entry = {"scene": scene_gpu.scene, "vbo": scene_gpu.vbo, "table": scene_gpu.chunks, "lods": None,
                     "face_normals": None}
            self._chunk_cache[key] = entry  # registered first: released with the cache whatever follows
            entry["face_normals"] = self._face_normals(scene_gpu)
            while len(self._chunk_cache) > CHUNK_CACHE:
                self._release_entry(self._chunk_cache.pop(next(iter(self._chunk_cache))))
        cached = self._chunk_cache[key]
        if lods and cached["lods"] is None:
            cached["lods"] = []  # filled in place: what is built is released with the cache whatever follows
            for rel in self.settings.lod_errors:
                cached["lods"].append(self._lod_table(scene_gpu, rel * scene_gpu.scene.diagonal))
        return cached

    def _lod_levels(self, c: ClusterCamera, object_bounds: np.ndarray, errors: list[float]) -> np.ndarray:
        """(n_objects,) int: per object the coarsest level (0 = full detail, l ≥ 1 =
        errors[l-1]) whose error is at most settings.lod_texels texels of the cluster
        image where the object is nearest to e_c (its AABB's least depth along the
        camera axis, at least near; texel = the atlas viewport's tangent extent per
        texel × depth)."""
        lvl = np.zeros(len(object_bounds), np.int64)
        if not errors or c.atlas[2] <= 0 or c.atlas[3] <= 0:
            return lvl
        lo, hi = object_bounds[:, 0], object_bounds[:, 1]
        fwd = np.asarray(c.forward, np.float64)
        depth = np.minimum(lo * fwd, hi * fwd).sum(axis=1) - float(fwd @ c.center)
        depth = np.maximum(depth, c.near)
        u0, v0, u1, v1 = c.rect
        texel = depth * max((u1 - u0) / c.atlas[2], (v1 - v0) / c.atlas[3])
        for level, err in enumerate(errors, start=1):
            lvl[err <= self.settings.lod_texels * texel] = level
        return lvl

    def _draw_atlas(self, scene_gpu: SceneGPU, cams: list[ClusterCamera], fbos: list[moderngl.Framebuffer],
                    atlas_size: tuple[int, int]) -> int:
        """Render every cluster image into its atlas viewport: layer 0 = the objects
        other than the cluster's reflector, layer 1 = the reflector itself, layer 2 its
        second surface, layer 3 the others' second surface; only the triangle chunks
        that survive frustum and back-face culling are drawn (adjacent visible chunks
        of one object in one draw), the other objects at their level of detail
        (_lod_levels; the reflector always at full detail: the trace's self-hit test
        finds the sample's own triangle's plane in its layers). Returns the number of
        chunks drawn."""
        ctx = self.gl.ctx
        ch = self._chunks(scene_gpu)
        tables = [ch["table"], *(lod["table"] for lod in ch["lods"])]
        errors = [lod["error"] for lod in ch["lods"]]
        sun = np.asarray(scene_gpu.scene.sun_direction)
        materials = scene_gpu.scene.materials
        ctx.enable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        ctx.depth_func = "<"
        ctx.front_face = "ccw"
        ctx.cull_face = "back"
        ctx.enable_direct(GL_CLIP_DISTANCE0)
        drawn = 0
        used = (0, 0, *atlas_size)  # the packed rectangle (some of it in no viewport)
        # One clear of the frame's atlas area: the pack to the background, the layers' depth
        # attachments only (their colour is read only where the pack says this frame
        # drew it).
        self._pack_fbo.clear(BACKGROUND_DEPTH, BACKGROUND_DEPTH, BACKGROUND_DEPTH, BACKGROUND_DEPTH, viewport=used)
        for fbo in fbos:
            mask = fbo.color_mask
            fbo.color_mask = tuple((False,) * 4 for _ in mask)
            fbo.clear(depth=1.0, viewport=used)
            fbo.color_mask = mask
        albedo = [tuple(float(x) for x in m[:3]) for m in materials]  # per material id (object k: k + 1)
        plans = []  # per valid cluster: its uniforms and, for the reflector (True) and the others (False), its draws
        for c in cams:
            if not c.valid:
                continue
            own = c.object_id - 1
            # Planar clusters stay exact (their texels are the samples' mirror rays): full detail.
            level = self._lod_levels(c, scene_gpu.object_bounds, [] if c.planar else errors)
            level[own] = 0
            draws: dict[bool, list] = {True: [], False: []}  # [(level, [(first, count, albedo)])]
            for lv in np.unique(level).tolist():
                t = tables[lv]
                v = cc.visible_boxes(c, t.bounds, t.corners) & (level[t.obj] == lv)
                if self.settings.backface_chunks:
                    v &= ~cc.backfacing_chunks(c, t.cones)
                for mine in (True, False):  # levels > 0 hold only other objects (the reflector is at level 0)
                    sel = np.flatnonzero(v & ((t.obj == own) == mine))
                    if len(sel):
                        draws[mine].append((lv, len(sel), [(f, n, albedo[k + 1]) for k, f, n in runs(t, sel)]))
            uniforms = (("u_view", c.view_matrix()), ("u_view_proj", c.view_projection()),
                        ("u_clip_plane", np.array([*c.plane_normal, c.clip_offset])), ("u_sun", sun))
            plans.append((c, uniforms, draws))
        # Layer by layer, so that each layer's framebuffer is bound once (a software
        # rasteriser flushes its binned triangles at every framebuffer change); the peel
        # layers read finished layers 0 and 1.
        for layer, fbo in enumerate(fbos):
            peel, mine = layer >= 2, layer in (1, 2)
            prog = self.layer_progs[layer]
            if peel:
                UNITS.bind_texture("u_prev", self._owns[1 if layer == 2 else 0])
            fbo.use()
            for c, uniforms, draws in plans:
                if layer == 3 and (c.planar or not self.settings.others_peel):
                    continue  # from a planar cluster's e0 nothing on its rays is hidden
                for name, value in uniforms:
                    set_uniform(prog, name, value)
                fbo.viewport = c.atlas
                for lv, n_chunks, items in draws[mine]:
                    drawn += n_chunks
                    vao = scene_gpu.vao(prog) if lv == 0 else ch["lods"][lv - 1]["vaos"][peel]
                    self._draw_runs(prog, vao, items)
        ctx.disable_direct(GL_CLIP_DISTANCE0)
        ctx.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        return drawn

    @staticmethod
    def _draw_runs(prog, vao, items: list[tuple[int, int, tuple[float, float, float]]]) -> None:
        """Draw runs of consecutive chunks of one object (chunks.runs): per run its
        first face, face count and albedo."""
        albedo = prog["u_albedo"] if "u_albedo" in prog else None
        for first, count, rgb in items:
            if albedo is not None:
                albedo.value = rgb
            vao.render(moderngl.TRIANGLES, vertices=3 * count, first=3 * first)

    def forget_scene(self, scene_gpu: SceneGPU) -> None:
        """Release what is cached of `scene_gpu` (its face normals, levels of detail
        and their vertex arrays over its buffers): its owner is releasing it."""
        self.gl.check_thread()
        if self._chunk_cache_hit(scene_gpu):
            self._release_entry(self._chunk_cache.pop(id(scene_gpu)))

    def release(self) -> None:
        self.gl.check_thread()
        self.gbuffer.release()
        if self._resolved is not None:
            self._resolved.release()
            self._resolved = None
        self.clustering.release()
        self.extent.release()
        self._release_atlas()
        for entry in self._chunk_cache.values():
            self._release_entry(entry)
        self._chunk_cache.clear()
        for t in self._outputs.values():
            t.release()
        self._outputs.clear()
