"""Generalised winding numbers of points with respect to a triangle mesh, exact and fast.

The winding number of a point is the sum of the signed solid angles its triangles subtend,
over 4 pi (Van Oosterom & Strackee's formula per triangle; Jacobson et al. 2013, "Robust
inside-outside segmentation using generalized winding numbers"). Summing every triangle
for every point costs points x triangles, which on a 1 M-face scan is minutes and
gigabytes. Here the triangles are cut into spatial cells and a cell far from the point is
replaced by a *cap*: a fan of triangles from one point of the cell over the cell's boundary
edges. A cell's triangles minus its cap form a closed surface inside the cell's box, whose
winding number at any point outside that box is exactly 0 (Jacobson et al., section 3.3),
so the cap subtends the same solid angle as the cell. A patch of n triangles has about
sqrt(n) boundary edges: the cost per point drops from T to (cells x boundary + the
triangles of the few cells whose box holds the point). Results equal the direct sum up
to floating-point rounding (about 1e-12).

Array letters: T triangles, N points, K cells, B cap triangles.
"""

from __future__ import annotations

import itertools
import math
import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

from planner.scene import column_bounds, corner_extremes

# below this many point-triangle pairs the direct sum is cheaper than building cells
_DIRECT_PAIRS = 4_000_000
# up to this many points the direct sum is cheaper than building cells whatever the
# triangles: building costs about what 80 points' direct sums do (1.06 M triangles: 3.4 CPU
# s and some 550 MB of scratch to build, 0.04 s a point direct), so a few tripod setups
# around the stations never build them
_DIRECT_POINTS = 32
# fewest triangles per cell aimed at (see _Cells.build)
_MIN_FACES_PER_CELL = 400


def winding_numbers(triangles: NDArray[np.float64], points: NDArray[np.float64]
                    ) -> NDArray[np.float64]:
    """(N,) winding numbers of (N, 3) points w.r.t. (T, 3, 3) triangles."""
    triangles = np.ascontiguousarray(triangles, np.float64).reshape(-1, 3, 3)
    points = np.ascontiguousarray(points, np.float64).reshape(-1, 3)
    if len(points) == 0 or len(triangles) == 0:
        return np.zeros(len(points))
    if not needs_cells(len(triangles), len(points)):
        # a point's sum over many triangles is worth a thread of its own (the tripod setups
        # around two stations: 16 points over a million faces)
        return _in_threads(points, lambda chunk: _direct(triangles, chunk),
                           points_per_worker=1 if len(triangles) >= _DIRECT_PAIRS // 16
                           else 16)
    return cells_winding_numbers(winding_cells(triangles), points)


def needs_cells(n_triangles: int, n_points: int) -> bool:
    """Whether :func:`winding_numbers` builds cells for so many triangles and points (else
    it sums every triangle for every point)."""
    return not (n_points <= _DIRECT_POINTS or n_triangles * n_points <= _DIRECT_PAIRS)


def winding_cells(triangles: NDArray[np.float64],
                  corner_rank: NDArray[np.integer[Any]] | None = None) -> WindingCells:
    """The cells of (T, 3, 3) ``triangles``, to ask for several sets of points.

    ``corner_rank`` (T, 3), optional: labels of the corners that order them as their
    coordinates do (x, then y, then z) and are equal exactly where the coordinates are, e.g.
    :func:`coordinate_ranks` of the mesh's vertices at its faces (a sort of V vertices
    instead of the 3 T corners). Any such labels give the same cells."""
    triangles = np.ascontiguousarray(triangles, np.float64).reshape(-1, 3, 3)
    if corner_rank is not None and np.shape(corner_rank) != (len(triangles), 3):
        raise ValueError("corner_rank must be (T, 3), one label per corner")
    return _Cells.build(triangles, corner_rank)


def coordinate_ranks(points: NDArray[np.float64], dtype: type[np.integer[Any]] = np.int64
                     ) -> NDArray[np.integer[Any]]:
    """(N,) the rank of each of the (N, 3) points' coordinates among the distinct ones,
    ordered by x, then y, then z: equal points get the same rank (``dtype``: int32 where
    the ranks fit, half the memory)."""
    by_position = np.lexsort(points.T[::-1])
    ordered = points[by_position]
    new_rank = np.r_[False, (ordered[1:] != ordered[:-1]).any(axis=1)].cumsum(dtype=dtype)
    del ordered
    rank = np.empty(len(points), dtype)
    rank[by_position] = new_rank
    return rank


def cells_winding_numbers(cells: WindingCells, points: NDArray[np.float64]
                          ) -> NDArray[np.float64]:
    """(N,) winding numbers of (N, 3) points w.r.t. the triangles of ``cells`` (those of
    :func:`winding_numbers` when it builds cells)."""
    points = np.ascontiguousarray(points, np.float64).reshape(-1, 3)
    if len(points) == 0:
        return np.zeros(0)
    return _in_threads(points, cells.winding)


