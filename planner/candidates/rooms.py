"""Scanner candidates from the rooms (IfcSpace) of a BIM model.

The rooms come from ``scene.metadata["spaces"]`` (see :mod:`planner.io.ifc`): a floor polygon
in XY and the floor's height per room.

For each room (restricted by ``spec.storeys`` / ``spec.rooms``): grid points at multiples of
``grid_spacing_m`` inside the floor polygon (boundary inclusive) and inside
``area_of_interest`` if given, at ``floor_z_m + scanner_height_m``. A point is dropped when
the first surface straight below the scanner is not within ``FLOOR_TOLERANCE_M`` of the
room's floor (``no_floor``: a stair hole, a void; but a room where no point has a floor has
no slab in this model, e.g. the slabs live in the structural model, and its IfcSpace's own
bottom is the floor: ``CandidateSet.floor_from_space`` names those rooms;
``blocked_above_floor``: a table, a stair under the scanner), when it is inside a closed
object (``inside_geometry``), or when the tripod lacks ``clearance_m`` of room around its
axis from that floor to above the scanner (``too_close``, as
:func:`planner.candidates.grid.closer_than` measures it). A point on the boundary shared by two
rooms belongs to the first. Order: rooms as in
``metadata["spaces"]``, then grid rows (y, then x).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray
from shapely import Polygon, intersects_xy

from planner.candidates.grid import (
    DROP_REASONS,
    CandidateSet,
    closer_than,
    grid_points_xy,
    inside_closed_groups,
)
from planner.candidates.winding import winding_numbers
from planner.errors import NoCandidatesError, ParameterError
from planner.parameters import PlanSpec
from planner.rays import RayCaster
from planner.scene import Scene

FLOOR_TOLERANCE_M = 0.3


def room_candidates(scene: Scene, spec: PlanSpec, caster: RayCaster) -> CandidateSet:
    """Candidates inside the rooms of an IFC model (see the module docstring).

    Parameters
    ----------
    scene : a scene read by :func:`read_ifc` (``metadata["spaces"]`` non-empty)
    spec : grid spacing, scanner height, clearance, storey and room restrictions
    caster : first hits over the occluding faces

    Raises
    ------
    ParameterError
        a storey or room that the model does not have
    NoCandidatesError
        no room is left after the restriction, or no point in the rooms is usable
    """
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
    on_floor, floor_z, no_floor = _on_floor(scene, positions, spec, caster, keep_mask,
                                            dropped)
    from_space = _rooms_without_slab(labels, keep_mask, no_floor)
    if from_space:
        # the room's own bottom is its floor: the slab lives in another model (structure)
        rescued = np.isin([label["room_global_id"] for label in labels], list(from_space))
        rescued &= no_floor
        dropped["no_floor"] -= int(rescued.sum())
        on_floor |= rescued
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
        floor_from_space=tuple(from_space.values()),
    )


def _rooms_without_slab(labels: list[dict[str, str]], alive: NDArray[np.bool_],
                        no_floor: NDArray[np.bool_]) -> dict[str, str]:
    """Rooms none of whose points has a floor under it: GlobalId -> room name, in order.

    One point without a floor is a stair hole or a void and stays dropped; a room without
    any floor has no slab in this model, and its IfcSpace's bottom stands in for it.
    """
    rooms: dict[str, str] = {}
    has_floor: set[str] = set()
    for label, live, missing in zip(labels, alive, no_floor, strict=True):
        if not live:
            continue
        rooms.setdefault(label["room_global_id"], label["room"])
        if not missing:
            has_floor.add(label["room_global_id"])
    return {gid: name for gid, name in rooms.items() if gid not in has_floor}


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


def _on_floor(scene: Scene, positions: NDArray[np.float64], spec: PlanSpec, caster: RayCaster,
              alive: NDArray[np.bool_], dropped: dict[str, int]
              ) -> tuple[NDArray[np.bool_], NDArray[np.float64], NDArray[np.bool_]]:
    """(C,) bool: straight below the scanner, the first surface is the room's floor.

    Also returns (C,) the height of that surface (the room's floor where nothing was hit)
    and (C,) bool: the points dropped as ``no_floor``.
    """
    ok = np.ones(len(positions), bool)
    floor_z = positions[:, 2] - spec.scanner_height_m
    missing = np.zeros(len(positions), bool)
    index = np.flatnonzero(alive)
    if len(index) == 0:
        return ok, floor_z, missing
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
    missing[index[no_floor]] = True
    return ok, floor_z, missing


def _clear(scene: Scene, positions: NDArray[np.float64], clearance_m: float,
           floor_z: NDArray[np.float64], alive: NDArray[np.bool_], dropped: dict[str, int]
           ) -> NDArray[np.bool_]:
    """(C,) bool: not inside an element's solid, and the tripod has ``clearance_m`` of room.

    The room is measured as :func:`planner.candidates.grid.closer_than` does, from the floor
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

    Per element rather than per group (:func:`planner.candidates.grid.inside_closed_groups`):
    an element's box holds few points. And on the file's triangles
    (:attr:`planner.scene.Scene.file_triangles`): the pieces of a triangle subtend the same
    solid angle as the triangle, so the winding number is the same at a fraction of the
    cost (FZK-Haus: 21 668 triangles instead of 1.16 M). Scenes without elements fall back
    to groups.
    """
    if not scene.elements:
        return inside_closed_groups(scene, points)
    result = np.zeros(len(points), bool)
    triangles, owner = scene.file_triangles, scene.file_face_element
    order = np.argsort(owner, kind="stable")
    bounds = np.searchsorted(owner[order], np.arange(len(scene.elements) + 1))
    for e in range(len(scene.elements)):
        tri = triangles[order[bounds[e]:bounds[e + 1]]]
        if len(tri) == 0:
            continue
        lo, hi = tri.reshape(-1, 3).min(axis=0), tri.reshape(-1, 3).max(axis=0)
        boxed = np.flatnonzero(((points > lo) & (points < hi)).all(axis=1) & ~result)
        result[boxed] = winding_numbers(tri, points[boxed]) > 0.5
    return result
