"""A generated multi-storey office: storeys, corridors, closed doors, stairs, two units.

:func:`office_building` returns a plain triangle mesh (no groups, no IFC classes: what a
BIM tool's OBJ or PLY export without semantics gives) in metres, +Z up, of two office units
side by side with a yard between them:

- each unit: ``floors`` storeys of ``STOREY_M`` (slabs ``SLAB_M`` thick, the ground slab's
  top at z = 0, nothing below it: no terrain), a corridor along +x between two rows of
  ``rooms_per_side`` rooms, and a stair hall at the corridor's east end;
- every room has a door from the corridor, the corridor one to the stair hall and the
  ground storey one to the outside at the corridor's west end; every door is an opening in
  its wall filled by a *closed* leaf (a ``LEAF_M`` thick panel with 5 mm gaps), as a BIM
  model draws it;
- the stairs: a scissor stair (flights alternately along +x and -x in two strips, under a
  hole through every upper slab); unit A's flights are steps of ``RISER_M`` x ``TREAD_M``,
  unit B's flights are sloped solids (wedges) at the same pitch;
- the two units are joined only outside, through their front doors;
- ``furnished``: a desk in every room (a 1.6 x 0.8 m top at 0.76 m on four legs).

Every part is a box (or a wedge); each box side is cut into a grid of squares whose
triangles' edges are at most ``max_edge_m`` long, so the face count is a parameter:
:func:`max_edge_for_faces` gives the ``max_edge_m`` of about a wanted number of faces.
The geometry does not depend on ``max_edge_m``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from numpy.typing import NDArray

from planner.rays import RayCaster, make_ray_caster
from planner.scene import Scene
from planner.walkgraph import DOOR_SILL_MAX_M, door_faces

STOREY_M = 3.2  # floor to floor
SLAB_M = 0.25
WALL_M = 0.2  # interior walls
FACADE_M = 0.3  # exterior walls
ROOM_X_M, ROOM_Y_M, CORRIDOR_Y_M = 4.0, 5.0, 2.0
DOOR_W_M, DOOR_H_M = 0.9, 2.1
LEAF_M = 0.04  # door leaf thickness
LEAF_GAP_M = 0.005  # between the leaf and its opening
RISER_M = 0.2  # 16 risers a storey
TREAD_M = 0.28
FLIGHT_Y_M = 1.2  # width of one flight; the two strips of a scissor stair side by side
LANDING_M = 1.2  # free floor before and after the flights
YARD_M = 6.0  # between the two units
DESK_M = (1.6, 0.8, 0.76)  # top size and height

Box = tuple[tuple[float, float, float], tuple[float, float, float]]


@dataclass(frozen=True)
class Unit:
    """Where one unit lies and what it holds (for tests: rooms, doors, stair footprint)."""

    origin_y_m: float
    length_x_m: float
    stair_x_m: tuple[float, float]  # the flights' x range
    stepped: bool


def unit_length_m(rooms_per_side: int) -> float:
    run = (STOREY_M / RISER_M) * TREAD_M
    return rooms_per_side * ROOM_X_M + 2 * LANDING_M + run


def units(rooms_per_side: int) -> tuple[Unit, Unit]:
    """Unit A (stepped stair) at y in [0, 12], unit B (sloped stair) a yard further north."""
    length = unit_length_m(rooms_per_side)
    x0 = rooms_per_side * ROOM_X_M + LANDING_M
    run = (STOREY_M / RISER_M) * TREAD_M
    depth = 2 * ROOM_Y_M + CORRIDOR_Y_M
    return (Unit(0.0, length, (x0, x0 + run), True),
            Unit(depth + YARD_M, length, (x0, x0 + run), False))


def _wall_x(x0: float, x1: float, y0: float, y1: float, z0: float, z1: float,
            doors: list[float]) -> tuple[list[Box], list[Box]]:
    """A wall along x over [x0, x1] x [y0, y1] x [z0, z1] with door openings centred at the
    x of ``doors``; (wall boxes, leaf boxes)."""
    walls: list[Box] = []
    leaves: list[Box] = []
    x = x0
    mid = (y0 + y1) / 2
    for centre in sorted(doors):
        a, b = centre - DOOR_W_M / 2, centre + DOOR_W_M / 2
        walls.append(((x, y0, z0), (a, y1, z1)))
        walls.append(((a, y0, z0 + DOOR_H_M), (b, y1, z1)))
        leaves.append(((a + LEAF_GAP_M, mid - LEAF_M / 2, z0 + LEAF_GAP_M),
                       (b - LEAF_GAP_M, mid + LEAF_M / 2, z0 + DOOR_H_M - LEAF_GAP_M)))
        x = b
    walls.append(((x, y0, z0), (x1, y1, z1)))
    return walls, leaves


def _wall_y(x0: float, x1: float, y0: float, y1: float, z0: float, z1: float,
            doors: list[float]) -> tuple[list[Box], list[Box]]:
    """:func:`_wall_x` turned: a wall along y, door centres given in y."""
    swap = [((b[0][1], b[0][0], b[0][2]), (b[1][1], b[1][0], b[1][2]))
            for b in _wall_x(y0, y1, x0, x1, z0, z1, doors)[0]]
    leaves = [((b[0][1], b[0][0], b[0][2]), (b[1][1], b[1][0], b[1][2]))
              for b in _wall_x(y0, y1, x0, x1, z0, z1, doors)[1]]
    return swap, leaves


def _slab(x0: float, x1: float, y0: float, y1: float, top: float,
          hole: tuple[float, float, float, float] | None) -> list[Box]:
    """A slab over [x0, x1] x [y0, y1] with its top at ``top``, less the ``hole``
    (hx0, hx1, hy0, hy1) inside it."""
    bottom = top - SLAB_M
    if hole is None:
        return [((x0, y0, bottom), (x1, y1, top))]
    hx0, hx1, hy0, hy1 = hole
    return [((x0, y0, bottom), (hx0, y1, top)), ((hx1, y0, bottom), (x1, y1, top)),
            ((hx0, y0, bottom), (hx1, hy0, top)), ((hx0, hy1, bottom), (hx1, y1, top))]


def _desk(cx: float, cy: float, z0: float) -> list[Box]:
    """A desk centred on (cx, cy) standing on the floor at z0: a top and four legs."""
    w, d, h = DESK_M
    top = ((cx - w / 2, cy - d / 2, z0 + h - 0.04), (cx + w / 2, cy + d / 2, z0 + h))
    legs = [((x, y, z0), (x + 0.05, y + 0.05, z0 + h - 0.04))
            for x in (cx - w / 2, cx + w / 2 - 0.05) for y in (cy - d / 2, cy + d / 2 - 0.05)]
    return [top, *legs]


def storey_walls(unit: Unit, rooms_per_side: int, z0: float, z1: float, front_door: bool
                 ) -> list[tuple[list[Box], list[Box]]]:
    """One storey's walls of ``unit`` from ``z0`` to ``z1``, each as (wall boxes, door
    leaves): the facades (the west one with the front door when ``front_door``), the
    corridor's walls with a door to every room, the walls between rooms and the stair
    hall's west wall with its door from the corridor."""
    oy = unit.origin_y_m
    length = unit.length_x_m
    corridor0, corridor1 = oy + ROOM_Y_M, oy + ROOM_Y_M + CORRIDOR_Y_M
    north = oy + 2 * ROOM_Y_M + CORRIDOR_Y_M
    hall_x = rooms_per_side * ROOM_X_M
    f, e = FACADE_M, WALL_M / 2
    front = [(corridor0 + corridor1) / 2] if front_door else []
    parts = [
        _wall_x(-f, length + f, oy - f, oy, z0, z1, []),  # facades
        _wall_x(-f, length + f, north, north + f, z0, z1, []),
        _wall_y(-f, 0.0, oy, north, z0, z1, front),
        _wall_y(length, length + f, oy, north, z0, z1, []),
    ]
    room_doors = [i * ROOM_X_M + ROOM_X_M / 2 for i in range(rooms_per_side)]
    parts.append(_wall_x(0.0, hall_x - e, corridor0 - e, corridor0 + e, z0, z1, room_doors))
    parts.append(_wall_x(0.0, hall_x - e, corridor1 - e, corridor1 + e, z0, z1, room_doors))
    for i in range(1, rooms_per_side):  # between rooms
        x = i * ROOM_X_M
        parts.append(_wall_y(x - e, x + e, oy, corridor0 - e, z0, z1, []))
        parts.append(_wall_y(x - e, x + e, corridor1 + e, north, z0, z1, []))
    # the stair hall's west wall, a door from the corridor
    parts.append(_wall_y(hall_x - e, hall_x + e, oy, north, z0, z1,
                         [(corridor0 + corridor1) / 2]))
    return parts


