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
  (:func:`_outlines`); shapely's union of the faces only where those edges make no closed
  loops. The generated office of 9.7 M split faces takes 0.07 triangles a face. A feature
  is drawn in the colour of its worst face (the lowest best LPD over the requirement), so
  a covered feature's shade is what all of it reaches at least. An unsplit model (the
  paper's halls) has a feature a face, feature ``i`` being face ``i``, drawn as before.
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
import shapely
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
# a merged outline drops a corner this close to the line through its neighbours (pieces
# are split at edge midpoints, which lie on the edge only to rounding)
_COLLINEAR_M = 1e-6

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

    def __call__(self, points: NDArray[np.float64]) -> NDArray[np.uint16]:
        """(N, 3) points -> (N, 3) grid steps, ``_CHUNK_VERTICES`` at a time (no (N, 3)
        float64 temporaries)."""
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
    (``ratio``: (F,) best LPD over the requirement, :func:`_lpd_ratio`)."""
    bands = np.zeros(len(classes), np.uint8)
    covered = classes == COVERED
    doublings = np.floor(np.log2(np.maximum(ratio[covered], 1.0)))
    bands[covered] = np.clip(doublings, 0, LPD_BANDS - 1).astype(np.uint8)
    return bands


def _lpd_ratio(result: PlanResult) -> NDArray[np.float64]:
    """(F,) each face's best LPD over its requirement (inf where it requires none)."""
    best = np.asarray(result.faces["best_lpd_pts_m2"], np.float64)
    required = np.broadcast_to(np.asarray(result.limits.min_density_pts_m2, np.float64),
                               best.shape)
    return np.divide(best, required, out=np.full_like(best, np.inf), where=required > 0)


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
    ratio = _lpd_ratio(result)
    key = source.astype(np.int64) * (len(CLASS_NAMES) * LPD_BANDS) + (
        classes.astype(np.int64) * LPD_BANDS + lpd_bands(ratio, classes))
    rows = np.argsort(key, kind="stable").astype(np.int32)
    sorted_key = key[rows]
    offsets = np.append(np.flatnonzero(np.diff(sorted_key, prepend=-1)), n).astype(np.int64)
    del sorted_key
    del key
    worst = _first_least(ratio, rows, offsets)
    del ratio
    first = rows[offsets[:-1]]
    file_face = source[first].astype(np.int64)
    counts = np.diff(offsets)
    whole = counts == np.bincount(source, minlength=len(scene.file_mesh[1]))[file_face]
    triangle_feature, triangles, to_merge = _outlined(
        scene, rows, offsets, first, np.flatnonzero(~whole & (counts > 1)))
    merged = [triangles]
    merged_feature = [triangle_feature]
    for feature in to_merge.tolist():  # edges that make no closed loops: shapely's union
        members = rows[offsets[feature]:offsets[feature + 1]]
        merged.append(_merge(scene, scene.faces[members], int(first[feature]),
                             float(scene.areas[members].sum())))
        merged_feature.append(np.full(len(merged[-1]), feature, np.int64))
    triangle_feature = np.concatenate(merged_feature)
    by_feature = np.argsort(triangle_feature, kind="stable")
    triangle_feature, triangles = triangle_feature[by_feature], np.concatenate(merged)[by_feature]
    del merged, merged_feature, by_feature
    made = np.ones(len(counts), np.int64)
    made[~whole & (counts > 1)] = 0
    made += np.bincount(triangle_feature, minlength=len(counts))
    starts = np.concatenate([[0], np.cumsum(made)[:-1]])
    corners = np.empty((int(made.sum()), 3), np.int64)
    single = counts == 1
    corners[starts[single]] = scene.faces[first[single]]
    # a file face all of one state: the file face itself (its vertices follow the scene's)
    alone = whole & ~single
    corners[starts[alone]] = scene.file_mesh[1][file_face[alone]] + len(scene.vertices)
    # each merged feature's triangles, in order, from its start
    rank = np.arange(len(triangle_feature)) - np.searchsorted(triangle_feature, triangle_feature)
    corners[starts[triangle_feature] + rank] = triangles
    return _Features(rows=rows, offsets=offsets, worst=worst, classes=classes[first],
                     corners=corners,
                     triangle_feature=np.repeat(np.arange(len(counts), dtype=np.int32), made))


