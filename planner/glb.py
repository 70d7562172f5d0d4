"""``coverage.glb``: the model coloured by coverage, with a numbered marker at each station.

Written by hand (glTF 2.0 binary) rather than through an exporter, so that the bytes depend
only on the plan: the JSON chunk has sorted keys, the binary chunk is laid out in a fixed
order, nothing carries a date or a version string that changes.

Layout
------
- Model coordinates are Z-up metres; glTF is Y-up, so the root node ``scanplan`` carries a
  rotation of -90 degrees about X. Everything below it is in model coordinates.
- One node and mesh per face class (``covered``, ``coverable_not_covered``,
  ``not_coverable``, ``not_target``; empty classes are left out), so a viewer toggles a
  class by hiding a node. Faces do not share vertices (3 per face, in ascending face
  order), so ``COLOR_0`` is exactly the face colour of :func:`planner.drawing.face_rgb`
  (stored linear, as glTF requires) and ``NORMAL`` is the flat face normal.
- ``_FEATURE_ID_0`` (float, per vertex) is the face index (the row of ``faces.npz``).
  ``EXT_mesh_features`` points it at the property table of ``EXT_structural_metadata``
  (class ``face``): ``covered``, ``face_class``, ``best_lpd_pts_m2``,
  ``min_density_pts_m2``, ``n_stations``, ``first_station``, ``n_candidates``,
  ``source_face`` per face, so a platform can recolour without the npz. Both extensions are
  optional (``extensionsUsed`` only): viewers that do not know them still show the colours.
- One node per station, ``station <n>``, a disc-topped marker at the scanner position with
  its number drawn as seven-segment bars standing above it (readable from the south,
  i.e. from -Y); its ``extras`` hold ``order``, ``candidate_index``, ``position``,
  ``new_area_m2``, ``covered_area_m2`` and ``coverage_fraction``.
- ``scenes[0].extras.scanplan`` carries the totals and the class names and colours.
"""

from __future__ import annotations

import json
import math
import struct
from typing import Any

import numpy as np
from numpy.typing import NDArray

from planner.drawing import (
    CLASS_NAMES,
    CLASS_RGB,
    COVERED_HIGH_RGB,
    COVERED_LOW_RGB,
    COVERED_SATURATION,
    STATION_RGB,
    face_classes,
    face_rgb,
)
from planner.orientation import glb_root_rotation, scene_rotation, to_model
from planner.pipeline import PlanResult

_FLOAT, _UBYTE, _USHORT, _UINT = 5126, 5121, 5123, 5125
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_Z_UP_TO_Y_UP = [-math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)]  # quaternion x, y, z, w
_MARKER_RADIUS_M = 0.12
_DIGIT_HEIGHT_M = 0.3

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
    """sRGB bytes -> the linear UNSIGNED_BYTE values stored in ``COLOR_0``."""
    return np.rint(srgb_to_linear(rgb) * 255.0).astype(np.uint8)


class _Builder:
    """Accumulates buffer views and accessors of one binary buffer."""

    def __init__(self) -> None:
        self.blob = bytearray()
        self.views: list[dict[str, Any]] = []
        self.accessors: list[dict[str, Any]] = []

    def view(self, data: bytes, target: int | None = None, align: int = 8) -> int:
        while len(self.blob) % align:
            self.blob.append(0)
        view: dict[str, Any] = {"buffer": 0, "byteOffset": len(self.blob),
                                "byteLength": len(data)}
        if target is not None:
            view["target"] = target
        self.blob.extend(data)
        self.views.append(view)
        return len(self.views) - 1

    def accessor(self, array: NDArray[Any], kind: str, *, normalized: bool = False,
                 target: int | None = _ARRAY_BUFFER, bounds: bool = False) -> int:
        component = {np.dtype(np.float32): _FLOAT, np.dtype(np.uint8): _UBYTE,
                     np.dtype(np.uint16): _USHORT, np.dtype(np.uint32): _UINT}[array.dtype]
        data = np.ascontiguousarray(array)
        accessor: dict[str, Any] = {
            "bufferView": self.view(data.tobytes(), target),
            "componentType": component, "count": len(data), "type": kind,
        }
        if normalized:
            accessor["normalized"] = True
        if bounds:
            flat = data.reshape(len(data), -1)
            accessor["min"] = [float(v) for v in flat.min(axis=0)]
            accessor["max"] = [float(v) for v in flat.max(axis=0)]
        self.accessors.append(accessor)
        return len(self.accessors) - 1


