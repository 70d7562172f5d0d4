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
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from numpy.typing import NDArray
from shapely import MultiPolygon, Polygon

from planner.errors import SceneError
from planner.scene import Element, Scene, build_scene

__all__ = ["default_requirements", "read_ifc"]

SUPPORTED_SCHEMAS = ("IFC2X3", "IFC4", "IFC4X3")
NON_PHYSICAL = ("IfcSpace", "IfcOpeningElement", "IfcVirtualElement", "IfcAnnotation",
                "IfcGrid")
GLASS_CLASSES = ("IfcPlate",)
GLASS_SUFFIX = "/glass"
GLASS_MIN_TRANSPARENCY = 0.3
NOT_TARGET_CLASSES = ("IfcSite",)
# The hybrid CGAL/OpenCASCADE kernel gives the same triangles as plain OpenCASCADE on the
# shared models (face counts, areas) in about 60 % of the time.
_GEOMETRY_LIBRARY = "hybrid-cgal-simple-opencascade"
# One thread: on FZK-Haus two threads were slower (4.9 s vs 6.4 s), the boolean
# operations of a few walls dominate and the order is sorted afterwards anyway.
_GEOMETRY_THREADS = 1
_DECIMALS = 6


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
        model = ifcopenshell.open(str(path))
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
    shapes, space_shapes = _shapes(model, path, storey_name)
    if not shapes:
        raise SceneError(
            f"{path.name} has no geometry: no building element has a body representation "
            "IfcOpenShell can triangulate; export the model with its 3D geometry"
        )
    shapes.sort(key=lambda s: (s.ifc_class, s.global_id))
    scene = _scene(shapes, space_shapes, storeys, schema, scale)
    # plan.ifc is this file with the plan added (planner.outputs.ifc_plan)
    scene.metadata["source_path"] = str(path.resolve())
    scene.metadata["source_sha256"] = hashlib.sha256(path.read_bytes()).hexdigest()
    projects = model.by_type("IfcProject")
    scene.metadata["project_global_id"] = str(projects[0].GlobalId) if projects else ""
    return scene


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


def _shapes(model: Any, path: Path, storey_name: dict[str, str]
            ) -> tuple[list[_Shape], list[_Shape]]:
    """Triangulated building elements and spaces, in IfcOpenShell's order."""
    import ifcopenshell.geom

    geom: Any = ifcopenshell.geom  # its stubs are partial; keep the calls untyped
    library = _GEOMETRY_LIBRARY if geom.has_geometry_library(_GEOMETRY_LIBRARY) \
        else "opencascade"
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
        return [], []  # nothing to triangulate (and the iterator may refuse such a file)
    try:
        iterator = geom.iterator(
            _settings(), model, _GEOMETRY_THREADS, exclude=exclude, geometry_library=library,
        )
        started = iterator.initialize()
    except Exception as exc:
        raise SceneError(f"{path.name}: IfcOpenShell could not triangulate it: {exc}") from exc
    shapes: list[_Shape] = []
    spaces: list[_Shape] = []
    while started:
        shape = iterator.get()
        product = model.by_id(shape.id)
        item = _shape(product, shape.geometry, storey_name)
        if item is not None and not any(product.is_a(c) for c in NON_PHYSICAL[1:]):
            (spaces if product.is_a("IfcSpace") else shapes).append(item)
        if not iterator.next():
            break
    return shapes, spaces


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