# a chunk of the features to outline holds about this many pieces (bounds the outlines'
# scratch arrays: 3 edges a piece)
_OUTLINE_CHUNK_PIECES = 1 << 16
# _outlines' verdict on a feature: outlined, or left to _merge (shapely's union)
_OUTLINED, _TO_MERGE = 0, 1


@numba.njit(nogil=True, cache=True)
def _first_least(values: NDArray[np.float64], rows: NDArray[np.int32],
                 offsets: NDArray[np.int64]) -> NDArray[np.int64]:
    """(N,) of each group ``rows[offsets[n]:offsets[n + 1]]`` (rows ascending) the row of
    the least of ``values`` (the first such row; NaN above all, as a sort puts it)."""
    least = np.empty(len(offsets) - 1, np.int64)
    for n in range(len(offsets) - 1):
        best = rows[offsets[n]]
        for j in range(offsets[n] + 1, offsets[n + 1]):
            value = values[rows[j]]
            if value < values[best] or (np.isnan(values[best]) and not np.isnan(value)):
                best = rows[j]
        least[n] = best
    return least


@numba.njit(nogil=True, cache=True)
def _outlines(faces: NDArray[np.int32], rows: NDArray[np.int32], offsets: NDArray[np.int64],
              chosen: NDArray[np.int64], vertices: NDArray[np.float64],
              axes: NDArray[np.int64], tolerance: float
              ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64],
                         NDArray[np.int64], NDArray[np.int8], NDArray[np.float64]]:
    """The outlines of the ``chosen`` features (their faces ``rows[offsets[n]:offsets[n +
    1]]``: pieces of one file face, which meet edge to edge and share the vertex indices
    along their common edges, as :func:`planner.scene.remesh` splits).

    Each feature is seen along the main axis of its normal: ``axes`` (k, 2) the other two
    axes of ``vertices`` (V, 3). An edge that no other piece of the feature uses is on its
    outline; followed from corner to corner these make closed loops, wound as the pieces
    (where the outline touches itself, each loop keeps to one side of the corner). A corner
    within ``tolerance`` of the line from the last kept corner to the next one is dropped,
    unless the outline touches itself there. Loops wound the other way than the feature's
    area are holes, each in the smallest outer loop around the middle of its first edge.

    Returns the loops' kept vertices (one after another), their (L + 1,) offsets into
    them, (L,) each loop's feature (into ``chosen``), (L,) the outer loop of each (itself
    for an outer loop), (k,) per feature ``_OUTLINED`` or ``_TO_MERGE`` (an edge used by
    more than two pieces or twice the same way, an outline that does not close, a loop of
    fewer than 3 corners, a hole in no outer loop: left to :func:`_merge`), and (k,) the
    length of each feature's outline before corners were dropped.
    """
    total = 0
    for n in chosen:
        total += offsets[n + 1] - offsets[n]
    loop_vertices = np.empty(3 * total, np.int64)
    loop_offsets = np.zeros(total + 1, np.int64)
    loop_feature = np.empty(total, np.int64)
    loop_area = np.empty(total, np.float64)
    loop_shell = np.empty(total, np.int64)
    status = np.zeros(len(chosen), np.int8)
    length = np.zeros(len(chosen), np.float64)
    n_loops = 0
    n_vertices = 0
    for f in range(len(chosen)):
        n = chosen[f]
        lo, m = offsets[n], offsets[n + 1] - offsets[n]
        keys = np.empty(3 * m, np.int64)
        start = np.empty(3 * m, np.int64)
        end = np.empty(3 * m, np.int64)
        for j in range(m):
            face = faces[rows[lo + j]]
            for e in range(3):
                a, b = np.int64(face[e]), np.int64(face[(e + 1) % 3])
                start[3 * j + e], end[3 * j + e] = a, b
                keys[3 * j + e] = (min(a, b) << 32) | max(a, b)
        order = np.argsort(keys)
        # the edges used once: the outline (directed as their piece winds)
        boundary = np.empty(3 * m, np.int64)
        nb = 0
        i = 0
        bad = False
        while i < 3 * m:
            k = i + 1
            while k < 3 * m and keys[order[k]] == keys[order[i]]:
                k += 1
            if k - i == 1:
                boundary[nb] = order[i]
                nb += 1
            elif k - i > 2 or start[order[i]] == start[order[i + 1]]:
                bad = True
                break
            i = k
        if bad or nb < 3:
            status[f] = _TO_MERGE
            continue
        ax, ay = axes[f, 0], axes[f, 1]
        # the pieces' winding as seen: +1 counter-clockwise, -1 clockwise
        wound = 0.0
        for j in range(m):
            face = faces[rows[lo + j]]
            a, b, c = face[0], face[1], face[2]
            wound += ((vertices[b, ax] - vertices[a, ax]) * (vertices[c, ay] - vertices[a, ay])
                      - (vertices[b, ay] - vertices[a, ay]) * (vertices[c, ax] - vertices[a, ax]))
        tails = start[boundary[:nb]]
        by_tail = np.argsort(tails)
        sorted_tails = tails[by_tail]
        # the edge that follows each: the one starting where it ends; where the outline
        # touches itself (several start there), the first one turning from the edge's way
        # back towards its pieces' side, so that every loop keeps to one side of the corner
        after = np.empty(nb, np.int64)
        used = np.zeros(nb, np.int64)
        pinch = np.zeros(nb, np.bool_)  # the edge starts where the outline touches itself
        for i in range(nb):
            head = end[boundary[i]]
            at = np.searchsorted(sorted_tails, head)
            if at == nb or sorted_tails[at] != head:
                bad = True
                break
            best = by_tail[at]
            if at + 1 < nb and sorted_tails[at + 1] == head:
                tail = start[boundary[i]]
                bu = vertices[tail, ax] - vertices[head, ax]
                bv = vertices[tail, ay] - vertices[head, ay]
                least = 10.0
                k = at
                while k < nb and sorted_tails[k] == head:
                    pinch[by_tail[k]] = True
                    w = end[boundary[by_tail[k]]]
                    ou = vertices[w, ax] - vertices[head, ax]
                    ov = vertices[w, ay] - vertices[head, ay]
                    # the turn from the way back to this edge, against the pieces' winding
                    turn = math.atan2(ou * bv - ov * bu, ou * bu + ov * bv)
                    if wound < 0:
                        turn = -turn
                    if turn <= 0:
                        turn += 2 * math.pi
                    if turn < least:
                        least, best = turn, by_tail[k]
                    k += 1
            after[i] = best
            used[best] += 1
        for i in range(nb):
            if used[i] != 1:
                bad = True
        if bad:
            status[f] = _TO_MERGE
            continue
        # each edge's tail as a place in sorted_tails (the first of its vertex's)
        slot = np.empty(nb, np.int64)
        for k in range(nb):
            slot[by_tail[k]] = k if k == 0 or sorted_tails[k] != sorted_tails[k - 1] else (
                slot[by_tail[k - 1]])
        first_loop, first_vertex = n_loops, n_vertices
        seen = np.zeros(nb, np.bool_)
        # the path followed so far: vertices, kept whatever the line (the outline touches
        # there), and where on it each vertex is (by slot; -1: not on it)
        path = np.empty(nb, np.int64)
        path_slot = np.empty(nb, np.int64)
        fixed = np.empty(nb, np.bool_)
        on_path = np.full(nb, -1, np.int64)
        signed = 0.0
        shells = 0
        for i0 in range(nb):
            if seen[i0] or bad:
                continue
            top = 0
            i = i0
            while True:
                # back at the start, or at a vertex of the path: the loop since then (a loop
                # that touches itself is cut there: a shell and a hole, or two shells)
                at = 0 if seen[i] else on_path[slot[i]]
                if at >= 0:
                    kept = _keep_corners(vertices, ax, ay, path[at:top], fixed[at:top],
                                         tolerance, loop_vertices, n_vertices)
                    if kept < 0:
                        bad = True
                        break
                    area = 0.0
                    for t in range(at, top):
                        on_path[path_slot[t]] = -1
                        p, q = path[t], path[t + 1 if t + 1 < top else at]
                        length[f] += math.hypot(vertices[q, ax] - vertices[p, ax],
                                                vertices[q, ay] - vertices[p, ay])
                    for t in range(n_vertices, kept):
                        p = loop_vertices[t]
                        q = loop_vertices[t + 1 if t + 1 < kept else n_vertices]
                        area += (vertices[p, ax] * vertices[q, ay]
                                 - vertices[p, ay] * vertices[q, ax])
                    n_vertices = kept
                    loop_feature[n_loops] = f
                    loop_area[n_loops] = area
                    n_loops += 1
                    loop_offsets[n_loops] = n_vertices
                    signed += area
                    top = at
                    if seen[i]:
                        break
                seen[i] = True
                on_path[slot[i]] = top
                path[top], path_slot[top], fixed[top] = start[boundary[i]], slot[i], pinch[i]
                top += 1
                i = after[i]
        if not bad:
            for i in range(first_loop, n_loops):
                loop_area[i] = loop_area[i] * signed  # > 0: an outer loop, < 0: a hole
                loop_shell[i] = i
                if loop_area[i] > 0:
                    shells += 1
            bad = shells == 0
        if not bad and shells < n_loops - first_loop:
            # each hole in the smallest outer loop around the middle of its first edge
            for h in range(first_loop, n_loops):
                if loop_area[h] > 0:
                    continue
                p, q = loop_vertices[loop_offsets[h]], loop_vertices[loop_offsets[h] + 1]
                pu = 0.5 * (vertices[p, ax] + vertices[q, ax])
                pv = 0.5 * (vertices[p, ay] + vertices[q, ay])
                least = np.inf
                for o in range(first_loop, n_loops):
                    if (loop_area[o] > 0 and loop_area[o] < least
                            and _inside(vertices, ax, ay, loop_vertices, loop_offsets[o],
                                        loop_offsets[o + 1], pu, pv)):
                        least, loop_shell[h] = loop_area[o], o
                if least == np.inf:
                    bad = True
                    break
        if bad:
            status[f] = _TO_MERGE
            n_loops, n_vertices = first_loop, first_vertex
            continue
    return (loop_vertices[:n_vertices].copy(), loop_offsets[:n_loops + 1].copy(),
            loop_feature[:n_loops].copy(), loop_shell[:n_loops].copy(), status, length)


