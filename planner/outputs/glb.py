"""``coverage.glb``: the model coloured by coverage, with a numbered marker at each station.

Written by hand (glTF 2.0 binary) rather than through an exporter, so that the bytes depend
only on the plan: the JSON chunk has sorted keys, the binary chunk is laid out in a fixed
order, nothing carries a date or a version string that changes.

Layout
------
- Model coordinates are Z-up metres; glTF is Y-up, so the root node ``scanplan`` carries a
  rotation of -90 degrees about X. Everything below it is in model coordinates.
- Drawn by *feature*: the faces (rows of ``faces.npz``) that come from one face of the
  file and share a coverage state, i.e. a class and, covered, an LPD band (``LPD_BANDS``:
  best LPD 1-2, 2-4, 4-8, 8 or more times the requirement). A model split for the
  coverage (``max_edge_m``) has millions of faces but few features: a file face of one
  state is written as the file face itself (its three corners), one of several states as
  the outline of each state's faces (holes and all, corners on a straight run dropped)
  triangulated with no new vertices (GEOS's constrained Delaunay through ``shapely``;
  where that would not cover exactly the faces' area, the faces themselves). The outline
  is the faces' edges that no other face of the state uses (the pieces of a file face
  share their vertices along common edges), found for every feature in one compiled pass
  (:mod:`planner.outputs.outline`); shapely's union of the faces only where those edges
  make no closed loops. The generated office of 9.7 M split faces takes 0.07 triangles a
  face. A feature is drawn in the colour of its worst face (the lowest best LPD over the
  requirement), so a covered feature's shade is what all of it reaches at least. An
  unsplit model (the paper's halls) has a feature a face, feature ``i`` being face ``i``,
  drawn as before.
- One node and mesh per face class (``covered``, ``coverable_not_covered``,
  ``not_coverable``, ``not_target``; empty classes are left out), so a viewer toggles a
  class by hiding a node; its ``extras`` give ``faces`` (rows of ``faces.npz``) and
  ``features``. Triangles do not share vertices (3 each, feature after feature in
  feature order), so ``COLOR_0`` is exactly the feature's colour of
  :func:`planner.outputs.drawing.face_rgb` (stored linear, as glTF requires). No
  ``NORMAL``: glTF asks viewers to shade such meshes flat, which is what per-face colours
  show. A class of more than ``PRIMITIVE_MAX_FACES`` triangles is split into primitives of
  that many (the last fewer), in order (a feature may go on into the next primitive): each
  primitive's arrays are made, compressed and let go before the next, so a 10 M-face model
  never holds (F, 3) vertex arrays.
- Viewer-sized: positions are uint16 steps of one grid over the scene's bounds
  (``KHR_mesh_quantization``; the class node's ``scale`` and ``translation`` map them back,
  ``position_step_m`` in the scene extras gives the step), and every vertex attribute and
  property-table column is stored with ``EXT_meshopt_compression`` (lossless). Both are in
  ``extensionsRequired``; three.js and Babylon.js read them, and the parameter
  ``glb_compression`` ``none`` gives the same arrays uncompressed. The generated office
  of 9.7 M split faces takes 12.4 MB (152 MB when every face was drawn), 4.8 MB of it the
  features' rows of ``faces.npz``; exact per-face values stay in ``faces.npz``.
- ``_FEATURE_ID_0`` (float, per vertex) is the feature index: the row of the property
  table ``features`` of ``EXT_structural_metadata`` (class ``feature``) that
  ``EXT_mesh_features`` points it at. Per feature: ``covered``, ``face_class``,
  ``source_face`` (its file face), ``best_lpd_pts_m2`` and ``min_density_pts_m2`` of its
  worst face, the fewest ``n_stations`` and ``n_candidates`` of its faces, the latest
  ``first_station`` (the station by which all of it is covered), and ``faces``: a
  variable-length array of its rows of ``faces.npz`` (ascending), where a platform finds
  each face's own values. For an unsplit model feature ``i`` is face ``i`` and ``faces``
  is ``[i]``. Both extensions are optional (``extensionsUsed`` only): viewers that do not
  know them still show the colours.
- One node per station, ``station <n>``, a disc-topped marker at the scanner position with
  its number drawn as seven-segment bars standing above it (readable from the south,
  i.e. from -Y); its ``extras`` hold ``order``, ``candidate_index``, ``position``,
  ``new_area_m2``, ``covered_area_m2`` and ``coverage_fraction``.
- ``scenes[0].extras.scanplan`` carries the totals and the class names and colours.
"""

from __future__ import annotations

import dataclasses
import io
import json
import math
import struct
import tempfile
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import meshopt
import numba
import numpy as np
from numpy.typing import NDArray

from planner.io.orientation import glb_root_rotation, scene_rotation, to_model
from planner.memory import release_freed_memory
from planner.outputs.drawing import (
    CLASS_NAMES,
    CLASS_RGB,
    COVERED,
    COVERED_HIGH_RGB,
    COVERED_LOW_RGB,
    COVERED_SATURATION,
    STATION_RGB,
    face_classes,
    face_rgb,
)
from planner.outputs.outline import group_triangles
from planner.pipeline import PlanResult
from planner.scene import Scene