def _unit_parts(unit: Unit, floors: int, rooms_per_side: int, furnished: bool
                ) -> tuple[list[Box], list[Box], list[NDArray[np.float64]]]:
    """(boxes, door leaves, wedges as (6, 3) corner arrays) of one unit."""
    oy = unit.origin_y_m
    length = unit.length_x_m
    north = oy + 2 * ROOM_Y_M + CORRIDOR_Y_M
    fx0, fx1 = unit.stair_x_m
    hole = (fx0, fx1, oy, oy + 2 * FLIGHT_Y_M)
    boxes: list[Box] = []
    leaves: list[Box] = []
    wedges: list[NDArray[np.float64]] = []
    f = FACADE_M
    for k in range(floors + 1):  # slabs: ground, upper floors, roof
        boxes += _slab(-f, length + f, oy - f, north + f, k * STOREY_M,
                       hole if 0 < k < floors else None)
    for k in range(floors):
        z0, z1 = k * STOREY_M, (k + 1) * STOREY_M - SLAB_M
        parts = storey_walls(unit, rooms_per_side, z0, z1, front_door=k == 0)
        for walls, doors in parts:
            boxes += walls
            leaves += doors
        if furnished:
            for i in range(rooms_per_side):
                cx = i * ROOM_X_M + ROOM_X_M / 2
                boxes += _desk(cx, oy + ROOM_Y_M / 2, z0)
                boxes += _desk(cx, north - ROOM_Y_M / 2, z0)
        if k == floors - 1:
            continue
        # the flight from storey k to k + 1: along +x in the south strip on even storeys,
        # along -x in the north strip on odd ones
        y0 = oy if k % 2 == 0 else oy + FLIGHT_Y_M
        y1 = y0 + FLIGHT_Y_M
        steps = round(STOREY_M / RISER_M)
        if unit.stepped:
            for i in range(steps):
                xa = fx0 + i * TREAD_M if k % 2 == 0 else fx1 - (i + 1) * TREAD_M
                boxes.append(((xa, y0, z0), (xa + TREAD_M, y1, z0 + (i + 1) * RISER_M)))
        else:
            low, high = (fx0, fx1) if k % 2 == 0 else (fx1, fx0)
            wedges.append(np.array([[low, y0, z0], [high, y0, z0], [high, y0, z0 + STOREY_M],
                                    [low, y1, z0], [high, y1, z0], [high, y1, z0 + STOREY_M]]))
    return boxes, leaves, wedges


