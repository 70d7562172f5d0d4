"""Read a model file into a :class:`~planner.scene.Scene`.

Formats are recognised from the bytes, not the file name: OBJ, PLY, STL, OFF, GLB/glTF
through trimesh, IFC through IfcOpenShell (imported only when an IFC file comes). Faces keep
the file's order (``process=False``, ``maintain_order=True``) so that per-face results line
up with the user's model.

Group labels per face: OBJ ``g`` (or ``o``) names, glTF node names, the PLY face property
``class_id`` (named from a ``<stem>.elements.json`` beside the file when there is one).
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any, Literal

import numpy as np
import trimesh

from planner.errors import ParameterError, SceneError, UnsupportedFormatError
from planner.io.orientation import axis_rotation, default_up_axis, find_up
from planner.memory import release_freed_memory
from planner.parameters import UP_AXES
from planner.scene import Element, Scene, build_scene, remesh

FORMATS = ("obj", "ply", "stl", "off", "glb", "gltf", "ifc")
_SNIFF_BYTES = 65536


def sniff_format(head: bytes, total_size: int | None = None) -> str | None:
    """Recognise a model format from the first bytes of a file.

    Parameters
    ----------
    head : the first few kilobytes of the file
    total_size : the file's size in bytes, to recognise binary STL by its triangle count

    Returns
    -------
    one of ``FORMATS``, or None when the bytes are no model this planner reads
    """
    stripped = head.lstrip()
    if stripped.startswith(b"ISO-10303-21"):
        return "ifc"
    if head.startswith(b"ply"):
        return "ply"
    if head.startswith(b"glTF"):
        return "glb"
    if stripped.startswith(b"{") and b'"asset"' in head:
        return "gltf"
    if re.match(rb"[CN4ST]*OFF\b", stripped):
        return "off"
    if total_size is not None and len(head) >= 84:
        count = int.from_bytes(head[80:84], "little")
        if 84 + 50 * count == total_size:
            return "stl"
    if stripped.startswith(b"solid") and b"facet" in head:
        return "stl"
    if b"\x00" in head:
        return None
    text = head.decode("utf-8", errors="ignore")
    if re.search(r"^\s*v\s", text, flags=re.MULTILINE):
        return "obj"
    return None


def file_format(path: Path) -> str:
    """The format of the file at ``path``; :class:`UnsupportedFormatError` when unknown."""
    with path.open("rb") as handle:
        head = handle.read(_SNIFF_BYTES)
    if not head:
        raise SceneError(f"{path.name} is empty; upload the model's bytes")
    fmt = sniff_format(head, path.stat().st_size)
    if fmt is None:
        raise UnsupportedFormatError(
            f"{path.name} is not a model format the planner reads; "
            f"use one of {', '.join(FORMATS)}"
        )
    return fmt


def read_scene(
    path: str | Path, *, max_edge_m: float | None = 0.2, unit_scale: float = 1.0,
    up_axis: str | None = None, split_faces: Literal["all", "as_needed"] = "all",
) -> Scene:
    """Read a model and prepare it for planning.

    Parameters
    ----------
    path : the model file (format sniffed from its bytes)
    max_edge_m : split faces until no edge is longer; None uses the mesh as given
    split_faces : "all" splits every face longer than ``max_edge_m`` now; "as_needed" keeps
        the file's faces and leaves the split to :func:`planner.pipeline.plan`, which splits
        only the faces a candidate can qualify part of (``Scene.split_max_edge_m``,
        :mod:`planner.visibility.splitting`)
    unit_scale : multiply coordinates by this (0.001 for a model in millimetres); must be
        1 for IFC, which is converted from its own length unit
    up_axis : the model's up, one of :data:`planner.io.orientation.UP_AXES`; None follows the
        format (+Y for glTF/GLB, +Z otherwise). A model whose up is not +Z is rotated into
        the plan frame; ``metadata["orientation"]`` keeps the rotation so that outputs go
        back to model coordinates (:mod:`planner.io.orientation`)

    Raises
    ------
    SceneError, UnsupportedFormatError, ParameterError (unit_scale or up_axis with an IFC
    file, an unknown up_axis, auto that cannot tell)
    """
    path = Path(path)
    if not path.is_file():
        raise SceneError(f"{path} does not exist or is not a file")
    if max_edge_m is not None and max_edge_m <= 0:
        raise SceneError(f"max_edge_m is {max_edge_m}; use a positive length or null")
    fmt = file_format(path)
    if up_axis is not None and up_axis not in UP_AXES:
        raise ParameterError("up_axis", f"{up_axis!r} is not one of {', '.join(UP_AXES)}")
    if fmt == "ifc":
        if up_axis not in (None, "+Z", "auto"):  # rooms and storeys are Z-up by the schema
            raise ParameterError(
                "up_axis", f"is {up_axis}, but IFC world coordinates are Z-up by the schema; "
                "leave up_axis unset, +Z or auto")
        if unit_scale != 1.0:  # rooms and storeys are in metres too: scaling would split them
            raise ParameterError(
                "unit_scale", f"is {unit_scale}, but an IFC file is converted to metres from "
                "its own length unit; leave unit_scale at 1")
        from planner.io import ifc  # IfcOpenShell is heavy: import it only for IFC files

        scene = ifc.read_ifc(path)
    else:
        scene = _read_mesh(path, fmt)
    # the parser's freed memory, before the plan's peaks: IfcOpenShell's geometry of
    # Amersfoort's 165,364 faces left 269 MiB of freed heap resident, 487 MiB after reading
    release_freed_memory()
    if unit_scale != 1.0:
        scene = _scaled(scene, unit_scale)
    scene.metadata.setdefault("format", fmt)
    scene = _oriented(scene, fmt, up_axis)
    warning = _unit_warning(scene, unit_scale)
    if warning:
        scene.metadata.setdefault("warnings", []).append(warning)
    if max_edge_m is not None:
        scene = (remesh(scene, max_edge_m) if split_faces == "all"
                 else scene.replaced(split_max_edge_m=max_edge_m))
    return scene


# a model wider than this is probably not in metres (a 15 km "room" is 15 m in millimetres)
_LARGEST_PLAUSIBLE_M = 2_000.0
# narrower than this, probably in kilometres or decimetres gone wrong
_SMALLEST_PLAUSIBLE_M = 0.5


def _unit_warning(scene: Scene, unit_scale: float) -> str | None:
    return unit_warning(float(np.ptp(scene.vertices, axis=0).max()), unit_scale)


def unit_warning(extent_m: float, unit_scale: float) -> str | None:
    """A warning naming ``unit_scale`` when a model ``extent_m`` across (its longest side
    after scaling) suggests another unit; None when the size is plausible in metres."""
    if extent_m > _LARGEST_PLAUSIBLE_M:
        return (f"unit_scale: the model is {extent_m:,.0f} m across with unit_scale "
                f"{unit_scale}; if it is in millimetres use unit_scale 0.001, in inches "
                "0.0254, in feet 0.3048")
    if extent_m < _SMALLEST_PLAUSIBLE_M:
        return (f"unit_scale: the model is only {extent_m:.3g} m across with unit_scale "
                f"{unit_scale}; check that it is in metres (unit_scale converts)")
    return None


def _oriented(scene: Scene, fmt: str, up_axis: str | None) -> Scene:
    """The scene in the Z-up plan frame, ``metadata["orientation"]`` saying how."""
    if fmt == "ifc":
        applied, source = "+Z", "IFC world coordinates"
    elif up_axis is None:
        applied, source = default_up_axis(fmt), f"{fmt.upper()} default"
    elif up_axis == "auto":
        applied, source = "auto", "auto"
    else:
        applied, source = up_axis, "up_axis"
    info: dict[str, Any] = {"up_axis": applied, "source": source, "rotation": None}
    if applied == "auto":
        rotation, report = find_up(scene.vertices, scene.faces)
        info.update(report)
    else:
        rotation = axis_rotation(applied)
    # the rounded matrix is the one applied, so that writing back uses exactly its inverse;
    # auto on a level model rounds to the identity and leaves the scene untouched
    exact = np.round(rotation, 12) + 0.0  # + 0.0: no -0.0 in plan.json
    if np.array_equal(exact, np.eye(3)):
        scene.metadata["orientation"] = info
        return scene
    info["rotation"] = exact.tolist()
    return _with(scene, scene.vertices @ exact.T, {**scene.metadata, "orientation": info})


def _with(scene: Scene, vertices: np.ndarray, metadata: dict[str, Any]) -> Scene:
    return Scene(
        vertices=vertices,
        faces=scene.faces,
        file_face_group=scene.file_face_group,
        groups=scene.groups,
        source_face=scene.source_face,
        file_face_element=scene.file_face_element,
        elements=scene.elements,
        metadata=metadata,
    )


def _scaled(scene: Scene, unit_scale: float) -> Scene:
    return Scene(
        vertices=scene.vertices * unit_scale,
        faces=scene.faces,
        file_face_group=scene.file_face_group,
        groups=scene.groups,
        source_face=scene.source_face,
        file_face_element=scene.file_face_element,
        elements=scene.elements,
        metadata=scene.metadata,
        file_vertices=None if scene.file_vertices is None else scene.file_vertices * unit_scale,
        file_faces=scene.file_faces,
    )


def _read_mesh(path: Path, fmt: str) -> Scene:
    try:
        loaded = trimesh.load(
            str(path), file_type=fmt, process=False, maintain_order=True,
            group_material=True, skip_materials=True,
        )
    except IndexError as exc:
        raise SceneError(
            f"{path.name}: a face refers to a vertex that does not exist ({exc}); the file is "
            "probably truncated or broken, export it again"
        ) from exc
    except Exception as exc:  # trimesh raises many kinds for a broken file
        raise SceneError(f"{path.name} could not be read as {fmt.upper()}: {exc}") from exc
    if fmt in ("glb", "gltf") or isinstance(loaded, trimesh.Scene):
        return _from_trimesh_scene(path, loaded)
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise SceneError(f"{path.name} contains no triangles; export the model with its faces")
    vertices = np.asarray(loaded.vertices, np.float64)
    faces = np.asarray(loaded.faces, np.int64)
    if fmt == "obj":
        face_group, groups = _obj_groups(path, len(faces))
        return build_scene(vertices, faces, face_group, groups)
    if fmt == "ply":
        return _ply_scene(path, loaded, vertices, faces)
    return build_scene(vertices, faces)


def _from_trimesh_scene(path: Path, loaded: Any) -> Scene:
    if isinstance(loaded, trimesh.Trimesh):
        return build_scene(loaded.vertices, loaded.faces)
    vertices: list[np.ndarray] = []
    faces: list[np.ndarray] = []
    labels: list[str] = []
    offset = 0
    for node in loaded.graph.nodes_geometry:
        transform, geometry_name = loaded.graph[node]
        geometry = loaded.geometry[geometry_name]
        if not isinstance(geometry, trimesh.Trimesh) or len(geometry.faces) == 0:
            continue
        moved = trimesh.transform_points(np.asarray(geometry.vertices, np.float64), transform)
        vertices.append(moved)
        faces.append(np.asarray(geometry.faces, np.int64) + offset)
        labels.extend([str(node)] * len(geometry.faces))
        offset += len(moved)
    if not faces:
        raise SceneError(f"{path.name} contains no triangle meshes")
    groups = tuple(dict.fromkeys(labels))
    lookup = {name: i for i, name in enumerate(groups)}
    return build_scene(
        np.concatenate(vertices), np.concatenate(faces),
        np.array([lookup[label] for label in labels], np.int64), groups,
    )


def _obj_groups(path: Path, n_faces: int) -> tuple[np.ndarray, tuple[str, ...]]:
    """Group label of every triangle from the ``g``/``o`` lines (polygons as fans)."""
    groups: dict[str, int] = {}
    labels: list[int] = []
    current = ""
    with path.open("r", encoding="utf-8", errors="replace") as handle:
        for line in handle:
            if line.startswith("f ") or line.startswith("f\t"):
                corners = len(line.split()) - 1
                index = groups.setdefault(current, len(groups))
                labels.extend([index] * max(corners - 2, 0))
            elif line.startswith(("g ", "o ", "g\t", "o\t")):
                current = line[2:].strip()
    if len(labels) != n_faces or not groups:
        # a layout trimesh reads differently (e.g. lines folded with "\"): keep one group
        return np.zeros(n_faces, np.int64), ("",)
    return np.asarray(labels, np.int64), tuple(groups)


def _ply_scene(path: Path, loaded: Any, vertices: np.ndarray, faces: np.ndarray) -> Scene:
    raw = loaded.metadata.get("_ply_raw", {}).get("face", {}).get("data")
    names = raw.dtype.names if raw is not None and raw.dtype.names else ()
    if "class_id" not in names:
        return build_scene(vertices, faces)
    class_id = np.asarray(raw["class_id"], np.int64).reshape(-1)
    table = _elements_table(path)
    class_names = list(table.get("classes", []))
    used = np.unique(class_id)
    groups = tuple(
        class_names[c] if 0 <= c < len(class_names) else f"class_{c}" for c in used
    )
    face_group = np.searchsorted(used, class_id)
    if "element_id" in names and table.get("elements"):
        elements = tuple(
            Element(
                global_id=str(e.get("global_id", "")),
                ifc_class=str(e.get("ifc_class", "")),
                name=str(e.get("name") or ""),
                storey=str(e.get("storey") or ""),
            )
            for e in table["elements"]
        )
        face_element = np.asarray(raw["element_id"], np.int64).reshape(-1)
        return build_scene(vertices, faces, face_group, groups,
                           face_element=face_element, elements=elements)
    return build_scene(vertices, faces, face_group, groups)


def _elements_table(path: Path) -> dict[str, Any]:
    sidecar = path.with_suffix(".elements.json")
    if not sidecar.is_file():
        return {}
    try:
        data = json.loads(sidecar.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}