def _flat_primitive(builder: _Builder, triangles: NDArray[np.float64],
                    rgba: NDArray[np.uint8], feature: NDArray[np.float32] | None,
                    material: int) -> dict[str, Any]:
    """A primitive of unshared triangles (T, 3, 3) with one RGBA per triangle."""
    n = len(triangles)
    positions = triangles.reshape(-1, 3).astype(np.float32)
    cross = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    length = np.linalg.norm(cross, axis=1, keepdims=True)
    normals = np.divide(cross, length, out=np.tile([0.0, 0.0, 1.0], (n, 1)), where=length > 0)
    attributes = {
        "POSITION": builder.accessor(positions, "VEC3", bounds=True),
        "NORMAL": builder.accessor(np.repeat(normals, 3, axis=0).astype(np.float32), "VEC3"),
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


def coverage_glb(result: PlanResult) -> bytes:
    """The bytes of ``coverage.glb`` (see the module docstring)."""
    scene = result.scene
    builder = _Builder()
    materials = [
        {"name": "coverage", "doubleSided": True,
         "pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0],
                                  "metallicFactor": 0.0, "roughnessFactor": 1.0}},
        {"name": "station", "doubleSided": True,
         "pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0],
                                  "metallicFactor": 0.0, "roughnessFactor": 0.8}},
    ]
    classes = face_classes(result.faces, result.limits.target)
    rgb = face_rgb(result.faces, result.limits.target, result.limits.min_density_pts_m2)
    rgba = np.concatenate([linear_bytes(rgb), np.full((len(rgb), 1), 255, np.uint8)], axis=1)
    triangles = scene.triangles
    meshes: list[dict[str, Any]] = []
    # the root puts the plan frame back into the model's coordinates (up_axis)
    root_rotation = glb_root_rotation(scene.metadata) or _Z_UP_TO_Y_UP
    nodes: list[dict[str, Any]] = [{"name": "scanplan", "rotation": root_rotation,
                                    "children": []}]
    for k, name in enumerate(CLASS_NAMES):
        members = np.flatnonzero(classes == k)
        if len(members) == 0:
            continue
        primitive = _flat_primitive(builder, triangles[members], rgba[members],
                                    members.astype(np.float32), material=0)
        meshes.append({"name": name, "primitives": [primitive]})
        nodes[0]["children"].append(len(nodes))
        nodes.append({"name": name, "mesh": len(meshes) - 1,
                      "extras": {"face_class": name, "faces": len(members)}})

    station_rgba = np.array([[*linear_bytes(np.array(STATION_RGB, np.uint8)), 255]], np.uint8)
    marker = _marker(_MARKER_RADIUS_M)
    meshes.append({"name": "station_marker", "primitives": [_flat_primitive(
        builder, marker, np.repeat(station_rgba, len(marker), axis=0), None, material=1)]})
    marker_mesh = len(meshes) - 1
    chosen = result.chosen
    max_area = chosen.max_achievable_area_m2
    for order, candidate in enumerate(chosen.stations):
        label = str(order + 1)
        digits = _digits(label, _DIGIT_HEIGHT_M) + np.array([0.0, 0.0, 0.15])
        meshes.append({"name": f"station {label} number", "primitives": [_flat_primitive(
            builder, digits, np.repeat(station_rgba, len(digits), axis=0), None,
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

    metadata = _property_table(builder, result, classes)
    totals_covered = chosen.covered_area_m2[-1] if chosen.stations else 0.0
    document: dict[str, Any] = {
        "asset": {"version": "2.0", "generator": "scanplan coverage.glb"},
        "extensionsUsed": ["EXT_mesh_features", "EXT_structural_metadata"],
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
            "face_ids": "_FEATURE_ID_0 = row of faces.npz",
        }}}],
        "nodes": nodes,
        "meshes": meshes,
        "materials": materials,
        "accessors": builder.accessors,
        "bufferViews": builder.views,
        "buffers": [{"byteLength": 0}],
    }
    while len(builder.blob) % 4:
        builder.blob.append(0)
    document["buffers"][0]["byteLength"] = len(builder.blob)
    return _pack(document, bytes(builder.blob))


def _property_table(builder: _Builder, result: PlanResult,
                    classes: NDArray[np.uint8]) -> dict[str, Any]:
    faces = result.faces
    columns: list[tuple[str, str, NDArray[Any]]] = [
        ("covered", "UINT8", np.asarray(faces["covered"], np.uint8)),
        ("face_class", "UINT8", classes),
        ("best_lpd_pts_m2", "FLOAT32", np.asarray(faces["best_lpd_pts_m2"], np.float32)),
        ("min_density_pts_m2", "FLOAT32",
         np.asarray(result.limits.min_density_pts_m2, np.float32)),
        ("n_stations", "INT32", np.asarray(faces["n_stations"], np.int32)),
        ("first_station", "INT32", np.asarray(faces["first_station"], np.int32)),
        ("n_candidates", "INT32", np.asarray(faces["n_candidates"], np.int32)),
        ("source_face", "INT32", np.asarray(result.scene.source_face, np.int32)),
    ]
    properties = {}
    table = {}
    for name, component, values in columns:
        properties[name] = {"type": "SCALAR", "componentType": component}
        table[name] = {"values": builder.view(np.ascontiguousarray(values).tobytes())}
    return {
        "schema": {"id": "scanplan", "classes": {"face": {
            "description": "per-face coverage of the plan, one row per face of faces.npz",
            "properties": properties}}},
        "propertyTables": [{"name": "faces", "class": "face",
                            "count": int(result.scene.n_faces), "properties": table}],
    }


def _pack(document: dict[str, Any], blob: bytes) -> bytes:
    text = json.dumps(document, sort_keys=True, separators=(",", ":"), allow_nan=False)
    json_bytes = text.encode("utf-8")
    json_bytes += b" " * (-len(json_bytes) % 4)
    total = 12 + 8 + len(json_bytes) + 8 + len(blob)
    return b"".join([
        struct.pack("<4sII", b"glTF", 2, total),
        struct.pack("<I4s", len(json_bytes), b"JSON"), json_bytes,
        struct.pack("<I4s", len(blob), b"BIN\x00"), blob,
    ])
