"""A deterministic multi-storey IFC office, built with ``ifcopenshell.api``, for benchmarks.

Stands in for real office models that cannot be shared: storeys of offices on both sides of
a central corridor, a stair core, closed doors in their openings, windows, furniture and
columns, every room an IfcSpace. The same arguments always give the same bytes (GlobalIds
from a counter, a fixed header time stamp).

Layout (x along ``width_m``, y along ``depth_m``, storey k at elevation ``k *
storey_height_m``)::

    y = depth   +-----+-----+-----+-- ... --+-------+
                | office    | office        | stair |   north offices, bays of bay_width_m
    corridor    +--D--+--D--+--D--+-- ... --+---D---+
    (central)   D           corridor                |   D: door (entrance at x = 0, ground)
                +--D--+--D--+--D--+-- ... --+---D---+
                | office    | office        | office|   south offices
    y = 0       +-----+-----+-----+-- ... --+-------+

Per storey: a floor slab (top at the storey's elevation; over the stair a slab opening), a
suspended ceiling (IfcCovering CEILING, off by default), exterior walls with windows (optional),
corridor walls and partitions with one door per room (IfcDoor leaf closed in an opening that
voids the wall), columns, desks and cabinets (IfcFurniture; IfcFurnishingElement in IFC2X3)
in each office, and an IfcSpace per office, corridor and stair core (extruded footprints).
Between storeys a straight IfcStairFlight modelled as a stepped solid, aggregated in an
IfcStair. On top a roof slab.

Size: with the defaults (3 storeys, 50 x 37 m; 33,676 file faces, 1,285 elements, 63
rooms) ``plan()`` splits it at 0.2 m into 13.8 M faces and finds 8,556 room candidates
(default parameters), somewhat heavier than the 10.4 M-face office it stands in for;
``--width-m 38`` comes closest to that one (9.73 M faces, 6,432 candidates);
``--width-m 15 --depth-m 20 --storeys 2`` gives a small office (1.5 M faces, 973
candidates) for quick runs.

    .venv/bin/python benchmarks/ifc_office.py OUT.ifc [--storeys 3] [--width-m 50]
        [--depth-m 37] [--schema IFC4] [--no-windows] [--ceilings] [--count-faces]
"""

from __future__ import annotations

import argparse
import hashlib
import itertools
import math
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import ifcopenshell
import ifcopenshell.api.aggregate
import ifcopenshell.api.context
import ifcopenshell.api.feature
import ifcopenshell.api.geometry
import ifcopenshell.api.owner
import ifcopenshell.api.project
import ifcopenshell.api.root
import ifcopenshell.api.spatial
import ifcopenshell.api.unit
import ifcopenshell.guid
import numpy as np

Entity = ifcopenshell.entity_instance
XYZ = tuple[float, float, float]
Schema = Literal["IFC2X3", "IFC4"]

SLAB_THICKNESS_M = 0.3
EXTERIOR_WALL_M = 0.3
INTERIOR_WALL_M = 0.12
DOOR_WIDTH_M = 0.9
DOOR_HEIGHT_M = 2.1
WINDOW_WIDTH_M = 2.0
WINDOW_HEIGHT_M = 1.5
WINDOW_SILL_M = 0.9
CEILING_HEIGHT_M = 2.8  # underside of the suspended ceiling above the floor
CEILING_THICKNESS_M = 0.02
COLUMN_M = 0.4
DESK_M = (1.6, 0.8, 0.75)  # width, depth, height
CABINET_M = (0.8, 0.4, 2.0)
STAIR_WIDTH_M = 1.2
STAIR_GOING_M = 0.28  # tread depth
STAIR_MAX_RISER_M = 0.18
STAIR_WAIST_M = 0.2  # thickness of the flight under the nosings
STAIR_LANDING_M = 1.5  # free floor between the corridor wall and the first riser
TIMESTAMP = "2000-01-01T00:00:00"
TIMESTAMP_S = 946_684_800  # the same instant in seconds since 1970 (IfcTimeStamp)


