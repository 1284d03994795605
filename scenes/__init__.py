"""Scene model, cameras, loaders and built-in procedural scenes (no GL, no Embree)."""

from scenes.camera import Camera, CameraError, flythrough_path, look_at_scene, orbit_path
from scenes.model import AMBIENT, AreaLight, Material, Scene, SceneObject, vertex_normals

__all__ = [
    "AMBIENT", "AreaLight", "Camera", "CameraError", "Material", "Scene", "SceneObject",
    "flythrough_path", "look_at_scene", "orbit_path", "vertex_normals",
]