def _grid_rectangle(corner: NDArray[np.float64], u: NDArray[np.float64],
                    v: NDArray[np.float64], cell_m: float | None
                    ) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """The rectangle corner + [0, 1] u + [0, 1] v as a grid of squares no wider than
    ``cell_m`` (two triangles each, normal along u x v)."""
    nu = 1 if cell_m is None else max(1, math.ceil(np.linalg.norm(u) / cell_m))
    nv = 1 if cell_m is None else max(1, math.ceil(np.linalg.norm(v) / cell_m))
    s, t = np.meshgrid(np.linspace(0, 1, nu + 1), np.linspace(0, 1, nv + 1), indexing="ij")
    vertices = corner + s.reshape(-1, 1) * u + t.reshape(-1, 1) * v
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    a = (i * (nv + 1) + j).ravel()
    b, c, d = a + nv + 1, a + nv + 2, a + 1
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return vertices, faces


def _triangle(points: NDArray[np.float64], cell_m: float | None
              ) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """A triangle cut into n x n similar triangles with edges no longer than ``cell_m``."""
    p0, p1, p2 = points
    longest = max(np.linalg.norm(p1 - p0), np.linalg.norm(p2 - p1), np.linalg.norm(p0 - p2))
    n = 1 if cell_m is None else max(1, math.ceil(longest / cell_m))
    index: dict[tuple[int, int], int] = {}
    vertices: list[NDArray[np.float64]] = []
    for i in range(n + 1):
        for j in range(n + 1 - i):
            index[i, j] = len(vertices)
            vertices.append(p0 + (p1 - p0) * i / n + (p2 - p0) * j / n)
    faces: list[list[int]] = []
    for i in range(n):
        for j in range(n - i):
            faces.append([index[i, j], index[i + 1, j], index[i, j + 1]])
            if i + j < n - 1:
                faces.append([index[i + 1, j], index[i + 1, j + 1], index[i, j + 1]])
    return np.array(vertices), np.array(faces, np.int64)