@dataclass(frozen=True)
class OfficeLayout:
    """Dimensions of the office in metres (see the module docstring for the plan)."""

    storeys: int = 3
    width_m: float = 50.0
    depth_m: float = 37.0
    storey_height_m: float = 3.5
    corridor_width_m: float = 2.4
    bay_width_m: float = 5.0
    desk_row_pitch_m: float = 2.2
    windows: bool = True
    ceilings: bool = False

    @property
    def corridor_y_m(self) -> tuple[float, float]:
        """South and north faces of the corridor (inner faces of its walls)."""
        half = self.corridor_width_m / 2
        return self.depth_m / 2 - half, self.depth_m / 2 + half

    @property
    def bays_x_m(self) -> list[tuple[float, float]]:
        """Bay boundaries along x, wall axis to wall axis; the last bay takes the rest."""
        n = max(1, int(self.width_m // self.bay_width_m))
        edges = [i * self.width_m / n for i in range(n + 1)]
        return list(itertools.pairwise(edges))


class _Builder:
    """Adds boxes, openings, doors, spaces to one IFC file; every position in metres."""

    def __init__(self, schema: Schema) -> None:
        self.schema = schema
        self.f = ifcopenshell.api.project.create_file(version=schema)
        if schema == "IFC2X3":  # owner history is mandatory there; the API finds these
            ifcopenshell.api.owner.add_application(self.f)
            ifcopenshell.api.owner.add_person_and_organisation(
                self.f, person=ifcopenshell.api.owner.add_person(self.f),
                organisation=ifcopenshell.api.owner.add_organisation(self.f))
        self.project = self.create("IfcProject", "scanplan benchmark office")
        ifcopenshell.api.unit.assign_unit(self.f, length={"is_metric": True, "raw": "METRES"})
        model = ifcopenshell.api.context.add_context(self.f, context_type="Model")
        self.body = ifcopenshell.api.context.add_context(
            self.f, context_type="Model", context_identifier="Body", target_view="MODEL_VIEW",
            parent=model)
        self.furniture_class = "IfcFurniture" if schema != "IFC2X3" else "IfcFurnishingElement"

    def create(self, ifc_class: str, name: str, predefined_type: str | None = None) -> Entity:
        entity: Entity = ifcopenshell.api.root.create_entity(
            self.f, ifc_class=ifc_class, name=name, predefined_type=predefined_type)
        return entity

    def place(self, product: Entity, origin: XYZ, *, turned: bool = False) -> None:
        """Put the product's local origin at ``origin``; ``turned`` rotates it 90 degrees about
        +Z (local x along world +y)."""
        matrix = np.eye(4)
        if turned:
            matrix[:3, :3] = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
        matrix[:3, 3] = origin
        ifcopenshell.api.geometry.edit_object_placement(self.f, product=product, matrix=matrix)

    def box(self, ifc_class: str, name: str, corner: XYZ, size: XYZ, storey: Entity,
            predefined_type: str | None = None) -> Entity:
        """An axis-aligned box from ``corner`` (lowest x, y, z) over ``size`` (dx, dy, dz)."""
        product = self.create(ifc_class, name, predefined_type)
        self.shape(product, corner, size)
        ifcopenshell.api.spatial.assign_container(
            self.f, products=[product], relating_structure=storey)
        return product

    def shape(self, product: Entity, corner: XYZ, size: XYZ) -> None:
        rep = ifcopenshell.api.geometry.add_wall_representation(
            self.f, context=self.body, length=size[0], thickness=size[1], height=size[2])
        ifcopenshell.api.geometry.assign_representation(self.f, product=product,
                                                        representation=rep)
        self.place(product, corner)

    def void(self, element: Entity, corner: XYZ, size: XYZ) -> Entity:
        """An IfcOpeningElement box voiding ``element``."""
        opening = self.create("IfcOpeningElement", "Opening")
        self.shape(opening, corner, size)
        ifcopenshell.api.feature.add_feature(self.f, feature=opening, element=element)
        return opening

    def prism(self, product: Entity, polygon: list[tuple[float, float]], z0: float,
              height: float) -> None:
        """``polygon`` (XY, counter-clockwise) extruded from ``z0`` up by ``height``."""
        rep = ifcopenshell.api.geometry.add_slab_representation(
            self.f, context=self.body, depth=height, polyline=polygon)
        ifcopenshell.api.geometry.assign_representation(self.f, product=product,
                                                        representation=rep)
        self.place(product, (0.0, 0.0, z0))

    def door(self, wall: Entity, storey: Entity, name: str, x: float, y: float, z: float,
             thickness: float, *, along_y: bool = False) -> None:
        """A closed door leaf in an opening through ``wall``: the opening's width runs along
        x (or y) from (x, y), through the wall's ``thickness``."""
        margin = 0.1
        if along_y:
            corner: XYZ = (x - margin, y, z)
            size: XYZ = (thickness + 2 * margin, DOOR_WIDTH_M, DOOR_HEIGHT_M)
        else:
            corner, size = (x, y - margin, z), (DOOR_WIDTH_M, thickness + 2 * margin,
                                                DOOR_HEIGHT_M)
        opening = self.void(wall, corner, size)
        door = self.create("IfcDoor", name)
        rep = ifcopenshell.api.geometry.add_door_representation(
            self.f, context=self.body, overall_height=DOOR_HEIGHT_M,
            overall_width=DOOR_WIDTH_M, operation_type="SINGLE_SWING_LEFT",
            lining_properties={"LiningDepth": thickness, "LiningThickness": 0.05},
            panel_properties={"PanelDepth": 0.04})
        assert rep is not None  # None only without a width and height
        ifcopenshell.api.geometry.assign_representation(self.f, product=door,
                                                        representation=rep)
        if along_y:  # local x along +y, local y along -x: the lining spans x - t .. x
            self.place(door, (x + thickness, y, z), turned=True)
        else:
            self.place(door, (x, y, z))
        ifcopenshell.api.feature.add_filling(self.f, opening=opening, element=door)
        ifcopenshell.api.spatial.assign_container(self.f, products=[door],
                                                  relating_structure=storey)

    def window(self, wall: Entity, storey: Entity, name: str, x: float, y: float, z: float,
               thickness: float) -> None:
        """A window in an opening through a wall running along x."""
        opening = self.void(wall, (x, y - 0.1, z), (WINDOW_WIDTH_M, thickness + 0.2,
                                                    WINDOW_HEIGHT_M))
        window = self.create("IfcWindow", name)
        rep = ifcopenshell.api.geometry.add_window_representation(
            self.f, context=self.body, overall_height=WINDOW_HEIGHT_M,
            overall_width=WINDOW_WIDTH_M, partition_type="SINGLE_PANEL",
            lining_properties={"LiningDepth": thickness})
        ifcopenshell.api.geometry.assign_representation(self.f, product=window,
                                                        representation=rep)
        self.place(window, (x, y - 0.065, z))  # the lining starts 0.05 into the wall
        ifcopenshell.api.feature.add_filling(self.f, opening=opening, element=window)
        ifcopenshell.api.spatial.assign_container(self.f, products=[window],
                                                  relating_structure=storey)

    def space(self, storey: Entity, name: str, long_name: str, x0: float, y0: float,
              x1: float, y1: float, z0: float, height: float) -> None:
        space = self.create("IfcSpace", name)
        space.LongName = long_name
        self.prism(space, [(x0, y0), (x1, y0), (x1, y1), (x0, y1)], z0, height)
        ifcopenshell.api.aggregate.assign_object(self.f, products=[space],
                                                 relating_object=storey)

    def finish(self) -> ifcopenshell.file:
        """Deterministic GlobalIds, header and members of relationships and unit assignments
        (the API collects these in sets), so that the same layout gives the same bytes."""
        for rel in self.f.by_type("IfcRelationship") + self.f.by_type("IfcUnitAssignment"):
            for index, value in enumerate(rel):
                if isinstance(value, tuple) and all(
                        isinstance(v, ifcopenshell.entity_instance) for v in value):
                    rel[index] = tuple(sorted(value, key=lambda v: v.id()))
        for index, root in enumerate(self.f.by_type("IfcRoot")):
            digest = hashlib.sha256(f"scanplan-office-{index}".encode()).digest()[:16]
            root.GlobalId = ifcopenshell.guid.compress(uuid.UUID(bytes=digest).hex)
        self.f.header.file_name.time_stamp = TIMESTAMP
        for history in self.f.by_type("IfcOwnerHistory"):  # IFC2X3: times of creation
            history.CreationDate = TIMESTAMP_S
            if history.LastModifiedDate is not None:
                history.LastModifiedDate = TIMESTAMP_S
        return self.f


def build_ifc_office(path: str | Path, *, storeys: int = 3, width_m: float = 50.0,
                     depth_m: float = 37.0, schema: Schema = "IFC4", windows: bool = True,
                     ceilings: bool = False, storey_height_m: float = 3.5,
                     bay_width_m: float = 5.0) -> Path:
    """Write the office (see the module docstring) to ``path`` and return the path.

    Raises ValueError when the plan is too small for a corridor, offices and a stair.
    """
    layout = OfficeLayout(storeys=storeys, width_m=width_m, depth_m=depth_m,
                          storey_height_m=storey_height_m, bay_width_m=bay_width_m,
                          windows=windows, ceilings=ceilings)
    _check(layout)
    b = _Builder(schema)
    site = b.create("IfcSite", "Site")
    building = b.create("IfcBuilding", "Office")
    ifcopenshell.api.aggregate.assign_object(b.f, products=[site], relating_object=b.project)
    ifcopenshell.api.aggregate.assign_object(b.f, products=[building], relating_object=site)
    levels = []
    for k in range(storeys):
        storey = b.create("IfcBuildingStorey", f"Level {k}")
        storey.Elevation = k * storey_height_m
        ifcopenshell.api.aggregate.assign_object(b.f, products=[storey],
                                                 relating_object=building)
        levels.append(storey)
    stair = _stair_rect(layout)
    for k, storey in enumerate(levels):
        _storey(b, layout, storey, k, stair)
    roof_z = storeys * storey_height_m
    b.box("IfcSlab", "Roof", (0.0, 0.0, roof_z - SLAB_THICKNESS_M),
          (width_m, depth_m, SLAB_THICKNESS_M), levels[-1], "ROOF")
    out = Path(path)
    b.finish().write(str(out))
    return out


def _check(layout: OfficeLayout) -> None:
    _, c1 = layout.corridor_y_m
    min_office_m = STAIR_LANDING_M + _flight_run_m(layout) + 1.0
    if layout.storeys < 1:
        raise ValueError(f"storeys is {layout.storeys}; use 1 or more")
    if layout.depth_m - c1 < min_office_m:
        raise ValueError(f"depth_m is {layout.depth_m}; use at least "
                         f"{2 * min_office_m + layout.corridor_width_m:.1f} to fit the stair")
    if layout.width_m < 2 * layout.bay_width_m:
        raise ValueError(f"width_m is {layout.width_m}; use at least two bays "
                         f"({2 * layout.bay_width_m} m)")


def _risers(layout: OfficeLayout) -> int:
    return math.ceil(layout.storey_height_m / STAIR_MAX_RISER_M)


def _flight_run_m(layout: OfficeLayout) -> float:
    return _risers(layout) * STAIR_GOING_M


def _stair_rect(layout: OfficeLayout) -> tuple[float, float, float, float]:
    """x0, y0, x1, y1 of the flight (its slab openings) in the last north bay."""
    x_left, _ = layout.bays_x_m[-1]
    _, c1 = layout.corridor_y_m
    x0 = x_left + INTERIOR_WALL_M / 2 + 0.3
    y0 = c1 + INTERIOR_WALL_M + STAIR_LANDING_M
    return x0, y0, x0 + STAIR_WIDTH_M, y0 + _flight_run_m(layout)


def _storey(b: _Builder, layout: OfficeLayout, storey: Entity, k: int,
            stair: tuple[float, float, float, float]) -> None:
    width, depth, height = layout.width_m, layout.depth_m, layout.storey_height_m
    z = k * height
    wall_h = height - SLAB_THICKNESS_M
    t_ext, t_int = EXTERIOR_WALL_M, INTERIOR_WALL_M
    c0, c1 = layout.corridor_y_m
    tag = f"L{k}"
    slab = b.box("IfcSlab", f"{tag} floor", (0.0, 0.0, z - SLAB_THICKNESS_M),
                 (width, depth, SLAB_THICKNESS_M), storey, "FLOOR")
    sx0, sy0, sx1, sy1 = stair
    if k > 0:  # the flight from the storey below comes up through this slab
        b.void(slab, (sx0, sy0, z - SLAB_THICKNESS_M - 0.1),
               (sx1 - sx0, sy1 - sy0, SLAB_THICKNESS_M + 0.2))
    if layout.ceilings:
        ceiling = b.box("IfcCovering", f"{tag} ceiling", (t_ext, t_ext, z + CEILING_HEIGHT_M),
                        (width - 2 * t_ext, depth - 2 * t_ext, CEILING_THICKNESS_M), storey,
                        "CEILING")
        if k < layout.storeys - 1:
            b.void(ceiling, (sx0, sy0, z + CEILING_HEIGHT_M - 0.1),
                   (sx1 - sx0, sy1 - sy0, CEILING_THICKNESS_M + 0.2))

    # exterior walls: south and north run along x, west and east along y between them
    south = b.box("IfcWall", f"{tag} south facade", (0.0, 0.0, z), (width, t_ext, wall_h), storey)
    north = b.box("IfcWall", f"{tag} north facade", (0.0, depth - t_ext, z), (width, t_ext, wall_h),
                  storey)
    west = b.box("IfcWall", f"{tag} west facade", (0.0, t_ext, z), (t_ext, depth - 2 * t_ext,
                                                                    wall_h), storey)
    b.box("IfcWall", f"{tag} east facade", (width - t_ext, t_ext, z), (t_ext, depth - 2 * t_ext,
                                                                   wall_h), storey)
    if k == 0:
        b.door(west, storey, "Entrance", 0.0, (c0 + c1) / 2 - DOOR_WIDTH_M / 2, z, t_ext,
               along_y=True)

    # corridor walls (inner faces at c0 and c1), one door per room
    corridor_s = b.box("IfcWall", f"{tag} corridor wall south", (t_ext, c0 - t_int, z),
                       (width - 2 * t_ext, t_int, wall_h), storey)
    corridor_n = b.box("IfcWall", f"{tag} corridor wall north", (t_ext, c1, z),
                       (width - 2 * t_ext, t_int, wall_h), storey)
    b.space(storey, f"{tag}-C", f"Corridor {tag}", t_ext, c0, width - t_ext, c1, z, wall_h)

    bays = layout.bays_x_m
    for i, (xa, xb) in enumerate(bays):
        x0 = max(xa + t_int / 2, t_ext)  # inner faces of the room
        x1 = min(xb - t_int / 2, width - t_ext)
        if i > 0:  # partitions at the bay boundaries, both sides of the corridor
            b.box("IfcWall", f"{tag} partition S{i}", (xa - t_int / 2, t_ext, z),
                  (t_int, c0 - t_int - t_ext, wall_h), storey)
            b.box("IfcWall", f"{tag} partition N{i}", (xa - t_int / 2, c1 + t_int, z),
                  (t_int, depth - t_ext - c1 - t_int, wall_h), storey)
        for side, y0, y1, wall in (("S", t_ext, c0 - t_int, corridor_s),
                                   ("N", c1 + t_int, depth - t_ext, corridor_n)):
            name = f"{tag}-{side}{i:02d}"
            is_stair = side == "N" and i == len(bays) - 1
            door_x = x1 - DOOR_WIDTH_M - 0.3 if is_stair else x0 + 0.3
            b.door(wall, storey, f"Door {name}", door_x, c0 - t_int if side == "S" else c1,
                   z, t_int)
            if is_stair:
                b.space(storey, name, f"Stair core {tag}", x0, y0, x1, y1, z, wall_h)
                if k < layout.storeys - 1:
                    _flight(b, layout, storey, name, stair, z)
                continue
            b.space(storey, name, f"Office {name}", x0, y0, x1, y1, z, wall_h)
            _office_furniture(b, layout, storey, name, x0, y0, x1, y1, z, side)
        if layout.windows:
            for wall, y in ((south, 0.0), (north, depth - t_ext)):
                b.window(wall, storey, f"Window {tag}-{i:02d}{'S' if y == 0 else 'N'}",
                         (xa + xb) / 2 - WINDOW_WIDTH_M / 2, y, z + WINDOW_SILL_M, t_ext)


def _office_furniture(b: _Builder, layout: OfficeLayout, storey: Entity, name: str,
                      x0: float, y0: float, x1: float, y1: float, z: float,
                      side: str) -> None:
    """Rows of desk pairs from the facade towards the corridor, a column against the high-x
    partition, a row of cabinets along the low-x partition."""
    dw, dd, dh = DESK_M
    cw, cd, ch = CABINET_M
    aisle_m = 1.2  # free strip along the corridor wall and the door
    row_ys = []
    y = y0 + 0.8 if side == "S" else y1 - 0.8 - dd
    while y0 + 0.5 <= y and y + dd <= y1 - 0.5 and (
            (side == "S" and y + dd <= y1 - aisle_m) or (side == "N" and y >= y0 + aisle_m)):
        row_ys.append(y)
        y += layout.desk_row_pitch_m if side == "S" else -layout.desk_row_pitch_m
    mid = (x0 + x1) / 2
    for r, y in enumerate(row_ys):
        for c, x in enumerate((mid - dw - 0.1, mid + 0.1)):
            b.box(b.furniture_class, f"Desk {name}.{r}.{c}", (x, y, z), (dw, dd, dh), storey)
    # cabinets along the low-x partition, clear of the corridor door strip
    y_start = y0 + 0.8 if side == "S" else y0 + aisle_m + 0.8
    y_end = y1 - aisle_m - 0.8 if side == "S" else y1 - 0.8
    n_cabinets = max(0, int((y_end - y_start) // (cw * 4)))
    for j in range(n_cabinets):
        b.box(b.furniture_class, f"Cabinet {name}.{j}", (x0, y_start + j * cw * 4, z),
              (cd, cw, ch), storey)
    # a column against the high-x partition, halfway into the deep room
    column_y = (y0 + y1) / 2 - COLUMN_M / 2
    b.box("IfcColumn", f"Column {name}", (x1 - COLUMN_M, column_y, z),
          (COLUMN_M, COLUMN_M, layout.storey_height_m - SLAB_THICKNESS_M), storey)


def _flight(b: _Builder, layout: OfficeLayout, storey: Entity, name: str,
            stair: tuple[float, float, float, float], z: float) -> None:
    """A straight flight up +y from this storey's floor to the next, as a stepped solid: the
    sawtooth profile in the (y, z) plane extruded across the flight's width."""
    n = _risers(layout)
    riser = layout.storey_height_m / n
    g = STAIR_GOING_M
    profile: list[tuple[float, float]] = [(0.0, 0.0)]
    for i in range(n):
        profile += [(i * g, (i + 1) * riser), ((i + 1) * g, (i + 1) * riser)]
    run = n * g
    top = n * riser
    profile += [(run, top - STAIR_WAIST_M - riser), (2 * g, 0.0)]
    container = b.create("IfcStair", f"Stair {name}", "STRAIGHT_RUN_STAIR")
    if b.schema == "IFC2X3":  # the shape is a mandatory attribute there
        container.ShapeType = "STRAIGHT_RUN_STAIR"
    ifcopenshell.api.spatial.assign_container(b.f, products=[container],
                                              relating_structure=storey)
    flight = b.create("IfcStairFlight", f"Flight {name}", "STRAIGHT")
    setattr(flight, "NumberOfRiser" if b.schema == "IFC2X3" else "NumberOfRisers", n)
    flight.NumberOfTreads = n - 1
    flight.RiserHeight = riser
    flight.TreadLength = g
    rep = ifcopenshell.api.geometry.add_slab_representation(
        b.f, context=b.body, depth=STAIR_WIDTH_M, polyline=profile)
    ifcopenshell.api.geometry.assign_representation(b.f, product=flight, representation=rep)
    # profile x along world +y, profile y up, extrusion (local z) along world +x
    sx0, sy0, _, _ = stair
    matrix = np.array([[0.0, 0.0, 1.0, sx0], [1.0, 0.0, 0.0, sy0], [0.0, 1.0, 0.0, z],
                       [0.0, 0.0, 0.0, 1.0]])
    ifcopenshell.api.geometry.edit_object_placement(b.f, product=flight, matrix=matrix)
    ifcopenshell.api.aggregate.assign_object(b.f, products=[flight], relating_object=container)


def count_faces(path: Path, max_edge_m: float = 0.2) -> dict[str, Any]:
    """Faces of the model as read by scanplan, and after its remesh at ``max_edge_m``."""
    from planner.io.readers import read_scene

    raw = read_scene(path, max_edge_m=None)
    split = read_scene(path, max_edge_m=max_edge_m, split_faces="all")
    return {"file_faces": raw.n_faces, "remeshed_faces": split.n_faces,
            "elements": len(raw.elements), "spaces": len(raw.metadata["spaces"]),
            "storeys": [s["name"] for s in raw.metadata["storeys"]]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--storeys", type=int, default=3)
    parser.add_argument("--width-m", type=float, default=50.0)
    parser.add_argument("--depth-m", type=float, default=37.0)
    parser.add_argument("--schema", default="IFC4", choices=("IFC2X3", "IFC4"))
    parser.add_argument("--no-windows", action="store_true")
    parser.add_argument("--ceilings", action="store_true",
                        help="add suspended ceilings (about 30 %% more faces)")
    parser.add_argument("--count-faces", action="store_true",
                        help="read the model back with scanplan and print its face counts")
    args = parser.parse_args()
    path = build_ifc_office(args.out, storeys=args.storeys, width_m=args.width_m,
                            depth_m=args.depth_m, schema=args.schema,
                            windows=not args.no_windows, ceilings=args.ceilings)
    print(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB)")
    if args.count_faces:
        for key, value in count_faces(path).items():
            print(f"{key:<16}{value}")


if __name__ == "__main__":
    main()
