"""Where a person with a tripod can walk: a graph of floor samples built from the model.

Floor samples: a grid of vertical rays (``WALK_GRID_M`` apart) is cast down through the
whole model, level after level; a hit on a near-horizontal face (``|n_z| >= cos 35 deg``)
with ``HEADROOM_M`` free above it is a node. Two nodes in neighbouring grid columns (8
neighbours) are linked when their floor heights differ by at most ``STEP_M`` (so stairs join
storeys without any IFC semantics) and the straight segment between them at
``KNEE_HEIGHT_M`` above the floor hits nothing. The link costs its 3D length.

Array letters: N nodes, E links.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from planner.method.visibility import RayCaster
from planner.scene import Scene

WALK_GRID_M = 0.25  # floor sample spacing; finer than a stair tread (~0.26-0.30 m)
MAX_COLUMNS = 400_000  # the grid coarsens on very large models to stay within this
KNEE_HEIGHT_M = 0.5  # the link must be free at this height above the floor
# largest floor height change between neighbouring samples: a stair riser is <= 0.19 m in
# most building codes; two risers can fall between samples 0.25 m apart on steep stairs
STEP_M = 0.4
HEADROOM_M = 1.8  # free height a person needs above a floor sample
_MIN_FLOOR_NZ = math.cos(math.radians(35.0))  # steeper than 35 deg is a wall, not a floor
_LINKS_PER_BLOCK = 1 << 18
_MAX_LEVELS = 8  # floors stacked over one grid column (storeys, stairs, roofs)
_EPS_M = 1e-3


# IFC classes modelled closed that a survey crew opens: people walk and scanners see through
OPEN_DOOR_CLASSES = ("IfcDoor",)


def door_faces(scene: Scene) -> NDArray[np.bool_]:
    """(F,) bool: faces of IFC doors (all False for a mesh without elements)."""
    if not scene.elements:
        return np.zeros(scene.n_faces, bool)
    door = np.array([e.ifc_class in OPEN_DOOR_CLASSES for e in scene.elements] + [False])
    result: NDArray[np.bool_] = door[scene.face_element]  # -1 picks the trailing False
    return result


@dataclass(frozen=True, eq=False)
class WalkGraph:
    """Floor samples and the links between them.

    Attributes
    ----------
    floor_xyz : (N, 3) float64, floor points (metres)
    links : (N, N) CSR float64, symmetric, link length in metres
    """

    floor_xyz: NDArray[np.float64]
    links: sp.csr_matrix
    grid_m: float

    @property
    def n_nodes(self) -> int:
        return len(self.floor_xyz)


def _floor_samples(scene: Scene, caster: RayCaster, grid_m: float
                   ) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.int64]]:
    """(N, 3) floor points and their (N,) grid column indices ix, iy."""
    lo, hi = scene.bounds
    nx = math.floor((hi[0] - lo[0]) / grid_m) + 1
    ny = math.floor((hi[1] - lo[1]) / grid_m) + 1
    grid_x, grid_y = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    ix, iy = grid_x.ravel(), grid_y.ravel()
    xy = np.stack([lo[0] + (ix + 0.5) * grid_m, lo[1] + (iy + 0.5) * grid_m], axis=1)
    z = np.full(len(xy), hi[2] + 1.0)
    down = np.tile([0.0, 0.0, -1.0], (len(xy), 1))
    up = np.tile([0.0, 0.0, 1.0], (len(xy), 1))
    points: list[NDArray[np.float64]] = []
    columns: list[NDArray[np.int64]] = []
    alive = np.arange(len(xy))
    for _ in range(_MAX_LEVELS):
        origins = np.column_stack([xy[alive], z[alive]])
        face, distance = caster.first_hit(origins, down[alive])
        hit = face >= 0
        alive, face, distance, origins = alive[hit], face[hit], distance[hit], origins[hit]
        if len(alive) == 0:
            break
        floor = origins.copy()
        floor[:, 2] -= distance
        horizontal = np.abs(scene.normals[face, 2]) >= _MIN_FLOOR_NZ
        above = floor + np.array([0.0, 0.0, _EPS_M * 10])
        _, free = caster.first_hit(above, up[: len(above)])
        keep = horizontal & (free >= HEADROOM_M)
        points.append(floor[keep])
        columns.append(alive[keep])
        z[alive] = floor[:, 2] - _EPS_M  # continue below this surface
    if not points:
        return np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0, np.int64)
    floor_xyz = np.concatenate(points)
    column = np.concatenate(columns)
    order = np.lexsort((floor_xyz[:, 2], column))  # by column, then height: deterministic
    floor_xyz, column = floor_xyz[order], column[order]
    return floor_xyz, ix[column], iy[column]


def segment_free(caster: RayCaster, a: NDArray[np.float64], b: NDArray[np.float64]
                 ) -> NDArray[np.bool_]:
    """(K,) bool: the segments (K, 3) a -> (K, 3) b hit no face."""
    delta = b - a
    length = np.linalg.norm(delta, axis=1)
    free = np.ones(len(a), bool)
    moving = length > _EPS_M
    if moving.any():
        direction = delta[moving] / length[moving, None]
        _, distance = caster.first_hit(a[moving], direction)
        free[moving] = distance > length[moving]
    return free


def build_walk_graph(scene: Scene, caster: RayCaster) -> WalkGraph:
    """The walk graph of ``scene`` (see the module docstring)."""
    lo, hi = scene.bounds
    columns = ((hi[0] - lo[0]) / WALK_GRID_M + 1) * ((hi[1] - lo[1]) / WALK_GRID_M + 1)
    grid_m = WALK_GRID_M * max(1.0, math.sqrt(columns / MAX_COLUMNS))
    floor_xyz, ix, iy = _floor_samples(scene, caster, grid_m)
    n = len(floor_xyz)
    # nodes by grid column: a neighbour column's nodes are found by a sorted-key search
    width = int(iy.max()) + 2 if n else 1
    key = ix * width + iy
    rows: list[NDArray[np.int64]] = []
    cols: list[NDArray[np.int64]] = []
    for dx, dy in ((1, 0), (0, 1), (1, 1), (1, -1)):
        target = (ix + dx) * width + (iy + dy)
        start = np.searchsorted(key, target, side="left")
        stop = np.searchsorted(key, target, side="right")
        counts = stop - start
        a = np.repeat(np.arange(n), counts)
        b = (np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
             + np.repeat(start, counts))
        close = np.abs(floor_xyz[a, 2] - floor_xyz[b, 2]) <= STEP_M
        rows.append(a[close])
        cols.append(b[close])
    a = np.concatenate(rows) if rows else np.zeros(0, np.int64)
    b = np.concatenate(cols) if cols else np.zeros(0, np.int64)
    knee = np.array([0.0, 0.0, KNEE_HEIGHT_M])
    # the links' knee-high segments, both ways, a block at a time: Embree's hit record is
    # some 50 bytes a ray, and a large floor has millions of links
    free = np.ones(len(a), bool)
    for first in range(0, len(a), _LINKS_PER_BLOCK):
        block = slice(first, first + _LINKS_PER_BLOCK)
        from_a, from_b = floor_xyz[a[block]] + knee, floor_xyz[b[block]] + knee
        free[block] = segment_free(caster, from_a, from_b) & segment_free(caster, from_b, from_a)
    a, b = a[free], b[free]
    length = np.linalg.norm(floor_xyz[a] - floor_xyz[b], axis=1)
    links = sp.coo_matrix((np.concatenate([length, length]),
                           (np.concatenate([a, b]), np.concatenate([b, a]))),
                          shape=(n, n)).tocsr()
    return WalkGraph(floor_xyz=floor_xyz, links=links, grid_m=grid_m)