def _box_sides(box: Box) -> list[tuple[NDArray[np.float64], NDArray[np.float64],
                                       NDArray[np.float64]]]:
    """The six sides of a box as (corner, u, v), u x v pointing out."""
    lo, hi = np.array(box[0], float), np.array(box[1], float)
    dx, dy, dz = np.diag(hi - lo)
    return [(lo, dy, dx), (lo + dz, dx, dy),  # bottom, top
            (lo, dx, dz), (lo + dy, dz, dx),  # south, north
            (lo, dz, dy), (lo + dx, dy, dz)]  # west, east


def _wedge_sides(w: NDArray[np.float64]
                 ) -> tuple[list[tuple[NDArray[np.float64], NDArray[np.float64],
                                       NDArray[np.float64]]], list[NDArray[np.float64]]]:
    """A wedge (prism over the triangle w[0..2], extruded to w[3..5]): its three
    rectangles and two triangles, outward."""
    a, b, c, a2, b2, c2 = w
    rectangles = [(a, a2 - a, b - a), (b, b2 - b, c - b), (c, c2 - c, a - c)]
    triangles = [np.array([a, c, b]), np.array([a2, b2, c2])]
    # orient outward: away from the wedge's centre
    centre = w.mean(axis=0)
    fixed = []
    for corner, u, v in rectangles:
        n = np.cross(u, v)
        mid = corner + (u + v) / 2
        fixed.append((corner, u, v) if n @ (mid - centre) > 0 else (corner, v, u))
    tris = []
    for t in triangles:
        n = np.cross(t[1] - t[0], t[2] - t[0])
        tris.append(t if n @ (t.mean(axis=0) - centre) > 0 else t[[0, 2, 1]])
    return fixed, tris


def office_parts(floors: int = 3, rooms_per_side: int = 4, furnished: bool = True
                 ) -> tuple[list[Box], list[Box], list[NDArray[np.float64]]]:
    """Boxes, door leaves and wedges of the whole building (both units)."""
    boxes: list[Box] = []
    leaves: list[Box] = []
    wedges: list[NDArray[np.float64]] = []
    for unit in units(rooms_per_side):
        b, d, w = _unit_parts(unit, floors, rooms_per_side, furnished)
        boxes += b
        leaves += d
        wedges += w
    return boxes, leaves, wedges


