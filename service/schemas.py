"""Request and response bodies of the HTTP API (pydantic v2).

Validation errors become HTTP 422 responses whose ``detail`` entries carry the
field's location (e.g. ``["body", "camera", "eye"]``) and a message naming the
problem. Limits that depend on the service settings (frame size) are checked by
the route, also with 422.
"""

from __future__ import annotations

import math
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from scenes.camera import Camera, CameraError

Vec3 = tuple[float, float, float]

#: Effect methods accepted by /frames (soft shadows arrive with the Ch. 3 passes).
SHADOW_METHODS = ("none",)
#: cluster: cluster depth images (thesis Ch. 4, GL); raytrace: Embree reference;
#: envmap: environment map only (baseline); none: local shading only.
REFLECTION_METHODS = ("none", "cluster", "raytrace", "envmap")
#: Glossy lobe rays per reflective sample (thesis §4.6 uses 8–49).
MAX_GLOSSY_RAYS = 64


def _finite_vec3(name: str, v: Any) -> Any:
    if isinstance(v, (list, tuple)) and len(v) == 3:
        for x in v:
            if isinstance(x, (int, float)) and not isinstance(x, bool) and not math.isfinite(x):
                raise ValueError(f"camera {name} must be finite numbers (got NaN or infinity)")
    return v


class CameraSpec(BaseModel):
    """A pinhole camera: eye, target, up (world units), vertical fov in degrees.
    Near/far are fitted to the scene bounds by the service."""

    model_config = ConfigDict(extra="forbid")

    eye: Vec3 = Field(description="camera position", examples=[[0.0, 1.0, 3.5]])
    target: Vec3 = Field(description="point the camera looks at", examples=[[0.0, 1.0, 0.0]])
    up: Vec3 = Field(default=(0.0, 1.0, 0.0), description="up direction (not parallel to target - eye)")
    fov: float = Field(default=45.0, gt=0.0, lt=180.0, allow_inf_nan=False, description="vertical field of view, deg")

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


class Effects(BaseModel):
    """Effects applied to a frame: reflections by method (2×2 supersampled), with
    `glossy_rays` lobe rays per sample on glossy surfaces."""

    model_config = ConfigDict(extra="forbid")

    shadows: str = Field(default="none", description=f"soft-shadow method; one of {list(SHADOW_METHODS)}")
    reflections: str = Field(default="none", description=f"reflection method; one of {list(REFLECTION_METHODS)}")
    glossy_rays: int = Field(default=8, ge=1, le=MAX_GLOSSY_RAYS, description="lobe rays per glossy sample")

    @field_validator("shadows")
    @classmethod
    def _shadows(cls, v: str) -> str:
        if v not in SHADOW_METHODS:
            raise ValueError(f"shadows method {v!r} is not available; supported: {', '.join(SHADOW_METHODS)}")
        return v

    @field_validator("reflections")
    @classmethod
    def _reflections(cls, v: str) -> str:
        if v not in REFLECTION_METHODS:
            raise ValueError(
                f"reflections method {v!r} is not available; supported: {', '.join(REFLECTION_METHODS)}")
        return v


class FrameRequest(BaseModel):
    """Render one frame of a stored scene."""

    model_config = ConfigDict(extra="forbid", json_schema_extra={"examples": [{
        "camera": {"eye": [0.0, 1.0, 3.5], "target": [0.0, 1.0, 0.0]}, "width": 256, "height": 256,
        "format": "png"}]})

    camera: CameraSpec
    width: int = Field(default=512, ge=1, description="pixels; at most the service's max_width")
    height: int = Field(default=512, ge=1, description="pixels; at most the service's max_height")
    format: Literal["png", "exr"] = Field(
        default="png", description="png: sRGB colour; exr: linear float channels RGB, Z, N, id, object")
    effects: Effects = Field(default_factory=Effects)
    cull_back_faces: bool = Field(default=True, description="back-face culling (on, as the thesis)")

    @model_validator(mode="after")
    def _camera_is_valid(self) -> FrameRequest:
        self.to_camera()  # CameraError is a ValueError → 422 naming the problem
        return self

    def to_camera(self) -> Camera:
        """The scenes.camera.Camera (without near/far) this request describes."""
        c = self.camera
        try:
            return Camera(eye=c.eye, target=c.target, up=c.up, fov=c.fov, width=self.width, height=self.height)
        except CameraError as exc:
            raise ValueError(str(exc)) from exc


class BuiltinParams(BaseModel):
    """Parameters of a built-in procedural scene."""

    model_config = ConfigDict(extra="forbid")

    detail: float = Field(default=1.0, gt=0.0, allow_inf_nan=False, description="tessellation scale")
    seed: int = Field(default=0, ge=0, lt=2**63, description="random seed of the procedural generator")


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
    width: int = Field(default=512, ge=1)
    height: int = Field(default=512, ge=1)
    layers: int = Field(default=3, ge=1, le=MAX_SET_IMAGES, description="peeling layers")
    format: Literal["exr", "npz"] = Field(
        default="exr", description="exr: one part per image (RGB, Z, N, P, id); npz: stacked arrays")
    metrics: bool = Field(default=False, description="add the four §2.3.2 sampling metrics (JSON response)")
    intermediate_views: int = Field(default=16, ge=1, le=MAX_METRIC_VIEWS,
                                    description="intermediate views for the useful/available metrics")
    seed: int = Field(default=0, ge=0, lt=2**63, description="seed of the intermediate views")

    def to_cameras(self) -> list[Camera] | None:
        """The requested cameras (without near/far), or None for the rig."""
        if self.cameras is None:
            return None
        return [Camera(eye=c.eye, target=c.target, up=c.up, fov=c.fov, width=self.width, height=self.height)
                for c in self.cameras]