@numba.njit(nogil=True, cache=True)
def _inside(vertices: NDArray[np.float64], ax: int, ay: int, loop: NDArray[np.int64],
            start: int, stop: int, pu: float, pv: float) -> bool:
    """Whether the point (``pu``, ``pv``) is inside the loop ``loop[start:stop]`` (vertex
    indices; seen along the axis other than ``ax`` and ``ay``): even-odd crossings."""
    inside = False
    for t in range(start, stop):
        a, b = loop[t], loop[t + 1 if t + 1 < stop else start]
        au, av, bu, bv = vertices[a, ax], vertices[a, ay], vertices[b, ax], vertices[b, ay]
        if (av > pv) != (bv > pv) and pu < au + (pv - av) * (bu - au) / (bv - av):
            inside = not inside
    return inside


@numba.njit(nogil=True, cache=True)
def _keep_corners(vertices: NDArray[np.float64], ax: int, ay: int, loop: NDArray[np.int64],
                  fixed: NDArray[np.bool_], tolerance: float, out: NDArray[np.int64],
                  n_out: int) -> int:
    """Write the corners of the closed ``loop`` (vertex indices) to ``out`` from ``n_out``
    on, leaving out those within ``tolerance`` of the line from the last kept corner to the
    next one (never a ``fixed`` one); returns where they end, -1 when fewer than 3 are
    left (a loop seen along the axis other than ``ax`` and ``ay``)."""
    size = len(loop)
    s = -1  # a corner to start from: one off the line through its neighbours
    for t in range(size):
        if fixed[t] or not _on_line(vertices, ax, ay, loop[(t + size - 1) % size], loop[t],
                                    loop[(t + 1) % size], tolerance):
            s = t
            break
    if s < 0:
        return -1
    end = n_out
    out[end] = loop[s]
    end += 1
    for t in range(1, size):
        if fixed[(s + t) % size] or not _on_line(vertices, ax, ay, out[end - 1],
                                                 loop[(s + t) % size],
                                                 loop[(s + t + 1) % size], tolerance):
            out[end] = loop[(s + t) % size]
            end += 1
    return end if end - n_out >= 3 else -1


