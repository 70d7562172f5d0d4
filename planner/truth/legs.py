"""No leg through a wall: every leg of a written route checked against the model itself,
independently of the walk graph that made it.

A person walks a leg upright: from the knee to the head, the space over the floor the leg
walks on must be free. The route writes each leg as a polyline of points at
``KNEE_HEIGHT_M`` above its floor (:mod:`planner.survey.route`); here every segment of it
is swept at ``SWEEP_HEIGHTS_M`` above that floor (the floor under each end is its point less
the knee height, and a segment on a stair rises with it), each height as one segment cast
both ways against every face of the model but the doors. A segment whose ray meets a face
before its other end is *blocked*, and its leg goes *through a wall* (or a window, a
column, a stair's underside or a slab's edge at head height: anything a person cannot
walk through).

Doors are excepted as the survey opens them: the ``door`` mask (IFC doors by class; for a
plain mesh exported from an IFC model the ground truth from the IFC: its doors, and its
windows that come down to the floor, since a plain mesh cannot tell a French window from a
glazed door and its door rule opens both, see ``tests.planner.buildings.
plain_mesh_doorways``; a window with a parapet, a wall or a stair still blocks). Nothing
of the walk graph is used: not its floor samples, links or room floors, only the legs'
points and the model's faces, so a defect in the graph's links shows here.

Array letters: F faces, K segments, H heights.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from planner.io.orientation import scene_rotation, to_plan
from planner.rays import RayCaster, make_ray_caster
from planner.scene import Scene
from planner.walkgraph import KNEE_HEIGHT_M, UPRIGHT_HEIGHTS_M

# the heights above the floor a walking person fills, knee to head: the same definition of
# walking upright as the walk graph's (its links are tested at these heights too); only the
# rays are cast here anew, against the model, not the graph's links
SWEEP_HEIGHTS_M = UPRIGHT_HEIGHTS_M
_MIN_SEGMENT_M = 1e-3  # shorter segments (a station's foot on its own node) are not cast
_SEGMENTS_PER_BLOCK = 1 << 16  # rays per Embree call: bounds the hit records
_GRAZING = 1e-3  # |cos| of a face's normal to the segment below which the face is grazed
_GRAZE_STEP_M = 1e-3  # past a grazed face, the ray goes on from this far beyond the hit
_MAX_GRAZES = 8  # grazed faces passed along one segment; past that many it counts as free


@dataclass(frozen=True)
class BlockedLeg:
    """A leg that does not keep free space: the first of its segments that is blocked.

    ``start`` / ``end``: the leg's station ids (``start`` None from the route's start);
    ``at_m``: (x, y, z) of the hit, on the segment at ``height_m`` above the floor;
    ``face``: the face hit (scene face id).
    """

    index: int  # the leg's place in the route, from 0
    start: int | None
    end: int
    height_m: float
    at_m: tuple[float, float, float]
    face: int

    def to_dict(self) -> dict[str, Any]:
        return {"leg": self.index, "from": self.start, "to": self.end,
                "height_m": round(self.height_m, 3),
                "at": [round(v, 3) for v in self.at_m], "face": self.face}


def legs_through_walls(scene: Scene, door: NDArray[np.bool_],
                       legs: Sequence[dict[str, Any]],
                       heights_m: Iterable[float] = SWEEP_HEIGHTS_M,
                       caster: RayCaster | None = None) -> list[BlockedLeg]:
    """The legs whose path does not keep free space from knee to head height.

    ``scene``: the model (plan frame); ``door``: (F,) bool, its door faces, which do not
    block; ``legs``: the route's legs as plan.json writes them (``from``, ``to`` and
    ``path``, (P, 3) points at knee height, in the plan frame: see :func:`legs_in_plan`);
    ``heights_m``: above the floor, each swept; ``caster``: a first-hit caster over the
    faces that are not doors, when one is made already. Legs in route order, each once
    (its first blocked segment, lowest height first).
    """
    heights = np.asarray(sorted(heights_m), np.float64)  # (H,)
    starts: list[NDArray[np.float64]] = []
    ends: list[NDArray[np.float64]] = []
    owner: list[NDArray[np.int64]] = []
    for index, leg in enumerate(legs):
        path = np.asarray(leg["path"], np.float64).reshape(-1, 3)
        if len(path) < 2:
            continue
        a, b = path[:-1], path[1:]
        moving = np.linalg.norm(b - a, axis=1) > _MIN_SEGMENT_M
        starts.append(a[moving])
        ends.append(b[moving])
        owner.append(np.full(int(moving.sum()), index, np.int64))
    if not starts or not sum(len(s) for s in starts):
        return []
    a, b = np.concatenate(starts), np.concatenate(ends)  # (K, 3) each, at knee height
    leg_of = np.concatenate(owner)  # (K,)
    if caster is None:
        caster = make_ray_caster(scene, ~np.asarray(door, bool))
    lift = np.zeros((len(heights), 1, 3))
    lift[:, 0, 2] = heights - KNEE_HEIGHT_M
    from_a = (a[None] + lift).reshape(-1, 3)  # (H * K, 3), height by height
    from_b = (b[None] + lift).reshape(-1, 3)
    face, hit_at = _blocked(caster, scene.normals_of, from_a, from_b)
    back_face, back_at = _blocked(caster, scene.normals_of, from_b, from_a)
    use_back = (face < 0) & (back_face >= 0)
    face = np.where(use_back, back_face, face)
    hit_at[use_back] = back_at[use_back]
    blocked = np.flatnonzero(face >= 0)
    if len(blocked) == 0:
        return []
    k = len(a)
    segment, level = blocked % k, blocked // k
    # per leg, its first blocked segment along the path, the lowest height there
    order = np.lexsort((level, segment, leg_of[segment]))
    result: list[BlockedLeg] = []
    seen: set[int] = set()
    for i in order:
        index = int(leg_of[segment[i]])
        if index in seen:
            continue
        seen.add(index)
        leg = legs[index]
        point = hit_at[blocked[i]]
        result.append(BlockedLeg(index, leg.get("from"), int(leg["to"]),
                                 float(heights[level[i]]),
                                 (float(point[0]), float(point[1]), float(point[2])),
                                 int(face[blocked[i]])))
    return result


def _blocked(caster: RayCaster,
             normals_of: Callable[[NDArray[np.int64]], NDArray[np.float64]],
             a: NDArray[np.float64], b: NDArray[np.float64]
             ) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """The face each segment (K, 3) a -> (K, 3) b crosses first, -1 when free, and the
    (K, 3) hit points (NaN when free). A face in the segment's own plane (``normals_of``:
    (k,) faces -> (k, 3) unit normals; within ``_GRAZING`` of square to the normal) is
    grazed, not crossed: the ray goes on past it (a path along a wall's face, or along a
    mitred corner's plane, where float32 rays report a hit anywhere on the line)."""
    face = np.full(len(a), -1, np.int64)
    at = np.full((len(a), 3), np.nan)
    delta = b - a
    length = np.linalg.norm(delta, axis=1)
    for first in range(0, len(a), _SEGMENTS_PER_BLOCK):
        block = np.arange(first, min(first + _SEGMENTS_PER_BLOCK, len(a)))
        direction = delta[block] / length[block, None]
        origin = a[block].copy()
        travelled = np.zeros(len(block))
        todo = np.arange(len(block))
        for _ in range(_MAX_GRAZES + 1):
            hit_face, distance = caster.first_hit(origin[todo], direction[todo])
            inside = (hit_face >= 0) & (travelled[todo] + distance < length[block[todo]])
            grazed = np.zeros(len(todo), bool)
            grazed[inside] = np.abs(np.einsum(
                "kc,kc->k", normals_of(hit_face[inside]), direction[todo[inside]])) < _GRAZING
            crossed = inside & ~grazed
            done = todo[crossed]
            face[block[done]] = hit_face[crossed]
            at[block[done]] = origin[done] + distance[crossed, None] * direction[done]
            step = distance[grazed] + _GRAZE_STEP_M
            origin[todo[grazed]] += step[:, None] * direction[todo[grazed]]
            travelled[todo[grazed]] += step
            todo = todo[grazed]
            if len(todo) == 0:
                break
    return face, at


def legs_in_plan(scene: Scene, route: dict[str, Any]) -> list[dict[str, Any]]:
    """plan.json's ``route["legs"]`` (paths in the model's coordinates) with their paths in
    the scene's plan frame, as :func:`legs_through_walls` takes them."""
    rotation = scene_rotation(scene.metadata)
    legs = []
    for leg in route.get("legs", []):
        path = np.asarray(leg["path"], np.float64).reshape(-1, 3)
        legs.append({**leg, "path": to_plan(rotation, path).tolist() if len(path) else []})
    return legs
