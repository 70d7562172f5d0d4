"""Rooms are floors: where an IFC model has IfcSpace but no slab under it, the walk graph
walks on the bottom of the space.

A BIM platform often sends one discipline: the architectural model, whose floor slabs live
in the structural model. Its rooms (``metadata["spaces"]``, :mod:`planner.io.ifc`) still
say where the floors are: the bottom of each space. The rule, per room and then per
sample of its floor (``WALK_GRID_M`` apart, inside its floor polygon):

1. *The room has no slab*, as for the room candidates
   (:func:`planner.candidates.rooms.slab_less`): a ray straight down from ``FLOOR_PROBE_M``
   above the room's floor meets a surface within ``FLOOR_TOLERANCE_M`` of it at none of
   the samples that can tell, or at fewer than half of them on a storey where that holds
   over all its rooms (a model with its slabs meets one nearly everywhere; a stair's top
   tread under a few samples is no slab; a sample with furniture on the floor cannot
   tell; a stair hall's large hole on a storey with slabs stays a hole).
2. *Its samples become floor* where the model has none: no surface within
   ``FLOOR_TOLERANCE_M`` of the floor (the model's own floor, where it has one, is walked
   as it is; the top of a wall or of other structure, ``STRUCTURE_CLASSES``, is not a
   floor: the lower storey's walls stop where the missing slab would start, a hand's
   breadth under the room's floor, and their tops are laid over), none below it closer
   than ``HEADROOM_M`` (a void under the room's outline; a wall's top excepted)
   and no stair closer than ``STAIR_HEADROOM_M`` under it (``STAIRWELL_CLASSES`` met first
   straight down, at the sample or at a corner of its square): a room's outline often
   spans the stairwell that the missing slab leaves open, and a floor there would cut the
   flight's head room (further down, under a landing, a lower flight keeps its floor).

The samples reach ``DOORWAY_M`` beyond the room's outline, so that the floor runs
through the doorways and openings of its walls (inside a wall the ray meets the wall's
own foot at the floor, and no floor is added there).

Each sample becomes a horizontal square of the walk grid's size at the room's floor
height, seen only by the walk's rays (:class:`FloorsCaster`): the coverage, the
candidates and the model's faces are unchanged. Rooms are joined through their doors
(door faces are open to the walk) and storeys through the stairs' own geometry.

Array letters: S samples.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray
from shapely import Polygon, intersects_xy

from planner.candidates.rooms import FLOOR_TOLERANCE_M, slab_less
from planner.rays import RayCaster, make_ray_caster
from planner.scene import Scene, build_scene
from planner.walkgraph import HEADROOM_M, WALK_GRID_M

FLOOR_PROBE_M = 0.5  # the floor is looked for from this high above the room's floor
# the floor reaches this far beyond the room's outline: through the wall's doorways and
# openings (a wall's own foot is a surface at the floor, where no floor is added)
DOORWAY_M = 0.5
_EPS_M = 1e-3
# what lies under a stairwell: a room's floor is not laid over these (an architectural model
# draws the room over its stair's opening; the opening was the slab's, which it lacks)
# structure whose top is not a floor: a wall's top, a column's, a beam's (a room's floor is
# laid over them where the model has no slab)
STRUCTURE_CLASSES = ("IfcWall", "IfcWallStandardCase", "IfcCurtainWall", "IfcColumn",
                     "IfcBeam", "IfcMember")
# the head room over a stair's pitch line: 2 m over the whole flight and its landings,
# measured vertically from the pitch line (Approved Document K, 2013 edition, "Headroom for
# stairs"; NHBC Standards 2020, 6.6.7, https://nhbc-standards.co.uk/2020/6-superstructure-
# excluding-roofs/6-6-staircases/6-6-7-design-of-steps/), more than a floor's HEADROOM_M
STAIR_HEADROOM_M = 2.0
STAIRWELL_CLASSES = ("IfcStair", "IfcStairFlight", "IfcRamp", "IfcRampFlight", "IfcRailing")


class FloorsCaster:
    """A walk caster that also hits the rooms' floors: the faces of ``scene`` (ids as the
    ``base`` caster gives them) and the floor squares, ids from ``first_floor_id`` on."""

    def __init__(self, base: RayCaster, floors: RayCaster, first_floor_id: int) -> None:
        self.base = base
        self.floors = floors
        self.first_floor_id = first_floor_id

    def first_hit(self, origins: NDArray[np.floating[Any]],
                  directions: NDArray[np.floating[Any]]
                  ) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        face, distance = self.base.first_hit(origins, directions)
        floor_face, floor_distance = self.floors.first_hit(origins, directions)
        closer = floor_distance < distance
        face = np.where(closer, floor_face + self.first_floor_id, face)
        return face, np.minimum(distance, floor_distance)


def room_floor_samples(scene: Scene, caster: RayCaster) -> tuple[NDArray[np.float64],
                                                                  list[str]]:
    """(S, 3) floor samples of the rooms without a slab (see the module docstring) and
    those rooms' names, in model order."""
    spaces = scene.metadata.get("spaces") or []
    # (F + 1,) the faces of each, the last entry (read for a ray that hits nothing) false
    stairs = np.append(scene.faces_of_classes(STAIRWELL_CLASSES), False)
    structure = np.append(scene.faces_of_classes(STRUCTURE_CLASSES), False)
    candidates: list[tuple[str, NDArray[np.float64]]] = []
    counts: dict[str, tuple[str, int, int]] = {}
    down = np.array([0.0, 0.0, -1.0])
    for space in spaces:
        polygon = Polygon(space["polygon"], space.get("holes") or None)
        if not polygon.is_valid or polygon.area <= 0:
            continue
        # the room and a ring around it as wide as a wall: its doorways and openings
        around = polygon.buffer(DOORWAY_M, join_style="mitre")
        x0, y0, x1, y1 = around.bounds
        xs = np.arange(x0 + WALK_GRID_M / 2, x1, WALK_GRID_M)
        ys = np.arange(y0 + WALK_GRID_M / 2, y1, WALK_GRID_M)
        gx, gy = np.meshgrid(xs, ys)
        xy = np.column_stack([gx.ravel(), gy.ravel()])
        if len(xy) == 0:
            continue
        xy = xy[intersects_xy(around, xy[:, 0], xy[:, 1])]
        if len(xy) == 0:
            continue
        floor_z = float(space["floor_z_m"])
        origins = np.column_stack([xy, np.full(len(xy), floor_z + FLOOR_PROBE_M)])
        face, distance = caster.first_hit(origins, np.tile(down, (len(xy), 1)))
        below_m = distance - FLOOR_PROBE_M  # how far under the room's floor the hit is
        # the top of a wall under the floor (an up-facing face of structure met from
        # above); a ray from inside a wall meets its foot from within, facing down
        wall_top = structure[face] & (below_m > _EPS_M)
        wall_top[wall_top] = scene.normals_of(face[wall_top])[:, 2] > 0
        has_floor = (np.abs(below_m) <= FLOOR_TOLERANCE_M) & ~wall_top
        # a hit above the floor (furniture) cannot tell
        lacks = (below_m > FLOOR_TOLERANCE_M) | wall_top
        own = intersects_xy(polygon, xy[:, 0], xy[:, 1])  # the room's own floor decides
        gid = str(space["global_id"])
        counts[gid] = (str(space["storey"]), int(has_floor[own].sum()), int(lacks[own].sum()))
        # no floor of the model here, nor a stair or anything else within head room below
        # (and nothing standing on the floor: a hit above it is furniture or a wall's foot)
        free = ~has_floor & ((below_m > HEADROOM_M) | wall_top)
        # not over a stair: straight down (the ray above) nor at a corner of the square
        free &= ~(stairs[face] & (below_m > _EPS_M) & (below_m < STAIR_HEADROOM_M))
        free[free] = ~_over_stairs(caster, stairs, origins[free])
        if free.any():
            candidates.append((gid, np.column_stack([xy[free],
                                                     np.full(int(free.sum()), floor_z)])))
    bare = slab_less(counts)  # the rooms whose slab the model does not have
    name = {str(s["global_id"]): str(s["long_name"] or s["name"] or s["global_id"])
            for s in spaces}
    points = [samples for gid, samples in candidates if gid in bare]
    if not points:
        return np.zeros((0, 3)), []
    return np.concatenate(points), [name[gid] for gid, _ in candidates if gid in bare]


