"""IFC models through IfcOpenShell: the scene, its storeys and rooms, and room candidates.

Only :mod:`planner.io.readers` imports this module, and only when an IFC file comes, because
IfcOpenShell is heavy.

Reading (:func:`read_ifc`)
--------------------------
- Schemas IFC2X3, IFC4 and IFC4X3 (whatever IfcOpenShell opens among them).
- Geometry from ``ifcopenshell.geom.iterator`` with world coordinates, welded vertices,
  the default body context and openings subtracted (door and window holes are real holes).
  IfcOpenShell already returns metres whatever the file's length unit; the unit's scale is
  kept in ``metadata["length_unit_scale"]`` and used for attributes in file units (storey
  elevations).
- Non-physical entities never become faces: IfcSpace (rooms, kept as metadata),
  IfcOpeningElement, IfcVirtualElement, IfcAnnotation, IfcGrid.
- Elements are sorted by (IFC class, GlobalId), faces keep IfcOpenShell's order inside an
  element: the same file always gives the same scene.
- Every face is labelled: ``scene.face_element`` points at its element (GlobalId, class,
  name, storey: the name of the IfcBuildingStorey it is contained in, through spaces and
  aggregates; "" for the site), and its group is the element's IFC class, except glazing.
- Triangulation uses IfcOpenShell's hybrid CGAL/OpenCASCADE kernel when it has one, on one
  thread (see ``_GEOMETRY_LIBRARY``).
- ``metadata["source_path"]`` and ``metadata["source_sha256"]`` name the file read, for
  ``plan.ifc`` (:mod:`planner.outputs.ifc_plan`), which is this file with the plan added;
  ``metadata["project_global_id"]`` is its IfcProject's, which ``plan.bcf`` refers to.

Glass
-----
A laser passes through glass, and glass returns no usable points. IfcWindow (and IfcDoor)
elements mix frames and panes in one element, so the decision is made per face, from the
surface style IfcOpenShell reports for it: a face whose style lets at least
``GLASS_MIN_TRANSPARENCY`` of the light through is glazing and gets the group
``"<IfcClass>/glass"`` (``"IfcWindow/glass"``). Every IfcPlate is treated as glazing too
(curtain-wall and window panels; the issue's default), transparent style or not, so its
group is always ``"IfcPlate/glass"`` and a user's ``"IfcPlate"`` key (a class, not a group)
reaches all its faces. By default
(``metadata["default_group_requirements"]``) glazing neither occludes nor is a target, and
IfcSite (terrain) occludes but is not a target; everything else is both. A user overrides
any of these in ``group_requirements``: ``"IfcWindow/glass"`` for the panes,
``"IfcWindow"`` for the frames (it is a group name, so it does not reach the panes), a
GlobalId for a whole element (panes included). A window without style information stays
one opaque ``IfcWindow`` group: a pane that wrongly occludes only hides the outside.

Rooms and storeys
-----------------
``metadata["storeys"]``: ``[{global_id, name, elevation_m}]`` ordered by elevation.
``metadata["spaces"]``: ``[{global_id, name, long_name, storey, storey_global_id,
floor_z_m, area_m2, polygon, holes}]``, one per IfcSpace with geometry, ordered by storey,
then name. The floor polygon is the outline of the space's volume projected on the XY
plane (union of its projected triangles), its floor the lowest point of the volume.

The candidates in those rooms are made by :mod:`planner.candidates.rooms`.
"""

from __future__ import annotations

import hashlib
import re
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from numpy.typing import NDArray
from shapely import MultiPolygon, Polygon

from planner.errors import SceneError
from planner.scene import Element, Scene, build_scene

__all__ = ["default_requirements", "geometry_library", "read_ifc"]

SUPPORTED_SCHEMAS = ("IFC2X3", "IFC4", "IFC4X3")
NON_PHYSICAL = ("IfcSpace", "IfcOpeningElement", "IfcVirtualElement", "IfcAnnotation",
                "IfcGrid")