def _in_threads(points: NDArray[np.float64],
                kernel: Callable[[NDArray[np.float64]], NDArray[np.float64]],
                points_per_worker: int = 16) -> NDArray[np.float64]:
    """Run a nogil kernel over parts of the points on the machine's cores, at least
    ``points_per_worker`` points a part (the same result: each point's sum is its own)."""
    workers = min(os.cpu_count() or 1, max(1, len(points) // points_per_worker))
    if workers == 1:
        return np.asarray(kernel(points))
    bounds = np.linspace(0, len(points), workers + 1).astype(int)
    with ThreadPoolExecutor(max_workers=workers) as pool:
        parts = list(pool.map(kernel, [points[a:b] for a, b in itertools.pairwise(bounds)]))
    return np.concatenate(parts)


def _direct(triangles: NDArray[np.float64], points: NDArray[np.float64]
            ) -> NDArray[np.float64]:
    starts = np.array([0, len(triangles)], np.int64)
    box = np.full((1, 3), np.inf)
    return np.asarray(_winding_kernel(points, triangles, starts, triangles[:0], np.zeros(
        2, np.int64), -box, box))


class _Cells:
    """Triangles sorted by cell, each cell's cap and its box."""

    def __init__(self, triangles: NDArray[np.float64], face_start: NDArray[np.int64],
                 caps: NDArray[np.float64], cap_start: NDArray[np.int64],
                 lo: NDArray[np.float64], hi: NDArray[np.float64]) -> None:
        self.triangles, self.face_start = triangles, face_start
        self.caps, self.cap_start, self.lo, self.hi = caps, cap_start, lo, hi

    @classmethod
    def build(cls, triangles: NDArray[np.float64],
              corner_rank: NDArray[np.integer[Any]] | None = None) -> _Cells:
        # corner and cell ids as int32 where they fit, scratch dropped as soon as it is
        # used: the build's peak is a multiple of the (3T,) id arrays
        id_type = np.int32 if 3 * len(triangles) < 2**31 else np.int64
        corners = triangles.reshape(-1, 3)
        # shared corners by exact coordinates: files often repeat vertices per face. Only
        # the order of the ids matters below (which of two corners is less, which are
        # equal), so the ranks of the mesh's vertices serve as well as the corners' own
        flat_id: NDArray[np.integer[Any]]
        if corner_rank is None:
            flat_id = coordinate_ranks(corners, id_type)
            n_ids = len(corners)
        else:
            flat_id = np.asarray(corner_rank).reshape(-1)
            n_ids = int(flat_id.max()) + 1
            if n_ids > np.iinfo(id_type).max:
                id_type = np.int64
            flat_id = flat_id.astype(id_type)
        corner_id = flat_id.reshape(-1, 3)
        lo_all, hi_all = column_bounds(corners)
        # caps cost about T / sqrt(n) per point for n triangles per cell, the cells around
        # the point about n: both balance at n = T^(2/3)
        per_cell = max(_MIN_FACES_PER_CELL, len(triangles) ** (2 / 3))
        per_axis = max(1, math.ceil(math.sqrt(len(triangles) / per_cell)))
        size = max(float((hi_all - lo_all).max()) / per_axis, 1e-9)
        key3 = np.floor((triangles.mean(axis=1) - lo_all) / size).astype(np.int64)
        key = (key3[:, 0] * (per_axis + 1) + key3[:, 1]) * (per_axis + 1) + key3[:, 2]
        del key3
        order = np.argsort(key, kind="stable")
        cell_keys, cell_of_face = np.unique(key[order], return_inverse=True)
        del key
        cell_of_face = cell_of_face.astype(id_type)
        n_cells = len(cell_keys)
        sorted_tri = np.ascontiguousarray(triangles[order])
        ids = corner_id[order]
        del order, flat_id, corner_id
        face_start = np.searchsorted(cell_of_face, np.arange(n_cells + 1)).astype(np.int64)
        # each face's box from its three corners, then each cell's
        face_lo, face_hi = corner_extremes(sorted_tri)
        lo = np.minimum.reduceat(face_lo, face_start[:-1])
        hi = np.maximum.reduceat(face_hi, face_start[:-1])
        del face_lo, face_hi

        # boundary: directed edges u->v that their reverse does not cancel, per cell
        u = ids.ravel()
        v = ids[:, [1, 2, 0]].ravel()
        del ids
        cell = np.repeat(cell_of_face, 3)
        del cell_of_face
        a, b = np.minimum(u, v), np.maximum(u, v)
        # by cell first, so caps come out per cell: one stable sort of the three packed
        # into an int64 where they fit (the order lexsort gives, in a third of its time)
        if float(n_cells) * float(n_ids) * float(n_ids) < 2.0 ** 62:
            packed = (cell.astype(np.int64) * n_ids + a) * n_ids + b
            order_e = np.argsort(packed, kind="stable")
            del packed
        else:
            order_e = np.lexsort((b, a, cell))
        ce, ae, be = cell[order_e], a[order_e], b[order_e]
        first_of_run = np.flatnonzero(np.r_[True, (ce[1:] != ce[:-1]) | (ae[1:] != ae[:-1])
                                            | (be[1:] != be[:-1])])
        del ce, ae, be
        sign = np.where(u[order_e] < v[order_e], 1, -1).astype(np.int8)
        del v
        net = np.add.reduceat(sign, first_of_run, dtype=np.int64)
        del sign
        keep = np.flatnonzero(net != 0)
        first = order_e[first_of_run]
        del order_e, first_of_run
        repeat = np.abs(net[keep])
        src = first[keep]  # a representative directed edge of each net boundary edge
        start_pt = np.where((net[keep] > 0)[:, None], _corner(sorted_tri, src, a, u),
                            _corner(sorted_tri, src, b, u))
        end_pt = np.where((net[keep] > 0)[:, None], _corner(sorted_tri, src, b, u),
                          _corner(sorted_tri, src, a, u))
        edge_cell = cell[src]
        del u, a, b, cell
        start_pt, end_pt = np.repeat(start_pt, repeat, axis=0), np.repeat(end_pt, repeat, 0)
        edge_cell = np.repeat(edge_cell, repeat)
        # apex: a corner of the cell (inside its box, so the closed surface stays inside)
        apex = sorted_tri[face_start[:-1], 0]
        caps = np.ascontiguousarray(np.stack([apex[edge_cell], start_pt, end_pt], axis=1))
        cap_start = np.searchsorted(edge_cell, np.arange(n_cells + 1)).astype(np.int64)
        return cls(sorted_tri, face_start, caps, cap_start, lo, hi)

    def winding(self, points: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.asarray(_winding_kernel(points, self.triangles, self.face_start, self.caps,
                                          self.cap_start, self.lo, self.hi))


WindingCells = _Cells


def _corner(tri: NDArray[np.float64], edge: NDArray[np.int64], wanted: NDArray[np.integer[Any]],
            u: NDArray[np.integer[Any]]) -> NDArray[np.float64]:
    """Coordinates of corner id ``wanted[edge]`` of the directed edge ``edge`` (3 per face).

    Directed edge e of face f = e // 3 runs from corner e % 3 to corner (e % 3 + 1) % 3.
    """
    face, k = edge // 3, edge % 3
    from_is_wanted = u[edge] == wanted[edge]
    corner = np.where(from_is_wanted, k, (k + 1) % 3)
    return np.asarray(tri[face, corner])


@numba.njit(nogil=True, cache=True)
def _winding_kernel(points: NDArray[np.float64], triangles: NDArray[np.float64],
                    face_start: NDArray[np.int64], caps: NDArray[np.float64],
                    cap_start: NDArray[np.int64], lo: NDArray[np.float64],
                    hi: NDArray[np.float64]) -> NDArray[np.float64]:  # pragma: no cover
    out = np.zeros(len(points))
    margin = 1e-9
    for i in range(len(points)):
        px, py, pz = points[i, 0], points[i, 1], points[i, 2]
        total = 0.0
        for k in range(len(face_start) - 1):
            outside = (px < lo[k, 0] - margin or px > hi[k, 0] + margin
                       or py < lo[k, 1] - margin or py > hi[k, 1] + margin
                       or pz < lo[k, 2] - margin or pz > hi[k, 2] + margin)
            if outside:
                source, s0, s1 = caps, cap_start[k], cap_start[k + 1]
            else:
                source, s0, s1 = triangles, face_start[k], face_start[k + 1]
            for t in range(s0, s1):
                total += triangle_solid_angle(source, t, px, py, pz)
        out[i] = total / (4.0 * math.pi)
    return out


@numba.njit(nogil=True, cache=True)
def triangle_solid_angle(source: NDArray[np.float64], t: int, px: float, py: float,
                         pz: float) -> float:
    """The signed solid angle of triangle ``t`` of the (T, 3, 3) ``source`` seen from the
    point (Van Oosterom and Strackee: twice the angle whose tangent they give); positive
    where the triangle's corners run counter-clockwise seen from the point."""
    ax = source[t, 0, 0] - px
    ay = source[t, 0, 1] - py
    az = source[t, 0, 2] - pz
    bx = source[t, 1, 0] - px
    by = source[t, 1, 1] - py
    bz = source[t, 1, 2] - pz
    cx = source[t, 2, 0] - px
    cy = source[t, 2, 1] - py
    cz = source[t, 2, 2] - pz
    la = math.sqrt(ax * ax + ay * ay + az * az)
    lb = math.sqrt(bx * bx + by * by + bz * bz)
    lc = math.sqrt(cx * cx + cy * cy + cz * cz)
    det = (ax * (by * cz - bz * cy) - ay * (bx * cz - bz * cx)
           + az * (bx * cy - by * cx))
    denom = (la * lb * lc + (ax * bx + ay * by + az * bz) * lc
             + (cx * ax + cy * ay + cz * az) * lb
             + (bx * cx + by * cy + bz * cz) * la)
    return 2.0 * math.atan2(det, denom)


__all__ = ["WindingCells", "cells_winding_numbers", "coordinate_ranks", "needs_cells",
           "triangle_solid_angle", "winding_cells", "winding_numbers"]
