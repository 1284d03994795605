"""Request and response bodies of the HTTP API (pydantic v2).

Validation errors become HTTP 422 responses whose ``detail`` entries carry the
field's location (e.g. ``["body", "camera", "eye"]``) and a message naming the
problem. Limits that depend on the service settings (frame size) are checked by
the route, also with 422.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, StrictBool, StrictFloat, StrictInt, field_validator, model_validator

from scenes.builtin import MAX_DETAIL, MIN_DETAIL
from scenes.camera import Camera, CameraError
from scenes.lights import MIN_LIGHT_SINE, light_sine
from scenes.rig import peeling_camera
from service.excerpts import quoted

#: Strict scalars (issue 15): ``true`` is not a number, ``"64"`` is not a number,
#: ``"no"`` is not a boolean; an integer is accepted where a float is expected.
Number = StrictFloat
#: Largest magnitude of a camera or light coordinate: positions are rendered in float32,
#: and beyond this their differences (view direction, light edges) lose all precision.
MAX_COORDINATE = 1e12
#: A coordinate (the bounds are in the OpenAPI document; ``_finite_vec3`` checks them first
#: with a message naming the vector).
Coordinate = Annotated[Number, Field(ge=-MAX_COORDINATE, le=MAX_COORDINATE)]
Vec3 = tuple[Coordinate, Coordinate, Coordinate]
#: Smallest vertical field of view in degrees: below it the projection's 1/tan(fov/2)
#: overflows the float32 precision of the depth and position buffers.
MIN_FOV = 0.01

#: Soft-shadow occluders (thesis Ch. 3, Alg. 5): the original scene, reconstructions of
#: depth images by method, or the exact Embree truth.
SHADOW_METHODS = ("geometry", "non_redundant", "conventional", "peeling", "raytrace")
#: Most light samples per side of a soft-shadow light (k² shadow maps).
MAX_SHADOW_SAMPLES = 32
#: Largest reference-image side of a reconstruction (a 2048² image gives up to ~8 M triangles).
MAX_RECONSTRUCTION_RES = 2048
#: cluster: cluster depth images (thesis Ch. 4, GL); raytrace: Embree reference;
#: envmap: environment map only (baseline); none: local shading only.
REFLECTION_METHODS = ("none", "cluster", "raytrace", "envmap")
#: Glossy lobe rays per reflective sample (thesis §4.6 uses 8–49).
MAX_GLOSSY_RAYS = 64
#: Stream message ids are below this (a JSON number a browser holds exactly).
MAX_MESSAGE_ID = 2**53


def _finite_vec3(name: str, v: Any, what: str = "camera") -> Any:
    if isinstance(v, (list, tuple)) and len(v) == 3:
        for x in v:
            if isinstance(x, (int, float)) and not isinstance(x, bool):
                if isinstance(x, float) and not math.isfinite(x):
                    raise ValueError(f"{what} {name} must be finite numbers (got NaN or infinity)")
                if abs(x) > MAX_COORDINATE:
                    raise ValueError(f"{what} {name} coordinate {_magnitude(x)} is out of range: coordinates must "
                                     f"be within ±{MAX_COORDINATE:.0e}")
    return v


def _magnitude(x: int | float) -> str:
    """`x` as ``.6g``; an integer too large for a float (valid JSON) by its digit count."""
    try:
        return f"{x:.6g}"
    except OverflowError:
        return f"(an integer of {len(str(abs(x))):,} digits)"


class CameraSpec(BaseModel):
    """A pinhole camera: eye, target, up (world units), vertical fov in degrees.
    Near/far are fitted to the scene bounds by the service."""

    model_config = ConfigDict(extra="forbid")

    eye: Vec3 = Field(description="camera position", examples=[[0.0, 1.0, 3.5]])
    target: Vec3 = Field(description="point the camera looks at", examples=[[0.0, 1.0, 0.0]])
    up: Vec3 = Field(default=(0.0, 1.0, 0.0), description="up direction (not parallel to target - eye)")
    fov: Number = Field(default=45.0, ge=MIN_FOV, lt=180.0, allow_inf_nan=False,
                        description=f"vertical field of view in degrees, at least {MIN_FOV}")

    @field_validator("eye", "target", "up", mode="before")
    @classmethod
    def _finite(cls, v: Any, info: Any) -> Any:
        return _finite_vec3(info.field_name, v)

    @model_validator(mode="after")
    def _geometry(self) -> CameraSpec:
        """eye != target, up non-zero and not parallel to the view direction."""
        try:
            Camera(eye=self.eye, target=self.target, up=self.up, fov=self.fov, width=1, height=1)
        except CameraError as exc:
            raise ValueError(str(exc)) from exc
        return self


class LightSpec(BaseModel):
    """A rectangular area light: centre C and edge vectors u, v (world units); the
    rectangle is C + a·u + b·v for a, b in [−1/2, 1/2]; it lights the side u × v points away from."""

    model_config = ConfigDict(extra="forbid")

    center: Vec3
    u: Vec3
    v: Vec3

    @field_validator("center", "u", "v", mode="before")
    @classmethod
    def _finite(cls, v: Any, info: Any) -> Any:
        return _finite_vec3(info.field_name, v, "light")

    @model_validator(mode="after")
    def _rectangle(self) -> LightSpec:
        if light_sine(self.u, self.v) < MIN_LIGHT_SINE:  # the rule light_normal applies
            raise ValueError("light u and v must be non-zero and not parallel (their angle's sine under "
                             f"{MIN_LIGHT_SINE:g})")
        return self


#: Which sides of the surfaces a reconstruction's depth images keep (`gl_passes.depth_images`).
Sides = Literal["front", "both"]
SIDES_DOC = ("surfaces the depth images keep: front (back faces culled, as the thesis's §2.3) or both "
             "(a single-sided surface seen from behind, e.g. a room's walls and ceiling from a light outside, "
             "then still casts its shadow)")


class SoftShadowSpec(BaseModel):
    """Soft shadows of a rectangular area light (thesis Ch. 3, Alg. 5) from k×k
    shadow maps whose occluders are the original scene (`geometry`) or the
    reconstruction of depth images from the light's 4 corners (`non_redundant`,
    `conventional`) or of 4 peeling layers from its centre (`peeling`);
    `raytrace` is the exact Embree truth."""

    model_config = ConfigDict(extra="forbid")

    light: LightSpec | None = Field(default=None, description="omitted: a light sized to the scene "
                                                                "(diagonal = scene diagonal, from the sun's side)")
    samples: StrictInt = Field(default=16, ge=1, le=MAX_SHADOW_SAMPLES, description="k: k×k light samples")
    method: Literal["geometry", "non_redundant", "conventional", "peeling", "raytrace"] = Field(
        default="non_redundant", description="the occluders of the shadow maps: geometry (the scene), the "
        "reconstruction of non_redundant or conventional images from the light's corners or of peeling layers "
        "from its centre; or raytrace (Embree, exact). All but raytrace need the whole scene box in front of "
        "the light (422). The first frame under a light builds its reconstruction and k² maps (seconds to tens "
        "of seconds at the defaults on a CPU rasteriser); later frames under it reuse them")
    reconstruction: Literal["hybrid", "grid", "compact"] = Field(
        default="hybrid", description="hybrid (Alg. 4), grid (baseline) or compact (simplified hybrid)")
    resolution: StrictInt = Field(default=1024, ge=16, le=MAX_RECONSTRUCTION_RES,
                            description="reference-image side in pixels")
    sides: Sides = Field(default="front", description=SIDES_DOC + "; geometry and raytrace always see both")


class Effects(BaseModel):
    """Effects applied to a frame: reflections by method (2×2 supersampled), with
    `glossy_rays` lobe rays per sample on glossy surfaces; or soft shadows of an area
    light (one of the two per frame: both together are 422)."""

    model_config = ConfigDict(extra="forbid")

    soft_shadows: SoftShadowSpec | None = Field(default=None, description="soft shadows (thesis Ch. 3)")
    reflections: str = Field(default="none", description=f"reflection method; one of {list(REFLECTION_METHODS)}",
                             json_schema_extra={"enum": list(REFLECTION_METHODS)})
    glossy_rays: StrictInt = Field(default=8, ge=1, le=MAX_GLOSSY_RAYS, description="lobe rays per glossy sample")

    @field_validator("reflections")
    @classmethod
    def _reflections(cls, v: str) -> str:
        if v not in REFLECTION_METHODS:
            raise ValueError(
                f"reflections method {quoted(v)} is not available; supported: {', '.join(REFLECTION_METHODS)}")
        return v

    @model_validator(mode="after")
    def _one_effect(self) -> Effects:
        if self.soft_shadows is not None and self.reflections != "none":
            raise ValueError("soft_shadows and reflections cannot be combined in one frame yet")
        return self


#: The channels of a frame's EXR, by effect (service.worker, service.effects, service.soft_shadows).
FRAME_EXR_CHANNELS = ("RGB, Z, N.xyz, id, object (with reflections: RGB, reflected.RGB, diffuse.RGB, specular, "
                      "ray_length; with soft shadows also visible)")


class FrameRequest(BaseModel):
    """Render one frame of a stored scene."""

    model_config = ConfigDict(extra="forbid", json_schema_extra={"examples": [{
        "camera": {"eye": [0.0, 1.0, 3.5], "target": [0.0, 1.0, 0.0]}, "width": 256, "height": 256,
        "format": "png"}]})

    camera: CameraSpec
    width: StrictInt = Field(default=512, ge=1, description="pixels; at most the service's max_width")
    height: StrictInt = Field(default=512, ge=1, description="pixels; at most the service's max_height")
    format: Literal["png", "exr"] = Field(
        default="png", description=f"png: sRGB colour; exr: linear float channels {FRAME_EXR_CHANNELS}")
    effects: Effects = Field(default_factory=Effects)
    cull_back_faces: StrictBool = Field(default=True, description="back-face culling of the camera's view (on, "
                                        "as the thesis); off is 422 with reflections, whose passes and truth "
                                        "cull back faces throughout")

    @model_validator(mode="after")
    def _camera_is_valid(self) -> FrameRequest:
        self.to_camera()  # CameraError is a ValueError → 422 naming the problem
        if not self.cull_back_faces and self.effects.reflections != "none":
            raise ValueError("cull_back_faces false cannot be combined with reflections: their passes and "
                             "their Embree truth cull back faces throughout (as the thesis)")
        return self

    def to_camera(self) -> Camera:
        """The scenes.camera.Camera (without near/far) this request describes."""
        c = self.camera
        try:
            return Camera(eye=c.eye, target=c.target, up=c.up, fov=c.fov, width=self.width, height=self.height)
        except CameraError as exc:
            raise ValueError(str(exc)) from exc


class StreamRequest(FrameRequest):
    """A camera message on ``/scenes/{id}/stream``: the frames endpoint's camera, size and
    effects, and an optional ``id`` the frame answering it echoes (the client's latency
    clock). The stream picks the encoding (JPEG while the camera moves, PNG at rest)."""

    model_config = ConfigDict(extra="forbid", json_schema_extra={"examples": [{
        "id": 1, "camera": {"eye": [0.0, 1.0, 3.5], "target": [0.0, 1.0, 0.0]}, "width": 320, "height": 240,
        "effects": {"reflections": "cluster"}}]})

    id: StrictInt | None = Field(default=None, ge=0, lt=MAX_MESSAGE_ID,
                                 description="echoed in the answering frame's stats")
    format: Literal["png"] = Field(default="png", description="not used: the stream sends JPEG while the camera "
                                                             "moves and PNG once it rests")


class BuiltinParams(BaseModel):
    """Parameters of a built-in procedural scene."""

    model_config = ConfigDict(extra="forbid")

    detail: Number = Field(default=1.0, ge=MIN_DETAIL, le=MAX_DETAIL, allow_inf_nan=False,
                           description="tessellation scale")
    seed: StrictInt = Field(default=0, ge=0, lt=2**63, description="random seed of the procedural generator")


class BuiltinSceneRequest(BaseModel):
    """``POST /scenes`` JSON body: register a built-in scene (id = hash of name + params)."""

    model_config = ConfigDict(extra="forbid", json_schema_extra={"examples": [
        {"builtin": "cornell", "params": {"detail": 1.0, "seed": 0}}]})

    builtin: str = Field(description="built-in scene name (GET /scenes lists them)")
    params: BuiltinParams = Field(default_factory=BuiltinParams)


class SceneInfo(BaseModel):
    """A stored or built-in scene."""

    id: str = Field(description="sha256 content address (64 lowercase hex digits)")
    kind: Literal["upload", "builtin"]
    name: str
    triangles: int = Field(description="triangle count (an estimate for built-ins: see triangles_estimated)")
    triangles_estimated: bool = False
    format: str | None = Field(default=None, description="upload format (glb, gltf, obj, ply)")
    size_bytes: int | None = None
    objects: int | None = None
    bounds: list[list[float]] | None = Field(default=None, description="[[min x,y,z], [max x,y,z]] (uploads)")
    builtin: str | None = None
    params: dict[str, Any] | None = None
    description: str | None = None
    default: bool = Field(default=False, description="a built-in default entry (always present, not deletable)")
    created_at: float = Field(description="seconds since the epoch")


class SceneList(BaseModel):
    scenes: list[SceneInfo]


class Readiness(BaseModel):
    ready: bool
    renderer: str | None = None
    backend: str | None = None
    software: bool | None = None
    gl_version: str | None = None
    error: str | None = None


#: Most images in one depth-image set (the NR shader binds one texture per previous image).
MAX_SET_IMAGES = 16
#: Most intermediate views for the view-dependent metrics of one request.
MAX_METRIC_VIEWS = 256


def check_peeling_camera(method: str, cameras: list[Camera] | None) -> None:
    """ValueError (a 422 naming the problem) when `method` is peeling and the
    peeling viewpoint of `cameras` (``scenes.rig.peeling_camera``) is invalid."""
    if method == "peeling" and cameras:
        try:
            peeling_camera(cameras)
        except CameraError as exc:
            raise ValueError(str(exc)) from exc


class DepthImagesRequest(BaseModel):
    """``POST /scenes/{id}/depth-images``: a depth-image set (thesis Ch. 2).

    Cameras come from ``cameras`` or, when omitted, from the Fig. 8 rig (three
    viewpoints around the scene; peeling from their centroid). ``peeling`` renders
    ``layers`` layers from one viewpoint: the single given camera, or the eyes'
    centroid looking at the first camera's target."""

    model_config = ConfigDict(extra="forbid", json_schema_extra={"examples": [
        {"method": "non_redundant", "width": 256, "height": 256, "metrics": True}]})

    cameras: list[CameraSpec] | None = Field(
        default=None, min_length=1, max_length=MAX_SET_IMAGES,
        description="reference viewpoints in rendering order; omitted → the Fig. 8 rig")
    method: Literal["conventional", "non_redundant", "peeling"] = "non_redundant"
    redundancy: Literal["pixel", "visibility"] = Field(
        default="pixel", description="non_redundant only: pixel (GL, Alg. 3) or visibility (Embree, Alg. 2)")
    width: StrictInt = Field(default=512, ge=1)
    height: StrictInt = Field(default=512, ge=1)
    layers: StrictInt = Field(default=3, ge=1, le=MAX_SET_IMAGES, description="peeling layers")
    format: Literal["exr", "npz"] = Field(
        default="exr", description="exr: one part per image (RGB, Z, N, P, id); npz: stacked arrays")
    metrics: StrictBool = Field(default=False, description="add the four §2.3.2 sampling metrics (JSON response)")
    intermediate_views: StrictInt = Field(default=16, ge=1, le=MAX_METRIC_VIEWS,
                                    description="intermediate views for the useful/available metrics")
    seed: StrictInt = Field(default=0, ge=0, lt=2**63, description="seed of the intermediate views")

    @model_validator(mode="after")
    def _valid_set(self) -> DepthImagesRequest:
        if "redundancy" in self.model_fields_set and self.method != "non_redundant":
            raise ValueError(f"redundancy applies to method non_redundant only, not {self.method}")
        check_peeling_camera(self.method, self.to_cameras())
        return self

    def to_cameras(self) -> list[Camera] | None:
        """The requested cameras (without near/far), or None for the rig."""
        if self.cameras is None:
            return None
        return [Camera(eye=c.eye, target=c.target, up=c.up, fov=c.fov, width=self.width, height=self.height)
                for c in self.cameras]