GLASS_CLASSES = ("IfcPlate",)
GLASS_SUFFIX = "/glass"
GLASS_MIN_TRANSPARENCY = 0.3
NOT_TARGET_CLASSES = ("IfcSite",)
# The hybrid kernel: CGAL's simple kernel first, OpenCASCADE where it cannot. IfcOpenShell
# knows a hybrid by the names of its parts ("hybrid-<first>-<second>"), and
# has_geometry_library answers for single libraries only, so each part is asked for. On the
# shared IFC models it gives every element's faces with the same areas and bounds as plain
# OpenCASCADE, except curved and stair faces tessellated more coarsely (Lantern Hollow's
# round columns: 112 triangles instead of 208, 0.6 % less area), in less time: Amersfoort
# 3.1 instead of 22.3 s (its windows), FZK-Haus 2.1 instead of 4.5 s, Renga's house 3.6
# instead of 3.9 s (2-core machine).
_GEOMETRY_PARTS = ("cgal-simple", "opencascade")
_GEOMETRY_LIBRARY = "hybrid-" + "-".join(_GEOMETRY_PARTS)
# One thread: on FZK-Haus two threads were slower (4.9 s vs 6.4 s), the boolean
# operations of a few walls dominate and the order is sorted afterwards anyway. On the
# Amersfoort sports hall (165,364 faces, OpenCASCADE alone) two threads gave the same
# scene in 18.9 instead of 22.7 s, for 36.0 instead of 22.6 CPU s (idle 2-core machine):
# a site server runs two workers, so the CPU counts more than that wall time.
_GEOMETRY_THREADS = 1
_DECIMALS = 6
_UNREAD_NAMED = 8  # elements named in a warning about unreadable geometry


@dataclass
class _Shape:
    ifc_class: str
    global_id: str
    name: str
    storey: str
    vertices: NDArray[np.float64]
    faces: NDArray[np.int64]
    glass: NDArray[np.bool_]
    long_name: str = ""


def read_ifc(path: str | Path) -> Scene:
    """Read an IFC file into a scene in metres (see the module docstring).

    Raises
    ------
    SceneError
        the file cannot be parsed, its schema is not supported, or no element has geometry
    """
    import ifcopenshell

    path = Path(path)
    try:
        model, warnings = open_model(path)
    except ifcopenshell.SchemaError as exc:
        raise SceneError(
            f"{path.name}: IfcOpenShell does not support its schema ({exc}); "
            f"export it as one of {', '.join(SUPPORTED_SCHEMAS)}"
        ) from exc
    except Exception as exc:  # ifcopenshell.Error, RuntimeError, OSError from the parser
        raise SceneError(
            f"{path.name} could not be read as IFC by IfcOpenShell: {exc}; "
            "check that it is a complete IFC (STEP) file"
        ) from exc
    schema = str(model.schema)
    if not schema.upper().startswith(SUPPORTED_SCHEMAS):
        raise SceneError(
            f"{path.name} uses the IFC schema {schema}; supported are "
            f"{', '.join(SUPPORTED_SCHEMAS)}"
        )
    scale = _unit_scale(model)
    storeys = _storeys(model, scale)
    storey_name = {s["global_id"]: s["name"] for s in storeys}
    shapes, space_shapes, unread = _shapes(model, path, storey_name)
    warnings += unread_warnings(path.name, unread)
    if not shapes:
        raise SceneError(
            f"{path.name} has no geometry: no building element has a body representation "
            "IfcOpenShell can triangulate; export the model with its 3D geometry"
            + (f" ({'; '.join(warnings)})" if warnings else "")
        )
    shapes.sort(key=lambda s: (s.ifc_class, s.global_id))
    scene = _scene(shapes, space_shapes, storeys, schema, scale)
    if warnings:  # what of the file could not be read as written, for plan.json
        scene.metadata.setdefault("warnings", []).extend(warnings)
    scene.metadata["unread_elements"] = len(unread)
    scene.metadata["spaces_unread"] = _spaces_unread(model, scene.metadata["spaces"], unread,
                                                     storey_name)
    # plan.ifc is this file with the plan added (planner.outputs.ifc_plan)
    scene.metadata["source_path"] = str(path.resolve())
    scene.metadata["source_sha256"] = hashlib.sha256(path.read_bytes()).hexdigest()
    projects = model.by_type("IfcProject")
    scene.metadata["project_global_id"] = str(projects[0].GlobalId) if projects else ""
    return scene


