"""IFC models through IfcOpenShell: the scene, its storeys and rooms, and room candidates.

Only :mod:`planner.readers` imports this module, and only when an IFC file comes, because
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
  name, storey), and its group is the element's IFC class, except glazing (below).

Glass
-----
A laser passes through glass, and glass returns no usable points. IfcWindow (and IfcDoor)
elements mix frames and panes in one element, so the decision is made per face, from the
surface style IfcOpenShell reports for it: a face whose style lets at least
``GLASS_MIN_TRANSPARENCY`` of the light through is glazing and gets the group
``"<IfcClass>/glass"`` (``"IfcWindow/glass"``). Every IfcPlate is treated as glazing too
(curtain-wall and window panels; the issue's default), transparent style or not. By default
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

Candidates from rooms (:func:`room_candidates`)
-----------------------------------------------
For each room (restricted by ``spec.storeys`` / ``spec.rooms``): grid points at multiples of
``grid_spacing_m`` inside the floor polygon (boundary inclusive) and inside
``area_of_interest`` if given, at ``floor_z_m + scanner_height_m``. A point is dropped when
the first surface straight below the scanner is not within ``FLOOR_TOLERANCE_M`` of the
room's floor (``no_floor``: a stair hole, a void; ``blocked_above_floor``: a table, a stair
under the scanner), when it is inside a closed object (``inside_geometry``), or when the
tripod lacks ``clearance_m`` of room around its axis from that floor to above the scanner
(``too_close``, as :func:`planner.candidates.closer_than` measures it). A point on the
boundary shared by two rooms belongs to the first. Order: rooms as in
``metadata["spaces"]``, then grid rows (y, then x).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from numpy.typing import NDArray
from shapely import MultiPolygon, Polygon, intersects_xy

from planner.candidates import (
    DROP_REASONS,
    CandidateSet,
    closer_than,
    grid_points_xy,
    inside_closed_groups,
)
from planner.errors import NoCandidatesError, ParameterError, SceneError
from planner.parameters import PlanSpec
from planner.scene import Element, Scene, build_scene

SUPPORTED_SCHEMAS = ("IFC2X3", "IFC4", "IFC4X3")
NON_PHYSICAL = ("IfcSpace", "IfcOpeningElement", "IfcVirtualElement", "IfcAnnotation",
                "IfcGrid")
GLASS_CLASSES = ("IfcPlate",)
GLASS_SUFFIX = "/glass"
GLASS_MIN_TRANSPARENCY = 0.3
NOT_TARGET_CLASSES = ("IfcSite",)
FLOOR_TOLERANCE_M = 0.3
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
    return _scene(shapes, space_shapes, storeys, schema, scale)


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
    schema = ifcopenshell.ifcopenshell_wrapper.schema_by_name(model.schema)
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


def room_candidates(scene: Scene, spec: PlanSpec, caster: object) -> CandidateSet:
    """Candidates inside the rooms of an IFC model (see the module docstring).

    Parameters
    ----------
    scene : a scene read by :func:`read_ifc` (``metadata["spaces"]`` non-empty)
    spec : grid spacing, scanner height, clearance, storey and room restrictions
    caster : a :class:`planner._embree.EmbreeOcclusion` over the occluding faces

    Raises
    ------
    ParameterError
        a storey or room that the model does not have
    NoCandidatesError
        no room is left after the restriction, or no point in the rooms is usable
    """
    from planner._embree import EmbreeOcclusion

    assert isinstance(caster, EmbreeOcclusion)
    spaces = select_spaces(scene.metadata.get("spaces", []),
                           scene.metadata.get("storeys", []), spec)
    area = None
    if spec.area_of_interest is not None:
        area = Polygon(spec.area_of_interest)
        if not area.is_valid or area.area <= 0:
            raise ParameterError(
                "area_of_interest", "is not a valid polygon (self-intersecting or flat)")
    dropped = dict.fromkeys(DROP_REASONS, 0)
    points: list[NDArray[np.float64]] = []
    labels: list[dict[str, str]] = []
    seen: set[tuple[float, float, float]] = set()
    for space in spaces:
        room = Polygon(space["polygon"], space.get("holes") or None)
        xy = grid_points_xy(np.asarray(room.bounds, np.float64).reshape(2, 2),
                            spec.grid_spacing_m, room)
        if len(xy):
            xy = xy[intersects_xy(room, xy[:, 0], xy[:, 1])]
        z = float(space["floor_z_m"]) + spec.scanner_height_m
        keep = []
        for x, y in xy:
            key = (round(float(x), 6), round(float(y), 6), round(z, 6))
            if key not in seen:  # a point on a shared wall line belongs to the first room
                seen.add(key)
                keep.append((x, y, z))
        if not keep:
            continue
        points.append(np.asarray(keep, np.float64))
        label = {
            "room": str(space["long_name"] or space["name"] or space["global_id"]),
            "room_name": str(space["name"]),
            "room_global_id": str(space["global_id"]),
            "storey": str(space["storey"]),
        }
        labels.extend([label] * len(keep))
    positions = np.concatenate(points) if points else np.zeros((0, 3))
    considered = len(positions)
    keep_mask = np.ones(considered, bool)
    if area is not None and considered:
        inside = intersects_xy(area, positions[:, 0], positions[:, 1])
        dropped["outside_area_of_interest"] = int((~inside).sum())
        keep_mask &= inside
    on_floor, floor_z = _on_floor(scene, positions, spec, caster, keep_mask, dropped)
    keep_mask &= on_floor
    keep_mask &= _clear(scene, positions, spec.clearance_m, floor_z, keep_mask, dropped)
    if not keep_mask.any():
        raise NoCandidatesError(
            f"no point is left in the {len(spaces)} room(s) out of {considered} "
            f"({', '.join(f'{k}: {v}' for k, v in dropped.items() if v) or 'none in a room'}); "
            f"lower grid_spacing_m ({spec.grid_spacing_m}) or clearance_m "
            f"({spec.clearance_m}), choose other rooms or storeys, or give candidates "
            "explicitly"
        )
    index = np.flatnonzero(keep_mask)
    return CandidateSet(
        positions=positions[index], source="rooms", considered=considered,
        dropped=dropped, labels=tuple(labels[i] for i in index),
    )


def select_spaces(spaces: list[dict[str, Any]], storeys: list[dict[str, Any]],
                  spec: PlanSpec) -> list[dict[str, Any]]:
    """The rooms the plan is restricted to, in model order.

    ``spec.storeys`` matches a storey's name or GlobalId, ``spec.rooms`` a room's name,
    long name or GlobalId; both restrict together. An unknown name is a
    :class:`ParameterError` listing the known ones.
    """
    chosen = list(spaces)
    if spec.storeys is not None:
        known = {s["name"] for s in storeys} | {s["global_id"] for s in storeys}
        known |= {s["storey"] for s in spaces} | {s["storey_global_id"] for s in spaces}
        known.discard("")
        unknown = [name for name in spec.storeys if name not in known]
        if unknown:
            names = ", ".join(repr(s["name"]) for s in storeys) or "none"
            raise ParameterError(
                "storeys", f"{unknown[0]!r} is not a storey of the model; known storeys are "
                f"{names} (or their GlobalIds)")
        wanted = set(spec.storeys)
        chosen = [s for s in chosen if s["storey"] in wanted or s["storey_global_id"] in wanted]
    if spec.rooms is not None:
        known = {v for s in spaces for v in (s["name"], s["long_name"], s["global_id"]) if v}
        unknown = [name for name in spec.rooms if name not in known]
        if unknown:
            names = ", ".join(
                repr(s["long_name"] or s["name"]) + (f" ({s['name']})" if s["long_name"] else "")
                for s in spaces) or "none"
            raise ParameterError(
                "rooms", f"{unknown[0]!r} is not a room of the model; known rooms are "
                f"{names} (by name, long name or GlobalId)")
        wanted = set(spec.rooms)
        chosen = [s for s in chosen
                  if wanted & {s["name"], s["long_name"], s["global_id"]}]
    if not chosen:
        raise NoCandidatesError(
            f"no room is left after restricting to storeys {list(spec.storeys or [])} and "
            f"rooms {list(spec.rooms or [])}: the rooms asked for are on other storeys; "
            "change storeys or rooms, or set them to null to use every room")
    return chosen


def _on_floor(scene: Scene, positions: NDArray[np.float64], spec: PlanSpec, caster: Any,
              alive: NDArray[np.bool_], dropped: dict[str, int]
              ) -> tuple[NDArray[np.bool_], NDArray[np.float64]]:
    """(C,) bool: straight below the scanner, the first surface is the room's floor.

    Also returns (C,) the height of that surface (the room's floor where nothing was hit).
    """
    ok = np.ones(len(positions), bool)
    floor_z = positions[:, 2] - spec.scanner_height_m
    index = np.flatnonzero(alive)
    if len(index) == 0:
        return ok, floor_z
    down = np.tile([0.0, 0.0, -1.0], (len(index), 1))
    face, distance = caster.first_hit(positions[index], down)
    height = spec.scanner_height_m
    no_floor = (face < 0) | (distance > height + FLOOR_TOLERANCE_M)
    blocked = ~no_floor & (distance < height - FLOOR_TOLERANCE_M)
    dropped["no_floor"] += int(no_floor.sum())
    dropped["blocked_above_floor"] += int(blocked.sum())
    ok[index[no_floor | blocked]] = False
    hit = ~(no_floor | blocked)
    floor_z[index[hit]] = positions[index[hit], 2] - distance[hit]
    return ok, floor_z


def _clear(scene: Scene, positions: NDArray[np.float64], clearance_m: float,
           floor_z: NDArray[np.float64], alive: NDArray[np.bool_], dropped: dict[str, int]
           ) -> NDArray[np.bool_]:
    """(C,) bool: not inside an element's solid, and the tripod has ``clearance_m`` of room.

    The room is measured as :func:`planner.candidates.closer_than` does, from the floor
    found under the scanner.
    """
    ok = np.ones(len(positions), bool)
    index = np.flatnonzero(alive)
    if len(index) == 0:
        return ok
    inside = inside_elements(scene, positions[index])
    dropped["inside_geometry"] += int(inside.sum())
    ok[index[inside]] = False
    index = index[~inside]
    near = closer_than(scene, positions[index], clearance_m, floor_z[index])
    dropped["too_close"] += int(near.sum())
    ok[index[near]] = False
    return ok


def inside_elements(scene: Scene, points: NDArray[np.float64]) -> NDArray[np.bool_]:
    """(N,) bool: inside some element's closed solid (winding number above one half).

    Per element rather than per group (:func:`planner.candidates.inside_closed_groups`):
    an element's box holds few points and its faces are few, which keeps the winding-number
    arrays small on a remeshed building. Scenes without elements fall back to groups.
    """
    if not scene.elements:
        return inside_closed_groups(scene, points)
    from planner.candidates import winding_number

    result = np.zeros(len(points), bool)
    triangles = scene.triangles
    order = np.argsort(scene.face_element, kind="stable")
    bounds = np.searchsorted(scene.face_element[order], np.arange(len(scene.elements) + 1))
    for e in range(len(scene.elements)):
        faces = order[bounds[e]:bounds[e + 1]]
        if len(faces) == 0:
            continue
        tri = triangles[faces]
        lo, hi = tri.reshape(-1, 3).min(axis=0), tri.reshape(-1, 3).max(axis=0)
        boxed = np.flatnonzero(((points > lo) & (points < hi)).all(axis=1) & ~result)
        step = max(1, 2_000_000 // max(1, len(faces)))
        for s in range(0, len(boxed), step):
            chunk = boxed[s:s + step]
            result[chunk] = winding_number(tri, points[chunk]) > 0.5
    return result
