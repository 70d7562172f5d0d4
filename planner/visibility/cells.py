"""A uniform grid of points (face centroids, bundle centres) for "what lies within reach".

Cubes of side ``cell_m``: with cells at least the reach wide, whatever lies within reach
of a point is in the 3 x 3 x 3 cells around the point's own (:func:`cells_around`, used by
the bundles, :mod:`planner.visibility.bundles`); the pair search (:mod:`planner.visibility.pairs`)
makes cells a fraction of the reach and keeps those that come within reach.

The points are given as :class:`Points`: rows of coordinates, or the centroids of a
scene's faces, computed where a kernel reads them (a model's centroids are not kept).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

from planner.scene import Scene, centroids_into, face_centroid

_NO_CORNERS = np.zeros((0, 3), np.int32)


@dataclass(frozen=True)
class Points:
    """(N, 3) points: the rows of ``xyz`` when ``corners`` is empty, else the centroids
    of the (N, 3) ``corners`` (a scene's faces) over the vertices ``xyz``."""

    xyz: NDArray[np.float64]
    corners: NDArray[np.int32]

    @classmethod
    def rows(cls, xyz: NDArray[np.float64]) -> Points:
        return cls(np.ascontiguousarray(xyz, np.float64), _NO_CORNERS)

    @classmethod
    def face_centroids(cls, scene: Scene) -> Points:
        return cls(scene.vertices, scene.faces)

    def at(self, which: NDArray[np.integer[Any]]) -> NDArray[np.float64]:
        """(k, 3) float64, the points ``which`` (k,)."""
        index = np.ascontiguousarray(which, np.int64)
        if len(self.corners) == 0:
            rows: NDArray[np.float64] = self.xyz[index]
            return rows
        out = np.empty((len(index), 3))
        centroids_into(self.xyz, self.corners, index, out)
        return out


@numba.njit(nogil=True, cache=True, inline="always")
def point_xyz(xyz: NDArray[np.float64], corners: NDArray[np.int32], i: int
              ) -> tuple[float, float, float]:
    """Point ``i`` of :class:`Points` (``xyz``, ``corners``)."""
    if corners.shape[0] == 0:
        return xyz[i, 0], xyz[i, 1], xyz[i, 2]
    return face_centroid(xyz, corners, i)


@numba.njit(nogil=True, cache=True)
def cells_around(px: float, py: float, pz: float, grid_origin: NDArray[np.float64],
                 cell_m: float, grid_dims: NDArray[np.int64], out: NDArray[np.int64]) -> int:
    """Write the ids of the grid cells in the 3 x 3 x 3 block around the point's cell (those
    inside the grid) into ``out``, in increasing order; returns how many."""
    cx = int(np.floor((px - grid_origin[0]) / cell_m))
    cy = int(np.floor((py - grid_origin[1]) / cell_m))
    cz = int(np.floor((pz - grid_origin[2]) / cell_m))
    n = 0
    for gx in range(max(cx - 1, 0), min(cx + 2, grid_dims[0])):
        for gy in range(max(cy - 1, 0), min(cy + 2, grid_dims[1])):
            for gz in range(max(cz - 1, 0), min(cz + 2, grid_dims[2])):
                out[n] = (gx * grid_dims[1] + gy) * grid_dims[2] + gz
                n += 1
    return n


@numba.njit(nogil=True, cache=True)
def cell_members(cell_of: NDArray[np.int32], n_cells: int
                 ) -> tuple[NDArray[np.int64], NDArray[np.int32]]:
    """Counting sort of the n points by cell: (n_cells + 1,) starts and (n,) members, the
    points of each cell in increasing order (4 bytes a point, no (n,) int64 argsort)."""
    return _stable_by(cell_of, 0, n_cells, _IN_ORDER)


# no order given to _stable_by: the points in increasing order
_IN_ORDER = np.zeros(0, np.int32)


@numba.njit(nogil=True, cache=True)
def _stable_by(key: NDArray[np.int32], shift: int, n_keys: int, order: NDArray[np.int32]
               ) -> tuple[NDArray[np.int64], NDArray[np.int32]]:
    """Counting sort of the n points by ``key`` + ``shift`` (0 to ``n_keys`` - 1), those of
    one key in the (n,) ``order`` given (empty: increasing): (n_keys + 1,) starts and (n,)
    points."""
    n = key.shape[0]
    start = np.zeros(n_keys + 1, np.int64)
    for i in range(n):
        start[key[i] + shift + 1] += 1
    for k in range(n_keys):
        start[k + 1] += start[k]
    fill = start[:-1].copy()
    points = np.empty(n, np.int32)
    for j in range(n):
        i = order[j] if order.shape[0] else j
        points[fill[key[i] + shift]] = i
        fill[key[i] + shift] += 1
    return start, points


@numba.njit(nogil=True, cache=True)
def grouped_members(cell_of: NDArray[np.int32], group: NDArray[np.int32], n_groups: int,
                    n_cells: int, most_per_run: int
                    ) -> tuple[NDArray[np.int64], NDArray[np.int32], NDArray[np.int64],
                               NDArray[np.int64], NDArray[np.int32]]:
    """:func:`cell_members` with each cell's points ordered by their ``group`` (n,) (-1:
    in none, first), then by position, and cut into *runs*: the points of one cell and one
    group, one after the other, at most ``most_per_run`` of them (a cell's points in no
    group make runs of that many).

    Returns the (n_cells + 1,) starts and (n,) members as :func:`cell_members`, the
    (n_cells + 1,) first run of each cell, the (R + 1,) first member of each run and the
    (R,) group of each run. Two counting sorts (by group, then stably by cell), no argsort.
    """
    _, by_group = _stable_by(group, 1, n_groups + 1, _IN_ORDER)
    start, members = _stable_by(cell_of, 0, n_cells, by_group)
    # the runs: a new one where the cell or the group changes, or the run is full
    # (counted, then written)
    no_int64, no_int32 = np.zeros(0, np.int64), np.zeros(0, np.int32)
    n_runs = _runs(start, members, group, most_per_run, no_int64, no_int64, no_int32, False)
    cell_runs = np.zeros(n_cells + 1, np.int64)
    run_first = np.empty(n_runs + 1, np.int64)
    run_group = np.empty(n_runs, np.int32)
    _runs(start, members, group, most_per_run, cell_runs, run_first, run_group, True)
    return start, members, cell_runs, run_first, run_group


@numba.njit(nogil=True, cache=True)
def _runs(start: NDArray[np.int64], members: NDArray[np.int32], group: NDArray[np.int32],
          most_per_run: int, cell_runs: NDArray[np.int64], run_first: NDArray[np.int64],
          run_group: NDArray[np.int32], write: bool) -> int:
    """Count the runs of :func:`grouped_members` and, with ``write``, fill their arrays."""
    n_cells = start.shape[0] - 1
    r = 0
    for c in range(n_cells):
        if write:
            cell_runs[c] = r
        opened = start[c]
        for m in range(start[c], start[c + 1]):
            if (m == start[c] or group[members[m]] != group[members[m - 1]]
                    or m - opened == most_per_run):
                opened = m
                if write:
                    run_first[r] = m
                    run_group[r] = group[members[m]]
                r += 1
    if write:
        cell_runs[n_cells] = r
        run_first[r] = members.shape[0]
    return r


@numba.njit(nogil=True, cache=True)
def _bounds(xyz: NDArray[np.float64], corners: NDArray[np.int32], subset: NDArray[np.int32],
            low: NDArray[np.float64], high: NDArray[np.float64]) -> None:
    """The lowest and highest coordinate of the (n,) ``subset`` of the points (``xyz``,
    ``corners``: :class:`Points`), per axis, into the (3,) ``low`` and ``high`` (one
    pass, no (n, 3) gathered copy)."""
    low[0], low[1], low[2] = point_xyz(xyz, corners, subset[0])
    high[:] = low
    for i in range(subset.shape[0]):
        x, y, z = point_xyz(xyz, corners, subset[i])
        low[0], high[0] = min(low[0], x), max(high[0], x)
        low[1], high[1] = min(low[1], y), max(high[1], y)
        low[2], high[2] = min(low[2], z), max(high[2], z)


@numba.njit(nogil=True, cache=True)
def _cells_of(xyz: NDArray[np.float64], corners: NDArray[np.int32],
              subset: NDArray[np.int32], low: NDArray[np.float64], cell_m: float,
              grid_dims: NDArray[np.int64], out: NDArray[np.int32]) -> None:
    """The cell of each point of the (n,) ``subset`` (of :class:`Points` ``xyz``,
    ``corners``) into ``out``: along each axis floor((x - low) / cell_m), at most the
    last cell."""
    point = np.empty(3)
    for i in range(subset.shape[0]):
        point[0], point[1], point[2] = point_xyz(xyz, corners, subset[i])
        cell = 0
        for axis in range(3):
            index = min(int(np.floor((point[axis] - low[axis]) / cell_m)),
                        grid_dims[axis] - 1)
            cell = cell * grid_dims[axis] + index
        out[i] = cell


# the longest run of a RunGrid: a part of a pair search holds whole runs, so this bounds the
# part's tests beyond the most asked (a cell's faces in no bundle would be one long run)
MOST_PER_RUN = 512
# most cells a grid has (a cell is at least the reach wide): bounds the starts
MAX_CELLS = 1 << 21


@dataclass(frozen=True)
class PointGrid:
    """Some of the (N, 3) points (``subset``) binned in cubes of side ``cell_m`` (at least
    the reach): those a point can reach lie in the 27 cells around its own."""

    origin: NDArray[np.float64]  # (3,) the grid's lowest corner
    cell_m: float
    dims: NDArray[np.int64]  # (3,) cells along x, y, z
    start: NDArray[np.int64]  # (cells + 1,) the members of cell c: members[start[c]:start[c+1]]
    members: NDArray[np.int32]  # (n,) positions in ``subset``

    @classmethod
    def of(cls, points: Points, subset: NDArray[np.int32], reach_m: float,
           cells_per_reach: int = 1) -> PointGrid:
        """The grid of the (n,) ``subset`` of ``points`` for ``reach_m``:
        cubes a ``cells_per_reach``-th of it wide (or wider, to stay within
        :data:`MAX_CELLS`); with more than one, look them up by the distance to each
        cell, as the pair search does."""
        if len(subset) == 0:
            return cls(np.zeros(3), 1.0, np.ones(3, np.int64), np.zeros(2, np.int64),
                       np.zeros(0, np.int32))
        low, cell_m, dims, cell_of = _layout(points, subset, reach_m, cells_per_reach)
        start, members = cell_members(cell_of, int(np.prod(dims)))
        return cls(low, cell_m, dims, start, members)


@dataclass(frozen=True)
class RunGrid(PointGrid):
    """A :class:`PointGrid` whose points carry a group (the pair search's: each piece's
    finest bundle, :mod:`planner.visibility.bundles`), each cell's members ordered by group
    and cut into runs of one group: a search skips a run whose group it has ruled out with
    one test, instead of one a point."""

    cell_runs: NDArray[np.int64]  # (cells + 1,) the runs of cell c: cell_runs[c]:cell_runs[c+1]
    run_first: NDArray[np.int64]  # (R + 1,) the members of run r: run_first[r]:run_first[r+1]
    run_group: NDArray[np.int32]  # (R,) the group of each run, -1: points in no group
    # (R, 6) float32, each run's box (lowest x, y, z, then highest), rounded outward so that
    # it holds every point of the run: a search skips a run whose box lies out of reach
    run_box: NDArray[np.float32]

    @classmethod
    def grouped(cls, points: Points, subset: NDArray[np.int32], reach_m: float,
                cells_per_reach: int, group: NDArray[np.int32] | None) -> RunGrid:
        """:meth:`PointGrid.of` with the (N,) ``group`` of every point (-1: none; None: no
        point is in a group)."""
        subset_group = (np.full(len(subset), -1, np.int32) if group is None
                        else np.ascontiguousarray(group[subset], np.int32))
        n_groups = int(subset_group.max()) + 1 if len(subset) else 0
        if len(subset) == 0:
            return cls(np.zeros(3), 1.0, np.ones(3, np.int64), np.zeros(2, np.int64),
                       np.zeros(0, np.int32), np.zeros(2, np.int64), np.zeros(1, np.int64),
                       np.zeros(0, np.int32), np.zeros((0, 6), np.float32))
        low, cell_m, dims, cell_of = _layout(points, subset, reach_m, cells_per_reach)
        start, members, cell_runs, run_first, run_group = grouped_members(
            cell_of, subset_group, n_groups, int(np.prod(dims)), MOST_PER_RUN)
        run_box = np.empty((len(run_group), 6), np.float32)
        _run_boxes(points.xyz, points.corners, subset, members, run_first, run_box)
        return cls(low, cell_m, dims, start, members, cell_runs, run_first, run_group,
                   run_box)


@numba.njit(nogil=True, cache=True)
def _run_boxes(xyz: NDArray[np.float64], corners: NDArray[np.int32],
               subset: NDArray[np.int32], members: NDArray[np.int32],
               run_first: NDArray[np.int64], out: NDArray[np.float32]) -> None:
    """Each run's box into the (R, 6) ``out``: the lowest and highest coordinate of its
    points ``subset[members[run]]`` (of :class:`Points` ``xyz``, ``corners``) per axis,
    rounded outward to float32 (:func:`float32_outward`), so the box holds every point
    exactly."""
    low, high = np.empty(3), np.empty(3)
    for r in range(run_first.shape[0] - 1):
        low[0], low[1], low[2] = point_xyz(xyz, corners, subset[members[run_first[r]]])
        high[:] = low
        for m in range(run_first[r], run_first[r + 1]):
            x, y, z = point_xyz(xyz, corners, subset[members[m]])
            low[0], high[0] = min(low[0], x), max(high[0], x)
            low[1], high[1] = min(low[1], y), max(high[1], y)
            low[2], high[2] = min(low[2], z), max(high[2], z)
        for axis in range(3):
            out[r, axis], out[r, axis + 3] = float32_outward(low[axis], high[axis])


@numba.njit(nogil=True, cache=True)
def float32_outward(low: float, high: float) -> tuple[np.float32, np.float32]:
    """The float64 interval [low, high] as float32 bounds that hold it: a bound that is
    not a float32 moves one float32 step out."""
    low32, high32 = np.float32(low), np.float32(high)
    if np.float64(low32) > low:
        low32 = np.nextafter(low32, np.float32(-np.inf))
    if np.float64(high32) < high:
        high32 = np.nextafter(high32, np.float32(np.inf))
    return low32, high32


def _layout(points: Points, subset: NDArray[np.int32], reach_m: float,
            cells_per_reach: int) -> tuple[NDArray[np.float64], float, NDArray[np.int64],
                                           NDArray[np.int32]]:
    """The grid of :meth:`PointGrid.of` for the (n,) non-empty ``subset``: its (3,) lowest
    corner, cell side, (3,) cells along each axis and (n,) cell of each point."""
    low, high = np.empty(3), np.empty(3)
    _bounds(points.xyz, points.corners, subset, low, high)
    extent = np.maximum(high - low, 1e-9)
    # wider than the reach by far more than rounding, so no face in reach is missed
    cell_m = max(reach_m * (1.0 + 1e-6) / cells_per_reach, float(extent.max()) * 1e-6)
    while np.prod(np.floor(extent / cell_m) + 1) > MAX_CELLS:
        cell_m *= 2.0
    dims = (np.floor(extent / cell_m) + 1).astype(np.int64)
    cell_of = np.empty(len(subset), np.int32)
    _cells_of(points.xyz, points.corners, subset, low, cell_m, dims, cell_of)
    return low, cell_m, dims, cell_of


def pairs_in_reach(points: NDArray[np.float64], centre: NDArray[np.float64],
                   radius_m: NDArray[np.float64], reach_m: float, grid: PointGrid
                   ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """(P,) point and (P,) ball of every (point, ball) pair where the ball (``centre``,
    ``radius_m``: (N, 3) and (N,); ``grid`` made for reach + the largest radius) comes
    within ``reach_m`` of one of the (B, 3) ``points``; by point, then ball."""
    args = (np.ascontiguousarray(points, np.float64), centre, radius_m, reach_m, grid.origin,
            grid.cell_m, grid.dims, grid.start, grid.members)
    count = _reach_pairs(*args, np.zeros(0, np.int64), np.zeros(0, np.int64), False)
    point, ball = np.empty(count, np.int64), np.empty(count, np.int64)
    _reach_pairs(*args, point, ball, True)
    return point, ball


@numba.njit(nogil=True, cache=True)
def _reach_pairs(points: NDArray[np.float64], centre: NDArray[np.float64],
                 radius_m: NDArray[np.float64], reach_m: float, grid_origin: NDArray[np.float64],
                 cell_m: float, grid_dims: NDArray[np.int64], cell_start: NDArray[np.int64],
                 cell_member: NDArray[np.int32], out_point: NDArray[np.int64],
                 out_ball: NDArray[np.int64], fill: bool) -> int:
    """Count the pairs of :func:`pairs_in_reach`, and with ``fill`` write them."""
    cells = np.empty(27, np.int64)
    n = 0
    for b in range(points.shape[0]):
        px, py, pz = points[b, 0], points[b, 1], points[b, 2]
        n_cells = cells_around(px, py, pz, grid_origin, cell_m, grid_dims, cells)
        first = n
        for c in range(n_cells):
            for m in range(cell_start[cells[c]], cell_start[cells[c] + 1]):
                k = cell_member[m]
                limit = reach_m + radius_m[k]
                dx, dy, dz = centre[k, 0] - px, centre[k, 1] - py, centre[k, 2] - pz
                if dx * dx + dy * dy + dz * dz <= limit * limit:
                    if fill:
                        out_point[n] = b
                        out_ball[n] = k
                    n += 1
        if fill:
            out_ball[first:n] = np.sort(out_ball[first:n])
    return n
