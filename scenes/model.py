"""Scene model shared by GL passes and the Embree reference (DESIGN.md, "Conventions").

A Scene is a list of objects (triangle meshes with one material each), a sun
direction for local shading and an optional rectangular area light (§3.3). The
concatenation of the objects' face arrays, in object order, defines triangle ids:
id = global face index + 1 (0 = background). Object ids are 1-based object indices.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from scenes.excerpts import quoted

#: Ambient term of the local shading formula (identical in GLSL and numpy).
AMBIENT = 0.25


@dataclass(frozen=True)
class Material:
    """Per-object material: linear RGB albedo, specular factor s and glossiness g.

    s in [0, 1] blends the diffuse colour with the reflected colour (§4.2);
    g in [0, 1] is the width of the glossy lobe (0 = perfect mirror, §4.6).
    """

    albedo: tuple[float, float, float] = (0.8, 0.8, 0.8)
    specular: float = 0.0
    glossiness: float = 0.0

    def __post_init__(self) -> None:
        if len(self.albedo) != 3 or not all(np.isfinite(self.albedo)):
            raise ValueError(f"albedo must be 3 finite floats, got {self.albedo!r}")
        for name in ("specular", "glossiness"):
            v = getattr(self, name)
            if not (0.0 <= v <= 1.0):
                raise ValueError(f"{name} must be in [0, 1], got {v!r}")

    @property
    def reflective(self) -> bool:
        return self.specular > 0.0


@dataclass
class SceneObject:
    """One triangle mesh. vertices (V,3) float32 world units, faces (F,3) uint32
    counter-clockwise front faces, normals (V,3) float32 unit vertex normals."""

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray | None = None
    material: Material = field(default_factory=Material)

    def __post_init__(self) -> None:
        self.vertices = np.ascontiguousarray(self.vertices, dtype=np.float32).reshape(-1, 3)
        self.faces = np.ascontiguousarray(self.faces, dtype=np.uint32).reshape(-1, 3)
        if len(self.faces) and int(self.faces.max()) >= len(self.vertices):
            raise ValueError(f"object {quoted(self.name)}: face index out of range")
        if not np.all(np.isfinite(self.vertices)):
            raise ValueError(f"object {quoted(self.name)}: non-finite vertex coordinates")
        if self.normals is None:
            self.normals = vertex_normals(self.vertices, self.faces)
        else:
            self.normals = np.ascontiguousarray(self.normals, dtype=np.float32).reshape(-1, 3)
            if self.normals.shape != self.vertices.shape:
                raise ValueError(f"object {quoted(self.name)}: normals shape != vertices shape")

    @property
    def n_triangles(self) -> int:
        return len(self.faces)


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals (V,3) float32; isolated vertices get +Y."""
    v = vertices.astype(np.float64)
    f = faces.astype(np.int64)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])  # |fn| = 2 * area
    n = np.zeros_like(v)
    for k in range(3):
        np.add.at(n, f[:, k], fn)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    out = np.where(length > 1e-30, n / np.maximum(length, 1e-30), np.array([0.0, 1.0, 0.0]))
    return out.astype(np.float32)


@dataclass(frozen=True)
class AreaLight:
    """Rectangular area light: centre C, edge vectors u and v (world units); the
    rectangle is C + a·u + b·v for a, b in [-1/2, 1/2] (§3.3, Alg. 5)."""

    center: tuple[float, float, float]
    u: tuple[float, float, float]
    v: tuple[float, float, float]

    def corners(self) -> np.ndarray:
        """(4,3) float64 corners in order (-,-), (+,-), (+,+), (-,+)."""
        c, u, v = (np.asarray(x, dtype=np.float64) for x in (self.center, self.u, self.v))
        return np.array([c - u / 2 - v / 2, c + u / 2 - v / 2, c + u / 2 + v / 2, c - u / 2 + v / 2])

    def samples(self, k: int) -> np.ndarray:
        """(k*k,3) float64 sample positions at the centres of a k×k grid of cells."""
        c, u, v = (np.asarray(x, dtype=np.float64) for x in (self.center, self.u, self.v))
        t = (np.arange(k) + 0.5) / k - 0.5
        a, b = np.meshgrid(t, t, indexing="xy")
        return c + a.reshape(-1, 1) * u + b.reshape(-1, 1) * v


@dataclass
class Scene:
    """A list of objects plus lighting. sun_direction points from the scene toward
    the sun (unit vector); local shading uses it with AMBIENT."""

    objects: list[SceneObject]
    sun_direction: tuple[float, float, float] = (0.35, 0.85, 0.4)
    area_light: AreaLight | None = None
    name: str = "scene"

    def __post_init__(self) -> None:
        if not self.objects:
            raise ValueError("a scene needs at least one object")
        if len(self.objects) >= 65535:
            raise ValueError("too many objects (object ids are uint16)")
        d = np.asarray(self.sun_direction, dtype=np.float64)
        n = np.linalg.norm(d)
        if not np.isfinite(n) or n == 0:
            raise ValueError("sun_direction must be a non-zero finite vector")
        self.sun_direction = tuple(float(x) for x in d / n)

    # --- concatenated arrays (define triangle ids) -------------------------------
    @cached_property
    def face_offsets(self) -> np.ndarray:
        """(n_objects+1,) int64: object k owns global faces [off[k], off[k+1])."""
        return np.concatenate([[0], np.cumsum([o.n_triangles for o in self.objects])]).astype(np.int64)

    @cached_property
    def vertex_offsets(self) -> np.ndarray:
        return np.concatenate([[0], np.cumsum([len(o.vertices) for o in self.objects])]).astype(np.int64)

    @cached_property
    def vertices(self) -> np.ndarray:
        """(V,3) float32 all vertices, object order."""
        return np.concatenate([o.vertices for o in self.objects]).astype(np.float32)

    @cached_property
    def normals(self) -> np.ndarray:
        """(V,3) float32 all vertex normals."""
        return np.concatenate([o.normals for o in self.objects]).astype(np.float32)

    @cached_property
    def faces(self) -> np.ndarray:
        """(F,3) uint32 global faces indexing self.vertices; row k is triangle id k+1."""
        return np.concatenate(
            [o.faces.astype(np.int64) + off for o, off in zip(self.objects, self.vertex_offsets[:-1], strict=True)]
        ).astype(np.uint32)

    @cached_property
    def face_object(self) -> np.ndarray:
        """(F,) uint16 object id (1-based) of each global face."""
        return np.repeat(np.arange(1, len(self.objects) + 1), [o.n_triangles for o in self.objects]).astype(np.uint16)

    @cached_property
    def materials(self) -> np.ndarray:
        """(n_objects+1, 5) float32 rows [r, g, b, s, g]; row 0 is the background."""
        rows = [[0, 0, 0, 0, 0]]
        rows += [[*o.material.albedo, o.material.specular, o.material.glossiness] for o in self.objects]
        return np.asarray(rows, dtype=np.float32)

    @property
    def n_triangles(self) -> int:
        return int(self.face_offsets[-1])

    @cached_property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(min, max) corners of the axis-aligned bounding box, float64 (3,)."""
        v = self.vertices
        return v.min(axis=0).astype(np.float64), v.max(axis=0).astype(np.float64)

    @property
    def center(self) -> np.ndarray:
        lo, hi = self.bounds
        return (lo + hi) / 2

    @property
    def diagonal(self) -> float:
        lo, hi = self.bounds
        return float(np.linalg.norm(hi - lo))
