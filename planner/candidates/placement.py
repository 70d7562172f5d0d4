"""Where a tripod really stands: placement tolerance and instrument heights.

A plan's station is a point; on site the tripod lands up to ``placement_tolerance_m`` off it
(a cable, a pallet, a door that opens the other way) and its head stands at the height the
crew sets. This module gives

- :func:`offsets_m`: the displaced setups evaluated for a position: the position itself and
  ``OFFSET_DIRECTIONS`` = 8 points on the circle of radius ``placement_tolerance_m`` around
  it (every 45 degrees from +X, counter-clockwise). On hall-full, 16 directions and an inner
  ring at half the radius change no station's worst loss by more than the figures in the
  README (``benchmarks/tolerance_cost.py`` prints the comparison);
- :func:`displaced_positions`: those setups put on the floor: a displaced setup stands on
  the floor under it when that floor is flat (as a generated candidate's, 30 degrees), lies
  within ``SAME_FLOOR_M`` of the position's own floor (the gap that separates two levels
  in :mod:`planner.candidates.grid`: a table top or a stair step is another floor), has
  head room up to ``clearance_m`` above the head, and passes the candidates' clearance and
  inside-an-object tests (:func:`planner.candidates.grid.unclear_mask`). Its head is at the
  position's own height above the floor. Setups that cannot stand are not evaluated: no crew
  sets up there (which faces they keep: :mod:`planner.visibility.robust`);
- :func:`at_heights`: generated candidates at each of ``scanner_heights_m`` over the same
  floor points, as separate candidates, height after height.

Array letters: N positions, K displaced setups per position (K = 9, the first the position
itself), F faces.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from planner.candidates.grid import (
    _LEVEL_GAP_M,
    _MAX_FLOOR_SLOPE_DEG,
    DROP_REASONS,
    CandidateSet,
    unclear_mask,
)
from planner.errors import NoCandidatesError
from planner.parameters import PlanSpec
from planner.rays import RayCaster
from planner.scene import Scene

OFFSET_DIRECTIONS = 8
# a displaced setup stands on the position's own floor when the two floors are this close
SAME_FLOOR_M = _LEVEL_GAP_M
# the head room is tested from this far above the floor, as for generated candidates
_LIFT_M = 0.01


def offsets_m(tolerance_m: float, directions: int = OFFSET_DIRECTIONS,
              rings: tuple[float, ...] = (1.0,)) -> NDArray[np.float64]:
    """(K, 2) horizontal offsets: (0, 0), then ``directions`` points on each ring (a
    fraction of ``tolerance_m``), every 360 / ``directions`` degrees from +X."""
    angles = 2 * math.pi * np.arange(directions) / directions
    circle = np.column_stack([np.cos(angles), np.sin(angles)])
    rows = [np.zeros((1, 2))] + [circle * tolerance_m * ring for ring in rings]
    offsets = np.concatenate(rows)
    offsets[np.abs(offsets) < 1e-12] = 0.0  # cos 90 degrees is 6e-17: no "-0.0"
    return offsets


@dataclass(frozen=True, eq=False)
class Displaced:
    """The displaced setups of N positions.

    Attributes
    ----------
    offsets_m : (K, 2) float64, horizontal offsets; row 0 is (0, 0), the position itself
    positions : (N, K, 3) float64, the scanner's head at each setup
    valid : (N, K) bool, the setup stands on the position's floor with room for a tripod
        (row 0 always)
    """

    offsets_m: NDArray[np.float64]
    positions: NDArray[np.float64]
    valid: NDArray[np.bool_]


def displaced_positions(scene: Scene, positions: NDArray[np.float64], tolerance_m: float,
                        clearance_m: float, caster: RayCaster,
                        offsets: NDArray[np.float64] | None = None) -> Displaced:
    """The setups of :func:`offsets_m` around each of the (N, 3) ``positions``, on their
    floors (see the module docstring). A position with no floor under it keeps only
    itself."""
    offsets = offsets_m(tolerance_m) if offsets is None else offsets
    points = np.asarray(positions, np.float64).reshape(-1, 3)
    n, k = len(points), len(offsets)
    down = np.tile([0.0, 0.0, -1.0], (n, 1))
    face, distance = caster.first_hit(points, down)
    has_floor = face >= 0
    floor_z = points[:, 2] - distance  # (N,) -inf where there is none
    height = np.where(has_floor, points[:, 2] - floor_z, 0.0)  # (N,) head above floor
    steep = math.cos(math.radians(_MAX_FLOOR_SLOPE_DEG))
    moved = np.repeat(points[None], k, axis=0)  # (K, N, 3)
    valid = np.zeros((k, n), bool)
    valid[0] = True
    for at in range(1, k):
        heads = points + np.array([offsets[at, 0], offsets[at, 1], 0.0])
        hit, drop = caster.first_hit(heads, down)
        ok = has_floor & (hit >= 0)
        ok[ok] = np.abs(scene.normals_of(hit[ok])[:, 2]) >= steep
        new_floor = heads[:, 2] - drop
        ok[ok] = np.abs(new_floor[ok] - floor_z[ok]) <= SAME_FLOOR_M  # (no -inf - -inf)
        heads[:, 2] = np.where(ok, new_floor + height, heads[:, 2])
        # nothing between just above the floor and clearance_m above the head
        index = np.flatnonzero(ok)
        start = np.column_stack([heads[index, :2], new_floor[index] + _LIFT_M])
        _, room = caster.first_hit(start, -down[:len(index)])
        ok[index] = room > height[index] + clearance_m - _LIFT_M
        moved[at] = heads
        valid[at] = ok
    # inside an object, or an obstacle within clearance_m of the tripod: one pass for all
    flat_points = moved[1:].reshape(-1, 3)
    flat_valid = valid[1:].reshape(-1)
    index = np.flatnonzero(flat_valid)
    if len(index):
        floors = flat_points[index, 2] - np.tile(height, k - 1)[index]
        clear = unclear_mask(scene, flat_points[index], clearance_m,
                             dict.fromkeys(DROP_REASONS, 0), floors)
        flat_valid[index] = clear
        valid[1:] = flat_valid.reshape(k - 1, n)
    return Displaced(offsets_m=offsets, positions=np.ascontiguousarray(moved.transpose(1, 0, 2)),
                     valid=np.ascontiguousarray(valid.T))


def at_heights(spec: PlanSpec, generate: Callable[[PlanSpec], CandidateSet]) -> CandidateSet:
    """Generated candidates at every height of ``spec.heights_m``, height after height
    (``generate`` places them with ``scanner_height_m`` set to each), with their heights.

    The floor points are the same for every height; a point may drop out at one height and
    not another (a shelf over the head at 1.8 m, not at 1.2 m). A height that leaves no
    candidate at all is skipped when another does.
    """
    sets: list[CandidateSet] = []
    heights: list[float] = []
    failure: NoCandidatesError | None = None
    for height in spec.heights_m:
        try:
            sets.append(generate(dataclasses.replace(spec, scanner_height_m=height)))
        except NoCandidatesError as exc:
            failure = failure or exc
            continue
        heights.append(height)
    if not sets:
        assert failure is not None
        raise failure
    heights_m = np.concatenate([np.full(len(s), h) for s, h in zip(sets, heights, strict=True)])
    if len(sets) == 1:
        return dataclasses.replace(sets[0], heights_m=heights_m)
    dropped = {reason: sum(s.dropped.get(reason, 0) for s in sets) for reason in DROP_REASONS}
    levels: list[dict[str, object]] | None = None
    if any(s.levels is not None for s in sets):
        merged: dict[str, dict[str, object]] = {}
        for s in sets:
            for level in s.levels or ():
                entry = merged.setdefault(str(level["name"]), {**level, "candidates": 0})
                entry["candidates"] = int(str(entry["candidates"])) + int(
                    str(level["candidates"]))
        levels = sorted(merged.values(), key=lambda level: float(str(level["floor_z_m"])))
    spaces = sorted({name for s in sets for name in s.floor_from_space or ()})
    return CandidateSet(
        positions=np.concatenate([s.positions for s in sets]),
        source=sets[0].source, considered=sum(s.considered for s in sets), dropped=dropped,
        labels=tuple(label for s in sets for label in s.labels)
        if all(s.labels for s in sets) else (),
        levels=levels,
        floor_from_space=tuple(spaces) if any(s.floor_from_space is not None for s in sets)
        else None,
        heights_m=heights_m, rooms=_merged_rooms(sets),
        also_in=tuple(rooms for s in sets for rooms in s.also_in)
        if all(s.also_in for s in sets) else ())


def _merged_rooms(sets: list[CandidateSet]) -> list[dict[str, object]] | None:
    """``candidates.rooms`` over several heights: grid points, candidates, the points left
    out and those shared with an earlier, overlapping room summed room by room; a room
    keeps a reason only while no height gives it a candidate (the first height's
    reason)."""
    if all(s.rooms is None for s in sets):
        return None
    merged: dict[str, dict[str, object]] = {}
    left_out: dict[str, dict[str, int]] = {}
    for s in sets:
        for room in s.rooms or ():
            gid = str(room["room_global_id"])
            counts = left_out.setdefault(gid, {})
            for reason, count in _counts(room.get("left_out")).items():
                counts[reason] = counts.get(reason, 0) + count
            entry = merged.get(gid)
            if entry is None:
                merged[gid] = dict(room)
                continue
            for key in ("grid_points", "candidates"):
                entry[key] = int(str(entry[key])) + int(str(room[key]))
            if "shared" in room:  # the points an earlier, overlapping room counts too
                entry["shared"] = {key: int(v) + _counts(room["shared"]).get(key, 0)
                                   for key, v in _counts(entry["shared"]).items()}
    rooms = list(merged.values())
    for room in rooms:
        counts = left_out[str(room["room_global_id"])]
        if counts:
            room["left_out"] = dict(sorted(counts.items()))
        if int(str(room["candidates"])) > 0:
            room.pop("reason", None)
    return rooms


def _counts(value: object) -> dict[str, int]:
    """A room's ``left_out`` counts (an absent one is empty)."""
    return {str(k): int(v) for k, v in value.items()} if isinstance(value, dict) else {}
