"""The scene: a triangle mesh in metres with a group label and a source face per face.

Array shapes use fixed letters: V vertices, F faces, G groups.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numba
import numpy as np
from numpy.typing import NDArray

from planner.errors import SceneError
from planner.memory import GrowingArray
from planner.threads import in_block_order

FloatArray = NDArray[np.float64]
# face and label indices: int32 (4 bytes a face each instead of 8; a model has fewer than
# 2**31 vertices, faces and groups, which Scene checks)
IndexArray = NDArray[np.int32]
_Value = TypeVar("_Value", bound=np.generic)

# Per-face arrays are derived, and faces remeshed, a block at a time: the temporaries are
# (B, 3, 3) floats, not (F, 3, 3), so a 10 M-face model needs no 720 MB scratch arrays.
# A block's scratch is some 250 bytes a face on each of the threads: at 131,072 faces a
# block some 30 MB, where blocks of 1,048,576 faces made the split's peak (Amersfoort,
# 3.87 M faces: two threads' 250 MB over the old and the new scene)
_DERIVE_BLOCK_FACES = 1 << 17
# remesh: at most about this many pieces per call of trimesh (its scratch is some 450
# bytes a piece, two blocks at a time). The blocks decide which vertices are stored twice,
# and the plan's identities hash the vertices (planner.outputs.stations.namespace), so the
# size is part of the output: smaller blocks would split faster (3.8 M pieces of a 2-storey
# office: 1.8 instead of 2.6 s) but give every large model new GlobalIds.
_REMESH_BLOCK_PIECES = 1 << 20


def read_only(array: NDArray[Any]) -> NDArray[Any]:
    """``array`` contiguous and read-only (a copy only where it is not contiguous)."""
    array = np.ascontiguousarray(array)
    array.flags.writeable = False
    return array


def face_values(vertices: FloatArray, faces: IndexArray, *, normals: bool = True
                ) -> tuple[FloatArray | None, FloatArray]:
    """(F, 3) unit normals (zero for a face of no area; None without ``normals``) and (F,)
    areas of the (F, 3) ``faces`` over ``vertices``, float64, a block at a time on a few
    threads (numpy releases the GIL), each into its own rows."""
    n = len(faces)
    areas = np.empty(n)
    unit = np.zeros((n, 3)) if normals else None

    def derive(start: int) -> None:
        block = slice(start, start + _DERIVE_BLOCK_FACES)
        _, cross, doubled = _cross_products(vertices, faces[block])
        if unit is not None:
            np.divide(cross, doubled[:, None], out=unit[block], where=doubled[:, None] > 0)
        areas[block] = doubled / 2.0

    list(in_block_order(derive, range(0, n, _DERIVE_BLOCK_FACES)))
    return unit, areas


@numba.njit(nogil=True, cache=True, inline="always")
def face_centroid(vertices: FloatArray, faces: IndexArray, f: int
                  ) -> tuple[float, float, float]:
    """The centroid of face ``f`` of the (F, 3) ``faces`` over the (V, 3) ``vertices``:
    per axis (a + b + c) / 3, added left to right, the same bits as numpy's
    ``vertices[faces].mean(axis=1)`` (a sum over an axis of three, then one division).
    Kernels compute it where they read it: a 9.7 M-piece model's stored centroids were
    234 MB under every stage. Inlined into kernels of other modules, whose numba caches
    are checked against their own files only: after changing it, clear ``__pycache__``."""
    a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
    return ((vertices[a, 0] + vertices[b, 0] + vertices[c, 0]) / 3.0,
            (vertices[a, 1] + vertices[b, 1] + vertices[c, 1]) / 3.0,
            (vertices[a, 2] + vertices[b, 2] + vertices[c, 2]) / 3.0)


@numba.njit(nogil=True, cache=True)
def centroids_into(vertices: FloatArray, faces: IndexArray, which: NDArray[np.int64],
                   out: FloatArray) -> None:
    """The centroids (:func:`face_centroid`) of the faces ``which`` (k,) of the (F, 3)
    ``faces`` over ``vertices`` into the (k, 3) ``out``."""
    for i in range(which.shape[0]):
        out[i, 0], out[i, 1], out[i, 2] = face_centroid(vertices, faces, which[i])


def unit_normals(vertices: FloatArray, faces: IndexArray) -> FloatArray:
    """(F, 3) float64: the unit normals of the (F, 3) ``faces`` (zero for a face of no
    area), the same bits as :func:`face_values` gives them."""
    unit = np.zeros((len(faces), 3))

    def derive(start: int) -> None:
        block = slice(start, start + _DERIVE_BLOCK_FACES)
        _, cross, doubled = _cross_products(vertices, faces[block])
        np.divide(cross, doubled[:, None], out=unit[block], where=doubled[:, None] > 0)

    list(in_block_order(derive, range(0, len(faces), _DERIVE_BLOCK_FACES)))
    return unit


def _cross_products(vertices: FloatArray, faces: IndexArray
                    ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(B, 3, 3) corners of the (B, 3) ``faces``, (B, 3) the cross products of their
    edges from the first corner and (B,) the products' lengths (twice the areas)."""
    triangles = vertices[faces]
    cross = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    return triangles, cross, np.linalg.norm(cross, axis=1)


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
    faces : (F, 3) int32, indices into ``vertices``
    file_face_group : (F0,) int32, each file face's index into ``groups`` (a face's group
        is its file face's: :attr:`face_group`)
    groups : tuple of G group names ("" when the file has none)
    source_face : (F,) int32, the face of the file each face comes from (remeshing splits)
    file_face_element : (F0,) int32, each file face's index into ``elements``, -1 when the
        file has no elements (:attr:`face_element`)
    elements : BIM elements of an IFC model, empty otherwise
    metadata : plain data the reader wants to pass on (format, IFC spaces, storeys, ...)
    file_vertices : (V0, 3) float64, the model as read before remeshing (None: ``vertices``)
    file_faces : (F0, 3) int32, the faces ``source_face`` indexes (None: ``faces``, and
        ``source_face`` is then the identity); occlusion rays are cast against these, so
        the ray caster stays the size of the file however finely the targets are split
    split_max_edge_m : faces longer than this are still to be split (a scene read with
        ``split_faces="as_needed"``): :func:`planner.pipeline.plan` splits, once it knows the
        candidates, only the faces some candidate can qualify part of
        (:mod:`planner.visibility.splitting`); None: the faces are final

    Groups and elements are kept per file face, so the pieces of a remeshed scene carry no
    (F,) copies of them (on a 9.7 M-face office two such arrays were 74 MB of every stage's
    memory): :attr:`face_group` and :attr:`face_element` look them up through
    ``source_face`` when asked. So are the unit normals (``file_normals``; a piece lies in
    its file face's plane): :meth:`normals_of` looks them up, 24 bytes a piece less.

    Derived: ``areas`` (F,) float64 of every face, and ``file_normals`` (F0, 3) float64,
    each file face's unit normal (zero for a face of no area; a scene never remeshed: each
    face's, (F, 3)). The centroids are not kept: :meth:`centroids_of` computes those of
    some faces, compiled kernels compute each where they read it
    (:func:`face_centroid`), the same bits either way.
    """

    vertices: FloatArray
    faces: IndexArray
    file_face_group: IndexArray
    groups: tuple[str, ...]
    source_face: IndexArray
    file_face_element: IndexArray
    elements: tuple[Element, ...] = ()
    metadata: dict[str, Any] = field(default_factory=dict)
    file_vertices: FloatArray | None = None
    file_faces: IndexArray | None = None
    split_max_edge_m: float | None = None
    # derived, filled in __post_init__
    file_normals: FloatArray = field(init=False, repr=False)
    areas: FloatArray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._check()
        # a remeshed scene's normals are its file faces': a piece lies in its face's plane,
        # and its own cross product would only repeat that plane, less well conditioned
        remeshed = self.file_faces is not None
        normals, areas = face_values(self.vertices, self.faces, normals=not remeshed)
        if normals is None:
            normals = unit_normals(*self.file_mesh)
        object.__setattr__(self, "file_normals", read_only(normals))
        object.__setattr__(self, "areas", read_only(areas))

    @classmethod
    def with_face_values(cls, file_normals: FloatArray | None, areas: FloatArray | None,
                         **fields: Any) -> Scene:
        """The scene of ``fields`` (the constructor's) whose (F0, 3) ``file_normals`` (one
        a file face, (F, 3) when the scene has no file mesh) and (F,) ``areas`` are given
        rather than derived from its vertices: a part of a scene keeps the scene's own
        float64 values, and the arithmetic that would only be thrown away is skipped (a
        tile of a few million faces: seconds). None leaves them out: only for a part on its
        way to where they are derived again (a tile in a task,
        :meth:`planner.visibility.tiles.Tile.detached`)."""
        scene = cls.__new__(cls)
        for spec in dataclasses.fields(cls):
            if not spec.init:
                continue
            if spec.name in fields:
                value = fields.pop(spec.name)
            elif spec.default is not dataclasses.MISSING:
                value = spec.default
            elif spec.default_factory is not dataclasses.MISSING:
                value = spec.default_factory()
            else:
                raise TypeError(f"Scene.with_face_values needs {spec.name}")
            object.__setattr__(scene, spec.name, value)
        if fields:
            raise TypeError(f"Scene has no field {', '.join(sorted(fields))}")
        scene._check()
        n = len(scene.faces)
        n_file = len(scene.file_mesh[1])
        for name, values, shape in (("file_normals", file_normals, (n_file, 3)),
                                    ("areas", areas, (n,))):
            if values is None:
                object.__setattr__(scene, name, None)
                continue
            values = np.asarray(values, np.float64)
            if values.shape != shape:
                raise ValueError(f"{name} of shape {values.shape}, not {shape}")
            object.__setattr__(scene, name, read_only(values))
        return scene

    def replaced(self, **changes: Any) -> Scene:
        """``dataclasses.replace`` for fields other than ``vertices`` and ``faces``: the
        faces' normals and areas are the same, so they are kept rather than derived again
        (a million faces: 0.35 CPU s)."""
        if {"vertices", "faces"} & changes.keys():
            raise ValueError("replaced keeps the vertices and faces; build a new Scene")
        return Scene.with_face_values(self.file_normals, self.areas,
                                      **{**self._init_fields(), **changes})

    def over_file_mesh(self, file_vertices: FloatArray, file_faces: IndexArray,
                       file_normals: FloatArray) -> Scene:
        """The scene over the file mesh of (V0, 3) ``file_vertices`` and (F0, 3)
        ``file_faces`` (the same arrays, not copies), whose (F0, 3) unit normals are given
        (``file_normals``: a worker derives them once for all its tiles); its faces'
        areas derived from its vertices. For a part that travelled without
        them (:meth:`planner.visibility.tiles.Tile.detached`)."""
        _, areas = face_values(self.vertices, self.faces, normals=False)
        return Scene.with_face_values(file_normals, areas, **{
            **self._init_fields(), "file_vertices": file_vertices, "file_faces": file_faces})

    def _init_fields(self) -> dict[str, Any]:
        """The constructor's fields, by name."""
        return {spec.name: getattr(self, spec.name) for spec in dataclasses.fields(self)
                if spec.init}

    def _check(self) -> None:
        """Checks the fields and makes the arrays read-only (int32 indices)."""
        if max(len(self.vertices), len(self.faces), len(self.groups)) >= 2**31 - 1:
            raise SceneError("the model has more than 2**31 vertices or faces; split it")
        if self.faces.ndim != 2 or self.faces.shape[1] != 3 or len(self.faces) == 0:
            raise SceneError("the model has no triangles; export it with its faces")
        if self.faces.min() < 0 or self.faces.max() >= len(self.vertices):
            raise SceneError("a face refers to a vertex that does not exist; the file is broken")
        for name in ("vertices", "faces", "file_face_group", "source_face", "file_face_element",
                     "file_vertices", "file_faces"):
            value = getattr(self, name)
            if value is None:
                continue
            if name not in ("vertices", "file_vertices"):
                value = np.asarray(value, np.int32)  # no copy when it is int32 already
            object.__setattr__(self, name, read_only(value))
        if (self.file_vertices is None) != (self.file_faces is None):
            raise ValueError("file_vertices and file_faces come together or not at all")
        n_file_faces = len(self.faces if self.file_faces is None else self.file_faces)
        if len(self.file_face_group) != n_file_faces or len(self.file_face_element) != n_file_faces:
            raise ValueError("file_face_group and file_face_element hold one value a file face")
        if not np.isfinite(self.vertices).all():
            bad = int(np.flatnonzero(~np.isfinite(self.vertices).all(axis=1))[0])
            raise SceneError(
                f"vertex {bad} has a non-finite coordinate {self.vertices[bad].tolist()}; "
                "fix or remove it in the model"
            )

    @property
    def n_faces(self) -> int:
        return len(self.faces)

    @property
    def face_group(self) -> IndexArray:
        """(F,) int32, each face's index into ``groups`` (a new array on a remeshed scene:
        read it once, not in a loop)."""
        return self.of_file_faces(self.file_face_group)

    @property
    def face_element(self) -> IndexArray:
        """(F,) int32, each face's index into ``elements``, -1 for none (a new array on a
        remeshed scene: read it once, not in a loop)."""
        return self.of_file_faces(self.file_face_element)

    def faces_of_classes(self, ifc_classes: tuple[str, ...]) -> NDArray[np.bool_]:
        """(F,) bool: the faces of elements of ``ifc_classes`` (none in a plain mesh)."""
        wanted = np.array([e.ifc_class in ifc_classes for e in self.elements] + [False])
        # an element index of -1 (no element) picks the trailing False
        result: NDArray[np.bool_] = self.of_file_faces(wanted[self.file_face_element])
        return result

    def of_file_faces(self, per_file_face: NDArray[_Value]) -> NDArray[_Value]:
        """(F,) the value of (F0,) ``per_file_face`` on each face: its file face's (the
        array itself when the scene was never remeshed). The inverse of
        :meth:`on_file_faces`."""
        return per_file_face if self.file_faces is None else per_file_face[self.source_face]

    @property
    def normals(self) -> FloatArray:
        """(F, 3) float64, each face's unit normal: its file face's (a new array on a
        remeshed scene: read it once, or take :meth:`normals_of` for some faces)."""
        return self.of_file_faces(self.file_normals)

    def normals_of(self, faces: NDArray[np.integer[Any]] | slice | int) -> FloatArray:
        """(k, 3) float64, the unit normals of ``faces`` ((k,) face indices or a slice;
        (3,) of one face)."""
        if self.file_faces is None:
            return self.file_normals[faces]
        return self.file_normals[self.source_face[faces]]

    def centroids_of(self, faces: NDArray[np.integer[Any]] | slice) -> FloatArray:
        """(k, 3) float64, the centroids of ``faces`` ((k,) face indices or a slice),
        computed now (:func:`face_centroid`: the same bits as the compiled kernels)."""
        which = (np.arange(*faces.indices(self.n_faces)) if isinstance(faces, slice)
                 else faces)
        which = np.ascontiguousarray(which, np.int64).reshape(-1)
        out = np.empty((len(which), 3))
        centroids_into(self.vertices, self.faces, which, out)
        return out

    @property
    def centroids(self) -> FloatArray:
        """(F, 3) float64, the centroid of every face: a new array each time (24 bytes a
        face; read it once, or take :meth:`centroids_of` for some faces)."""
        return self.centroids_of(slice(None))

    @property
    def triangles(self) -> FloatArray:
        """(F, 3, 3) float64: the corners of every face."""
        return self.vertices[self.faces]

    @property
    def file_mesh(self) -> tuple[FloatArray, IndexArray]:
        """(V0, 3) vertices and (F0, 3) faces of the model before remeshing.

        ``source_face`` indexes these faces; a scene that was never remeshed is its own file
        mesh.
        """
        if self.file_vertices is None or self.file_faces is None:
            return self.vertices, self.faces
        return self.file_vertices, self.file_faces

    @property
    def file_triangles(self) -> FloatArray:
        """(F0, 3, 3) float64: the corners of every face of the file (before remeshing)."""
        vertices, faces = self.file_mesh
        return vertices[faces]

    def on_file_faces(self, per_face: NDArray[Any]) -> NDArray[Any]:
        """(F0,) the value of (F,) ``per_face`` on each face of the file.

        For values that the pieces of a file face share (group, element): remeshing keeps
        every face of the file, in one or more pieces.
        """
        if self.file_faces is None:
            return per_face
        on_file = np.empty(len(self.file_faces), per_face.dtype)
        on_file[self.source_face] = per_face
        return on_file

    def file_face_blocks(self, size: int) -> list[slice]:
        """Consecutive slices of about ``size`` faces that cover every face, none cutting
        a file face's pieces apart: possible when the pieces are in file order
        (``source_face`` never decreases, as a scene split by :func:`remesh` has them);
        otherwise one slice of every face. A computation that groups the pieces of each
        file face can then run a block at a time, its scratch bounded by the block."""
        n = self.n_faces
        if not self._pieces_in_file_order():
            return [slice(0, n)]
        blocks = []
        start = 0
        while start < n:
            end = min(start + size, n)
            if end < n:  # on to the end of the file face the block would cut
                end = int(np.searchsorted(self.source_face, self.source_face[end - 1],
                                          side="right"))
            blocks.append(slice(start, end))
            start = end
        return blocks

    def first_pieces(self) -> tuple[IndexArray, NDArray[np.int64]]:
        """The file faces that have pieces, ascending, and the first piece of each."""
        if self._pieces_in_file_order():  # no (F,) sort: two (F0,) binary searches
            ids = np.arange(len(self.file_mesh[1]), dtype=self.source_face.dtype)
            left = np.searchsorted(self.source_face, ids, side="left")
            has_pieces = left < np.searchsorted(self.source_face, ids, side="right")
            return ids[has_pieces], left[has_pieces].astype(np.int64)
        faces, first = np.unique(self.source_face, return_index=True)
        return faces, first.astype(np.int64)

    def pieces_per_file_face(self) -> NDArray[np.int64]:
        """(F0,) int64, how many pieces each file face has (no (F,) int64 copy of
        ``source_face``, as ``np.bincount`` makes, where the pieces are in file order)."""
        n_file = len(self.file_mesh[1])
        if not self._pieces_in_file_order():
            counts: NDArray[np.int64] = np.bincount(self.source_face, minlength=n_file)
            return counts
        ids = np.arange(n_file, dtype=self.source_face.dtype)
        return (np.searchsorted(self.source_face, ids, side="right")
                - np.searchsorted(self.source_face, ids, side="left")).astype(np.int64)

    def _pieces_in_file_order(self) -> bool:
        """``source_face`` never decreases (checked a block at a time, no (F,) scratch)."""
        previous = -1
        for start in range(0, self.n_faces, _DERIVE_BLOCK_FACES):
            block = self.source_face[start:start + _DERIVE_BLOCK_FACES]
            if block[0] < previous or bool((block[1:] < block[:-1]).any()):
                return False
            previous = int(block[-1])
        return True

    @functools.cached_property
    def bounds(self) -> FloatArray:
        """(2, 3) float64, read-only: lowest and highest corner of the axis-aligned box
        (found once: the walk graph, the levels and the outputs each ask, 0.1 s a time over
        a 5 M-face scene's vertices)."""
        return read_only(np.stack(column_bounds(self.vertices)))

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
    faces = np.asarray(faces).reshape(-1, 3)  # int32 once Scene has checked its range
    n = len(faces)
    return Scene(
        vertices=np.asarray(vertices, dtype=np.float64).reshape(-1, 3),
        faces=faces,
        file_face_group=np.zeros(n, np.int32) if face_group is None
        else np.asarray(face_group, np.int32),
        groups=groups,
        source_face=np.arange(n, dtype=np.int32),
        file_face_element=np.full(n, -1, np.int32) if face_element is None
        else np.asarray(face_element, np.int32),
        elements=elements,
        metadata=dict(metadata or {}),
    )


def remesh(scene: Scene, max_edge_m: float, split: NDArray[np.bool_] | None = None) -> Scene:
    """Split faces until no edge is longer than ``max_edge_m``.

    ``split`` (F,) bool: split only these faces, keep the others whole (default: every
    face). A face is split the same way whichever other faces are split with it.

    Faces already small enough keep their place; the pieces of a split face follow
    trimesh's order (:func:`trimesh.remesh.subdivide_to_size`, which halves every long edge
    at one midpoint). ``source_face`` maps every new face back to the face of the file, and
    groups and elements travel along; the file's own mesh is kept as ``file_vertices`` /
    ``file_faces`` for the occlusion rays.

    The faces are split in blocks of the file's faces, each block with its own copy of the
    vertices it uses, so trimesh's scratch arrays stay bounded (about
    ``_REMESH_BLOCK_PIECES`` pieces per call) whatever the model's size. How a face is
    split depends only on its own edges (an edge's midpoint is the mean of its two
    corners), so the pieces, their corners and their order are the same as splitting the
    whole mesh at once; only vertices on a block boundary are stored twice.
    """
    pieces = subdivide(scene.vertices, scene.faces, max_edge_m, split)
    if pieces is None:
        return scene if scene.split_max_edge_m is None else scene.replaced(
            split_max_edge_m=None)
    new_vertices, new_faces, index = pieces
    file_vertices, file_faces = scene.file_mesh
    return Scene(
        vertices=new_vertices,
        faces=new_faces,
        file_face_group=scene.file_face_group,
        groups=scene.groups,
        source_face=scene.source_face[index],
        file_face_element=scene.file_face_element,
        elements=scene.elements,
        metadata=scene.metadata,
        file_vertices=file_vertices,
        file_faces=file_faces,
    )


# kept_pieces: at most about this many pieces per call of trimesh, each call's pieces
# sifted on its thread before the next (some 30 MB of scratch a thread)
_SIFTED_BLOCK_PIECES = 1 << 16
# kept_pieces: a face that would make more pieces than this is quartered first, and its
# quarters sifted as faces (a quarter of 4,096 pieces spans 64 of them along an edge)
_QUARTER_PIECES = 1 << 12


def kept_pieces(vertices: FloatArray, faces: IndexArray, max_edge_m: float,
                keep: Callable[[FloatArray, IndexArray], NDArray[np.bool_]]
                ) -> tuple[FloatArray, IndexArray]:
    """The pieces :func:`subdivide` splits the (F, 3) ``faces`` into that ``keep`` keeps:
    (V', 3) vertices and (F', 3) int32 faces of them, in no particular order, a vertex
    stored once per block. ``keep(piece_vertices, piece_faces)`` gets a block's (v, 3)
    vertices and (f, 3) faces and returns (f,) bool. It must be a test of a face's
    bounding box that a larger box passes whenever a smaller one inside it does: a face
    it drops then holds no piece it keeps.

    The same pieces, corner for corner, as :func:`subdivide` gives, without its scratch
    or its output for the pieces dropped: the faces are split about
    ``_SIFTED_BLOCK_PIECES`` pieces at a time on the thread pool, and a face that alone
    would make more than ``_QUARTER_PIECES`` (a site's ground: 589,824 pieces) is first
    split as trimesh's first step splits it (its three edges longer than ``max_edge_m``:
    four faces on their midpoints), again while its quarters are that big, and the
    quarters ``keep`` drops are let go unsplit (a site's ground far from every tripod).
    A quarter's pieces are the face's own (an edge's midpoint is the mean of its corners,
    a face's split depends on its own edges only)."""
    vertices, faces = _quartered(vertices, faces, max_edge_m, _QUARTER_PIECES, keep)
    blocks = _piece_blocks(longest_edges_m(vertices, faces), max_edge_m,
                           _SIFTED_BLOCK_PIECES)

    def sifted(block: tuple[int, int]) -> tuple[FloatArray, IndexArray]:
        """(v, 3) vertices and (k, 3) faces of the kept pieces of faces ``start:stop``."""
        start, stop = block
        pieces = subdivide(vertices, faces[start:stop], max_edge_m)
        if pieces is None:  # no face of the block longer than max_edge_m: each its own piece
            used, local = compact_indices(faces[start:stop], len(vertices))
            piece_vertices, piece_faces = vertices[used], local
        else:
            piece_vertices, piece_faces, _ = pieces
        kept = piece_faces[keep(piece_vertices, piece_faces)]
        used, local = compact_indices(kept, len(piece_vertices))
        return piece_vertices[used], local

    out_vertices = GrowingArray(np.float64)  # (3 V',) flat
    out_faces = GrowingArray(np.int32)  # (3 F',) flat
    n_vertices = 0
    for block_vertices, block_faces in in_block_order(sifted, blocks):
        out_vertices.append(block_vertices.reshape(-1))
        out_faces.append((block_faces + n_vertices).astype(np.int32).reshape(-1))
        n_vertices += len(block_vertices)
    return out_vertices.done().reshape(-1, 3), out_faces.done().reshape(-1, 3)


def _quartered(vertices: FloatArray, faces: IndexArray, max_edge_m: float, most_pieces: int,
               keep: Callable[[FloatArray, IndexArray], NDArray[np.bool_]]
               ) -> tuple[FloatArray, IndexArray]:
    """(V', 3) vertices and (F', 3) faces: the (F, 3) ``faces`` with every face that
    :func:`subdivide` could split into more than ``most_pieces`` pieces and whose three
    edges are longer than ``max_edge_m`` replaced, again until none is left, by those of
    the four faces trimesh's first step makes of it (:func:`trimesh.remesh.subdivide_to_size`,
    the regular 1 -> 4 split, its corners in its order) that ``keep`` keeps, new midpoints
    after the vertices."""
    for _ in range(64):
        halvings = np.ceil(np.log2(np.maximum(longest_edges_m(vertices, faces) / max_edge_m,
                                              1.0)))
        big = np.flatnonzero(4.0 ** halvings > most_pieces)
        if len(big) == 0:
            break
        corners = vertices[faces[big]]  # (b, 3, 3)
        # the edges v0v1, v1v2, v2v0 and their lengths as trimesh measures them
        length_m = ((corners - np.roll(corners, -1, axis=1)) ** 2).sum(axis=2) ** 0.5
        big = big[(length_m > max_edge_m).all(axis=1)]
        if len(big) == 0:
            break
        v0, v1, v2 = faces[big].T.astype(np.int64)
        # midpoints as trimesh makes them: the mean of the edge's two corners
        middles = np.stack([vertices[np.stack([a, b], axis=1)].mean(axis=1)
                            for a, b in ((v0, v1), (v1, v2), (v2, v0))])  # (3, b, 3)
        m0, m1, m2 = len(vertices) + np.arange(3 * len(big)).reshape(3, -1)
        children = np.column_stack((v0, m0, m2, m0, v1, m1, m2, m1, v2, m0, m1, m2)
                                   ).reshape(-1, 3)
        vertices = np.concatenate([vertices, middles.reshape(-1, 3)])
        whole = np.ones(len(faces), bool)
        whole[big] = False
        children = children.astype(np.int32)
        faces = np.concatenate([faces[whole], children[keep(vertices, children)]])
    return vertices, faces


def _piece_blocks(edge_m: FloatArray, max_edge_m: float, most_pieces: int
                  ) -> list[tuple[int, int]]:
    """(start, stop) blocks of consecutive faces, whose (F,) longest edges are ``edge_m``
    (0: a face kept whole), of about ``most_pieces`` pieces at most when split to
    ``max_edge_m``: at most 4 pieces per halving of a face's longest edge, an upper bound
    (a face alone may exceed it)."""
    halvings = np.ceil(np.log2(np.maximum(edge_m / max_edge_m, 1.0)))  # (F,)
    bound = np.cumsum(np.minimum(4.0 ** halvings, most_pieces))
    cuts = np.searchsorted(bound, np.arange(most_pieces, bound[-1], most_pieces),
                           side="right")
    starts = np.unique(np.concatenate([[0], cuts]))
    stops = np.append(starts[1:], len(edge_m))
    return list(zip(starts.tolist(), stops.tolist(), strict=True))


def longest_edges_m(vertices: FloatArray, faces: IndexArray) -> FloatArray:
    """(F,) the longest edge of each of the (F, 3) ``faces``, a block of faces at a time."""
    edge_m = np.empty(len(faces))
    for first in range(0, len(faces), _DERIVE_BLOCK_FACES):
        block = faces[first:first + _DERIVE_BLOCK_FACES]
        edges = vertices[np.roll(block, 1, axis=1)] - vertices[block]  # (B, 3, 3)
        _, edge_m[first:first + len(block)] = corner_extremes(
            np.linalg.norm(edges, axis=2))  # the longest of each face's (B, 3) edges
    return edge_m


def corner_extremes(corners: NDArray[Any]) -> tuple[NDArray[Any], NDArray[Any]]:
    """The least and the most of the (B, 3, ...) values of B faces' three corners (or
    edges), coordinate by coordinate: (B, ...) each, as ``corners.min(axis=1)`` and
    ``max(axis=1)`` (two element-wise passes; a reduction down the short middle axis is
    several times slower)."""
    first, second, third = corners[:, 0], corners[:, 1], corners[:, 2]
    return (np.minimum(np.minimum(first, second), third),
            np.maximum(np.maximum(first, second), third))


def column_bounds(points: NDArray[Any]) -> tuple[NDArray[Any], NDArray[Any]]:
    """(3,) the least and (3,) the most of the (N, 3) ``points``, column by column, as
    ``points.min(axis=0)`` and ``max(axis=0)`` (a reduction down the long first axis of
    an (N, 3) array is some ten times slower). N must be positive."""
    return (np.array([points[:, k].min() for k in range(3)]),
            np.array([points[:, k].max() for k in range(3)]))


def compact_indices(indices: NDArray[np.integer[Any]], size: int
                    ) -> tuple[NDArray[np.int64], NDArray[np.int32]]:
    """The values of ``indices`` (any shape, each in ``range(size)``) ascending, once each,
    and ``indices`` renumbered into them (int32): ``np.unique(indices,
    return_inverse=True)`` without its sort, by a mark over ``range(size)`` (a mesh's
    faces: millions of indices into a few million vertices)."""
    used = np.zeros(size, bool)
    used[indices] = True
    renumber = np.cumsum(used, dtype=np.int32)
    renumber -= 1
    return np.flatnonzero(used), renumber[indices]


def split_to_size(vertices: FloatArray, faces: NDArray[np.integer[Any]], max_edge_m: float,
                  max_iter: int) -> tuple[FloatArray, IndexArray, IndexArray]:
    """The pieces of :func:`trimesh.remesh.subdivide_to_size` (``return_index=True``), value
    for value and in its order: (V', 3) float64 vertices (the (V, 3) ``vertices`` first,
    then each round's midpoints), (F', 3) int32 faces and (F',) int32 the index of each
    piece's face in the (F, 3) ``faces``. Raises ValueError when ``max_iter`` rounds leave
    an edge longer than ``max_edge_m``, as trimesh does.

    Each round halves every edge longer than ``max_edge_m`` at one midpoint shared by the
    faces on it, and replaces a face by trimesh's template for its one, two or three
    halved edges. trimesh finds the unique edges of every face and hashes them each round
    (some 450 bytes of scratch a piece, a split's peak with two blocks of a million pieces
    at a time); here only the long edges are made unique, int32 indices throughout, and
    the round that finds no long edge measures the edges a block at a time (about 100
    bytes a piece). The midpoints are numbered as trimesh numbers them, in the order of
    their edges' (larger, smaller) corner index, which is the order of trimesh's edge
    hashes; lengths, midpoints and the two-edge template's diagonal are the same
    expressions on the same values.
    """
    vertices = np.asarray(vertices, np.float64)
    current: IndexArray = np.asarray(faces, np.int32)
    index = np.arange(len(current), dtype=np.int32)
    for round_ in range(max_iter + 1):
        long = _long_edges(vertices, current, max_edge_m)  # (F, 3): v0v1, v1v2, v2v0
        if not long.any():
            break
        if round_ >= max_iter:
            raise ValueError("max_iter exceeded!")
        # each long edge once, numbered by its (larger, smaller) corner pair
        first, second = current[long], np.roll(current, -1, axis=1)[long]  # (m,) each
        keys = np.maximum(first, second).astype(np.int64) << 32
        keys |= np.minimum(first, second)
        del first, second
        unique_keys, inverse = np.unique(keys, return_inverse=True)
        del keys
        middle = np.full(current.shape, -1, np.int32)  # (F, 3) each edge's midpoint, or -1
        middle[long] = inverse.astype(np.int32) + len(vertices)
        del inverse
        ends = np.stack((unique_keys & 0xFFFFFFFF, unique_keys >> 32), axis=1)  # (u, 2)
        del unique_keys
        vertices = np.concatenate([vertices, vertices[ends].mean(axis=1)])
        del ends
        count = np.count_nonzero(long, axis=1)  # (F,) halved edges of each face
        pieces = [current[count == 0]]
        indices = [index[count == 0]]
        # one halved edge: rotated to (a, b), the midpoint fanned to the opposite corner
        one = count == 1
        j = np.argmax(long[one], axis=1)
        r = np.arange(len(j))
        corners, middles = current[one], middle[one]
        a, b, c = corners[r, j], corners[r, (j + 1) % 3], corners[r, (j + 2) % 3]
        p = middles[r, j]
        pieces.append(np.column_stack((a, p, c, p, b, c)).reshape((-1, 3)))
        indices.append(np.repeat(index[one], 2))
        # two: rotated so that (c, a) is whole; a corner triangle and the quad (a, p, q, c)
        # cut along its shorter diagonal
        two = count == 2
        j = (np.argmin(long[two], axis=1) + 1) % 3
        r = np.arange(len(j))
        corners, middles = current[two], middle[two]
        a, b, c = corners[r, j], corners[r, (j + 1) % 3], corners[r, (j + 2) % 3]
        p, q = middles[r, j], middles[r, (j + 1) % 3]
        use_aq = (((vertices[a, :3] - vertices[q, :3]) ** 2).sum(axis=1)
                  <= ((vertices[p, :3] - vertices[c, :3]) ** 2).sum(axis=1))[:, None]
        pieces.append(np.column_stack((p, b, q)))
        pieces.append(np.where(use_aq, np.column_stack((a, p, q)), np.column_stack((a, p, c))))
        pieces.append(np.where(use_aq, np.column_stack((a, q, c)), np.column_stack((p, q, c))))
        indices.append(np.tile(index[two], 3))
        # three: the regular 1 -> 4 split
        three = count == 3
        v0, v1, v2 = current[three].T
        m0, m1, m2 = middle[three].T
        pieces.append(np.column_stack((v0, m0, m2, m0, v1, m1, m2, m1, v2, m0, m1, m2)
                                      ).reshape((-1, 3)))
        indices.append(np.repeat(index[three], 4))
        del long, middle, count, one, two, three, corners, middles, a, b, c, p, q, use_aq
        del v0, v1, v2, m0, m1, m2
        current = np.concatenate(pieces).astype(np.int32, copy=False)
        index = np.concatenate(indices)
        del pieces, indices
    return vertices, current, index


def _long_edges(vertices: FloatArray, faces: IndexArray, max_edge_m: float
                ) -> NDArray[np.bool_]:
    """(F, 3) bool: the edges v0v1, v1v2, v2v0 of the (F, 3) ``faces`` longer than
    ``max_edge_m``, measured as trimesh measures them: from the smaller corner index to the
    larger, sqrt((dx^2 + dy^2) + dz^2) in float64 (a compiled loop: numpy's gathers and
    temporaries were a quarter of a 10 M-piece split's CPU)."""
    long = np.empty(faces.shape, bool)
    _mark_long_edges(np.ascontiguousarray(vertices, np.float64), faces, max_edge_m, long)
    return long


@numba.njit(nogil=True, cache=True)
def _mark_long_edges(vertices: FloatArray, faces: NDArray[np.integer[Any]],
                     max_edge_m: float, out: NDArray[np.bool_]) -> None:
    """Write :func:`_long_edges` of the (F, 3) ``faces`` into the (F, 3) ``out``."""
    for f in range(faces.shape[0]):
        for k in range(3):
            first, second = faces[f, k], faces[f, (k + 1) % 3]
            low, high = min(first, second), max(first, second)
            dx = vertices[low, 0] - vertices[high, 0]
            dy = vertices[low, 1] - vertices[high, 1]
            dz = vertices[low, 2] - vertices[high, 2]
            out[f, k] = np.sqrt(dx * dx + dy * dy + dz * dz) > max_edge_m


def subdivide(vertices: FloatArray, faces: IndexArray, max_edge_m: float,
              split: NDArray[np.bool_] | None = None
              ) -> tuple[FloatArray, IndexArray, IndexArray] | None:
    """The pieces of :func:`remesh` as arrays: (V', 3) vertices, (F', 3) int32 faces and
    (F',) int32 the index of each piece's face in the (F, 3) ``faces``; None when no face of
    ``split`` (default: every face) is longer than ``max_edge_m``."""
    if split is None:
        edge_m = longest_edges_m(vertices, faces)
    else:  # the others are kept whole: as if already small enough
        edge_m = np.zeros(len(faces))
        edge_m[split] = longest_edges_m(vertices, faces[split])
    longest = float(edge_m.max())
    if longest <= max_edge_m:
        return None
    iterations = math.ceil(math.log2(longest / max_edge_m)) + 2
    blocks = _piece_blocks(edge_m, max_edge_m, _REMESH_BLOCK_PIECES)

    def pieces_of(block: tuple[int, int]) -> tuple[FloatArray, IndexArray, IndexArray]:
        """(v, 3) vertices, (f, 3) faces (local indices) and (f,) file-order source face
        (within the block) of the pieces of faces ``start:stop``, in file order."""
        start, stop = block
        used, local = compact_indices(faces[start:stop], len(vertices))  # local: (f, 3)
        # the block's faces to split (all, or those of ``split``); the others pass through
        cut: slice | NDArray[np.intp] = (
            slice(None) if split is None else np.flatnonzero(split[start:stop]))
        if isinstance(cut, slice) or len(cut):
            block_vertices, block_faces, index = split_to_size(
                vertices[used], local[cut], max_edge_m, iterations)
        else:
            block_vertices, block_faces, index = (
                vertices[used], np.zeros((0, 3), np.int32), np.zeros(0, np.int32))
        if split is not None:
            # split_to_size keeps the given vertices first: whole faces index them as is
            whole = np.flatnonzero(~split[start:stop])
            index = np.concatenate([np.asarray(cut, np.int32)[index], whole.astype(np.int32)])
            block_faces = np.concatenate([block_faces, local[whole]])
        # split_to_size groups the unsplit faces first; restore file order (stable)
        order = np.argsort(index, kind="stable")
        return block_vertices, block_faces[order], index[order]

    # grown in place block by block: no list of blocks and concatenated copy side by side
    out_vertices = GrowingArray(np.float64)  # (3 V',) flat
    out_faces = GrowingArray(np.int32)  # (3 F',) flat
    out_source = GrowingArray(np.int32)  # (F',)
    n_vertices = 0
    # split on a few threads (trimesh's numpy work mostly releases the GIL) and joined
    # in block order, so the pieces do not depend on the threads
    for (start, _), (block_vertices, block_faces, index) in zip(
            blocks, in_block_order(pieces_of, blocks), strict=True):
        out_vertices.append(block_vertices.reshape(-1))
        if n_vertices + len(block_vertices) >= 2**31 - 1:
            raise SceneError("the model has more than 2**31 vertices or faces; split it")
        block_faces += n_vertices  # a block's own array, int32 (checked to fit)
        out_faces.append(block_faces.reshape(-1))
        out_source.append(index + start)
        n_vertices += len(block_vertices)
    return (out_vertices.done().reshape(-1, 3), out_faces.done().reshape(-1, 3),
            out_source.done())