@numba.njit(nogil=True, cache=True)
def _on_line(vertices: NDArray[np.float64], ax: int, ay: int, p: int, c: int, q: int,
             tolerance: float) -> bool:
    """Whether vertex ``c`` lies within ``tolerance`` of the line through vertices ``p`` and
    ``q`` (seen along the axis other than ``ax`` and ``ay``)."""
    du, dv = vertices[q, ax] - vertices[p, ax], vertices[q, ay] - vertices[p, ay]
    chord = math.hypot(du, dv)
    cross = du * (vertices[c, ay] - vertices[p, ay]) - dv * (vertices[c, ax] - vertices[p, ax])
    return bool(chord > 0 and abs(cross) <= tolerance * chord)


def _outlined(scene: Scene, rows: NDArray[np.int32], offsets: NDArray[np.int64],
              first: NDArray[np.int32], chosen: NDArray[np.int64]
              ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """Triangles covering each of the ``chosen`` features (several faces, not their whole
    file face; ``first``: each feature's first face): its outline (:func:`_outlines`)
    triangulated by GEOS's constrained Delaunay (no new vertices), wound as its file face,
    ``_OUTLINE_CHUNK_PIECES`` faces' worth of features at a time.

    Returns (t,) the feature of each triangle (ascending), (t, 3) their vertex indices,
    and the features :func:`_outlines` left to :func:`_merge`. A feature whose triangles do
    not cover exactly its faces' area with their vertices is drawn as its faces."""
    pieces = offsets[chosen + 1] - offsets[chosen]
    cuts = np.searchsorted(np.cumsum(pieces), np.arange(
        _OUTLINE_CHUNK_PIECES, int(pieces.sum()), _OUTLINE_CHUNK_PIECES), side="right")
    main = np.argmax(np.abs(scene.normals[first[chosen]]), axis=1)
    # the two axes other than the main axis of each feature's normal
    axes = np.stack([(main == 0).astype(np.int64), 2 - (main == 2).astype(np.int64)], axis=1)
    found: list[tuple[NDArray[np.int64], NDArray[np.int64]]] = []
    to_merge: list[NDArray[np.int64]] = []
    for part in np.split(np.arange(len(chosen)), np.unique(cuts)):
        if len(part) == 0:
            continue
        features, triangles, left = _outlined_part(scene, rows, offsets, first,
                                                   chosen[part], axes[part])
        found.append((features, triangles))
        to_merge.append(left)
    if not found:
        empty = np.zeros(0, np.int64)
        return empty, np.zeros((0, 3), np.int64), empty
    return (np.concatenate([f for f, _ in found]), np.concatenate([t for _, t in found]),
            np.concatenate(to_merge))


def _outlined_part(scene: Scene, rows: NDArray[np.int32], offsets: NDArray[np.int64],
                   first: NDArray[np.int32], chosen: NDArray[np.int64],
                   axes: NDArray[np.int64]
                   ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """:func:`_outlined` for one chunk of features (``axes``: theirs, :func:`_outlines`)."""
    vertices = scene.vertices
    loop_vertices, loop_offsets, loop_feature, loop_shell, status, length = _outlines(
        scene.faces, rows, offsets, chosen, vertices, axes, _COLLINEAR_M)
    # a polygon per outer loop, its holes after it
    hole = loop_shell != np.arange(len(loop_shell))
    shell = ~hole
    loop_polygon = (np.cumsum(shell) - 1)[loop_shell]
    polygon_feature = loop_feature[shell]
    order = np.lexsort((hole, loop_polygon))  # each polygon's shell, then its holes
    sizes = np.diff(loop_offsets)[order]
    at = np.repeat(loop_offsets[:-1][order] - np.cumsum(sizes) + sizes, sizes) + np.arange(
        int(sizes.sum()))
    ids = loop_vertices[at]
    polygon = np.repeat(loop_polygon[order], sizes)
    feature_axes = axes[polygon_feature[polygon]]
    uv = np.stack([vertices[ids, feature_axes[:, 0]], vertices[ids, feature_axes[:, 1]]], axis=1)
    del feature_axes
    bad = np.zeros(len(chosen), bool)  # drawn as their faces
    if len(polygon_feature):
        rings = shapely.linearrings(uv, indices=np.repeat(np.arange(len(sizes)), sizes))
        polygons = shapely.polygons(rings, indices=loop_polygon[order])
        try:
            triangulated = shapely.constrained_delaunay_triangles(polygons)
        except shapely.errors.GEOSException:
            triangulated = np.empty(len(polygons), object)
            for p, outline in enumerate(polygons):
                try:
                    triangulated[p] = shapely.constrained_delaunay_triangles(outline)
                except shapely.errors.GEOSException:
                    triangulated[p] = shapely.GeometryCollection()
                    bad[polygon_feature[p]] = True
        # each triangle a closed ring of 4 points, in the geometry of its polygon
        corners, polygon_of_corner = shapely.get_coordinates(triangulated, return_index=True)
        corners = corners.reshape(-1, 4, 2)[:, :3].reshape(-1, 2)
        part_polygon = polygon_of_corner[::4]
        del triangulated, polygon_of_corner
    else:
        corners, part_polygon = np.zeros((0, 2)), np.zeros(0, np.int64)
    # back to vertex indices: each corner is a corner of its polygon's loops, bit for bit;
    # sorted together with them (corners after the loops' points), a corner follows the
    # loop point it is
    n = len(ids)
    both = np.lexsort((np.concatenate([np.zeros(n, np.int8), np.ones(len(corners), np.int8)]),
                       np.concatenate([uv[:, 1], corners[:, 1]]).view(np.int64),
                       np.concatenate([uv[:, 0], corners[:, 0]]).view(np.int64),
                       np.concatenate([polygon, np.repeat(part_polygon, 3)])))
    last = np.maximum.accumulate(np.where(both < n, np.arange(len(both)), -1))
    at = np.empty(len(corners), np.int64)  # the loop point each corner follows (-1: none)
    at[both[both >= n] - n] = np.where(last >= 0, both[last], -1)[both >= n]
    triangle_feature = polygon_feature[part_polygon]
    found = np.maximum(at, 0)
    matched = ((at >= 0) & (polygon[found] == np.repeat(part_polygon, 3))
               & (uv[found].view(np.int64) == corners.view(np.int64)).all(axis=1))
    bad[triangle_feature[~matched.reshape(-1, 3).all(axis=1)]] = True
    triangles = ids[found].reshape(-1, 3).astype(np.int64)
    # the area check: within what dropping corners off the line by up to _COLLINEAR_M
    # moves (in the plane; seen along the main axis, lengths shrink by at most sqrt(3))
    cross = _cross(vertices[triangles])
    drawn = np.bincount(triangle_feature, np.sqrt((cross * cross).sum(axis=1)) * 0.5,
                        minlength=len(chosen))
    pieces = offsets[chosen + 1] - offsets[chosen]
    members = rows[np.repeat(offsets[chosen] - np.cumsum(pieces) + pieces, pieces)
                   + np.arange(int(pieces.sum()))]
    area = np.bincount(np.repeat(np.arange(len(chosen)), pieces), scene.areas[members],
                       minlength=len(chosen))
    made = np.bincount(triangle_feature, minlength=len(chosen))
    bad |= (np.abs(drawn - area) > 2.0 * _COLLINEAR_M * length + 1e-9 * area) | (made == 0)
    bad &= status == _OUTLINED
    flip = (cross * scene.normals[first[chosen[triangle_feature]]]).sum(axis=1) < 0
    triangles[flip] = triangles[flip][:, ::-1]
    keep = ~bad[triangle_feature]
    # the features that failed: their faces
    faulty = np.repeat(bad, pieces)
    features = np.concatenate([triangle_feature[keep],
                               np.repeat(np.arange(len(chosen)), pieces)[faulty]])
    triangles = np.concatenate([triangles[keep], scene.faces[members[faulty]]])
    order = np.argsort(features, kind="stable")
    return (chosen[features[order]], triangles[order],
            chosen[status == _TO_MERGE])


def _merge(scene: Scene, pieces: NDArray[np.int32], first: int, area: float
           ) -> NDArray[np.int64]:
    """(t, 3) vertex indices of triangles covering the (m, 3) ``pieces`` of one file face
    (that of face ``first``; ``area`` theirs, m^2): their outline (holes and all: the
    pieces of a file face meet edge to edge), corners on a straight run dropped,
    triangulated (GEOS's constrained Delaunay, no new vertices), wound as the file face.
    The pieces themselves when that fails to cover exactly their area with their
    vertices."""
    vertices, normal = scene.vertices, scene.normals[first]
    axes = [a for a in range(3) if a != int(np.argmax(np.abs(normal)))]
    flat = vertices[pieces][:, :, axes]  # (m, 3, 2): the plane seen along its main axis
    try:
        outline = shapely.coverage_union_all(
            shapely.polygons(np.concatenate([flat, flat[:, :1]], axis=1)))
        # dropping corners off the line by up to _COLLINEAR_M moves at most this much area
        # (in the plane; seen along the main axis, lengths shrink by at most sqrt(3))
        slack = 2.0 * _COLLINEAR_M * float(shapely.length(outline))
        outline = shapely.simplify(outline, _COLLINEAR_M)
        parts = shapely.get_parts(shapely.constrained_delaunay_triangles(outline))
    except shapely.errors.GEOSException:
        return pieces.astype(np.int64)
    found = shapely.get_coordinates(parts).reshape(-1, 4, 2)[:, :3]  # (t, 3, 2)
    # back to vertex indices: each corner is a corner of a piece, bit for bit
    ids = np.unique(pieces)
    points = np.ascontiguousarray(vertices[ids][:, axes])
    order = np.lexsort((points[:, 1], points[:, 0]))
    keyed = points[order].view([("u", np.float64), ("v", np.float64)]).ravel()
    wanted = np.ascontiguousarray(found.reshape(-1, 2)).view(
        [("u", np.float64), ("v", np.float64)]).ravel()
    at = np.minimum(np.searchsorted(keyed, wanted), len(keyed) - 1)
    if len(found) == 0 or not (keyed[at] == wanted).all():
        return pieces.astype(np.int64)
    triangles = ids[order[at]].reshape(-1, 3).astype(np.int64)
    cross = _cross(vertices[triangles])
    if abs(0.5 * float(np.sqrt((cross * cross).sum(axis=1)).sum()) - area) > slack + 1e-9 * area:
        return pieces.astype(np.int64)
    flip = cross @ normal < 0
    triangles[flip] = triangles[flip][:, ::-1]
    return triangles


def _cross(corners: NDArray[np.float64]) -> NDArray[np.float64]:
    """(t, 3) the cross product of the edges from the first corner of (t, 3, 3) triangles
    (twice the area, along the normal); written out, np.cross is slow on small arrays."""
    a = corners[:, 1] - corners[:, 0]
    b = corners[:, 2] - corners[:, 0]
    return np.stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                     a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]], axis=1)


def _grid_vertices(scene: Scene, quantizer: _Quantizer) -> NDArray[np.uint16]:
    """(V + V0, 3) uint16 grid steps of the scene's vertices, then the file's (V0 only when
    the scene was split): the vertices :attr:`_Features.corners` index."""
    grid = quantizer(scene.vertices)
    if scene.file_vertices is None:
        return grid
    return np.concatenate([grid, quantizer(scene.file_vertices)])


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