def open_model(path: Path) -> tuple[Any, list[str]]:
    """The IFC model in ``path``, opened with IfcOpenShell, and what was repaired to read it.

    Some tools (Renga) write ``*``, the STEP mark of an attribute a supertype derives,
    where ``$`` (unset) belongs: for a name, a description, a unit. IfcOpenShell reads the
    file but fails on every element whose geometry passes through such an attribute, so
    the element has no geometry. Where the schema derives no attribute at that position
    the ``*`` is read as ``$`` (:func:`repair_derived_marks`); the file itself is left
    unchanged, and the returned warning says what was read differently.
    """
    import ifcopenshell

    data = path.read_bytes()
    schema = _header_schema(data)
    if schema is None:
        return ifcopenshell.open(str(path)), []
    repaired, marks = repair_derived_marks(data, schema)
    if not marks:
        return ifcopenshell.open(str(path)), []
    import tempfile

    with tempfile.TemporaryDirectory(prefix="scanplan-ifc-") as folder:
        copy = Path(folder) / path.name
        copy.write_bytes(repaired)
        model = ifcopenshell.open(str(copy))
    where = ", ".join(f"{name} {count}" for name, count in marks.most_common(6))
    more = len(marks) - 6
    warning = (f"{path.name} writes '*' (a derived attribute) where the schema has an "
               f"optional attribute, {marks.total():,} times ({where}"
               f"{f' and {more} more' if more > 0 else ''}); they were read as '$' (unset), "
               "as IFC requires: the file does not follow ISO 10303-21")
    return model, [warning]


_HEADER_SCHEMA = re.compile(rb"FILE_SCHEMA\s*\(\s*\(\s*'([^']+)'", re.IGNORECASE)
_INSTANCE = re.compile(rb"#\d+\s*=\s*([A-Za-z0-9_]+)\s*\(")
_STAR = re.compile(rb"[(,]\s*(\*)\s*(?=[,)])")


def _header_schema(data: bytes) -> Any:
    """IfcOpenShell's schema for the file's header, or None (the opening reports it)."""
    import ifcopenshell

    found = _HEADER_SCHEMA.search(data[:65536])
    if found is None:
        return None
    try:
        return ifcopenshell.ifcopenshell_wrapper.schema_by_name(
            found.group(1).decode("ascii", "replace").upper())
    except Exception:  # a schema IfcOpenShell does not know: opening says so
        return None


def repair_derived_marks(data: bytes, schema: Any) -> tuple[bytes, Counter[str]]:
    """``data`` (a STEP file) with every ``*`` at a top-level attribute the ``schema`` does
    not derive replaced by ``$``, and how many per ``Class.Attribute``.

    Only the instances holding a ``*`` token are parsed (strings and nested lists kept
    apart); ``*`` where the schema derives the attribute (``IfcSIUnit.Dimensions``) stays.
    """
    out: bytearray | None = None
    marks: Counter[str] = Counter()
    seen: set[int] = set()
    derived_of: dict[str, tuple[str, list[str], list[bool]] | None] = {}
    for star in _STAR.finditer(data):
        start = star.start(1)
        instance = None
        while instance is None:
            start = data.rfind(b"#", 0, start)
            if start < 0:
                break
            instance = _INSTANCE.match(data, start)
        if instance is None or start in seen:
            continue
        seen.add(start)
        name = instance.group(1).decode("ascii").upper()
        if name not in derived_of:
            try:
                declaration = schema.declaration_by_name(name)
                derived_of[name] = (str(declaration.name()),
                                    [str(a.name()) for a in declaration.all_attributes()],
                                    [bool(d) for d in declaration.derived()])
            except Exception:  # a type or a name outside the schema: left as written
                derived_of[name] = None
        known = derived_of[name]
        if known is None:
            continue
        entity, attributes, derived = known
        i, depth, index, quoted = instance.end(), 1, 0, False
        while i < len(data) and depth > 0:
            c = data[i]
            if quoted:
                if c == 0x27:  # ' ends the string unless doubled
                    if i + 1 < len(data) and data[i + 1] == 0x27:
                        i += 1
                    else:
                        quoted = False
            elif c == 0x27:
                quoted = True
            elif c == 0x28:
                depth += 1
            elif c == 0x29:
                depth -= 1
            elif c == 0x2C and depth == 1:
                index += 1
            elif c == 0x2A and depth == 1 and index < len(derived) and not derived[index]:
                if out is None:
                    out = bytearray(data)
                out[i] = 0x24  # '$'
                marks[f"{entity}.{attributes[index]}"] += 1
            i += 1
    return (data if out is None else bytes(out)), marks


