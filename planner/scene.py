"""The scene: a triangle mesh in metres with a group label and a source face per face.

Array shapes use fixed letters: V vertices, F faces, G groups.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import trimesh
from numpy.typing import NDArray

from planner.errors import SceneError

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


def _frozen(array: NDArray[Any]) -> NDArray[Any]:
    array = np.ascontiguousarray(array)
    array.flags.writeable = False
    return array


@dataclass(frozen=True)
class Element:
    """A BIM element (IFC product) that owns some faces."""

    global_id: str
    ifc_class: str
    name: str
    storey: str


@dataclass(frozen=True, eq=False)
class Scene:
    """A triangulated model, read-only.

    Attributes
    ----------
    vertices : (V, 3) float64, metres
    faces : (F, 3) int64, indices into ``vertices``
    face_group : (F,) int64, index into ``groups``
    groups : tuple of G group names ("" when the file has none)
    source_face : (F,) int64, the face of the file each face comes from (remeshing splits)
    face_element : (F,) int64, index into ``elements``, -1 when the file has no elements
    elements : BIM elements of an IFC model, empty otherwise
    metadata : plain data the reader wants to pass on (format, IFC spaces, storeys, ...)
    """

    vertices: FloatArray
    faces: IntArray
    face_group: IntArray
    groups: tuple[str, ...]
    source_face: IntArray
    face_element: IntArray
    elements: tuple[Element, ...] = ()
    metadata: dict[str, Any] = field(default_factory=dict)
    # derived, filled in __post_init__
    centroids: FloatArray = field(init=False, repr=False)
    normals: FloatArray = field(init=False, repr=False)
    areas: FloatArray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        for name in ("vertices", "faces", "face_group", "source_face", "face_element"):
            object.__setattr__(self, name, _frozen(getattr(self, name)))
        if self.faces.ndim != 2 or self.faces.shape[1] != 3 or len(self.faces) == 0:
            raise SceneError("the model has no triangles; export it with its faces")
        if not np.isfinite(self.vertices).all():
            bad = int(np.flatnonzero(~np.isfinite(self.vertices).all(axis=1))[0])
            raise SceneError(
                f"vertex {bad} has a non-finite coordinate {self.vertices[bad].tolist()}; "
                "fix or remove it in the model"
            )
        if self.faces.min() < 0 or self.faces.max() >= len(self.vertices):
            raise SceneError("a face refers to a vertex that does not exist; the file is broken")
        triangles = self.vertices[self.faces]
        cross = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
        doubled = np.linalg.norm(cross, axis=1)
        normals = np.divide(cross, doubled[:, None], out=np.zeros_like(cross),
                            where=doubled[:, None] > 0)
        object.__setattr__(self, "centroids", _frozen(triangles.mean(axis=1)))
        object.__setattr__(self, "normals", _frozen(normals))
        object.__setattr__(self, "areas", _frozen(doubled / 2.0))

    @property
    def n_faces(self) -> int:
        return len(self.faces)

    @property
    def triangles(self) -> FloatArray:
        """(F, 3, 3) float64: the corners of every face."""
        return self.vertices[self.faces]

    @property
    def bounds(self) -> FloatArray:
        """(2, 3) float64: lowest and highest corner of the axis-aligned box."""
        return np.stack([self.vertices.min(axis=0), self.vertices.max(axis=0)])

    def summary(self) -> dict[str, Any]:
        """Counts and bounds a user checks after an upload."""
        counts = np.bincount(self.face_group, minlength=len(self.groups))
        summary: dict[str, Any] = {
            "faces": self.n_faces,
            "vertices": len(self.vertices),
            "total_area_m2": round(float(self.areas.sum()), 6),
            "bounds": [[round(float(v), 6) for v in row] for row in self.bounds],
            "groups": {name: int(n) for name, n in zip(self.groups, counts, strict=True) if n},
        }
        if self.metadata.get("warnings"):  # e.g. a size that suggests another unit_scale
            summary["warnings"] = list(self.metadata["warnings"])
        return summary


def build_scene(
    vertices: NDArray[Any],
    faces: NDArray[Any],
    face_group: NDArray[Any] | None = None,
    groups: tuple[str, ...] = ("",),
    *,
    face_element: NDArray[Any] | None = None,
    elements: tuple[Element, ...] = (),
    metadata: dict[str, Any] | None = None,
) -> Scene:
    """A scene straight from arrays, each face its own source face."""
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    n = len(faces)
    return Scene(
        vertices=np.asarray(vertices, dtype=np.float64).reshape(-1, 3),
        faces=faces,
        face_group=np.zeros(n, np.int64) if face_group is None
        else np.asarray(face_group, np.int64),
        groups=groups,
        source_face=np.arange(n, dtype=np.int64),
        face_element=np.full(n, -1, np.int64) if face_element is None
        else np.asarray(face_element, np.int64),
        elements=elements,
        metadata=dict(metadata or {}),
    )


def remesh(scene: Scene, max_edge_m: float) -> Scene:
    """Split faces until no edge is longer than ``max_edge_m``.

    Faces already small enough keep their place; the pieces of a split face follow
    trimesh's order. ``source_face`` maps every new face back to the face of the file, and
    groups and elements travel along.
    """
    edges = scene.triangles - np.roll(scene.triangles, 1, axis=1)
    longest = float(np.linalg.norm(edges, axis=2).max())
    if longest <= max_edge_m:
        return scene
    iterations = math.ceil(math.log2(longest / max_edge_m)) + 2
    vertices, faces, index = trimesh.remesh.subdivide_to_size(  # type: ignore[no-untyped-call]
        scene.vertices, scene.faces, max_edge=max_edge_m, max_iter=iterations,
        return_index=True,
    )
    index = np.asarray(index, dtype=np.int64)
    # subdivide_to_size groups the unsplit faces first; restore file order (stable).
    order = np.argsort(index, kind="stable")
    return Scene(
        vertices=np.asarray(vertices, np.float64),
        faces=np.asarray(faces, np.int64)[order],
        face_group=scene.face_group[index[order]],
        groups=scene.groups,
        source_face=scene.source_face[index[order]],
        face_element=scene.face_element[index[order]],
        elements=scene.elements,
        metadata=scene.metadata,
    )