class ReconstructionRequest(BaseModel):
    """``POST /scenes/{id}/reconstruction``: the reconstruction (thesis Ch. 3, Alg. 4)
    of a depth-image set as GLB, one node per source image that holds samples.
    Reference viewpoints: ``cameras`` (square images of ``resolution``²; peeling from
    the single camera or the eyes' centroid, as ``DepthImagesRequest``), or the 4
    corners of ``light`` (peeling: its centre), or, with neither, of the default
    light sized to the scene."""

    model_config = ConfigDict(extra="forbid", json_schema_extra={"examples": [
        {"method": "non_redundant", "reconstruction": "hybrid", "resolution": 256}]})

    cameras: list[CameraSpec] | None = Field(default=None, min_length=1, max_length=MAX_SET_IMAGES)
    light: LightSpec | None = None
    method: Literal["non_redundant", "conventional", "peeling"] = "non_redundant"
    reconstruction: Literal["hybrid", "grid", "compact"] = "hybrid"
    resolution: StrictInt = Field(default=512, ge=16, le=MAX_RECONSTRUCTION_RES, description="image side in pixels")
    layers: StrictInt = Field(default=4, ge=1, le=MAX_SET_IMAGES, description="peeling layers")
    sides: Sides = Field(default="front", description=SIDES_DOC)

    @model_validator(mode="after")
    def _viewpoints(self) -> ReconstructionRequest:
        if self.cameras is not None and self.light is not None:
            raise ValueError("give cameras or a light, not both")
        check_peeling_camera(self.method, self.to_cameras())
        return self

    def to_cameras(self) -> list[Camera] | None:
        if self.cameras is None:
            return None
        return [Camera(eye=c.eye, target=c.target, up=c.up, fov=c.fov, width=self.resolution,
                       height=self.resolution) for c in self.cameras]


class ErrorResponse(BaseModel):
    """Every 4xx/5xx answer except a validation error: what went wrong, in words."""

    detail: str = Field(description="the problem, naming the field or limit (never more than an excerpt of "
                                    "the input)")


class ValidationIssue(BaseModel):
    """One invalid field of a request."""

    loc: list[str | int] = Field(description="where: e.g. ['body', 'camera', 'eye']")
    msg: str = Field(description="what is wrong with it")
    type: str = Field(description="pydantic's error type, e.g. int_type, greater_than_equal")
    input: Any = Field(default=None, description="the offending value, or an excerpt of it when long")


class ValidationErrorResponse(BaseModel):
    """422: the request's fields are invalid."""

    detail: list[ValidationIssue]