def unread_warnings(file_name: str, unread: list[tuple[str, str, str, str]]) -> list[str]:
    """One warning per cause for the elements whose geometry could not be read: (class,
    GlobalId, name, cause) each; the classes counted, the first elements named."""
    by_cause: dict[str, list[tuple[str, str, str]]] = {}
    for ifc_class, global_id, name, cause in unread:
        by_cause.setdefault(cause, []).append((ifc_class, global_id, name))
    warnings = []
    for cause, elements in by_cause.items():
        classes = Counter(c for c, _, _ in elements)
        named = ", ".join(f"{c} {g}" + (f" '{n}'" if n else "")
                          for c, g, n in sorted(elements)[:_UNREAD_NAMED])
        more = len(elements) - _UNREAD_NAMED
        warnings.append(
            f"{file_name}: IfcOpenShell could not triangulate {len(elements)} element(s) "
            f"({', '.join(f'{c} {k}' for c, k in sorted(classes.items()))}), which the plan "
            f"leaves out: {cause}. The file is the cause, not the parameters: {named}"
            f"{f' and {more} more' if more > 0 else ''}")
    return warnings


def _unit_scale(model: Any) -> float:
    import ifcopenshell.util.unit

    try:
        return float(ifcopenshell.util.unit.calculate_unit_scale(model))
    except Exception:  # a model without units: IFC's default unit is the metre
        return 1.0


def _storeys(model: Any, scale: float) -> list[dict[str, Any]]:
    import ifcopenshell.util.placement

    storeys = []
    for storey in model.by_type("IfcBuildingStorey"):
        elevation = storey.Elevation
        if elevation is None and storey.ObjectPlacement is not None:
            matrix = ifcopenshell.util.placement.get_local_placement(storey.ObjectPlacement)
            elevation = float(matrix[2, 3])
        storeys.append({
            "global_id": str(storey.GlobalId),
            "name": str(storey.Name or storey.LongName or storey.GlobalId),
            "elevation_m": round(float(elevation or 0.0) * scale, _DECIMALS),
        })
    storeys.sort(key=lambda s: (s["elevation_m"], s["name"], s["global_id"]))
    return storeys


def _storey_of(element: Any) -> Any:
    """The IfcBuildingStorey an element stands in: through containment and aggregation."""
    import ifcopenshell.util.element as util

    node = element
    for _ in range(64):  # a cycle in a broken file must not hang the reader
        if node is None or node.is_a("IfcBuildingStorey"):
            return node
        node = (util.get_container(node, should_get_direct=True)
                or util.get_aggregate(node) or util.get_nest(node))
    return None


def _settings() -> Any:
    import ifcopenshell.geom

    geom: Any = ifcopenshell.geom  # its stubs are partial; keep the calls untyped
    settings = geom.settings()
    settings.set("use-world-coords", True)
    settings.set("weld-vertices", True)
    return settings


def geometry_library() -> str:
    """The geometry kernel the reader asks IfcOpenShell for: the hybrid one when IfcOpenShell
    has both its parts, else OpenCASCADE alone."""
    import ifcopenshell.geom

    geom: Any = ifcopenshell.geom
    if all(geom.has_geometry_library(part) for part in _GEOMETRY_PARTS):
        return _GEOMETRY_LIBRARY
    return "opencascade"


