"""Scanner candidates from the rooms (IfcSpace) of a BIM model.

The rooms come from ``scene.metadata["spaces"]`` (see :mod:`planner.io.ifc`): a floor polygon
in XY and the floor's height per room.

For each room (restricted by ``spec.storeys`` / ``spec.rooms``): grid points at multiples of
``grid_spacing_m`` inside the floor polygon (boundary inclusive) and inside
``area_of_interest`` if given, at ``floor_z_m + scanner_height_m``. A point is dropped when
the first surface straight below the scanner is not within ``FLOOR_TOLERANCE_M`` of the
room's floor (``no_floor``: a stair hole, a void; but a room where fewer than half of
the points that can tell find its floor has no slab in this model, e.g. the slabs live
in the structural model, and its IfcSpace's own bottom is the floor:
``CandidateSet.floor_from_space`` names those rooms, whose points stand on it
wherever nothing lies within head room below, i.e. not over a stair's hole;
``blocked_above_floor``: a table, a stair under the scanner), when it is inside a closed
object (``inside_geometry``), or when the tripod lacks ``clearance_m`` of room around its
axis from that floor to above the scanner (``too_close``, as
:func:`planner.candidates.grid.closer_than` measures it). Order: rooms as in
``metadata["spaces"]``, then grid rows (y, then x).

Each grid point is one candidate, labelled with the first room that holds it. A point on
the wall line two neighbouring rooms share belongs to the first of them only. IfcSpaces may
also overlap (:func:`space_overlaps`): a tool that writes each room once per area scheme
(gross, lettable, usable: Revit's area plans, the Dutch NEN 2580 BVO/VVO/GO), a hall and
its sections, a copy left behind. A point in two overlapping rooms stands in both: the
rooms' report counts it in each (``CandidateSet.also_in`` names the later ones), and says
how much of the later room's floor the earlier one shares.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray
from shapely import Polygon, STRtree, intersects_xy, make_valid

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
from planner.walkgraph import HEADROOM_M

FLOOR_TOLERANCE_M = 0.3
# a room whose floor is found under fewer than this share of its points has no slab
MIN_SLAB_SHARE = 0.5
# two rooms' floors overlap where they share a part wider than this; a part of one outside
# the other no wider than this is the same outline drawn to another wall face (a finish, a
# wall line drawn twice), not floor of its own
OVERLAP_WIDTH_M = 0.05


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
    overlaps = space_overlaps(scene.metadata.get("spaces", []))
    points: list[NDArray[np.float64]] = []
    labels: list[dict[str, str]] = []
    also_in: list[tuple[str, ...]] = []  # per point: the later rooms that hold it too
    held: dict[tuple[float, float, float], int] = {}  # grid point -> its index in points
    # room GlobalId -> the rooms listed before it that hold some of its grid points on
    # their shared wall line, with how many
    on_boundary: dict[str, dict[str, int]] = {}
    for space in spaces:
        gid = space["global_id"]
        overlapping = {str(o["room_global_id"]) for o in overlaps.get(gid, ())}
        room = Polygon(space["polygon"], space.get("holes") or None)
        xy = grid_points_xy(np.asarray(room.bounds, np.float64).reshape(2, 2),
                            spec.grid_spacing_m, room)
        if len(xy):
            xy = xy[intersects_xy(room, xy[:, 0], xy[:, 1])]
        z = float(space["floor_z_m"]) + spec.scanner_height_m
        keep: list[tuple[float, float, float]] = []
        for x, y in xy:
            key = (round(float(x), 6), round(float(y), 6), round(z, 6))
            first = held.get(key)
            if first is None:
                held[key] = len(labels) + len(keep)
                keep.append((x, y, z))
                continue
            holder = labels[first]["room_global_id"]
            if overlapping.intersection((holder, *also_in[first])):
                also_in[first] = (*also_in[first], gid)  # in rooms that overlap: in each
            else:  # on a wall line shared with a neighbour: the neighbour's
                counts = on_boundary.setdefault(gid, {})
                counts[holder] = counts.get(holder, 0) + 1
        if not keep:
            continue
        points.append(np.asarray(keep, np.float64))
        label = {
            "room": str(space["long_name"] or space["name"] or gid),
            "room_name": str(space["name"]),
            "room_global_id": str(gid),
            "storey": str(space["storey"]),
        }
        labels.extend([label] * len(keep))
        also_in.extend([()] * len(keep))
    positions = np.concatenate(points) if points else np.zeros((0, 3))
    considered = len(positions)
    keep_mask = np.ones(considered, bool)
    why = np.full(considered, -1, np.int8)  # per point: index in DROP_REASONS, -1 kept
    if area is not None and considered:
        inside = intersects_xy(area, positions[:, 0], positions[:, 1])
        dropped["outside_area_of_interest"] = int((~inside).sum())
        keep_mask &= inside
        why[~inside] = DROP_REASONS.index("outside_area_of_interest")
    on_floor, floor_z, no_floor = _on_floor(scene, positions, spec, caster, keep_mask,
                                            dropped)
    from_space = _rooms_without_slab(labels, keep_mask, no_floor, on_floor)
    if from_space:
        # the room's own bottom is its floor: the slab lives in another model (structure)
        rescued = np.isin([label["room_global_id"] for label in labels], list(from_space))
        rescued &= no_floor
        # but not over a stair or a void with something within head room below: the hole
        rescued[rescued] = _nothing_below(positions[rescued], spec, caster)
        dropped["no_floor"] -= int(rescued.sum())
        on_floor |= rescued
        no_floor &= ~rescued
    why[keep_mask & ~on_floor] = DROP_REASONS.index("blocked_above_floor")
    why[keep_mask & no_floor] = DROP_REASONS.index("no_floor")
    keep_mask &= on_floor
    keep_mask &= _clear(scene, positions, spec.clearance_m, floor_z, keep_mask, dropped, why)
    rooms = room_report(scene.metadata, spaces, labels, why, spec, on_boundary, also_in,
                        overlaps)
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
        floor_from_space=tuple(from_space.values()), rooms=rooms,
        also_in=tuple(also_in[i] for i in index),
    )


# the words for a room's points left out, by reason (DROP_REASONS)
ROOM_REASONS = {
    "outside_area_of_interest": "outside area_of_interest",
    "no_floor": "no floor: nothing under the scanner within "
                f"{FLOOR_TOLERANCE_M:g} m of the room's floor (a stair hole, a void)",
    "blocked_above_floor": "head room: something between the floor and the scanner (a "
                           "sloping roof or ceiling, a stair, a table)",
    "inside_geometry": "inside an element (a wall, a column)",
    "too_close": "clearance: an obstacle within clearance_m of the tripod",
}


def room_report(metadata: dict[str, Any], chosen: list[dict[str, Any]],
                labels: list[dict[str, str]], why: NDArray[np.int8], spec: PlanSpec,
                on_boundary: dict[str, dict[str, int]], also_in: list[tuple[str, ...]],
                overlaps: dict[str, list[dict[str, object]]]) -> list[dict[str, object]]:
    """``candidates.rooms``: every IfcSpace of the model, in model order, with its storey,
    floor height and area, grid points, candidates and the points left out per reason;
    a room without candidates says why (``reason``): not asked for (``storeys`` /
    ``rooms``), no grid point inside it (smaller than the grid, or its points lie on the
    wall line of a neighbour listed before it, which holds them), or the reason that left
    out most of its points. IfcSpaces whose geometry could not be read
    (``metadata["spaces_unread"]``) are listed too.

    A room whose floor overlaps rooms listed before it (``overlaps``, see
    :func:`space_overlaps`) names them, and counts every point that stands in it, those
    the earlier rooms hold too included; ``shared`` says how many of its grid points and
    candidates are such (their labels name the earlier room), so that a storey's total
    counts each once.

    ``labels`` and ``why`` are per grid point considered (``why``: index in
    ``DROP_REASONS``, -1 for a candidate), ``also_in`` per grid point the later rooms that
    hold it too; ``on_boundary``: per room, the rooms listed before it that hold some of
    its grid points on their shared wall line, with how many.
    """
    wanted = {space["global_id"] for space in chosen}
    grid: dict[str, int] = {}
    kept: dict[str, int] = {}
    shared_grid: dict[str, int] = {}
    shared_kept: dict[str, int] = {}
    left_out: dict[str, dict[str, int]] = {}
    for label, reason, later in zip(labels, why.tolist(), also_in, strict=True):
        for gid in (label["room_global_id"], *later):
            grid[gid] = grid.get(gid, 0) + 1
            if reason < 0:
                kept[gid] = kept.get(gid, 0) + 1
            else:
                counts = left_out.setdefault(gid, {})
                counts[DROP_REASONS[reason]] = counts.get(DROP_REASONS[reason], 0) + 1
        for gid in later:
            shared_grid[gid] = shared_grid.get(gid, 0) + 1
            if reason < 0:
                shared_kept[gid] = shared_kept.get(gid, 0) + 1
    names = {space["global_id"]: _room_name(space) for space in metadata.get("spaces", [])}
    report: list[dict[str, object]] = []
    for space in metadata.get("spaces", []):
        gid = space["global_id"]
        entry: dict[str, object] = {
            "room": str(space["long_name"] or space["name"] or gid),
            "room_name": str(space["name"]), "room_global_id": gid,
            "storey": str(space["storey"]),
            "floor_z_m": round(float(space["floor_z_m"]), 3) + 0.0,
            "area_m2": round(float(space["area_m2"]), 2),
            "grid_points": grid.get(gid, 0), "candidates": kept.get(gid, 0),
        }
        if left_out.get(gid):
            entry["left_out"] = dict(sorted(left_out[gid].items()))
        if overlaps.get(gid):
            entry["overlaps"] = list(overlaps[gid])
            entry["shared"] = {"grid_points": shared_grid.get(gid, 0),
                               "candidates": shared_kept.get(gid, 0)}
        if gid not in wanted:
            entry["reason"] = "not planned: outside the storeys or rooms asked for"
        elif not grid.get(gid):
            holders = on_boundary.get(gid, {})
            entry["reason"] = (
                f"no grid point: its {sum(holders.values())} grid point(s) lie on the wall "
                "line it shares with " + ", ".join(names[h] for h in holders)
                + f", listed before it, which hold{'s' if len(holders) == 1 else ''} them"
                if holders else
                f"no grid point: no multiple of grid_spacing_m ({spec.grid_spacing_m:g} m) "
                "falls inside its floor")
        elif not kept.get(gid):
            counts = left_out[gid]
            entry["reason"] = "; ".join(
                f"{ROOM_REASONS[k]} ({n} of {grid[gid]} grid points)"
                for k, n in sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])))
        report.append(entry)
    for space in metadata.get("spaces_unread", []):
        report.append({
            "room": str(space["long_name"] or space["name"] or space["global_id"]),
            "room_name": str(space["name"]), "room_global_id": str(space["global_id"]),
            "storey": str(space["storey"]), "floor_z_m": None, "area_m2": None,
            "grid_points": 0, "candidates": 0,
            "reason": f"no geometry: {space['reason']}",
        })
    return report


def _room_name(space: dict[str, Any]) -> str:
    """A room as a reason names it: long name, name and GlobalId."""
    name = str(space["long_name"] or space["name"] or "")
    if space["long_name"] and space["name"]:
        name += f" {space['name']}"
    return f"{name} ({space['global_id']})" if name else str(space["global_id"])


# how a room's floor lies to the floor of an earlier room it overlaps
OVERLAP_RELATIONS = {
    "same": "the same floor",
    "inside": "inside the earlier room's floor",
    "contains": "holds the earlier room's floor",
    "partial": "partly on the earlier room's floor",
}


def space_overlaps(spaces: list[dict[str, Any]]) -> dict[str, list[dict[str, object]]]:
    """Per room (GlobalId), the rooms listed before it in ``spaces`` whose floor overlaps
    its own, in list order: ``room``, ``room_name``, ``room_global_id`` of the earlier
    room, ``shared_m2`` (the floor they share), ``share`` (of this room's floor) and
    ``relation`` (``OVERLAP_RELATIONS``). Rooms without such a room are left out.

    Two floors overlap where their floors lie within ``FLOOR_TOLERANCE_M`` in height and
    their outlines share a part wider than ``OVERLAP_WIDTH_M``: neighbours touching along
    a wall line, or overlapping by a sliver of a wall drawn twice, do not; rooms stacked on
    storeys do not. A part of one outside the other no wider than that does not count
    either: a room is ``inside`` (or the ``same`` as) an earlier one whose outline is
    drawn a few centimetres further out.
    """
    polygons = [make_valid(Polygon(s["polygon"], s.get("holes") or None)) for s in spaces]
    result: dict[str, list[dict[str, object]]] = {}
    if len(polygons) < 2:
        return result
    later, earlier = STRtree(polygons).query(polygons, predicate="intersects")
    pairs = sorted((int(i), int(j)) for i, j in zip(later, earlier, strict=True) if j < i)
    for i, j in pairs:
        mine, theirs = spaces[i], spaces[j]
        if abs(float(mine["floor_z_m"]) - float(theirs["floor_z_m"])) > FLOOR_TOLERANCE_M:
            continue
        common = polygons[i].intersection(polygons[j])
        if _thin(common):
            continue
        outside_mine = _thin(polygons[i].difference(polygons[j]))
        outside_theirs = _thin(polygons[j].difference(polygons[i]))
        relation = ("same" if outside_mine and outside_theirs else "inside" if outside_mine
                    else "contains" if outside_theirs else "partial")
        result.setdefault(str(mine["global_id"]), []).append({
            "room": str(theirs["long_name"] or theirs["name"] or theirs["global_id"]),
            "room_name": str(theirs["name"]), "room_global_id": str(theirs["global_id"]),
            "shared_m2": round(float(common.area), 2),
            "share": round(min(float(common.area) / max(polygons[i].area, 1e-12), 1.0), 3),
            "relation": relation,
        })
    return result


def _thin(region: Any) -> bool:
    """``region`` (a shapely geometry) holds no part wider than ``OVERLAP_WIDTH_M``."""
    return bool(region.is_empty or region.buffer(-OVERLAP_WIDTH_M / 2).is_empty)


def rooms_lines(rooms: list[dict[str, object]] | None) -> list[str]:
    """``candidates.rooms`` as one line per storey (CLI, job message): its rooms,
    candidates (and, in plan.json, the stations and the rooms with a station: a room has
    one when a station stands on its floor), the rooms that overlap rooms listed before
    them (their shared candidates and stations are counted once), and each room without
    candidates (:func:`line_name`) with the first words of its reason."""
    if not rooms:
        return []
    storeys: dict[str, list[dict[str, object]]] = {}
    for room in rooms:
        storeys.setdefault(str(room["storey"]) or "no storey", []).append(room)
    lines = []
    for storey, members in storeys.items():
        heights = [float(str(r["floor_z_m"])) for r in members if r["floor_z_m"] is not None]
        at = f" ({min(heights):+.2f} m)" if heights else ""
        planned = [r for r in members if int(str(r["candidates"])) > 0]
        line = (f"{storey}{at}: {len(planned)} of {len(members)} room"
                f"{'s' if len(members) != 1 else ''} with candidates, "
                f"{sum(_own(r, 'candidates') for r in planned)} candidates")
        if all("stations" in r for r in members):  # plan.json: the stations chosen too
            stations = sum(_own(r, "stations") for r in members)
            line += f", {stations} station{'s' if stations != 1 else ''}"
            if stations:
                with_one = sum(1 for r in members if int(str(r["stations"])) > 0)
                line += f" in {with_one} room{'s' if with_one != 1 else ''}"
        overlapping = [r for r in members if r.get("overlaps")]
        if overlapping:
            one = len(overlapping) == 1
            line += (f"; {len(overlapping)} room{'' if one else 's'} overlap"
                     f"{'s' if one else ''} rooms listed before {'it' if one else 'them'} "
                     "(the candidates and stations they share counted once)")
        empty = [r for r in members if int(str(r["candidates"])) == 0]
        if empty:
            line += "; none in " + ", ".join(
                f"{line_name(r, members)} ({str(r['reason']).split(':')[0]})" for r in empty)
        lines.append(line)
    return lines


def line_name(room: dict[str, object], members: list[dict[str, object]]) -> str:
    """A room as its storey's line names it: its long name, and its name (a number) too
    where another room of the storey has the same long name."""
    name, number = str(room["room"]), str(room["room_name"])
    if number and number != name and sum(str(r["room"]) == name for r in members) > 1:
        return f"{name} {number}"
    return name


def _own(room: dict[str, object], key: str) -> int:
    """A room's ``candidates`` or ``stations`` less those it shares with an earlier room
    it overlaps (which counts them)."""
    shared = room.get("shared")
    other = int(str(shared.get(key, 0))) if isinstance(shared, dict) else 0
    return int(str(room[key])) - other


def _rooms_without_slab(labels: list[dict[str, str]], alive: NDArray[np.bool_],
                        no_floor: NDArray[np.bool_], on_floor: NDArray[np.bool_]
                        ) -> dict[str, str]:
    """Rooms without a slab in this model: GlobalId -> room name, in order.

    Of a room's points where the ray down found something to judge by (the room's floor,
    or nothing near it: ``no_floor``; a point blocked above the floor by furniture or a
    stair says nothing about the slab), the share that found the floor decides
    (:func:`slab_less`): a room none of whose points finds its floor, or one where fewer
    than ``MIN_SLAB_SHARE`` do on a storey where, over all its rooms, fewer than that
    share do (the slabs live in the structural model; a stair's top tread under a few
    points does not make a slab). A stair hall with a large hole on a storey whose other
    rooms have their slabs keeps its hole.
    """
    rooms: dict[str, str] = {}
    storey_of: dict[str, str] = {}
    found: dict[str, int] = {}
    missing: dict[str, int] = {}
    for label, live, lacks, on in zip(labels, alive, no_floor, on_floor, strict=True):
        if not live:
            continue
        gid = label["room_global_id"]
        rooms.setdefault(gid, label["room"])
        storey_of[gid] = label["storey"]
        if lacks:
            missing[gid] = missing.get(gid, 0) + 1
        elif on:
            found[gid] = found.get(gid, 0) + 1
    chosen = slab_less({gid: (storey_of[gid], found.get(gid, 0), missing.get(gid, 0))
                        for gid in rooms})
    return {gid: name for gid, name in rooms.items() if gid in chosen}


def slab_less(counts: dict[str, tuple[str, int, int]]) -> set[str]:
    """The rooms without a slab among ``counts``: room -> (storey, points that found the
    floor, points that found nothing near it); see :func:`_rooms_without_slab`."""
    storey_found: dict[str, int] = {}
    storey_missing: dict[str, int] = {}
    for storey, found, missing in counts.values():
        storey_found[storey] = storey_found.get(storey, 0) + found
        storey_missing[storey] = storey_missing.get(storey, 0) + missing
    chosen = set()
    for room, (storey, found, missing) in counts.items():
        if missing == 0:
            continue
        bare_storey = found_share(storey_found[storey], storey_missing[storey]) \
            < MIN_SLAB_SHARE
        if found == 0 or (bare_storey and found_share(found, missing) < MIN_SLAB_SHARE):
            chosen.add(room)
    return chosen


def _nothing_below(positions: NDArray[np.float64], spec: PlanSpec, caster: RayCaster
                   ) -> NDArray[np.bool_]:
    """(C,) bool: nothing lies under the (C, 3) scanner positions' floors within
    ``HEADROOM_M``: a room without a slab stands there on its space's bottom. Where a
    stair climbs or anything else stands below within head room, the floor has a hole."""
    if len(positions) == 0:
        return np.zeros(0, bool)
    _, distance = caster.first_hit(positions, np.tile([0.0, 0.0, -1.0], (len(positions), 1)))
    free: NDArray[np.bool_] = distance > spec.scanner_height_m + HEADROOM_M
    return free


def found_share(found: int, missing: int) -> float:
    """The share of a room's judged points that found its floor."""
    return found / max(found + missing, 1)


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
           floor_z: NDArray[np.float64], alive: NDArray[np.bool_], dropped: dict[str, int],
           why: NDArray[np.int8] | None = None) -> NDArray[np.bool_]:
    """(C,) bool: not inside an element's solid, and the tripod has ``clearance_m`` of room.

    The room is measured as :func:`planner.candidates.grid.closer_than` does, from the floor
    found under the scanner. ``why`` (C,), when given, gets the reason (index in
    ``DROP_REASONS``) of each point left out here.
    """
    ok = np.ones(len(positions), bool)
    index = np.flatnonzero(alive)
    if len(index) == 0:
        return ok
    inside = inside_elements(scene, positions[index])
    dropped["inside_geometry"] += int(inside.sum())
    ok[index[inside]] = False
    if why is not None:
        why[index[inside]] = DROP_REASONS.index("inside_geometry")
    index = index[~inside]
    near = closer_than(scene, positions[index], clearance_m, floor_z[index])
    dropped["too_close"] += int(near.sum())
    ok[index[near]] = False
    if why is not None:
        why[index[near]] = DROP_REASONS.index("too_close")
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