def office_building(floors: int = 3, rooms_per_side: int = 4,
                    max_edge_m: float | None = None, furnished: bool = True
                    ) -> trimesh.Trimesh:
    """The office (see the module docstring) as one plain mesh.

    Parameters
    ----------
    floors : storeys per unit (>= 1)
    rooms_per_side : rooms on each side of a corridor (>= 1); a unit is
        ``unit_length_m(rooms_per_side)`` long and 12 m deep
    max_edge_m : no triangle edge is longer; None: two triangles a box side (the
        coarsest mesh)
    furnished : a desk in every room
    """
    if floors < 1 or rooms_per_side < 1:
        raise ValueError("floors and rooms_per_side must be at least 1")
    boxes, leaves, wedges = office_parts(floors, rooms_per_side, furnished)
    cell_m = None if max_edge_m is None else max_edge_m / math.sqrt(2.0)
    vertices: list[NDArray[np.float64]] = []
    faces: list[NDArray[np.int64]] = []
    count = 0

    def add(v: NDArray[np.float64], f: NDArray[np.int64]) -> None:
        nonlocal count
        vertices.append(v)
        faces.append(f + count)
        count += len(v)

    for box in boxes + leaves:
        for corner, u, v in _box_sides(box):
            add(*_grid_rectangle(corner, u, v, cell_m))
    for wedge in wedges:
        rectangles, triangles = _wedge_sides(wedge)
        for corner, u, v in rectangles:
            add(*_grid_rectangle(corner, u, v, cell_m))
        for t in triangles:
            add(*_triangle(t, max_edge_m))
    return trimesh.Trimesh(np.concatenate(vertices), np.concatenate(faces), process=False)


def office_area_m2(floors: int = 3, rooms_per_side: int = 4, furnished: bool = True
                   ) -> float:
    """Total surface area of the office's parts (what :func:`max_edge_for_faces` divides)."""
    return float(office_building(floors, rooms_per_side, furnished=furnished).area)


def max_edge_for_faces(faces: int, floors: int = 3, rooms_per_side: int = 4,
                       furnished: bool = True) -> float:
    """``max_edge_m`` that gives :func:`office_building` about ``faces`` faces: a square
    of side max_edge_m / sqrt(2) holds two triangles, so faces ~ 4 area / max_edge_m^2."""
    return math.sqrt(4.0 * office_area_m2(floors, rooms_per_side, furnished) / faces)


def export_plain_mesh(ifc_path: str | Path, out_path: str | Path,
                      scene: Scene | None = None) -> Path:
    """Write the IFC model's triangles to ``out_path`` (.obj or .ply) as a plain mesh: no
    IFC classes, no groups, no elements (what a BIM tool's mesh export without semantics
    gives). The geometry is IfcOpenShell's, as :func:`planner.io.ifc.read_ifc` reads it
    (``scene``: that reading, when already made)."""
    from planner.io.ifc import read_ifc

    if scene is None:
        scene = read_ifc(ifc_path)
    mesh = trimesh.Trimesh(np.asarray(scene.vertices), np.asarray(scene.faces), process=False)
    out_path = Path(out_path)
    if out_path.suffix == ".obj":  # vertices and faces only: no o/g lines, no normals
        lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in mesh.vertices.tolist()]
        lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in mesh.faces.tolist()]
        out_path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    else:
        mesh.export(out_path)
    return out_path


# scoring a plain mesh's door rule against the IFC model's doors -----------------------------

TOUCH_M = 0.05  # found faces this close belong to one found door
DOOR_FOUND_SHARE = 0.25  # an IfcDoor is found when this share of its area is: its leaf
TRUE_DOOR_SHARE = 0.5  # a found door is true when this share of its area is an IfcDoor's
# a window whose frame stands no higher than this over the floor beside it is a window to
# the floor (a French window, a sidelight): one step, as a door's sill
WINDOW_SILL_MAX_M = DOOR_SILL_MAX_M
WINDOW_FLOOR_PROBE_M = 0.5  # the floor is looked for this far to each side of the glass
_CELL_M = 0.5  # the grid that pairs nearby faces