def _shapes(model: Any, path: Path, storey_name: dict[str, str]
            ) -> tuple[list[_Shape], list[_Shape], list[tuple[str, str, str, str]]]:
    """Triangulated building elements and spaces, in IfcOpenShell's order, and the
    elements with a representation whose geometry could not be read: (class, GlobalId,
    name, IfcOpenShell's error) each.

    The iterator stops at the first element it cannot triangulate and skips the rest:
    every element with a representation it did not give is triangulated on its own
    (:func:`_missed_shapes`), so one broken element costs only itself."""
    import ifcopenshell.geom

    geom: Any = ifcopenshell.geom  # its stubs are partial; keep the calls untyped
    library = geometry_library()
    # the full identifier: IFC4X3 files are IFC4X3_ADD2 (or _ADD1) to the wrapper
    schema = ifcopenshell.ifcopenshell_wrapper.schema_by_name(model.schema_identifier)
    exclude = []
    for name in (*NON_PHYSICAL[1:], "IfcOpeningStandardCase"):
        try:
            schema.declaration_by_name(name)
        except Exception:  # not in this schema (IfcOpeningStandardCase is IFC4 only)
            continue
        exclude.append(name)
    if not any(p.Representation is not None and not p.is_a("IfcSpace")
               and not any(p.is_a(c) for c in exclude) for p in model.by_type("IfcProduct")):
        return [], [], []  # nothing to triangulate (and the iterator may refuse such a file)
    try:
        iterator = geom.iterator(
            _settings(), model, _GEOMETRY_THREADS, exclude=exclude, geometry_library=library,
        )
        started = iterator.initialize()
    except Exception as exc:
        raise SceneError(f"{path.name}: IfcOpenShell could not triangulate it: {exc}") from exc
    shapes: list[_Shape] = []
    spaces: list[_Shape] = []
    empty: list[tuple[str, str, str, str]] = []
    given: set[int] = set()
    while started:
        shape = iterator.get()
        product = model.by_id(shape.id)
        given.add(int(product.id()))
        item = _shape(product, shape.geometry, storey_name)
        if item is not None and not any(product.is_a(c) for c in NON_PHYSICAL[1:]):
            (spaces if product.is_a("IfcSpace") else shapes).append(item)
        elif item is None:
            empty.append(_unread(product, _NO_TRIANGLES))
        if not iterator.next():
            break
    missed, unread = _missed_shapes(model, given, exclude, storey_name)
    unread = empty + unread
    for item in missed:
        (spaces if item.ifc_class == "IfcSpace" else shapes).append(item)
    return shapes, spaces, unread


def _missed_shapes(model: Any, given: set[int], exclude: list[str],
                   storey_name: dict[str, str]
                   ) -> tuple[list[_Shape], list[tuple[str, str, str, str]]]:
    """The products with a body the iterator did not give (their STEP ids not in
    ``given``), triangulated one by one: the shapes read, and (class, GlobalId, name,
    error) of those that fail. A product whose representations are all 2D (an axis, a
    footprint) has no body and is no failure."""
    import ifcopenshell.geom

    geom: Any = ifcopenshell.geom
    shapes: list[_Shape] = []
    unread: list[tuple[str, str, str, str]] = []
    settings = None
    for product in model.by_type("IfcProduct"):
        if (product.Representation is None or int(product.id()) in given
                or any(product.is_a(c) for c in exclude) or not _has_body(product)):
            continue
        settings = settings or _settings()
        try:
            shape = geom.create_shape(settings, product)
        except Exception as exc:  # RuntimeError and the wrapper's own errors
            unread.append(_unread(product, _cause(exc)))
            continue
        item = _shape(product, shape.geometry, storey_name)
        if item is not None:
            shapes.append(item)
        else:
            unread.append(_unread(product, _NO_TRIANGLES))
    return shapes, unread


_NO_TRIANGLES = "its body gives no triangles"
# where IfcOpenShell's message starts to quote the product and representation it failed on
_QUOTED_ENTITY = re.compile(r"[\s.,:;]*(?:Product:|representation:)?\s*#\d+\s*=")


