"""Depth-image sets for the service (thesis Ch. 2): the plan, the Embree-only
paths, encoding and the §2.3.2 metrics. GL and Embree work (visibility redundancy,
metrics) run inside the job (`service.jobs.SetJob`) on the worker thread, so they
share its bounded queue and timeout; encoding runs in the thread pool."""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np

from reference.sampling_metrics import sampling_metrics
from reference.visibility import non_redundant_visibility
from scenes.camera import Camera
from scenes.depth_image import DepthImage
from scenes.model import Scene
from scenes.rig import fig8_rig, intermediate_views, peeling_camera
from service import image_io
from service.excerpts import quoted


@dataclass
class SetPlan:
    """What to render: the reference cameras (near/far fitted) and, for peeling,
    the peeling camera (None for the other methods of requested cameras)."""

    method: str
    redundancy: str
    cameras: list[Camera]
    peel_camera: Camera | None
    layers: int


def plan_set(scene: Scene, method: str, redundancy: str, cameras: list[Camera] | None, width: int, height: int,
             layers: int) -> SetPlan:
    """Cameras of the request, or the Fig. 8 rig; peeling from the single camera
    or from the eyes' centroid toward the first camera's target."""
    if cameras is None:
        cams, peel = fig8_rig(scene.bounds, width, height)
    else:
        cams = [c.fit_clip(scene.bounds) for c in cameras]
        peel = peeling_camera(cams).fit_clip(scene.bounds) if method == "peeling" else None
    return SetPlan(method, redundancy, cams, peel, layers)


def needs_gl(plan: SetPlan, metrics: bool) -> bool:
    return metrics or not (plan.method == "non_redundant" and plan.redundancy == "visibility")


def embree_set(scene: Scene, plan: SetPlan) -> list[DepthImage]:
    """The visibility-redundancy NR set (Alg. 2), Embree only."""
    return non_redundant_visibility(scene, plan.cameras)


def set_metrics(scene: Scene, plan: SetPlan, images: list[DepthImage], conv: list[DepthImage], n_views: int,
                seed: int) -> dict:
    """The four §2.3.2 metrics of `images` (redundancy definition of the plan;
    pixel for conventional/peeling sets), JSON-ready."""
    views = intermediate_views(plan.cameras, n_views, seed)
    redundancy = plan.redundancy if plan.method == "non_redundant" else "pixel"
    return sampling_metrics(scene, images, conv, views, redundancy=redundancy).to_dict()


def encode_set(images: list[DepthImage], fmt: str) -> bytes:
    """EXR: one part per image ("image_<k>": RGB, Z, N, P, id; its camera in OpenEXR's
    standard worldToCamera and worldToNDC attributes, row-vector M44f as Imath uses
    them, i.e. the transposed GL view and projection·view, and all of it as JSON in the
    string attribute "depthviewCamera"); npz: stacked arrays color (n,H,W,3), depth
    (n,H,W), normal, position (n,H,W,3), tri_id (n,H,W) and per-image camera
    view/projection matrices (n,4,4)."""
    if fmt == "exr":
        parts = [(f"image_{k}", {"RGB": im.color, "Z": im.depth, "N": im.normal, "P": im.position, "id": im.tri_id},
                  _camera_attributes(im.camera)) for k, im in enumerate(images)]
        return image_io.encode_exr_multipart(parts)
    if fmt == "npz":
        stack = {name: np.stack([np.ascontiguousarray(getattr(im, name)) for im in images])
                 for name in ("color", "depth", "normal", "position", "tri_id")}
        stack["view"] = np.stack([im.camera.view_matrix() for im in images])
        stack["projection"] = np.stack([im.camera.projection_matrix() for im in images])
        return image_io.encode_npz(stack)
    raise ValueError(f"unknown depth-image set format {quoted(fmt)}")


def _camera_attributes(camera: Camera) -> dict:
    """A depth image's camera as EXR header attributes (see encode_set)."""
    view = camera.view_matrix()
    return {"worldToCamera": np.ascontiguousarray(view.T, np.float32),
            "worldToNDC": np.ascontiguousarray((camera.projection_matrix() @ view).T, np.float32),
            "depthviewCamera": json.dumps(camera.describe())}