@dataclass(frozen=True)
class DoorScore:
    """Doors found in a plain export against the IFC model's own (see :func:`door_score`)."""

    ifc_doors: int  # IfcDoor elements with faces
    found: int  # found doors: groups of touching found faces
    true: int  # found doors mostly on IfcDoor faces
    ifc_doors_found: int  # IfcDoor elements with DOOR_FOUND_SHARE of their area found
    # found doors not true, mostly on IfcDoor and IfcWindow faces, with an IfcWindow that
    # comes down to the floor (its frame at most WINDOW_SILL_MAX_M over the floor beside it)
    windows_to_floor: int = 0
    # the middle of each false door's box (model metres), to look it up in the model
    false_at: tuple[tuple[float, float, float], ...] = ()

    @property
    def false(self) -> int:
        """Found doors that are neither an IfcDoor nor a window to the floor."""
        return self.found - self.true - self.windows_to_floor

    @property
    def missed(self) -> int:
        return self.ifc_doors - self.ifc_doors_found


def touching_groups(triangles: NDArray[np.float64]) -> NDArray[np.int64]:
    """(T,) group of each of the (T, 3, 3) triangles: triangles whose boxes, grown by
    ``TOUCH_M``, overlap are joined (transitively)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = len(triangles)
    if n == 0:
        return np.zeros(0, np.int64)
    lo = triangles.min(axis=1) - TOUCH_M
    hi = triangles.max(axis=1) + TOUCH_M
    first = np.floor(lo / _CELL_M).astype(np.int64)
    last = np.floor(hi / _CELL_M).astype(np.int64)
    cells: dict[tuple[int, int, int], list[int]] = {}
    for i in range(n):
        for cx in range(first[i, 0], last[i, 0] + 1):
            for cy in range(first[i, 1], last[i, 1] + 1):
                for cz in range(first[i, 2], last[i, 2] + 1):
                    cells.setdefault((cx, cy, cz), []).append(i)
    rows: list[NDArray[np.int64]] = []
    cols: list[NDArray[np.int64]] = []
    for members in cells.values():
        m = np.asarray(members)
        if len(m) < 2:
            continue
        a, b = np.triu_indices(len(m), 1)
        a, b = m[a], m[b]
        overlap = ((lo[a] <= hi[b]) & (lo[b] <= hi[a])).all(axis=1)
        rows.append(a[overlap])
        cols.append(b[overlap])
    r = np.concatenate(rows) if rows else np.zeros(0, np.int64)
    c = np.concatenate(cols) if cols else np.zeros(0, np.int64)
    graph = coo_matrix((np.ones(len(r), np.int8), (r, c)), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    result: NDArray[np.int64] = labels.astype(np.int64)
    return result


def door_score(ifc: Scene, found: NDArray[np.bool_]) -> DoorScore:
    """Score ``found`` (F,) bool, the door faces a rule found in the plain export of the
    IFC reading ``ifc`` (same faces, same order), against its IfcDoor faces."""
    truth = door_faces(ifc)
    element = np.asarray(ifc.face_element)
    triangles = ifc.triangles
    area = ifc.areas
    index = np.flatnonzero(found)
    groups = touching_groups(triangles[index])
    n_groups = int(groups.max()) + 1 if len(groups) else 0
    on_door = np.bincount(groups, area[index] * truth[index], n_groups)
    total = np.bincount(groups, area[index], n_groups)
    window = np.array([e.ifc_class == "IfcWindow" for e in ifc.elements] + [False])[element]
    on_window = np.bincount(groups, area[index] * window[index], n_groups)
    true = on_door >= TRUE_DOOR_SHARE * total
    glazed = ~true & (on_door + on_window >= TRUE_DOOR_SHARE * total) & (on_window > 0)
    to_floor = np.zeros(n_groups, bool)
    if glazed.any():  # one caster for every glazed door's window
        caster = make_ray_caster(ifc, np.ones(ifc.n_faces, bool))
        for g in np.flatnonzero(glazed):
            to_floor[g] = (_window_sill_m(ifc, index[(groups == g) & window[index]], caster)
                           <= WINDOW_SILL_MAX_M)
    false_at = []
    for g in np.flatnonzero(~true & ~to_floor):
        corners = triangles[index[groups == g]].reshape(-1, 3)
        middle = (corners.min(axis=0) + corners.max(axis=0)) / 2
        false_at.append((round(float(middle[0]), 2), round(float(middle[1]), 2),
                         round(float(middle[2]), 2)))
    doors = np.unique(element[truth])
    size = int(element.max()) + 1
    door_area = np.bincount(element[truth], area[truth], size)
    found_area = np.bincount(element[truth & found], area[truth & found], size)
    return DoorScore(
        ifc_doors=len(doors), found=n_groups, true=int(true.sum()),
        ifc_doors_found=int((found_area[doors] >= DOOR_FOUND_SHARE * door_area[doors]).sum()),
        windows_to_floor=int(to_floor.sum()), false_at=tuple(false_at))


def plain_mesh_doorways(ifc: Scene) -> NDArray[np.bool_]:
    """(F,) bool over ``ifc``'s faces: what a leg of a plain export's route may pass, by the
    IFC model's own classes (the ground truth of :func:`planner.truth.legs.
    legs_through_walls` for a plain mesh): its IfcDoor faces, and the faces of every
    IfcWindow that comes down to the floor (its lowest face at most ``WINDOW_SILL_MAX_M``
    over the floor beside it: a French window). A plain mesh cannot tell a French window
    from a glazed door (both a thin glazed filler from the floor to a lintel), so its door
    rule opens both (:func:`planner.walkgraph.mesh_doors`); a window with a parapet, a wall,
    a stair or anything else stays a wall here. An IFC model tells them apart: its own plan
    opens IfcDoor only."""
    passable = door_faces(ifc).copy()
    element = np.asarray(ifc.face_element)
    windows = [k for k, e in enumerate(ifc.elements) if e.ifc_class == "IfcWindow"]
    if not windows:
        return passable
    caster = make_ray_caster(ifc, np.ones(ifc.n_faces, bool))
    for k in windows:
        faces = np.flatnonzero(element == k)
        if len(faces) and _window_sill_m(ifc, faces, caster) <= WINDOW_SILL_MAX_M:
            passable[faces] = True
    return passable


def _window_sill_m(ifc: Scene, faces: NDArray[np.int64], caster: RayCaster) -> float:
    """How high the lowest of a window's ``faces`` (indices into ``ifc``'s faces) stands
    over the higher of the floors ``WINDOW_FLOOR_PROBE_M`` to each side of its largest face
    (its glass), found by rays down from just over that lowest point with ``caster`` (over
    every face of ``ifc``); inf: no floor."""
    triangles = ifc.triangles[faces]
    bottom = float(triangles[:, :, 2].min())
    glass = faces[np.argmax(ifc.areas[faces])]
    across = np.array([*ifc.normals[glass][:2], 0.0])
    across /= max(float(np.linalg.norm(across)), 1e-9)
    centre = triangles.reshape(-1, 3).mean(axis=0)
    starts = np.array([centre + side * WINDOW_FLOOR_PROBE_M * across for side in (-1, 1)])
    starts[:, 2] = bottom + 0.05
    _, distance = caster.first_hit(starts, np.tile([0.0, 0.0, -1.0], (2, 1)))
    if not np.isfinite(distance).any():
        return float("inf")
    return bottom - float((starts[:, 2] - distance).max())