def _cause(exc: Exception) -> str:
    """IfcOpenShell's error without the entities it quotes: one cause for many elements."""
    message = _QUOTED_ENTITY.split(" ".join(str(exc).split()), maxsplit=1)[0]
    return message.rstrip(" .,:;") or type(exc).__name__


def _unread(product: Any, cause: str) -> tuple[str, str, str, str]:
    """(class, GlobalId, name, cause) of an element whose geometry was not read."""
    try:
        name = str(product.Name or "")
    except Exception:  # the name itself written wrongly
        name = ""
    return str(product.is_a()), str(product.GlobalId), name, cause


def _has_body(product: Any) -> bool:
    """The product has a 3D representation (a body), not only an axis or a footprint."""
    try:
        representations = product.Representation.Representations or ()
    except Exception:  # an attribute the file writes wrongly: try it, and report it
        return True
    for representation in representations:
        try:
            identifier = str(representation.RepresentationIdentifier or "")
            kind = str(representation.RepresentationType or "")
        except Exception:
            return True
        if identifier in ("Body", "Facetation", "") and kind not in (
                "Curve2D", "GeometricCurveSet", "Annotation2D", "Point", "PointCloud"):
            return True
    return False


def _shape(product: Any, geometry: Any, storey_name: dict[str, str]) -> _Shape | None:
    vertices = np.asarray(geometry.verts, np.float64).reshape(-1, 3)
    faces = np.asarray(geometry.faces, np.int64).reshape(-1, 3)
    if len(faces) == 0 or not np.isfinite(vertices).all():
        return None
    transparent = np.array(
        [float(m.transparency or 0.0) >= GLASS_MIN_TRANSPARENCY for m in geometry.materials]
        + [False], bool)  # material id -1 (no style) picks the trailing False
    material = np.asarray(geometry.material_ids, np.int64).reshape(-1)
    glass = (transparent[material] if len(material) == len(faces)
             else np.zeros(len(faces), bool))
    storey = _storey_of(product)
    return _Shape(
        ifc_class=str(product.is_a()),
        global_id=str(product.GlobalId),
        name=str(product.Name or ""),
        storey="" if storey is None else storey_name.get(str(storey.GlobalId), ""),
        vertices=vertices,
        faces=faces,
        glass=glass,
        long_name=str(getattr(product, "LongName", None) or ""),
    )


def _scene(shapes: list[_Shape], space_shapes: list[_Shape], storeys: list[dict[str, Any]],
           schema: str, scale: float) -> Scene:
    labels = [
        np.where(s.glass | (s.ifc_class in GLASS_CLASSES), s.ifc_class + GLASS_SUFFIX, "")
        for s in shapes
    ]
    face_label = np.concatenate([
        np.where(label == "", s.ifc_class, label) for s, label in zip(shapes, labels, strict=True)
    ])
    groups = tuple(sorted(set(face_label.tolist())))
    face_group = np.searchsorted(np.array(groups), face_label)
    offsets = np.cumsum([0] + [len(s.vertices) for s in shapes])
    faces = np.concatenate([s.faces + offsets[i] for i, s in enumerate(shapes)])
    face_element = np.concatenate(
        [np.full(len(s.faces), i, np.int64) for i, s in enumerate(shapes)])
    elements = tuple(Element(s.global_id, s.ifc_class, s.name, s.storey) for s in shapes)
    metadata: dict[str, Any] = {
        "format": "ifc",
        "schema": schema,
        "length_unit_scale": scale,
        "storeys": storeys,
        "spaces": _spaces(space_shapes, storeys),
        "default_group_requirements": default_requirements(groups),
    }
    return build_scene(np.concatenate([s.vertices for s in shapes]), faces, face_group,
                       groups, face_element=face_element, elements=elements,
                       metadata=metadata)


def default_requirements(groups: tuple[str, ...]) -> dict[str, dict[str, Any]]:
    """Per-group defaults: glazing neither targets nor occludes, terrain is no target."""
    defaults: dict[str, dict[str, Any]] = {}
    for group in groups:
        if group.endswith(GLASS_SUFFIX) or group in GLASS_CLASSES:
            defaults[group] = {"target": False, "occludes": False}
        elif group in NOT_TARGET_CLASSES:
            defaults[group] = {"target": False, "occludes": True}
    return defaults