def _over_stairs(caster: RayCaster, stairs: NDArray[np.bool_],
                 origins: NDArray[np.float64]) -> NDArray[np.bool_]:
    """(S,) bool: a stair is the first thing straight down from a corner of the square of
    each of the (S, 3) ``origins`` (``FLOOR_PROBE_M`` over the floor; the corners inset by
    a centimetre), under the floor closer than ``STAIR_HEADROOM_M``."""
    over = np.zeros(len(origins), bool)
    if not stairs.any() or len(origins) == 0:
        return over
    reach = WALK_GRID_M / 2 - 0.01
    down = np.tile([0.0, 0.0, -1.0], (len(origins), 1))
    for dx, dy in ((-reach, -reach), (reach, -reach), (reach, reach), (-reach, reach)):
        face, distance = caster.first_hit(origins + np.array([dx, dy, 0.0]), down)
        # a miss (-1) reads the last entry: false
        # under the floor: a stair that stands on it (its first treads) is no stairwell
        below_m = distance - FLOOR_PROBE_M
        over |= stairs[face] & (below_m > _EPS_M) & (below_m < STAIR_HEADROOM_M)
    return over


def with_room_floors(scene: Scene, caster: RayCaster) -> tuple[RayCaster, list[str]]:
    """The walk ``caster`` with the floors of the rooms that have no slab, and the rooms'
    names; ``caster`` itself when every room has its slab (or the model has no rooms)."""
    samples, rooms = room_floor_samples(scene, caster)
    if len(samples) == 0:
        return caster, []
    half = WALK_GRID_M / 2
    corners = np.array([[-half, -half, 0.0], [half, -half, 0.0], [half, half, 0.0],
                        [-half, half, 0.0]])
    vertices = (samples[:, None, :] + corners[None]).reshape(-1, 3)
    first = 4 * np.arange(len(samples))[:, None]
    faces = np.concatenate([first + np.array([0, 1, 2]),
                            first + np.array([0, 2, 3])]).astype(np.int64)
    floors = build_scene(vertices, faces)
    floors_caster = make_ray_caster(floors, np.ones(floors.n_faces, bool))
    return FloorsCaster(caster, floors_caster, scene.n_faces), rooms
