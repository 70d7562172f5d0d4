"""The walking route: the order to visit the stations, and the path of every leg.

Each station is attached to the walk graph (:mod:`planner.walkgraph`) at the nearest floor
sample below it whose knee-height segment to the station's foot is free; shortest paths on
the graph come from ``scipy.sparse.csgraph.dijkstra``. The visiting order is a shortest
open tour (a path, no return) over those distances: exact (Held-Karp) up to
``EXACT_MAX_POINTS`` points, above that OR-Tools' routing solver
(cheapest-arc start, then local search to a local optimum):
from ``route_start`` when given (snapped to the graph like a station), else from whichever
station gives the shortest tour (a dummy depot at distance 0 from every station). Neither
step has a time limit, so the same input gives the same route.

Stations not attached to the graph are *unreachable*: they are reported by id, each with
the reason, and never joined by a straight line. A model whose parts the walk does not join
(a storey no stair reaches, rooms behind a door the model closes) is still walked: the part
of the start (or, with no start, of the most stations) first, then, part after part, the
one with the station nearest to where the last ended, from that station, each part its own
shortest tour (:class:`RoutePart`). Between two parts the route says where the crew must go
on by a way the model lacks (:class:`PartStep`), with the reason the first station of the
next part would be cut off. The reasons, for a station or a part, name what is missing,
found from the graph and the model (with the storeys, rooms and doors of :class:`Places`
where the model has them):

- *not on a floor*: nothing under it; a floor with less than ``HEADROOM_M`` over it (under
  a stair, a low roof: the head room measured); a floor within reach whose knee-high way
  to the station is blocked (it stands walled in); or a surface that is no floor (steeper
  than a walk, or a stair's stringer);
- *its part of the building is cut off* (checked where the part and the route's part come
  within ``_MEET_M`` of each other): at the same height, by a barrier at knee height at a
  named place (the door there, when the model names one whose opening the way across
  crosses with the barrier in it (:meth:`Places.crossed`), that the model closes; a door
  there whose sill the model sets higher than a step above the floors on both sides, its
  height over each given: the floors meet, no step is missing, the door stands at another
  level's height; in a plain mesh, an opening of door height over the wall set so
  (:func:`planner.walkgraph.raised_openings`); else a wall without a doorway or a door
  drawn as a wall); at another height, by a step higher than ``STEP_M`` with no stair
  modelled (the drop measured, where the higher floor's knee-high line over to the lower
  is free: the drop alone parts them); both where both are found; and where the two
  parts never meet, the two storeys that no stair, ramp or steps join;
- *it stands on the site outside the building*, cut off from the route: a part whose
  samples are mostly open ground (:func:`planner.walkgraph.open_ground`: under the sky,
  the lowest in their column, outside the building's footprint), parted from the route's
  ground by a wall or a fence at a named place, by a step, or by no modelled ground at all.

In a plain mesh the walk passes the doors :func:`planner.walkgraph.found_doors` finds, and
geometry alone cannot tell a glazed door from a French window, which may be fixed. Where a
leg passes through a found door glazed at knee height (:attr:`planner.walkgraph.MeshDoors.
glazed`), the route carries a *door check* (:func:`door_checks`): the leg, its stations,
where it passes and the pane, so that the crew checks that it opens. An IFC model opens its
IfcDoor only: no check.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

from planner.errors import ParameterError
from planner.rays import RayCaster, make_ray_caster
from planner.scene import Scene, build_scene
from planner.walkgraph import (
    HEADROOM_M,
    KNEE_HEIGHT_M,
    STEP_M,
    MeshDoors,
    WalkGraph,
    free_both_ways,
    open_ground,
    raised_openings,
    upright_free,
)

# a station attaches to a floor sample at most this far away horizontally (grid units)
_ATTACH_CELLS = 2.0
# OR-Tools costs are integers: millimetres
_COST_SCALE = 1000.0
# up to this many points (stations + start) the tour is the exact optimum
EXACT_MAX_POINTS = 11


# a part of the walk graph meets the route's part where their floor samples lie within
# this distance of each other (horizontally): a thick wall (0.5 m) and a grid cell each side
_MEET_M = 1.0
# at most this many samples of a part are compared with the route's (a stride over them)
_MAX_PART_SAMPLES = 20_000
# a barrier is at a door when the segment between the pair of floor samples it parts
# crosses the door's plane within its width (its box along its plane, frame and lining
# included) less this much at either end: a segment by the jamb crosses the wall beside
# the door, not its opening (Lantern Hollow: a wall at right angles to a door's end)
_DOOR_JAMB_M = 0.1
# and what blocks the way there lies within this much of the door's box across its plane
# (the wall through it, or under it: the face of the wall on the leaf's side)
_DOOR_ACROSS_M = 0.1
_MAX_STEPS_TRIED = 256  # pairs across a height difference tried for an open step, lowest first
# a cut-off part is on the site outside the building when more than this share of its floor
# samples is open ground (planner.walkgraph.open_ground): a lawn with a tree or an eave
# over its edge is still a lawn
_OPEN_GROUND_SHARE = 0.5


@dataclass(frozen=True)
class Places:
    """What an unreachable station's reason names, where the model has it (all optional).

    ``storeys``: (name, floor height in metres), lowest first (IFC storeys, or a plain
    mesh's storeys from its candidates); ``station_rooms``: per station (ids 1..S in
    order) the room it stands in, "" where unknown; ``doors``: per door its name and
    bounding box (lowest and highest corner, metres, plan frame); ``door_frames``: per door
    its box along its own plane (centre x, y; the unit direction of its width x, y; half
    its width and half its depth, metres, plan frame), as a door turned to the axes needs
    (empty: the bounding boxes, axis-aligned).
    """

    storeys: tuple[tuple[str, float], ...] = ()
    station_rooms: tuple[str, ...] = ()
    doors: tuple[tuple[str, tuple[float, float, float], tuple[float, float, float]], ...] = ()
    door_frames: tuple[tuple[float, float, float, float, float, float], ...] = ()

    def frames(self) -> NDArray[np.float64]:
        """(D, 6) each door's box along its plane (see ``door_frames``)."""
        if self.door_frames:
            return np.asarray(self.door_frames, np.float64)
        result = np.zeros((len(self.doors), 6))
        for i, (_, lo, hi) in enumerate(self.doors):
            half_x, half_y = (hi[0] - lo[0]) / 2, (hi[1] - lo[1]) / 2
            # the width along the box's longer side
            axis = (1.0, 0.0, half_x, half_y) if half_x >= half_y else (0.0, 1.0, half_y,
                                                                         half_x)
            result[i] = ((lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, *axis)
        return result

    def storey_at(self, floor_z_m: float) -> str:
        """The storey a floor at ``floor_z_m`` belongs to, named with its height."""
        below = [(name, z) for name, z in self.storeys if z <= floor_z_m + STEP_M]
        if not below:
            return f"the floor at {_m(floor_z_m)}"
        name, _ = below[-1]
        return f"storey {name!r} (floor at {_m(floor_z_m)})"

    def crossed(self, a_xyz: NDArray[np.float64], b_xyz: NDArray[np.float64]
                ) -> NDArray[np.bool_]:
        """(P, D) bool: the horizontal segment from each (P, 3) point a to b crosses each
        door's plane (a and b on either side of it, or on it) within its width less
        ``_DOOR_JAMB_M`` at either end: the way from a to b is through that door's opening,
        not past its jamb through another wall."""
        frames = self.frames()  # (D, 6)
        u, half_width = frames[:, 2:4], frames[:, 4]

        def local(points: NDArray[np.float64]) -> tuple[NDArray[np.float64],
                                                        NDArray[np.float64]]:
            x = points[:, 0, None] - frames[None, :, 0]  # (P, D)
            y = points[:, 1, None] - frames[None, :, 1]
            return x * u[:, 0] + y * u[:, 1], y * u[:, 0] - x * u[:, 1]

        along_a, across_a = local(a_xyz)
        along_b, across_b = local(b_xyz)
        sides = across_a * across_b <= 0.0
        share = np.where(sides, across_a / np.where(sides, across_a - across_b, 1.0), 0.0)
        share = np.nan_to_num(share, nan=0.5)  # both on the plane
        along = along_a + (along_b - along_a) * share
        result: NDArray[np.bool_] = sides & (np.abs(along) <= half_width - _DOOR_JAMB_M)
        return result

    def door_near(self, a_xyz: NDArray[np.float64], b_xyz: NDArray[np.float64]
                  ) -> str | None:
        """The name of the door whose opening the way between the (3,) floor points a and
        b crosses (:meth:`crossed`) and whose box spans the floor's height, the nearest;
        None when none does."""
        z = (a_xyz[2] + b_xyz[2]) / 2
        found = self._nearest_door(a_xyz, b_xyz, lambda lo, hi: lo - STEP_M <= z <= hi)
        return None if found is None else found[0]

    def raised_door_near(self, a_xyz: NDArray[np.float64], b_xyz: NDArray[np.float64]
                         ) -> tuple[str, float] | None:
        """The door whose opening the way between the (3,) floor points a and b crosses
        whose sill stands higher than a step but lower than head room above their floor (a
        door the model sets at another level), the nearest: its name and the sill's height
        over the floor midway, metres; None when none does."""
        z = (a_xyz[2] + b_xyz[2]) / 2
        found = self._nearest_door(a_xyz, b_xyz,
                                   lambda lo, hi: STEP_M < lo - z < HEADROOM_M)
        return None if found is None else (found[0], found[1] - float(z))

    def _nearest_door(self, a_xyz: NDArray[np.float64], b_xyz: NDArray[np.float64],
                      fits: Callable[[float, float], bool]) -> tuple[str, float] | None:
        """The door whose opening the way between the (3,) points a and b crosses and
        whose bottom and top heights ``fits``, the nearest to their middle: its name and
        bottom height; None when none."""
        best: tuple[float, str, float] | None = None
        if not self.doors:
            return None
        middle = (a_xyz + b_xyz) / 2
        inside = self.crossed(a_xyz[None], b_xyz[None])[0]  # (D,)
        for (name, lo, hi), frame, there in zip(self.doors, self.frames(), inside,
                                                 strict=True):
            if not (there and fits(lo[2], hi[2])):
                continue
            distance = float(np.hypot(middle[0] - frame[0], middle[1] - frame[1]))
            if best is None or distance < best[0]:
                best = (distance, name, lo[2])
        return None if best is None else (best[1], best[2])


@dataclass(frozen=True)
class Leg:
    start: int | None  # station id; None for the leg from route_start
    end: int
    length_m: float
    path: tuple[tuple[float, float, float], ...]  # points at knee height


@dataclass(frozen=True)
class DoorCheck:
    """A leg of the route through a found door of a plain mesh that may be a fixed window
    (glazed at knee height, :attr:`planner.walkgraph.MeshDoors.glazed`)."""

    leg: int  # the leg's place in Route.legs, 1 the first
    start: int | None  # the leg's station ids, as Leg's
    end: int
    door: int  # the door's number among the mesh's found doors (MeshDoors)
    at: tuple[float, float, float]  # where the leg passes it, at knee height (plan frame)
    floor_z_m: float  # the floor under that point
    width_m: float  # the door's width (its box, horizontally)
    pane_m: float  # the filler's thickness at knee height (MeshDoors.filler_m)

    def warning(self, at: tuple[float, float, float] | None = None) -> str:
        """What the crew is told, in a sentence; ``at``: the point in the model's own
        coordinates (else the plan frame's, :attr:`at`)."""
        x, y, z = self.at if at is None else at
        start = "the route's start" if self.start is None else f"station {self.start}"
        return (f"leg {self.leg} of the route, from {start} to station {self.end}, passes at "
                f"({x:.2f}, {y:.2f}, {z:.2f}), floor at {_m(self.floor_z_m)}, through an "
                f"opening glazed to the floor ({self.width_m:.2f} m wide, a "
                f"{self.pane_m * 1000:.0f} mm pane at knee height) that the plan takes for a "
                "door: a model without classes cannot tell a glazed door from a French "
                "window, which may be fixed. Check that it opens; if not, walk round")

    def to_dict(self, at: tuple[float, float, float] | None = None) -> dict[str, Any]:
        """plan.json's entry; ``at``: the point in the model's own coordinates (else the
        plan frame's)."""
        point = self.at if at is None else at
        return {"leg": self.leg, "from": self.start, "to": self.end, "door": self.door,
                "at": [round(float(v), 3) for v in point],
                "width_m": round(self.width_m, 3), "pane_m": round(self.pane_m, 4),
                "warning": self.warning(point)}


@dataclass(frozen=True)
class RoutePart:
    """The stations of one part of the walk the model joins on foot, in walking order,
    and the length of its legs."""

    visits: tuple[int, ...]
    length_m: float

    def to_dict(self) -> dict[str, Any]:
        return {"visits": list(self.visits), "length_m": round(self.length_m, 3)}


@dataclass(frozen=True)
class PartStep:
    """Where the route goes on from one part of the walk to the next, which the model
    does not join on foot (no stair or door between them, or a defect): the crew walks
    it on site, by a way the model lacks."""

    start: int | None  # the last station of the part before (None: the route's start)
    end: int  # the first station of the next part
    straight_m: float  # between the two stations' feet, in a straight line
    reason: str  # why the model has no way between them (as an unreachable station's)

    def to_dict(self) -> dict[str, Any]:
        return {"from": self.start, "to": self.end, "straight_m": round(self.straight_m, 3),
                "note": "the model has no stair or way here; walk it on site: "
                        + self.reason}


@dataclass(frozen=True)
class Route:
    """The walking route. ``visits``: every station on a floor, in walking order; a model
    whose parts are not joined on foot (no stair between storeys, a door it closes) is
    walked part after part (``parts``, two or more; empty when one part holds them all),
    with a step between each part and the next (``steps``) that the crew walks on site.
    ``unreachable``: the stations on no floor a person can walk on."""

    visits: tuple[int, ...]  # station ids in walking order
    legs: tuple[Leg, ...]  # within the parts
    unreachable: tuple[int, ...]
    unreachable_reasons: tuple[str, ...] = ()  # one per unreachable station
    # legs through found doors of a plain mesh that may be fixed windows (door_checks)
    door_checks: tuple[DoorCheck, ...] = ()
    parts: tuple[RoutePart, ...] = ()
    steps: tuple[PartStep, ...] = ()

    @property
    def length_m(self) -> float:
        return sum(leg.length_m for leg in self.legs)

    def to_dict(self) -> dict[str, Any]:
        """plan.json's ``route``; ``door_checks`` only where there are any."""
        data: dict[str, Any] = {
            "visits": list(self.visits),
            "length_m": round(self.length_m, 3),
            "legs": [{"from": leg.start, "to": leg.end, "length_m": round(leg.length_m, 3),
                      "path": [[round(v, 3) for v in p] for p in leg.path]}
                     for leg in self.legs],
            "unreachable": list(self.unreachable),
            "unreachable_reasons": {str(station): reason for station, reason
                                    in zip(self.unreachable, self.unreachable_reasons,
                                           strict=True)},
        }
        if self.parts:
            data["parts"] = [part.to_dict() for part in self.parts]
        if self.steps:
            data["steps_between_parts"] = [step.to_dict() for step in self.steps]
        if self.door_checks:
            data["door_checks"] = [check.to_dict() for check in self.door_checks]
        return data


def door_checks(scene: Scene, route: Route, doors: MeshDoors) -> tuple[DoorCheck, ...]:
    """Where the ``route``'s legs pass through a glazed door of ``doors`` (the found doors
    of the plain mesh ``scene``): each leg's path, segment by segment, is cast against the
    glazed doors' faces alone; the first crossing of each door on a leg is a check, in the
    order of the legs and along each."""
    glazed = doors.glazed
    if not glazed.any() or not route.legs:
        return ()
    pane = np.flatnonzero((doors.face_door >= 0) & glazed[np.maximum(doors.face_door, 0)])
    if len(pane) == 0:
        return ()
    # the panes' own triangles as a mesh of their own (the same float32 corners in the same
    # order, so the same hits): a caster over the whole split mesh copied every vertex of a
    # 5 M-piece site's mesh three times for a few doors, at the survey's peak
    used, corner = np.unique(scene.faces[pane], return_inverse=True)
    panes = build_scene(scene.vertices[used], corner.reshape(-1, 3))
    caster = make_ray_caster(panes, np.ones(len(pane), bool))
    checks: list[DoorCheck] = []
    for number, leg in enumerate(route.legs, start=1):
        path = np.asarray(leg.path, np.float64)  # (P, 3)
        if len(path) < 2:
            continue
        delta = path[1:] - path[:-1]
        length = np.linalg.norm(delta, axis=1)
        moving = np.flatnonzero(length > 1e-6)
        if len(moving) == 0:
            continue
        hit, distance = caster.first_hit(path[moving], delta[moving] / length[moving, None])
        face = np.where(hit >= 0, pane[np.maximum(hit, 0)], -1)
        crossed = np.flatnonzero((face >= 0) & (distance <= length[moving]))
        seen: set[int] = set()
        for k in crossed.tolist():
            door = int(doors.face_door[face[k]])
            if door in seen:
                continue
            seen.add(door)
            segment = int(moving[k])
            at = path[segment] + delta[segment] / length[segment] * distance[k]
            checks.append(DoorCheck(
                leg=number, start=leg.start, end=leg.end, door=door,
                at=(float(at[0]), float(at[1]), float(at[2])),
                floor_z_m=float(at[2]) - KNEE_HEIGHT_M,
                width_m=float(doors.width_m[door]),
                pane_m=float(doors.filler_m[door])))
    return tuple(checks)


def door_checks_line(route: dict[str, Any] | None) -> str | None:
    """A clause for a job's message from plan.json's ``route``: how many legs pass a
    glazed opening the crew must check; None when none does."""
    checks = (route or {}).get("door_checks") or []
    if not checks:
        return None
    legs = sorted({int(check["leg"]) for check in checks})
    return (f"check that {len(checks)} glazed opening{'s' if len(checks) > 1 else ''} to the "
            f"floor open{'s' if len(checks) == 1 else ''}: leg{'s' if len(legs) > 1 else ''} "
            f"{', '.join(map(str, legs))} of the route pass{'es' if len(legs) == 1 else ''} "
            "through one that the plan takes for a door and that may be a fixed window "
            "(route.door_checks)")


def parts_line(route: dict[str, Any] | None) -> str | None:
    """A clause for a job's message from plan.json's ``route``: the steps between parts
    of the walk that the model does not join, which the crew walks on site; None when
    one part holds every station."""
    steps = (route or {}).get("steps_between_parts") or []
    if not steps:
        return None
    between = ", ".join(f"{'the start' if step['from'] is None else step['from']} -> "
                        f"{step['to']}" for step in steps)
    return (f"the model joins the route's stations in {len(steps) + 1} parts, with no stair "
            f"or way between them: walk on site from station {between} "
            "(route.steps_between_parts)")


def attach(graph: WalkGraph, caster: RayCaster, points: NDArray[np.float64]
           ) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Node of every (K, 3) point (a station or the start) and its foot at knee height.

    The foot is where a ray straight down from the point meets the model; -1 when no
    floor sample is near enough or the way to it is blocked (from knee to head height,
    :func:`planner.walkgraph.upright_free`).
    """
    k = len(points)
    down = np.tile([0.0, 0.0, -1.0], (k, 1))
    _, drop = caster.first_hit(points, down)
    foot = points.copy()
    foot[:, 2] -= np.where(np.isfinite(drop), drop, 0.0)
    knee = np.array([0.0, 0.0, KNEE_HEIGHT_M])
    nodes = np.full(k, -1, np.int64)
    if graph.n_nodes == 0:
        return nodes, foot + knee
    reach = _ATTACH_CELLS * graph.grid_m
    for i in range(k):
        if not np.isfinite(drop[i]):
            continue
        horizontal = np.linalg.norm(graph.floor_xyz[:, :2] - foot[i, :2], axis=1)
        near = np.flatnonzero((horizontal <= reach)
                              & (np.abs(graph.floor_xyz[:, 2] - foot[i, 2]) <= STEP_M))
        if len(near) == 0:
            continue
        distance = np.linalg.norm(graph.floor_xyz[near] - foot[i], axis=1)
        near = near[np.lexsort((near, distance))]  # nearest first, ties by index
        free = upright_free(caster, np.repeat(foot[i:i + 1] + knee, len(near), axis=0),
                            graph.floor_xyz[near] + knee)
        if free.any():
            nodes[i] = near[int(np.argmax(free))]
    return nodes, foot + knee


def exact_open_tour(cost_m: NDArray[np.float64], start: int | None) -> list[int]:
    """The optimum open path by Held-Karp dynamic programming (O(2^n n^2); n <= 12).

    ``best[mask, j]``: shortest path that visits the points of ``mask`` and ends at j.
    """
    n = len(cost_m)
    full = (1 << n) - 1
    best = np.full((1 << n, n), np.inf)
    parent = np.full((1 << n, n), -1, np.int64)
    for j in range(n) if start is None else [start]:
        best[1 << j, j] = 0.0
    for mask in range(1, full + 1):
        row = best[mask]
        ends = [j for j in range(n) if np.isfinite(row[j])]
        if not ends:
            continue
        for k in range(n):
            if mask & (1 << k):
                continue
            # extend the best path of this mask by k; strict < keeps the lowest j on ties
            via = row[ends] + cost_m[ends, k]
            i = int(np.argmin(via))
            if via[i] < best[mask | (1 << k), k]:
                best[mask | (1 << k), k] = via[i]
                parent[mask | (1 << k), k] = ends[i]
    end = int(np.argmin(best[full]))
    order = [end]
    mask = full
    while parent[mask, order[-1]] >= 0:
        previous = int(parent[mask, order[-1]])
        mask &= ~(1 << order[-1])
        order.append(previous)
    return order[::-1]


def open_tour(cost_m: NDArray[np.float64], start: int | None) -> list[int]:
    """Order of the (n, n) cost matrix's points on a shortest open path.

    ``start``: index the path must begin at; None lets the solver choose. Up to
    ``EXACT_MAX_POINTS`` points the exact optimum (Held-Karp); above, OR-Tools.
    """
    n = len(cost_m)
    if n <= 1:
        return list(range(n))
    if n <= EXACT_MAX_POINTS:
        return exact_open_tour(cost_m, start)
    from ortools.constraint_solver import pywrapcp, routing_enums_pb2

    cost = np.round(cost_m * _COST_SCALE).astype(np.int64)
    # a depot the path leaves from and returns to at no cost: the tour becomes a path
    depot = n if start is None else start
    size = n + 1 if start is None else n
    full = np.zeros((size, size), np.int64)
    full[:n, :n] = cost
    full[:, depot] = 0  # returning to the depot is free: the path ends anywhere
    manager = pywrapcp.RoutingIndexManager(size, 1, depot)
    routing = pywrapcp.RoutingModel(manager)
    table = full.tolist()

    def arc(i: int, j: int) -> int:
        return int(table[manager.IndexToNode(i)][manager.IndexToNode(j)])

    routing.SetArcCostEvaluatorOfAllVehicles(routing.RegisterTransitCallback(arc))
    params = pywrapcp.DefaultRoutingSearchParameters()
    params.first_solution_strategy = routing_enums_pb2.FirstSolutionStrategy.PATH_CHEAPEST_ARC
    # local search (2-opt, or-opt, relocate, ...) down to a local optimum: no time limit,
    # so the same costs give the same order
    params.local_search_metaheuristic = (
        routing_enums_pb2.LocalSearchMetaheuristic.GREEDY_DESCENT)
    solution = routing.SolveWithParameters(params)
    order: list[int] = []
    index = routing.Start(0)
    while not routing.IsEnd(index):
        node = manager.IndexToNode(index)
        if node < n:
            order.append(node)
        index = solution.Value(routing.NextVar(index))
    return order


def parts_may_join_outside(graph: WalkGraph, caster: RayCaster,
                           points: NDArray[np.float64]) -> bool:
    """Whether two parts of ``graph``, a graph of part of the model's footprint, that each
    hold some of the (K, 3) ``points`` (the stations, the start) both reach its cut
    nodes (:attr:`WalkGraph.cut_nodes`): on the whole footprint's graph they may be one
    part, joined outside the area. A part that reaches no cut node is a part of the
    whole footprint's graph too: its nodes' links are all in the area."""
    if not len(graph.cut_nodes):
        return False
    nodes, _ = attach(graph, caster, np.asarray(points, np.float64))
    _, component = connected_components(graph.links, directed=False)
    held = np.unique(component[nodes[nodes >= 0]])
    return len(np.intersect1d(held, component[graph.cut_nodes])) >= 2


def plan_route(graph: WalkGraph, caster: RayCaster, stations_xyz: NDArray[np.float64],
               route_start: tuple[float, float, float] | None,
               places: Places | None = None, trees: TreeCache | None = None) -> Route:
    """The route over the (S, 3) stations (ids 1..S in this order); ``places``: what the
    reasons of unreachable stations name (storeys, rooms, doors); ``trees``: shortest-path
    trees kept from earlier routes on this ``graph`` (:class:`TreeCache`), the same route
    sooner when the stations are among theirs."""
    s = len(stations_xyz)
    points = stations_xyz if route_start is None else np.vstack([stations_xyz, [route_start]])
    nodes, feet = attach(graph, caster, np.asarray(points, np.float64))
    if route_start is not None and nodes[s] < 0:
        raise ParameterError(
            "route_start", f"{list(route_start)} is not over a floor a person can walk on; "
            "give a point inside the building, above its floor (e.g. at scanner height), "
            "or null to let the route choose")
    places = Places() if places is None else places
    if graph.n_nodes == 0:  # no floor anywhere (a facade, a single object): nobody walks
        return Route((), (), tuple(range(1, s + 1)),
                     (_NO_FLOOR + ": the model has no floor a person can walk on anywhere "
                      "(a facade, a single object)",) * s)
    _, component = connected_components(graph.links, directed=False)
    labels = np.where(nodes >= 0, component[np.maximum(nodes, 0)], -1)
    if route_start is not None:
        main = labels[s]
    else:
        counted = labels[:s][labels[:s] >= 0]
        # the part of the graph with the most stations; ties: the lowest station id's part
        main = -1
        if len(counted):
            values, counts = np.unique(counted, return_counts=True)
            best = values[counts == counts.max()]
            main = int(next(label for label in labels[:s] if label in set(best.tolist())))
    unreachable = tuple(i + 1 for i in range(s) if labels[i] < 0)
    why = _Why(graph, caster, labels, feet, component, int(main), places)
    reasons = tuple(why.station(i - 1) for i in unreachable)
    if main < 0:
        return Route((), (), unreachable, reasons)
    # each part of the walk its own tour: the route's part first (from the start), then
    # the part nearest to where the last one ended, from its station nearest to that
    members: dict[int, list[int]] = {}
    for i in range(s):
        if labels[i] >= 0:
            members.setdefault(int(labels[i]), []).append(i)
    visits: list[int] = []
    legs: list[Leg] = []
    parts: list[RoutePart] = []
    steps: list[PartStep] = []
    label = int(main)
    last: int | None = s if route_start is not None else None  # point index ended at
    while True:
        points_in = members.pop(label, [])
        first: int | None = None
        if label == main and route_start is not None:
            points_in = [*points_in, s]
            first = len(points_in) - 1
        elif last is not None:
            gap_m = np.linalg.norm(feet[points_in] - feet[last], axis=1)
            first = int(np.lexsort((points_in, gap_m))[0])
            steps.append(PartStep(None if last == s else last + 1, points_in[first] + 1,
                                  float(gap_m[first]), why.station(points_in[first])))
        part_visits, part_legs = _tour(graph, nodes, feet, points_in, first, s, trees)
        visits += part_visits
        legs += part_legs
        if part_visits:
            parts.append(RoutePart(tuple(part_visits),
                                   float(sum(leg.length_m for leg in part_legs))))
            last = part_visits[-1] - 1
        if not members:
            break
        # the next part: the one with the station nearest to where this one ended
        assert last is not None  # the route's part holds a station or the start
        ends = np.array([i for held in members.values() for i in held])
        gap_m = np.linalg.norm(feet[ends] - feet[last], axis=1)
        label = int(labels[ends[np.lexsort((ends, gap_m))[0]]])
    return Route(tuple(visits), tuple(legs), unreachable, reasons,
                 parts=tuple(parts) if len(parts) > 1 else (), steps=tuple(steps))


def _tour(graph: WalkGraph, nodes: NDArray[np.int64], feet: NDArray[np.float64],
          points_in: list[int], first: int | None, start_index: int,
          cache: TreeCache | None = None) -> tuple[list[int], list[Leg]]:
    """The shortest open tour over the points ``points_in`` (indices into ``nodes`` and
    ``feet``: stations, and the route's start at ``start_index``) of one part of the
    graph, from ``points_in[first]`` when given: the station ids in walking order (the
    start left out) and the legs."""
    if not points_in:
        return [], []
    sources = [int(nodes[i]) for i in points_in]
    found = None if cache is None else cache.between(sources)
    if found is None:
        between_m, trees = _shortest_paths(graph, sources)
        if cache is not None:
            cache.keep(sources, between_m, trees)
    else:
        between_m, trees = found
    # foot -> node -> ... -> node -> foot; the attaching segments count too
    attach_m = np.linalg.norm(graph.floor_xyz[sources] - (feet[points_in]
                              - [0, 0, KNEE_HEIGHT_M]), axis=1)
    cost = between_m + attach_m[:, None] + attach_m[None, :]
    np.fill_diagonal(cost, 0.0)
    order = open_tour(cost, first)
    knee = np.array([0.0, 0.0, KNEE_HEIGHT_M])
    point_ids = [None if i == start_index else i + 1 for i in points_in]
    feet_used = feet[points_in]
    legs: list[Leg] = []
    for a, b in itertools.pairwise(order):
        path_nodes = trees.path(a, sources, b)
        path = [feet_used[a]] + [graph.floor_xyz[p] + knee for p in path_nodes] + [feet_used[b]]
        end = point_ids[b]
        assert end is not None  # only the start is None, and it is never visited later
        legs.append(Leg(point_ids[a], end, float(cost[a, b]),
                        tuple((float(p[0]), float(p[1]), float(p[2])) for p in path)))
    return [pid for pid in (point_ids[i] for i in order) if pid is not None], legs


# sources whose shortest-path trees are grown at a time: the (k, N) float64 distances and
# int32 predecessors of a chunk are cut at once to the sources' columns and to the paths
# between the sources, so no (S, N) array stays. Four trees at a time: 48 bytes a node
# (16 made the peak of Lantern Hollow's plain mesh); the time is in the trees, not the
# calls (48 trees over a 2 M-node grid: 27.6 CPU s four at a time, 30.4 sixteen)
_SOURCES_PER_CHUNK = 4


@dataclass(frozen=True)
class _PathTrees:
    """Each source's shortest-path tree cut to its paths to the other sources: per source
    the (n,) ascending nodes on those paths (the source itself not among them) and the
    (n,) predecessor of each, as ``dijkstra``'s predecessors give them."""

    nodes: tuple[NDArray[np.int32], ...]
    predecessors: tuple[NDArray[np.int32], ...]

    def path(self, a: int, sources: list[int], b: int) -> list[int]:
        """The nodes from ``sources[a]`` to ``sources[b]`` on the tree of ``a``."""
        nodes, predecessors = self.nodes[a], self.predecessors[a]
        path = [sources[b]]
        while path[-1] != sources[a]:
            path.append(int(predecessors[np.searchsorted(nodes, path[-1])]))
        path.reverse()
        return path


@numba.njit(nogil=True, cache=True)
def _on_paths(predecessor: NDArray[np.int32], source: int, targets: NDArray[np.int64]
              ) -> NDArray[np.bool_]:
    """(N,) bool: the nodes on the paths of the (N,) ``predecessor`` tree from ``source``
    to the ``targets`` (the source not marked; a path is followed until it meets one
    marked before)."""
    on = np.zeros(len(predecessor), np.bool_)
    for target in targets:
        node = target
        while node != source and node >= 0 and not on[node]:
            on[node] = True
            node = predecessor[node]
    return on


def _shortest_paths(graph: WalkGraph, sources: list[int]
                    ) -> tuple[NDArray[np.float64], _PathTrees]:
    """(S, S) walking distances between the ``sources`` (walk-graph nodes) and each
    source's shortest-path tree cut to its paths to the others, as one ``dijkstra`` call
    over all sources would give them (each tree is grown on its own)."""
    between_m = np.empty((len(sources), len(sources)))
    targets = np.asarray(sources, np.int64)
    nodes: list[NDArray[np.int32]] = []
    predecessors: list[NDArray[np.int32]] = []
    for first in range(0, len(sources), _SOURCES_PER_CHUNK):
        chunk = slice(first, first + _SOURCES_PER_CHUNK)
        distance, predecessor = dijkstra(graph.links, directed=False, indices=sources[chunk],
                                         return_predecessors=True)
        between_m[chunk] = distance[:, sources]
        del distance
        for row, source in zip(predecessor, sources[chunk], strict=True):
            tree = np.asarray(row, np.int32)
            on = np.flatnonzero(_on_paths(tree, source, targets)).astype(np.int32)
            nodes.append(on)
            predecessors.append(tree[on])
        del predecessor
    return between_m, _PathTrees(tuple(nodes), tuple(predecessors))


class TreeCache:
    """Shortest-path trees of one walk graph kept between routes over sets of stations
    that are subsets of one another (a budget of hours routes every start of an order it
    tries). Each tree is grown from its source alone, so a source's distances and its
    paths to a set of targets are those to any subset of it: a route over stations among
    the kept ones reads them instead of growing the trees again, and is the same."""

    def __init__(self) -> None:
        # per source node: its targets (ascending nodes), the distances to them, metres,
        # and its tree cut to the paths to them (_PathTrees' nodes and predecessors)
        self._kept: dict[int, tuple[NDArray[np.int64], NDArray[np.float64],
                                    NDArray[np.int32], NDArray[np.int32]]] = {}

    def between(self, sources: list[int]) -> tuple[NDArray[np.float64], _PathTrees] | None:
        """What :func:`_shortest_paths` gives for ``sources``, when each was kept with a
        tree that reaches all of them; None otherwise."""
        wanted = np.asarray(sources, np.int64)
        between_m = np.empty((len(sources), len(sources)))
        for i, source in enumerate(sources):
            kept = self._kept.get(source)
            if kept is None:
                return None
            targets, distance_m = kept[0], kept[1]
            at = np.minimum(np.searchsorted(targets, wanted), len(targets) - 1)
            if not np.array_equal(targets[at], wanted):
                return None
            between_m[i] = distance_m[at]
        return between_m, _PathTrees(tuple(self._kept[source][2] for source in sources),
                                     tuple(self._kept[source][3] for source in sources))

    def keep(self, sources: list[int], between_m: NDArray[np.float64],
             trees: _PathTrees) -> None:
        """Keep the trees of ``sources`` (what :func:`_shortest_paths` gave for them)."""
        targets, first = np.unique(np.asarray(sources, np.int64), return_index=True)
        for i, source in enumerate(sources):
            self._kept[source] = (targets, between_m[i, first], trees.nodes[i],
                                  trees.predecessors[i])


_NO_FLOOR = "no floor a person can walk on under it"


def _m(z_m: float) -> str:
    """A height as the reasons give it: "+2.85 m" (never "-0.00 m")."""
    return f"{round(float(z_m), 2) + 0.0:+.2f} m"


class _Why:
    """Why a station is not on the route, in a sentence naming what is missing (see the
    module docstring); a part of the graph is described once for all its stations."""

    def __init__(self, graph: WalkGraph, caster: RayCaster, labels: NDArray[np.int64],
                 feet: NDArray[np.float64], component: NDArray[np.int32], main: int,
                 places: Places) -> None:
        self.graph, self.caster, self.labels, self.feet = graph, caster, labels, feet
        self.component, self.main, self.places = component, main, places
        # per cut-off part its reason and whether it is open ground outside the building
        self._parts: dict[int, tuple[str, bool]] = {}
        self._main_tree: cKDTree | None = None
        self._main_nodes: NDArray[np.int64] = np.zeros(0, np.int64)
        self._open_ground: NDArray[np.bool_] | None = None

    def station(self, i: int) -> str:
        """The reason of station index ``i``."""
        floor = self.feet[i] - np.array([0.0, 0.0, KNEE_HEIGHT_M])
        room = self.places.station_rooms[i] if i < len(self.places.station_rooms) else ""
        where = f"in room {room!r}, " if room else ""
        storey = self.places.storey_at(float(floor[2])) if (
            self.places.storeys and np.isfinite(floor[2])) else ""
        if self.labels[i] < 0:
            where = (where + storey).removesuffix(", ")
            return f"{_NO_FLOOR}{f' ({where})' if where else ''}: {self._no_floor(floor)}"
        label = int(self.labels[i])
        if label not in self._parts:
            self._parts[label] = self._cut_off(label)
        reason, outdoors = self._parts[label]
        # open ground belongs to no storey: its reason gives the ground's height
        where = (where + ("" if outdoors else storey)).removesuffix(", ")
        return f"{where}: {reason}" if where else reason

    def _blocked_in_door(self, a_xyz: NDArray[np.float64], b_xyz: NDArray[np.float64]
                         ) -> bool:
        """Whether the knee-high way between the (3,) floor points a and b is blocked, from
        either end, within the opening of a door it crosses (:meth:`Places.crossed`): the
        first face met lies within the door's width less ``_DOOR_JAMB_M`` and within
        ``_DOOR_ACROSS_M`` of its box across its plane."""
        knee = np.array([0.0, 0.0, KNEE_HEIGHT_M])
        frames = self.places.frames()[self.places.crossed(a_xyz[None], b_xyz[None])[0]]
        length = float(np.linalg.norm(b_xyz[:2] - a_xyz[:2]))
        if len(frames) == 0 or length == 0.0:
            return False
        for start, end in ((a_xyz, b_xyz), (b_xyz, a_xyz)):
            direction = (end - start) / float(np.linalg.norm(end - start))
            _, distance = self.caster.first_hit((start + knee)[None], direction[None])
            if not distance[0] < float(np.linalg.norm(end - start)):
                continue
            hit = start + direction * distance[0]
            x, y = hit[0] - frames[:, 0], hit[1] - frames[:, 1]
            along = np.abs(x * frames[:, 2] + y * frames[:, 3])
            across = np.abs(y * frames[:, 2] - x * frames[:, 3])
            if ((along <= frames[:, 4] - _DOOR_JAMB_M)
                    & (across <= frames[:, 5] + _DOOR_ACROSS_M)).any():
                return True
        return False

    def _raised_opening(self, a: NDArray[np.int64], b: NDArray[np.int64],
                        level: NDArray[np.bool_]) -> str | None:
        """Where a wall parts a cut-off part from the route's floor beside it at the same
        height (the (P,) node pairs ``a``, ``b`` across, ``level`` of them so): the clause
        naming an opening of door height over that wall, set higher than a step above
        both floors (:func:`planner.walkgraph.raised_openings`; a plain mesh names no
        door), at the nearest pair that has one; None when none does."""
        graph = self.graph
        gap = np.linalg.norm(graph.floor_xyz[b, :2] - graph.floor_xyz[a, :2], axis=1)
        ranked = np.flatnonzero(level)[np.lexsort((b[level], a[level], gap[level]))][
            :_MAX_STEPS_TRIED]
        sill = raised_openings(self.caster, graph.floor_xyz[a[ranked]],
                               graph.floor_xyz[b[ranked]])
        found = np.flatnonzero(np.isfinite(sill))
        if len(found) == 0:
            return None
        k = int(ranked[found[0]])
        here, there = float(graph.floor_xyz[a[k], 2]), float(graph.floor_xyz[b[k], 2])
        at = (graph.floor_xyz[a[k]] + graph.floor_xyz[b[k]]) / 2
        sill_z = max(here, there) + float(sill[found[0]])
        return (f"the route's floor lies beside it at the same height, but at ({at[0]:.2f}, "
                f"{at[1]:.2f}) at {_m(at[2])} a wall stands between them, and the opening of "
                f"door height in it (a door or a window, open or closed by a leaf or a pane) "
                f"has its sill at {_m(sill_z)}, {sill_z - here:.2f} m above this floor "
                f"({_m(here)}) and {sill_z - there:.2f} m above the route's floor on its "
                f"other side ({_m(there)}), with wall under it: the floors meet at the same "
                "height, so no step is missing; the model places the opening at another "
                f"level's height, more than the {STEP_M:g} m a person steps above both floors")

    def _no_floor(self, floor: NDArray[np.float64]) -> str:
        graph = self.graph
        if not np.isfinite(floor[2]):
            return "nothing under it: no floor, slab or ground below the station"
        reach = _ATTACH_CELLS * graph.grid_m
        horizontal = np.linalg.norm(graph.floor_xyz[:, :2] - floor[:2], axis=1)
        level = np.abs(graph.floor_xyz[:, 2] - floor[2]) <= STEP_M
        if (level & (horizontal <= reach)).any():
            return (f"the floor around it is walked, but within {reach:.2f} m of its foot "
                    f"every way to it is blocked at {KNEE_HEIGHT_M:g} m above the floor: it "
                    "stands walled in (in a wall's or an object's footprint, behind a "
                    "railing)")
        up = np.array([[0.0, 0.0, 1.0]])
        _, free = self.caster.first_hit(floor[None] + [0.0, 0.0, 0.01], up)
        head = float(free[0]) + 0.01
        if head < HEADROOM_M:
            return (f"only {head:.2f} m is free over its floor, less than the {HEADROOM_M:g} "
                    "m of head room a person needs (under a stair, a low roof, a duct)")
        return ("the surface under it is not walked: steeper than a stair or a ramp, or "
                "narrower than the walk grid (a stringer, a sill, a sloped roof)")

    def _cut_off(self, label: int) -> tuple[str, bool]:
        """The reason of the stations on the cut-off part ``label`` of the graph, and
        whether that part is open ground outside the building."""
        graph = self.graph
        part = np.flatnonzero(self.component == label)
        part_xyz = graph.floor_xyz[part]
        area = len(part) * graph.grid_m ** 2
        low, high = float(part_xyz[:, 2].min()), float(part_xyz[:, 2].max())
        span = _m(low) if high - low < 0.01 else f"{_m(low)[:-2]} to {_m(high)}"
        if self._open_ground is None:
            self._open_ground = open_ground(graph)
        outdoors = bool(self._open_ground[part].mean() > _OPEN_GROUND_SHARE)
        if outdoors:
            what = (f"it stands on the site outside the building, cut off from the route "
                    f"({area:.1f} m² of open ground at {span}: no roof or ceiling over it, "
                    "outside the building's footprint)")
        else:
            what = (f"it stands in a part of the building cut off from the route ({area:.1f} "
                    f"m² of floor at {span})")
        return self._cut_off_because(part, low, what, outdoors), outdoors

    def _cut_off_because(self, part: NDArray[np.int64], low: float, what: str,
                         outdoors: bool) -> str:
        """``what`` the cut-off ``part`` (its (P,) nodes, lowest at ``low`` metres) is,
        and what parts it from the route's part."""
        graph = self.graph
        if self.main < 0:
            return what
        if self._main_tree is None:
            self._main_nodes = np.flatnonzero(self.component == self.main)
            self._main_tree = cKDTree(graph.floor_xyz[self._main_nodes, :2])
        stride = max(1, len(part) // _MAX_PART_SAMPLES)
        sample = part[::stride]
        near = self._main_tree.query_ball_point(graph.floor_xyz[sample, :2],
                                                max(_MEET_M, 2.5 * graph.grid_m))
        counts = np.array([len(x) for x in near])
        if counts.sum():
            a = np.repeat(sample, counts)  # (P,) the part's node of each pair
            b = self._main_nodes[np.concatenate([np.asarray(x, np.int64) for x in near
                                                 if x])]
            rise = graph.floor_xyz[b, 2] - graph.floor_xyz[a, 2]
            gap = np.linalg.norm(graph.floor_xyz[b, :2] - graph.floor_xyz[a, :2], axis=1)
            level = np.abs(rise) <= STEP_M
            step = ~level & (np.abs(rise) < HEADROOM_M)  # over or under: a storey, no step
            clauses: list[str] = []
            if level.any():
                # the nearest pair in a door's opening, where the model names doors; else
                # the nearest pair
                ranked = np.flatnonzero(level)[np.lexsort((b[level], a[level], gap[level]))]
                middle = (graph.floor_xyz[a[ranked]] + graph.floor_xyz[b[ranked]]) / 2
                # a door at that height: spanning it, or standing on it less than head
                # room higher (a door set at another level)
                z_lo = np.array([lo[2] for _, lo, _ in self.places.doors], np.float64)
                z_hi = np.array([hi[2] for _, _, hi in self.places.doors], np.float64)
                at_height = ((middle[:, 2, None] > z_lo - HEADROOM_M)
                             & (middle[:, 2, None] <= z_hi))
                at_door = (self.places.crossed(graph.floor_xyz[a[ranked]],
                                               graph.floor_xyz[b[ranked]])
                           & at_height).any(axis=1)
                # and what blocks the way there lies in that door's opening: a wall drawn
                # through it, the wall under a raised door; not a wall beside it
                for j in np.flatnonzero(at_door)[:_MAX_STEPS_TRIED].tolist():
                    if self._blocked_in_door(graph.floor_xyz[a[ranked[j]]],
                                             graph.floor_xyz[b[ranked[j]]]):
                        break
                    at_door[j] = False
                else:
                    at_door[:] = False
                k = int(ranked[int(np.argmax(at_door))] if at_door.any() else ranked[0])
                at = (graph.floor_xyz[a[k]] + graph.floor_xyz[b[k]]) / 2
                door = self.places.door_near(graph.floor_xyz[a[k]], graph.floor_xyz[b[k]])
                place = f"({at[0]:.2f}, {at[1]:.2f}) at {_m(at[2])}"
                if door is not None:
                    clauses.append(
                        f"its way to the route's floor beside it, through door {door!r} at "
                        f"{place}, is blocked at {KNEE_HEIGHT_M:g} m above the floor: the "
                        "model closes that door's opening (a wall drawn through it, a leaf "
                        "outside the door, a sill higher than a step)")
                elif (raised := self.places.raised_door_near(graph.floor_xyz[a[k]],
                                                             graph.floor_xyz[b[k]])) is not None:
                    # both floors beside the door lie within a step of each other (a level
                    # pair): no step is missing between them, the door stands too high
                    here, there = float(graph.floor_xyz[a[k], 2]), float(graph.floor_xyz[b[k], 2])
                    sill = float(at[2]) + raised[1]
                    clauses.append(
                        f"its way to the route's floor beside it is through door "
                        f"{raised[0]!r} at {place}, but the model sets that door's sill at "
                        f"{_m(sill)}, {sill - here:.2f} m above this floor ({_m(here)}) and "
                        f"{sill - there:.2f} m above the route's floor on its other side "
                        f"({_m(there)}), with wall under it: the floors meet at the same "
                        "height, so no step is missing; the model places the door and its "
                        "opening at another level's height, more than the "
                        f"{STEP_M:g} m a person steps above both floors")
                elif not outdoors and (opening := self._raised_opening(a, b, level)):
                    clauses.append(opening)
                elif outdoors:
                    clauses.append(
                        f"the route's ground lies beside it at the same height, but at {place} "
                        "and all along it something stands between them at "
                        f"{KNEE_HEIGHT_M:g} m above the ground (a wall, a fence, a railing), "
                        "with no gate or opening in the model")
                else:
                    clauses.append(
                        f"the route's floor lies beside it at the same height, but at {place} "
                        "and all along it a wall stands between them at "
                        f"{KNEE_HEIGHT_M:g} m above the floor, with no doorway: a door the "
                        "model closes or draws as a wall, or an opening it lacks")
            # a step is where the higher floor's knee-high segment over to the lower one
            # is free: the drop itself is all that stands between them (not a wall)
            ranked = np.flatnonzero(step)[np.lexsort((b[step], a[step], gap[step],
                                                      np.abs(rise[step])))][:_MAX_STEPS_TRIED]
            top = np.maximum(graph.floor_xyz[a[ranked], 2], graph.floor_xyz[b[ranked], 2])
            over_a = np.column_stack([graph.floor_xyz[a[ranked], :2], top + KNEE_HEIGHT_M])
            over_b = np.column_stack([graph.floor_xyz[b[ranked], :2], top + KNEE_HEIGHT_M])
            open_step = ranked[free_both_ways(self.caster, over_a, over_b)]
            if len(open_step):
                k = int(open_step[0])
                at = graph.floor_xyz[a[k]]
                clauses.append(
                    f"it meets the route's floor at ({at[0]:.2f}, {at[1]:.2f}) with a step "
                    f"of {abs(float(rise[k])):.2f} m ({'up' if rise[k] > 0 else 'down'} to "
                    f"{_m(float(graph.floor_xyz[b[k], 2]))}), more than the {STEP_M:g} m a "
                    "person steps, and no stair or steps are modelled there")
            if clauses:
                door = None if outdoors or any(" door " in c for c in clauses) \
                    else self._door_of(part)
                return f"{what}: " + "; and ".join([*clauses, *([door] if door else [])])
        # the two parts never meet: name the storeys no stair joins
        route_z = graph.floor_xyz[self._main_nodes, 2]
        nearest = route_z[np.argmin(np.abs(route_z - low))]
        theirs = self.places.storey_at(low)
        ours = self.places.storey_at(float(nearest))
        if outdoors:
            return (f"{what}: no modelled ground joins it to the route (the route's floor "
                    f"nearest its height, at {_m(float(nearest))}, lies elsewhere): the site's "
                    "ground between them is not modelled, or the model's site ends first")
        door = self._door_of(part)
        if abs(float(nearest) - low) <= STEP_M:
            if door is not None:  # a door of the model opens from it: say where it leads
                return (f"{what}: the route's floor at the same height "
                        f"({_m(float(nearest))}) lies elsewhere; {door}")
            return (f"{what}: the route's floor at the same height ({_m(float(nearest))}) "
                    "lies elsewhere and no floor, door or way around the outside leads "
                    "between them: a room without a door or opening in the model")
        return (f"{what}: no stair, ramp or steps join {theirs} to {ours}, the route's "
                f"nearest: the model has no stair geometry between them (a stair left out or "
                "without a body, a ladder, a hatch)" + (f"; and {door}" if door else ""))

    def _door_of(self, part: NDArray[np.int64]) -> str | None:
        """A clause naming a door of the model that opens from the cut-off ``part`` and
        what stops the walk through it, with coordinates; None when no door does. A door
        opens from the part when the part has floor within ``_MEET_M`` of the door's middle,
        at most a step over its sill and at most head room under it, and its two sides'
        floors are not both the part's; of those, the door nearest to the route's part
        (the first in the model's order on a tie)."""
        frames = self.places.frames()
        if len(frames) == 0:
            return None
        graph = self.graph
        sills = np.array([lo[2] for _, lo, _ in self.places.doors], np.float64)
        tree = cKDTree(graph.floor_xyz[part, :2])
        found: list[tuple[float, int]] = []
        for d in range(len(frames)):
            near = tree.query_ball_point(frames[d, :2], _MEET_M)
            rise = sills[d] - graph.floor_xyz[part[near], 2]
            if not near or not ((rise >= -STEP_M) & (rise <= HEADROOM_M)).any():
                continue
            to_route = 0.0 if self._main_tree is None else float(
                self._main_tree.query(frames[d, :2])[0])
            found.append((to_route, d))
        own = int(self.component[part[0]])
        for _, d in sorted(found):
            sill = float(sills[d])
            cx, cy, ux, uy, _, half_depth = (float(v) for v in frames[d])
            normal = np.array([-uy, ux])
            sides = [np.array([cx, cy]) + sign * (half_depth + graph.grid_m) * normal
                     for sign in (1.0, -1.0)]
            nodes = [self._floor_under(xy, sill) for xy in sides]
            labels = [-1 if n < 0 else int(self.component[n]) for n in nodes]
            if own not in labels or labels[0] == labels[1]:
                continue  # not beside the part, or within it: not what cuts it off
            this = labels.index(own)
            door = (f"its door {self.places.doors[d][0]!r} at ({cx:.2f}, {cy:.2f}), sill at "
                    f"{_m(sill)}")
            return self._door_clause(door, sill, sides[this], nodes[this], sides[1 - this],
                                     nodes[1 - this], own)
        return None

    def _door_clause(self, door: str, sill: float, near_xy: NDArray[np.float64],
                     near_node: int, far_xy: NDArray[np.float64], far_node: int, own: int
                     ) -> str:
        """What stops the walk through the ``door`` (named, with its place and ``sill``
        height) from its side on the cut-off part ``own`` ((2,) ``near_xy``, floor node
        ``near_node``) to its other side (``far_xy``, ``far_node``, -1 for no floor
        there)."""
        graph = self.graph
        near_z = float(graph.floor_xyz[near_node, 2])
        if sill - near_z > STEP_M:
            return (f"{door}, stands {sill - near_z:.2f} m over this part's floor "
                    f"({_m(near_z)}) at ({near_xy[0]:.2f}, {near_xy[1]:.2f}), and no step or "
                    "stair is modelled up to its sill")
        where = f"({far_xy[0]:.2f}, {far_xy[1]:.2f})"
        if far_node < 0:
            _, drop = self.caster.first_hit(np.array([[*far_xy, sill + KNEE_HEIGHT_M]]),
                                            np.array([[0.0, 0.0, -1.0]]))
            if not np.isfinite(drop[0]):
                return (f"{door}, leads to nothing: no floor, slab or ground under its far "
                        f"side at {where} in the model")
            below = float(drop[0]) - KNEE_HEIGHT_M
            if below <= STEP_M:
                return (f"{door}, leads to a surface at {where} at {_m(sill - below)} that "
                        "no one walks on (too little head room, too steep, or too narrow)")
            return (f"{door}, leads to no floor within a step of its sill: under its far "
                    f"side at {where} the model's first surface lies {below:.2f} m lower, at "
                    f"{_m(sill - below)}, and no stair or steps are modelled there")
        far_z = float(graph.floor_xyz[far_node, 2])
        if sill - far_z > STEP_M:
            return (f"{door}, leads to floor {sill - far_z:.2f} m under its sill at {where} "
                    f"({_m(far_z)}), and no step or stair is modelled down to it")
        far_label = int(self.component[far_node])
        if far_label not in (self.main, own):
            return (f"{door}, leads to floor at {where} at {_m(far_z)} that is cut off from "
                    "the route too")
        knee_z = max(near_z, far_z) + KNEE_HEIGHT_M
        near_xyz = np.array([*near_xy, knee_z])
        direction = np.array([*far_xy, knee_z]) - near_xyz
        length = float(np.linalg.norm(direction))
        _, hit = self.caster.first_hit(near_xyz[None], (direction / length)[None])
        at = near_xyz + direction / length * min(float(hit[0]), length)
        return (f"{door}, leads to the route's floor, but something stands in its way at "
                f"({at[0]:.2f}, {at[1]:.2f}) at {KNEE_HEIGHT_M:g} m above the floor "
                "(a wall drawn through the opening, a leaf outside the door)")

    def _floor_under(self, xy: NDArray[np.float64], sill_m: float) -> int:
        """The graph node under a door's side: within 1.5 grid steps of the (2,) point
        ``xy``, at most a step over the door's sill ``sill_m`` and at most head room under
        it, the highest (then the nearest, then the first); -1 when none."""
        graph = self.graph
        horizontal = np.linalg.norm(graph.floor_xyz[:, :2] - xy, axis=1)
        rise = sill_m - graph.floor_xyz[:, 2]
        near = np.flatnonzero((horizontal <= 1.5 * graph.grid_m) & (rise >= -STEP_M)
                              & (rise <= HEADROOM_M))
        if len(near) == 0:
            return -1
        return int(near[np.lexsort((near, horizontal[near], rise[near]))[0]])