def _spaces(space_shapes: list[_Shape], storeys: list[dict[str, Any]]
            ) -> list[dict[str, Any]]:
    storey_rank = {s["name"]: i for i, s in enumerate(storeys)}
    storey_id = {s["name"]: s["global_id"] for s in storeys}
    spaces = []
    for shape in space_shapes:
        footprint = _footprint(shape.vertices, shape.faces)
        if footprint is None:
            continue
        shell = [[round(float(x), _DECIMALS), round(float(y), _DECIMALS)]
                 for x, y in list(footprint.exterior.coords)[:-1]]
        holes = [[[round(float(x), _DECIMALS), round(float(y), _DECIMALS)]
                  for x, y in list(ring.coords)[:-1]] for ring in footprint.interiors]
        spaces.append({
            "global_id": shape.global_id,
            "name": shape.name,
            "long_name": shape.long_name,
            "storey": shape.storey,
            "storey_global_id": storey_id.get(shape.storey, ""),
            "floor_z_m": round(float(shape.vertices[:, 2].min()), _DECIMALS),
            "area_m2": round(float(footprint.area), _DECIMALS),
            "polygon": shell,
            "holes": holes,
        })
    spaces.sort(key=lambda s: (storey_rank.get(s["storey"], len(storeys)), s["storey"],
                               s["name"], s["global_id"]))
    return spaces


def _spaces_unread(model: Any, spaces: list[dict[str, Any]],
                   unread: list[tuple[str, str, str, str]], storey_name: dict[str, str]
                   ) -> list[dict[str, str]]:
    """The IfcSpaces missing from ``spaces``, with the reason: IfcOpenShell's error, a body
    that gives no floor outline, or no body at all. In model order (storey, name)."""
    read = {space["global_id"] for space in spaces}
    causes = {global_id: cause for ifc_class, global_id, _, cause in unread
              if ifc_class == "IfcSpace"}
    missing = []
    for product in model.by_type("IfcSpace"):
        global_id = str(product.GlobalId)
        if global_id in read:
            continue
        if global_id in causes:
            reason = f"IfcOpenShell could not triangulate it: {causes[global_id]}"
        elif product.Representation is not None and _has_body(product):
            reason = "its body gives no floor outline (flat or empty)"
        else:
            reason = "it has no body (3D) representation"
        storey = _storey_of(product)
        name, long_name = _unread(product, "")[2], ""
        try:
            long_name = str(product.LongName or "")
        except Exception:  # written wrongly: the name and GlobalId still say which
            long_name = ""
        missing.append({
            "global_id": global_id, "name": name, "long_name": long_name,
            "storey": "" if storey is None else storey_name.get(str(storey.GlobalId), ""),
            "reason": reason,
        })
    missing.sort(key=lambda s: (s["storey"], s["name"], s["global_id"]))
    return missing


def _footprint(vertices: NDArray[np.float64], faces: NDArray[np.int64]) -> Polygon | None:
    """The largest polygon of the volume's projection on XY, or None when it is flat."""
    triangles = vertices[faces][:, :, :2]
    edge1 = triangles[:, 1] - triangles[:, 0]
    edge2 = triangles[:, 2] - triangles[:, 0]
    doubled = np.abs(edge1[:, 0] * edge2[:, 1] - edge1[:, 1] * edge2[:, 0])
    triangles = triangles[doubled > 1e-12]
    if len(triangles) == 0:
        return None
    union = shapely.union_all(shapely.polygons(triangles))
    # snapping away the slivers that float noise leaves between projected triangles
    union = union.buffer(1e-6, join_style="mitre").buffer(-1e-6, join_style="mitre")
    parts = list(union.geoms) if isinstance(union, MultiPolygon) else [union]
    parts = [p for p in parts if isinstance(p, Polygon) and p.area > 0]
    if not parts:
        return None
    return shapely.normalize(max(parts, key=lambda p: p.area))
