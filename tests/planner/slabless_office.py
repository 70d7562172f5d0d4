"""A generated architect's model without its structural slabs, as a BIM platform sends it.

:func:`slabless_office_ifc` writes an IFC4 office in metres: ``floors`` storeys of
``STOREY_M`` on one unit of :mod:`tests.planner.buildings` (a corridor along +x between two
rows of ``rooms_per_side`` rooms, a stair hall at its east end), with the pattern of a
Revit architectural model whose slabs live in the structural model:

- no IfcSlab and no IfcCovering: each storey's IfcSpace bottoms, at the storey's elevation,
  are the only floor there is (the ground storey's too: no ground slab, no terrain);
- every IfcWall stops ``wall_gap_m`` under the next storey (where the missing slab would
  start), the top storey's under the IfcRoof; so under each doorway of an upper storey lies
  the lower wall's top, ``wall_gap_m`` under the room floor, or nothing;
- an IfcDoor leaf, closed, in every doorway (a room's door from the corridor, the corridor's
  to the stair hall, the ground storey's to the outside);
- a stepped IfcStair per storey whose last tread is a riser under the next storey's floor
  (the last riser is the missing slab's edge).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from tests.planner.buildings import (
    CORRIDOR_Y_M,
    FACADE_M,
    FLIGHT_Y_M,
    RISER_M,
    ROOM_X_M,
    ROOM_Y_M,
    STOREY_M,
    TREAD_M,
    WALL_M,
    Box,
    storey_walls,
    units,
)

ROOF_M = 0.3  # the roof's thickness


def _box_mesh(box: Box) -> tuple[list[tuple[float, float, float]], list[tuple[int, ...]]]:
    """The 8 corners and 6 outward quads of an axis-aligned box."""
    (x0, y0, z0), (x1, y1, z1) = box
    corners = [(x0, y0, z0), (x1, y0, z0), (x1, y1, z0), (x0, y1, z0),
               (x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1)]
    quads = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6),
             (3, 0, 4, 7)]
    return corners, quads


def slabless_office_ifc(path: str | Path, floors: int = 2, rooms_per_side: int = 3,
                        wall_gap_m: float = 0.1) -> Path:
    """Write the office (see the module docstring) to ``path``; returns ``path``."""
    import ifcopenshell.api.root
    from ifcopenshell.api import aggregate, geometry, project, spatial, unit

    from tests.planner.ifc_parts import body_and_building, placed

    model = project.create_file(version="IFC4")
    ifc_project = ifcopenshell.api.root.create_entity(model, ifc_class="IfcProject",
                                                      name="slab-less office")
    unit.assign_unit(model, units=[unit.add_si_unit(model, unit_type="LENGTHUNIT"),
                                   unit.add_si_unit(model, unit_type="AREAUNIT")])
    body, building = body_and_building(model, ifc_project)
    unit_a = units(rooms_per_side)[0]
    length = unit_a.length_x_m
    oy = unit_a.origin_y_m
    corridor0, corridor1 = oy + ROOM_Y_M, oy + ROOM_Y_M + CORRIDOR_Y_M
    north = oy + 2 * ROOM_Y_M + CORRIDOR_Y_M
    hall_x = rooms_per_side * ROOM_X_M
    fx0, fx1 = unit_a.stair_x_m
    f, e = FACADE_M, WALL_M / 2

    def solid(ifc_class: str, name: str, boxes: list[Box]) -> Any:
        meshes = [_box_mesh(b) for b in boxes]
        representation = geometry.add_mesh_representation(
            model, body, vertices=[m[0] for m in meshes], faces=[m[1] for m in meshes])
        return placed(model, ifc_class, name, representation, (0.0, 0.0, 0.0))

    def space(storey: Any, name: str, x0: float, x1: float, y0: float, y1: float,
              z0: float) -> None:
        outline = [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
        room = placed(model, "IfcSpace", name, geometry.add_slab_representation(
            model, body, depth=STOREY_M - wall_gap_m, polyline=outline), (0.0, 0.0, z0))
        aggregate.assign_object(model, relating_object=storey, products=[room])

    for k in range(floors):
        z0 = k * STOREY_M
        z1 = (k + 1) * STOREY_M - wall_gap_m
        storey = ifcopenshell.api.root.create_entity(model, ifc_class="IfcBuildingStorey",
                                                     name=f"Level {k}")
        storey.Elevation = z0
        aggregate.assign_object(model, relating_object=building, products=[storey])
        walls = storey_walls(unit_a, rooms_per_side, z0, z1, front_door=k == 0)
        parts = []
        for n, (boxes, leaves) in enumerate(walls):
            parts.append(solid("IfcWall", f"Wall {k}.{n}", boxes))
            parts += [solid("IfcDoor", f"Door {k}.{n}.{d}", [leaf])
                      for d, leaf in enumerate(leaves)]
        if k < floors - 1:  # a flight to the next storey, its last tread a riser under it
            y0 = oy if k % 2 == 0 else oy + FLIGHT_Y_M
            steps = round(STOREY_M / RISER_M) - 1
            treads: list[Box] = []
            for i in range(steps):
                xa = fx0 + i * TREAD_M if k % 2 == 0 else fx1 - (i + 1) * TREAD_M
                treads.append(((xa, y0, z0), (xa + TREAD_M, y0 + FLIGHT_Y_M,
                                              z0 + (i + 1) * RISER_M)))
            parts.append(solid("IfcStair", f"Stair {k}", treads))
        else:
            parts.append(solid("IfcRoof", "Roof", [((-f, oy - f, z1),
                                                    (length + f, north + f, z1 + ROOF_M))]))
        spatial.assign_container(model, relating_structure=storey, products=parts)
        for i in range(rooms_per_side):  # rooms, the corridor, the stair hall
            x0 = i * ROOM_X_M + (e if i else 0.0)
            x1 = (i + 1) * ROOM_X_M - e
            space(storey, f"{k}.S{i + 1}", x0, x1, oy, corridor0 - e, z0)
            space(storey, f"{k}.N{i + 1}", x0, x1, corridor1 + e, north, z0)
        space(storey, f"{k}.Corridor", 0.0, hall_x - e, corridor0 + e, corridor1 - e, z0)
        space(storey, f"{k}.Stair hall", hall_x + e, length, oy, north, z0)
    model.write(str(path))
    return Path(path)