_FLOAT, _UBYTE, _USHORT, _UINT = 5126, 5121, 5123, 5125
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_TYPE_WIDTH = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}
_Z_UP_TO_Y_UP = [-math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)]  # quaternion x, y, z, w
_MARKER_RADIUS_M = 0.12
# faces of one primitive: a class mesh with more gets several (see the module docstring)
PRIMITIVE_MAX_FACES = 1 << 20
_CHUNK_VERTICES = 1 << 20
_COPY_BYTES = 1 << 20  # the binary chunk is copied from the spill file in blocks this big
_DIGIT_HEIGHT_M = 0.3
# a covered face's LPD band: how often its best LPD doubles the requirement, 1-2x, 2-4x,
# 4-8x, 8x and more (COVERED_SATURATION); pieces of a file face merge within one band
LPD_BANDS = 4

# seven-segment digits: segments a b c d e f g
_SEGMENTS = {
    "0": "abcdef", "1": "bc", "2": "abdeg", "3": "abcdg", "4": "bcfg",
    "5": "acdfg", "6": "acdefg", "7": "abc", "8": "abcdefg", "9": "abcdfg",
}


def srgb_to_linear(rgb: NDArray[np.uint8]) -> NDArray[np.float64]:
    """sRGB bytes -> linear floats in [0, 1] (glTF colours are linear)."""
    c = np.asarray(rgb, np.float64) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_bytes(rgb: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """sRGB bytes -> the linear UNSIGNED_BYTE values stored in ``COLOR_0`` (same shape)."""
    return np.rint(srgb_to_linear(rgb) * 255.0).astype(np.uint8)


# linear_bytes of each of the 256 byte values: a lookup instead of float64 temporaries
_LINEAR_BYTE = linear_bytes(np.arange(256, dtype=np.uint8))


class _Builder:
    """Accumulates buffer views and accessors of one binary buffer.

    With ``compress``, vertex attributes and property-table columns are stored with
    ``EXT_meshopt_compression`` (meshoptimizer's lossless vertex codec, via the ``meshopt``
    wheel): the compressed bytes go into the GLB's binary chunk (buffer 0) and each view
    names its place in buffer 1, a fallback buffer with no data that only gives the
    decompressed layout (the extension's ``fallback``). Without ``compress`` the same views
    hold the plain bytes in buffer 0, so both files decode to the same arrays.

    The binary chunk is the list of its ``pieces`` (``length`` bytes in all): padding, and
    ranges (offset, length) of ``spill``, a scratch file each view's bytes are written to
    as soon as they are made, so that the file's ~16 bytes a face are never all held.
    """

    def __init__(self, compress: bool, spill: BinaryIO) -> None:
        self.compress = compress
        self.spill = spill
        self.spilled = 0  # bytes written to spill
        self.pieces: list[bytes | tuple[int, int]] = []
        self.length = 0
        self.fallback_length = 0  # bytes of buffer 1 (the decompressed layout)
        self.views: list[dict[str, Any]] = []
        self.accessors: list[dict[str, Any]] = []

    @staticmethod
    def _pad(length: int, align: int) -> int:
        return length + (-length % align)

    def _append(self, piece: bytes | tuple[int, int]) -> None:
        self.pieces.append(piece)
        self.length += len(piece) if isinstance(piece, bytes) else piece[1]

    def stash(self, data: bytes | NDArray[Any]) -> tuple[int, int]:
        """Write ``data`` (bytes, or a C-contiguous array's bytes) to the spill file: its
        (offset, length) there."""
        offset = self.spilled
        self.spilled += self.spill.write(data.data if isinstance(data, np.ndarray) else data)
        return offset, self.spilled - offset

    def _align(self, align: int) -> None:
        if self.length % align:
            self._append(b"\0" * (-self.length % align))

    @staticmethod
    def encode(data: NDArray[Any], row_bytes: int) -> bytes:
        """``data``'s bytes meshopt-encoded in rows of ``row_bytes`` (a multiple of 4, up to
        256): vertex codec version 0, the one ``EXT_meshopt_compression`` defines."""
        rows = np.ascontiguousarray(data).view(np.uint8).reshape(-1, row_bytes)
        packed: bytes = meshopt.encode_gltf_buffer(rows, "ATTRIBUTES", version=0)
        return packed

    def view(self, data: NDArray[Any], target: int | None = None, *,
             stride: int | None = None) -> int:
        """A buffer view of ``data``'s bytes; ``stride``: bytes per vertex of an attribute.

        Meshopt-compressed when the builder compresses; the length must then be a multiple
        of 4 (the codec works on rows of 4 to 256 bytes: ``stride``, else 4).
        """
        raw = np.ascontiguousarray(data)
        if self.compress and raw.nbytes:
            row_bytes = stride if stride is not None else 4
            return self.packed_view(self.stash(self.encode(raw, row_bytes)), raw.nbytes,
                                    row_bytes, target=target, stride=stride)
        view = self._view_of(raw.nbytes, target, stride)
        self._align(8)
        view["byteOffset"] = self.length
        self._append(self.stash(raw))
        self.views.append(view)
        return len(self.views) - 1

    def packed_view(self, packed: tuple[int, int], nbytes: int, row_bytes: int, *,
                    target: int | None = None, stride: int | None = None) -> int:
        """A buffer view of ``nbytes`` bytes stored as their :meth:`encode`, ``packed``
        (:meth:`stash` ed)."""
        view = self._view_of(nbytes, target, stride)
        self._align(4)
        view["extensions"] = {"EXT_meshopt_compression": {
            "buffer": 0, "byteOffset": self.length, "byteLength": packed[1],
            "byteStride": row_bytes, "count": nbytes // row_bytes, "mode": "ATTRIBUTES"}}
        self._append(packed)
        # 8-byte aligned as EXT_structural_metadata asks of property values
        self.fallback_length = self._pad(self.fallback_length, 8)
        view["buffer"] = 1
        view["byteOffset"] = self.fallback_length
        self.fallback_length += nbytes
        self.views.append(view)
        return len(self.views) - 1

    @staticmethod
    def _view_of(nbytes: int, target: int | None, stride: int | None) -> dict[str, Any]:
        view: dict[str, Any] = {"buffer": 0, "byteLength": nbytes}
        if stride is not None:
            view["byteStride"] = stride
        if target is not None:
            view["target"] = target
        return view

    def accessor(self, array: NDArray[Any], kind: str, *, normalized: bool = False,
                 bounds: bool = False, count: int | None = None) -> int:
        """An accessor over a vertex attribute ``array`` (V, k), one row per vertex.

        Rows are padded to a multiple of 4 bytes (glTF's vertex stride rule), so a
        (V, 3) uint16 position takes 8 bytes per vertex; ``kind`` names the used part. An
        array that has the padded width already, such as (V, 4) uint16 for a VEC3, is
        taken as padded (its extra columns zero).
        """
        component = {np.dtype(np.float32): _FLOAT, np.dtype(np.uint8): _UBYTE,
                     np.dtype(np.uint16): _USHORT}[array.dtype]
        data = np.ascontiguousarray(array).reshape(len(array), -1)
        width = _TYPE_WIDTH[kind]
        row_bytes = data.itemsize * width
        stride = row_bytes + (-row_bytes % 4)
        if data.shape[1] * data.itemsize != stride:
            padded = np.zeros((len(data), stride // data.itemsize), data.dtype)
            padded[:, :width] = data
            data = padded
        accessor: dict[str, Any] = {
            "bufferView": self.view(data, _ARRAY_BUFFER, stride=stride),
            "componentType": component, "count": len(data), "type": kind,
        }
        if normalized:
            accessor["normalized"] = True
        if bounds:
            accessor["min"] = [float(v) for v in data[:, :width].min(axis=0)]
            accessor["max"] = [float(v) for v in data[:, :width].max(axis=0)]
        self.accessors.append(accessor)
        return len(self.accessors) - 1

    def buffers(self) -> list[dict[str, Any]]:
        """The document's ``buffers``: the binary chunk, and the fallback when compressed."""
        self._align(4)
        buffers: list[dict[str, Any]] = [{"byteLength": self.length}]
        if self.fallback_length:
            buffers.append({"byteLength": self._pad(self.fallback_length, 4),
                            "extensions": {"EXT_meshopt_compression": {"fallback": True}}})
        return buffers


class _Quantizer:
    """Model coordinates -> uint16 grid steps (``KHR_mesh_quantization``).

    One grid for every class mesh (origin: the scene's lower bound; step: its longest side
    / 65535, so 0.76 mm on a 50 m building) keeps the seams between classes closed. The
    node of each class mesh carries the inverse (``translation`` origin, ``scale`` step),
    so viewers draw model coordinates; a vertex moves by at most half a step per axis.
    """

    def __init__(self, bounds: NDArray[np.float64]) -> None:
        self.origin = np.asarray(bounds[0], np.float64)
        extent = float(np.max(bounds[1] - bounds[0]))
        self.step_m = extent / 65535.0 if extent > 0 else 1.0

    def __call__(self, points: NDArray[np.float64], out: NDArray[np.uint16] | None = None
                 ) -> NDArray[np.uint16]:
        """(N, 3) points -> (N, 3) grid steps (into ``out`` when given),
        ``_CHUNK_VERTICES`` at a time (no (N, 3) float64 temporaries)."""
        if out is None:
            out = np.empty(points.shape, np.uint16)
        for start in range(0, len(points), _CHUNK_VERTICES):
            block = slice(start, start + _CHUNK_VERTICES)
            steps = np.rint((points[block] - self.origin) / self.step_m)
            out[block] = np.clip(steps, 0, 65535)
        return out

    def node(self) -> dict[str, Any]:
        """``translation`` and ``scale`` of a node whose mesh holds quantized positions."""
        return {"translation": [float(v) for v in self.origin],
                "scale": [self.step_m] * 3}


def _flat_primitive(builder: _Builder, triangles: NDArray[np.float32] | NDArray[np.uint16],
                    rgba: NDArray[np.uint8], feature: NDArray[np.float32] | None,
                    material: int) -> dict[str, Any]:
    """A primitive of unshared triangles (T, 3, 3) with one RGBA (T, 4) per triangle;
    quantized, they may come as (T, 3, 4) with the last column zero (the padded rows the
    file stores, see :meth:`_Builder.accessor`).

    Not indexed on purpose: every face has its own colour and face id, so no two faces
    could share a vertex and an index buffer would only count 0, 1, 2, ... No ``NORMAL``:
    glTF viewers must then draw flat faces with computed normals, which is what a per-face
    colouring shows anyway, at a third less data. ``triangles`` are float32 model
    coordinates, or uint16 grid steps of :class:`_Quantizer` (the node scales them back).
    """
    positions = triangles.reshape(-1, triangles.shape[-1])
    attributes = {
        "POSITION": builder.accessor(positions, "VEC3", bounds=True),
        "COLOR_0": builder.accessor(np.repeat(rgba, 3, axis=0), "VEC4", normalized=True),
    }
    primitive: dict[str, Any] = {"attributes": attributes, "material": material, "mode": 4}
    if feature is not None:
        attributes["_FEATURE_ID_0"] = builder.accessor(np.repeat(feature, 3), "SCALAR")
        primitive["extensions"] = {"EXT_mesh_features": {"featureIds": [
            {"featureCount": int(feature.max()) + 1 if len(feature) else 0,
             "attribute": 0, "propertyTable": 0}]}}
    return primitive


def _box(lo: tuple[float, float, float], hi: tuple[float, float, float]) -> NDArray[np.float64]:
    """(12, 3, 3) outward triangles of an axis-aligned box."""
    x0, y0, z0 = lo
    x1, y1, z1 = hi
    c = np.array([[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0],
                  [x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]])
    quads = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]
    tris = [(q[0], q[1], q[2]) for q in quads] + [(q[0], q[2], q[3]) for q in quads]
    return np.asarray(c[np.array(tris)], np.float64)


def _marker(radius: float, segments: int = 16) -> NDArray[np.float64]:
    """(T, 3, 3) a standing pin: a thin post from the floor direction and a flat disc."""
    angles = np.linspace(0.0, 2 * math.pi, segments, endpoint=False)
    ring = np.stack([radius * np.cos(angles), radius * np.sin(angles),
                     np.zeros(segments)], axis=1)
    nxt = np.roll(ring, -1, axis=0)
    top = np.array([0.0, 0.0, 0.02])
    bottom = -top
    discs = [np.stack([np.broadcast_to(top, ring.shape), ring + top, nxt + top], axis=1),
             np.stack([np.broadcast_to(bottom, ring.shape), nxt + bottom, ring + bottom], axis=1)]
    post = _box((-0.015, -0.015, -0.6), (0.015, 0.015, 0.0))
    return np.concatenate([*discs, post])


def _digits(label: str, height: float) -> NDArray[np.float64]:
    """(T, 3, 3) seven-segment bars of ``label`` in the XZ plane, centred on x = 0, z >= 0."""
    w, t = height * 0.5, height * 0.12
    half = height / 2
    boxes = []
    pitch = w + height * 0.25
    start = -(pitch * len(label) - height * 0.25) / 2
    for i, char in enumerate(label):
        x = start + i * pitch
        bars = {
            "a": (x, height - t, x + w, height), "g": (x, half - t / 2, x + w, half + t / 2),
            "d": (x, 0.0, x + w, t), "f": (x, half, x + t, height),
            "b": (x + w - t, half, x + w, height), "e": (x, 0.0, x + t, half),
            "c": (x + w - t, 0.0, x + w, half),
        }
        for seg in _SEGMENTS.get(char, ""):
            x0, z0, x1, z1 = bars[seg]
            boxes.append(_box((x0, -0.01, z0), (x1, 0.01, z1)))
    return np.asarray(np.concatenate(boxes) if boxes else np.zeros((0, 3, 3)), np.float64)


@dataclass(frozen=True)
class _Features:
    """The file's features: the faces of the plan grouped by file face and coverage state.

    A feature is every face (piece) of one file face with one state: its class and, when
    covered, its LPD band (``LPD_BANDS``). It is drawn as few triangles as its outline
    needs, all in its colour (that of its worst face: the lowest best LPD over the
    requirement), and is one row of the property table. A scene that was never split has
    one feature a face, face ``i`` being feature ``i``, drawn as itself.

    Attributes (N features, T triangles; ``corners`` index the scene's vertices followed by
    the file's, :func:`_grid_vertices`)
    ----------
    rows : (F,) int32, the faces (rows of ``faces.npz``), feature after feature, each
        feature's ascending
    offsets : (N + 1,) int64, feature ``n`` holds ``rows[offsets[n]:offsets[n + 1]]``
    worst : (N,) int64, the row of each feature's face with the lowest best LPD over the
        requirement (the first such row)
    classes : (N,) uint8, each feature's class (``CLASS_NAMES``)
    corners : (T, 3) int, the triangles, feature after feature
    triangle_feature : (T,) int32 the feature of each triangle; None: triangle ``i`` is
        feature ``i`` (an unsplit scene)
    """

    rows: NDArray[np.int32]
    offsets: NDArray[np.int64]
    worst: NDArray[np.int64]
    classes: NDArray[np.uint8]
    corners: NDArray[np.integer[Any]]
    triangle_feature: NDArray[np.int32] | None

    @property
    def count(self) -> int:
        return len(self.classes)

    def triangle_classes(self) -> NDArray[np.uint8]:
        """(T,) uint8 the class of each triangle."""
        if self.triangle_feature is None:
            return self.classes
        return self.classes[self.triangle_feature]


def lpd_bands(ratio: NDArray[np.float64], classes: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """(F,) uint8 each face's LPD band: 0 for a face that is not covered, else 0 to
    ``LPD_BANDS - 1`` as its best LPD is 1-2, 2-4, ... times its requirement or more
    (``ratio``: (F,) best LPD over the requirement, :func:`_lpd_ratio`; any block of faces
    gives its own faces' bands)."""
    bands = np.zeros(len(classes), np.uint8)
    covered = classes == COVERED
    doublings = np.floor(np.log2(np.maximum(ratio[covered], 1.0)))
    bands[covered] = np.clip(doublings, 0, LPD_BANDS - 1).astype(np.uint8)
    return bands


def _best_and_required(result: PlanResult
                       ) -> tuple[NDArray[np.float32], NDArray[np.float64]]:
    """(F,) each face's best LPD (float32, as the plan holds it) and (F,) its requirement
    (float64; a read-only broadcast view where the plan has one requirement)."""
    best = np.asarray(result.faces["best_lpd_pts_m2"], np.float32)
    required = np.broadcast_to(np.asarray(result.limits.min_density_pts_m2, np.float64),
                               best.shape)
    return best, required


def _lpd_ratio(best: NDArray[np.float32], required: NDArray[np.float64]
               ) -> NDArray[np.float64]:
    """Each face's best LPD over its requirement (inf where it requires none), of the
    faces of (k,) ``best`` and ``required`` (:func:`_best_and_required`, or a block of
    them); the same division as :func:`_first_least` makes."""
    ratio = np.asarray(best, np.float64)
    return np.divide(ratio, required, out=np.full_like(ratio, np.inf), where=required > 0)


def _states(classes: NDArray[np.uint8], best: NDArray[np.float32],
            required: NDArray[np.float64]) -> NDArray[np.uint8]:
    """(F,) uint8 each face's state within its file face, class then LPD band
    (``classes * LPD_BANDS + band``), ``_CHUNK_VERTICES`` faces at a time: no (F,) float64
    ratios and their temporaries (some 250 MB on the 9.7 M-piece office)."""
    state = np.empty(len(classes), np.uint8)
    for start in range(0, len(classes), _CHUNK_VERTICES):
        block = slice(start, start + _CHUNK_VERTICES)
        ratio = _lpd_ratio(best[block], required[block])
        state[block] = classes[block] * LPD_BANDS + lpd_bands(ratio, classes[block])
    return state


def _features(result: PlanResult, classes: NDArray[np.uint8]) -> _Features:
    """The features of the plan (:class:`_Features`), from its (F,) face ``classes``."""
    scene = result.scene
    n = scene.n_faces
    if scene.file_faces is None:  # never split: each face its own feature, drawn as is
        every = np.arange(n, dtype=np.int32)
        return _Features(rows=every, offsets=np.arange(n + 1, dtype=np.int64),
                         worst=every.astype(np.int64), classes=classes,
                         corners=scene.faces, triangle_feature=None)
    source = scene.source_face
    best, required = _best_and_required(result)
    state = _states(classes, best, required)
    n_states = len(CLASS_NAMES) * LPD_BANDS
    # the faces by (file face, state), stably: a split scene keeps each file face's
    # pieces together in file order, so a counting sort of each file face's run of pieces
    # (no (F,) int64 keys, their argsort and their sorted copy: some 160 MB on a 5 M-piece
    # model, the peak of its outputs); a scene not in that order takes the sort
    rows = np.empty(n, np.int32)
    n_features = _features_by_face(source, state, n_states, rows, np.zeros(0, np.int64),
                                   False)
    if n_features >= 0:
        offsets = np.empty(n_features + 1, np.int64)
        _features_by_face(source, state, n_states, rows, offsets, True)
    else:
        key = source.astype(np.int64) * n_states + state
        rows = np.argsort(key, kind="stable").astype(np.int32)
        sorted_key = key[rows]
        del key
        # a feature starts where the key changes (no (F,) int64 differences)
        changes = np.flatnonzero(sorted_key[1:] != sorted_key[:-1]) + 1
        del sorted_key
        offsets = np.concatenate([[0] if n else [], changes, [n]]).astype(np.int64)
    del state
    worst = _first_least(best, required, rows, offsets)
    corners, made = group_triangles(scene, rows, offsets)
    return _Features(rows=rows, offsets=offsets, worst=worst,
                     classes=classes[rows[offsets[:-1]]], corners=corners,
                     triangle_feature=np.repeat(np.arange(len(made), dtype=np.int32), made))


@numba.njit(nogil=True, cache=True)
def _features_by_face(source: NDArray[np.int32], state: NDArray[np.uint8], n_states: int,
                      rows: NDArray[np.int32], offsets: NDArray[np.int64], write: bool) -> int:
    """How many features (distinct (file face, state)) the (F,) faces hold, -1 when
    ``source`` decreases somewhere (a file face's pieces not together in file order); with
    ``write``, the faces sorted stably by (file face, state) into ``rows`` and where each
    feature starts in them into ``offsets`` (its last: F). A counting sort of each file
    face's run of faces; compiled."""
    count = np.zeros(n_states, np.int64)
    place = np.zeros(n_states, np.int64)
    feature = 0
    first = 0
    while first < len(source):
        stop = first + 1
        while stop < len(source) and source[stop] == source[first]:
            stop += 1
        if stop < len(source) and source[stop] < source[first]:
            return -1
        count[:] = 0
        for i in range(first, stop):
            count[state[i]] += 1
        at = first
        for k in range(n_states):
            place[k] = at
            if count[k]:
                if write:
                    offsets[feature] = at
                feature += 1
            at += count[k]
        if write:
            for i in range(first, stop):
                rows[place[state[i]]] = i
                place[state[i]] += 1
        first = stop
    if write:
        offsets[feature] = len(source)
    return feature


@numba.njit(nogil=True, cache=True)
def _first_least(best: NDArray[np.float32], required: NDArray[np.float64],
                 rows: NDArray[np.int32], offsets: NDArray[np.int64]) -> NDArray[np.int64]:
    """(N,) of each group ``rows[offsets[n]:offsets[n + 1]]`` (rows ascending) the row of
    the least ratio of ``best`` over ``required`` (each (F,); inf where nothing is
    required: :func:`_lpd_ratio`'s values, computed here a row at a time); the first such
    row, NaN above all, as a sort puts it."""
    least = np.empty(len(offsets) - 1, np.int64)
    for n in range(len(offsets) - 1):
        worst = rows[offsets[n]]
        worst_value = _ratio(best, required, worst)
        for j in range(offsets[n] + 1, offsets[n + 1]):
            value = _ratio(best, required, rows[j])
            if value < worst_value or (np.isnan(worst_value) and not np.isnan(value)):
                worst, worst_value = rows[j], value
        least[n] = worst
    return least


@numba.njit(nogil=True, cache=True, inline="always")
def _ratio(best: NDArray[np.float32], required: NDArray[np.float64], row: int) -> float:
    """Row ``row``'s best LPD over its requirement, inf where it requires none."""
    if required[row] > 0:
        return float(np.float64(best[row]) / required[row])
    return np.inf


def _grid_vertices(scene: Scene, quantizer: _Quantizer) -> NDArray[np.uint16]:
    """(V + V0, 3) uint16 grid steps of the scene's vertices, then the file's (V0 only when
    the scene was split): the vertices :attr:`_Features.corners` index."""
    if scene.file_vertices is None:
        return quantizer(scene.vertices)
    n = len(scene.vertices)
    grid = np.empty((n + len(scene.file_vertices), 3), np.uint16)  # no concatenated copy
    quantizer(scene.vertices, grid[:n])
    quantizer(scene.file_vertices, grid[n:])
    return grid


def coverage_glb(result: PlanResult, *, compress: bool | None = None) -> bytes:
    """The bytes of ``coverage.glb`` (see the module docstring).

    ``compress`` (default: the plan's ``glb_compression`` is ``meshopt``): False leaves out
    ``EXT_meshopt_compression`` (same arrays, plain bytes) for loaders that lack a meshopt
    decoder.
    """
    out = io.BytesIO()
    write_coverage_glb(result, out, compress=compress)
    return out.getvalue()  # the buffer's own bytes, not a copy


def write_coverage_glb(result: PlanResult, out: BinaryIO, *, compress: bool | None = None,
                       spill_dir: Path | None = None) -> None:
    """Write ``coverage.glb`` (:func:`coverage_glb`'s bytes) to ``out``.

    The binary chunk is gathered in a scratch file in ``spill_dir`` (default: the system's
    temporary folder) and copied after the JSON chunk, so memory holds one primitive's
    arrays at a time rather than the whole file (145 MB for a 10 M-face plan).
    """
    with tempfile.TemporaryFile(dir=spill_dir) as spill:
        builder = _Builder(result.spec.glb_compression == "meshopt" if compress is None
                           else compress, spill)
        _pack(_document(result, builder), builder, out)
    release_freed_memory()  # the primitives' temporaries, freed, back to the system


def _document(result: PlanResult, builder: _Builder) -> dict[str, Any]:
    """The glTF JSON of the plan; the binary chunk's pieces are left in ``builder``."""
    scene = result.scene
    quantizer = _Quantizer(scene.bounds)
    materials = [
        {"name": "coverage", "doubleSided": True,
         "pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0],
                                  "metallicFactor": 0.0, "roughnessFactor": 1.0}},
        {"name": "station", "doubleSided": True,
         "pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0],
                                  "metallicFactor": 0.0, "roughnessFactor": 0.8}},
    ]
    classes = face_classes(result.faces, result.limits.target)
    features = _features(result, classes)
    # compressed, the property table's columns are packed first, while little else is held:
    # each is one view of N values (one meshopt stream, which cannot be split); its place
    # in the file stays after the meshes
    packed_columns = (list(_property_columns(builder, result, classes, features))
                      if builder.compress else None)
    if packed_columns is not None:  # the meshes read no rows: let them go (4 bytes a face)
        features = dataclasses.replace(features, rows=np.zeros(0, np.int32))
    # quantize the vertices once, then gather corners: (T, 3, 3) uint16 per class is a
    # quarter of the float64 corners a 10 M-face scene would otherwise copy
    grid_vertices = _grid_vertices(scene, quantizer)
    meshes: list[dict[str, Any]] = []
    # the root puts the plan frame back into the model's coordinates (up_axis)
    root_rotation = glb_root_rotation(scene.metadata) or _Z_UP_TO_Y_UP
    nodes: list[dict[str, Any]] = [{"name": "scanplan", "rotation": root_rotation,
                                    "children": []}]
    counts = np.bincount(classes, minlength=len(CLASS_NAMES))
    feature_counts = np.bincount(features.classes, minlength=len(CLASS_NAMES))
    triangle_classes = features.triangle_classes()
    for k, name in enumerate(CLASS_NAMES):
        if counts[k] == 0:
            continue
        primitives = []
        for members in _class_parts(triangle_classes, k, PRIMITIVE_MAX_FACES):
            ids = (members if features.triangle_feature is None
                   else features.triangle_feature[members])
            rgba = np.full((len(members), 4), 255, np.uint8)
            rgba[:, :3] = _LINEAR_BYTE[face_rgb(result.faces, result.limits.target,
                                                result.limits.min_density_pts_m2,
                                                features.worst[ids])]
            # the rows as stored, (T, 3, 4) with a zero fourth column, a corner at a time
            corners = np.zeros((len(members), 3, 4), np.uint16)
            for c in range(3):
                corners[:, c, :3] = grid_vertices[features.corners[members, c]]
            primitives.append(_flat_primitive(builder, corners, rgba,
                                              ids.astype(np.float32), material=0))
            del rgba, corners
            release_freed_memory()  # the part's temporaries, before the next part's
        meshes.append({"name": name, "primitives": primitives})
        nodes[0]["children"].append(len(nodes))
        nodes.append({"name": name, "mesh": len(meshes) - 1, **quantizer.node(),
                      "extras": {"face_class": name, "faces": int(counts[k]),
                                 "features": int(feature_counts[k])}})
    del grid_vertices, triangle_classes

    station_rgba = np.array([[*linear_bytes(np.array(STATION_RGB, np.uint8)), 255]], np.uint8)
    marker = _marker(_MARKER_RADIUS_M)
    meshes.append({"name": "station_marker", "primitives": [_flat_primitive(
        builder, marker.astype(np.float32), np.repeat(station_rgba, len(marker), axis=0),
        None, material=1)]})
    marker_mesh = len(meshes) - 1
    chosen = result.chosen
    max_area = chosen.max_achievable_area_m2
    for order, candidate in enumerate(chosen.stations):
        label = str(order + 1)
        digits = _digits(label, _DIGIT_HEIGHT_M) + np.array([0.0, 0.0, 0.15])
        meshes.append({"name": f"station {label} number", "primitives": [_flat_primitive(
            builder, digits.astype(np.float32), np.repeat(station_rgba, len(digits), axis=0), None,
            material=1)]})
        position = [round(float(v), 6) for v in result.candidates.positions[candidate]]
        at = result.candidates.positions[candidate:candidate + 1]
        # the node sits in the levelled frame under the root; extras give model coordinates
        in_model = [round(float(v), 6) for v in to_model(scene_rotation(scene.metadata), at)[0]]
        covered = chosen.covered_area_m2[order]
        nodes[0]["children"].append(len(nodes))
        nodes.append({
            "name": f"station {label}", "mesh": marker_mesh, "translation": position,
            "children": [len(nodes) + 1],
            "extras": {"station": order + 1, "order": order + 1,
                       "candidate_index": int(candidate), "position": in_model,
                       "new_area_m2": round(chosen.new_area_m2[order], 6),
                       "covered_area_m2": round(covered, 6),
                       "coverage_fraction": round(covered / max_area if max_area else 0.0, 6)},
        })
        nodes.append({"name": f"station {label} number", "mesh": len(meshes) - 1})

    metadata = _property_table(builder, features, _property_columns(
        builder, result, classes, features) if packed_columns is None else packed_columns)
    compression = ["EXT_meshopt_compression"] if builder.fallback_length else []
    totals_covered = chosen.covered_area_m2[-1] if chosen.stations else 0.0
    document: dict[str, Any] = {
        "asset": {"version": "2.0", "generator": "scanplan coverage.glb"},
        "extensionsUsed": sorted(["EXT_mesh_features", "EXT_structural_metadata",
                                  "KHR_mesh_quantization", *compression]),
        "extensionsRequired": sorted(["KHR_mesh_quantization", *compression]),
        "extensions": {"EXT_structural_metadata": metadata},
        "scene": 0,
        "scenes": [{"name": "scan plan", "nodes": [0], "extras": {"scanplan": {
            "up_axis": "model Z (root node rotates it to glTF Y)",
            "method": chosen.method, "stations": len(chosen.stations),
            "covered_area_m2": round(totals_covered, 6),
            "max_achievable_area_m2": round(max_area, 6),
            "coverage_goal": result.spec.coverage_goal,
            "min_density_pts_m2": result.spec.min_density_pts_m2,
            "face_classes": {name: {"index": k, "srgb": list(CLASS_RGB[k])}
                             for k, name in enumerate(CLASS_NAMES)},
            "covered_shading": {"low_srgb": list(COVERED_LOW_RGB),
                                "high_srgb": list(COVERED_HIGH_RGB),
                                "saturation_ratio": COVERED_SATURATION},
            "face_ids": ("_FEATURE_ID_0 = row of the property table 'features'; its "
                         "'faces' lists the feature's rows of faces.npz"),
            "lpd_bands": LPD_BANDS,
            "position_step_m": quantizer.step_m,
        }}}],
        "nodes": nodes,
        "meshes": meshes,
        "materials": materials,
        "accessors": builder.accessors,
        "bufferViews": builder.views,
        "buffers": builder.buffers(),
    }
    return document


def _class_parts(classes: NDArray[np.uint8], k: int, most: int) -> Iterator[NDArray[np.int64]]:
    """The faces of class ``k`` in ascending order, in runs of ``most`` (the last fewer):
    (n,) int64 each, found ``PRIMITIVE_MAX_FACES`` faces of ``classes`` at a time."""
    pending: list[NDArray[np.int64]] = []
    held = 0
    for start in range(0, len(classes), PRIMITIVE_MAX_FACES):
        members = start + np.flatnonzero(classes[start:start + PRIMITIVE_MAX_FACES] == k)
        while len(members):
            take = members[:most - held]
            pending.append(take)
            held += len(take)
            members = members[len(take):]
            if held == most:
                yield np.concatenate(pending)
                pending, held = [], 0
    if held:
        yield np.concatenate(pending)


# a column of the property table: name, component type, its role ("values", or
# "arrayOffsets" of the array column before it), and either its values (padded to whole
# 4-byte rows) or, compressed, their meshopt bytes (stashed) and length
_Column = tuple[str, str, str, NDArray[Any] | None, tuple[int, int] | None, int]


def _property_columns(builder: _Builder, result: PlanResult, classes: NDArray[np.uint8],
                      features: _Features) -> Iterator[_Column]:
    """The columns of the property table (one row a feature), made one at a time; a
    compressed column is written to the spill file at once.

    A feature of several faces holds their worst: the best LPD and requirement of its
    worst face (:attr:`_Features.worst`), the fewest stations and candidates, the latest
    ``first_station``; ``faces`` lists its rows of faces.npz."""
    faces = result.faces

    def least(name: str, dtype: type[np.generic], reduce: np.ufunc = np.minimum
              ) -> NDArray[Any]:
        values = np.asarray(faces[name], dtype)
        if features.triangle_feature is None:  # a face a feature
            return values
        return np.asarray(reduce.reduceat(values[features.rows], features.offsets[:-1]), dtype)

    def of_worst(values: NDArray[Any], dtype: type[np.generic]) -> NDArray[Any]:
        values = np.broadcast_to(np.asarray(values, dtype), (result.scene.n_faces,))
        return np.ascontiguousarray(values[features.worst])

    columns: list[tuple[str, str, str, Callable[[], NDArray[Any]]]] = [
        ("covered", "UINT8", "values", lambda: of_worst(faces["covered"], np.uint8)),
        ("face_class", "UINT8", "values", lambda: features.classes),
        ("best_lpd_pts_m2", "FLOAT32", "values",
         lambda: of_worst(faces["best_lpd_pts_m2"], np.float32)),
        ("min_density_pts_m2", "FLOAT32", "values",
         lambda: of_worst(result.limits.min_density_pts_m2, np.float32)),
        ("n_stations", "INT32", "values", lambda: least("n_stations", np.int32)),
        ("first_station", "INT32", "values",
         lambda: least("first_station", np.int32, np.maximum)),
        ("n_candidates", "INT32", "values", lambda: least("n_candidates", np.int32)),
        ("source_face", "INT32", "values",
         lambda: of_worst(result.scene.source_face, np.int32)),
        ("faces", "UINT32", "values", lambda: features.rows.view(np.uint32)),
        ("faces", "UINT32", "arrayOffsets", lambda: features.offsets.astype(np.uint32)),
    ]
    for name, component, role, make in columns:
        values = make()
        if values.nbytes % 4:  # uint8 columns: whole 4-byte rows for the codec; count says
            padded = np.zeros(len(values) + (-values.nbytes % 4), values.dtype)
            padded[:len(values)] = values
            values = padded
        if builder.compress:
            yield (name, component, role, None, builder.stash(builder.encode(values, 4)),
                   values.nbytes)
        else:
            yield name, component, role, values, None, values.nbytes


def _property_table(builder: _Builder, features: _Features, columns: Iterable[_Column]
                    ) -> dict[str, Any]:
    properties: dict[str, dict[str, Any]] = {}
    table: dict[str, dict[str, Any]] = {}
    for name, component, role, values, packed, nbytes in columns:
        if packed is None:
            assert values is not None
            view = builder.view(values)
        else:
            view = builder.packed_view(packed, nbytes, 4)
        if role == "arrayOffsets":  # of the variable-length array column before it
            properties[name]["array"] = True
            table[name].update({"arrayOffsets": view, "arrayOffsetType": "UINT32"})
            continue
        properties[name] = {"type": "SCALAR", "componentType": component}
        table[name] = {"values": view}
    return {
        "schema": {"id": "scanplan", "classes": {"feature": {
            "description": ("coverage of the plan per feature: the faces of faces.npz "
                            "(listed in 'faces') that come from one face of the file and "
                            "share a class and, covered, an LPD band; a feature of several "
                            "faces holds the values of its worst face"),
            "properties": properties}}},
        "propertyTables": [{"name": "features", "class": "feature",
                            "count": features.count, "properties": table}],
    }


def _pack(document: dict[str, Any], builder: _Builder, out: BinaryIO) -> None:
    """Write the GLB file to ``out``: header, JSON chunk, and the binary chunk copied from
    the builder's pieces (``_COPY_BYTES`` at a time)."""
    text = json.dumps(document, sort_keys=True, separators=(",", ":"), allow_nan=False)
    json_bytes = text.encode("utf-8")
    json_bytes += b" " * (-len(json_bytes) % 4)
    total = 12 + 8 + len(json_bytes) + 8 + builder.length
    out.write(struct.pack("<4sII", b"glTF", 2, total))
    out.write(struct.pack("<I4s", len(json_bytes), b"JSON"))
    out.write(json_bytes)
    out.write(struct.pack("<I4s", builder.length, b"BIN\x00"))
    for piece in builder.pieces:
        if isinstance(piece, bytes):
            out.write(piece)
            continue
        offset, left = piece
        builder.spill.seek(offset)
        while left:
            block = builder.spill.read(min(left, _COPY_BYTES))
            out.write(block)
            left -= len(block)
