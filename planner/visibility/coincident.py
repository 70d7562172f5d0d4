"""Faces that another face covers in part: the same plane, overlapping interiors.

A ray aimed at such a face meets it and its twin at the same distance, and which of the
two a closest-hit cast returns depends on the BVH's order among equal distances (two BVHs
over different occluders may differ). The overlap rows take a face's coverage verdict over
without a ray only where no twin can make this tie
(:class:`planner.visibility.overlap.SeenFaces`). Measured on FZK-Haus: every visible
coverage pair whose overlap ray (doors open) came out hidden, doors aside, ended on such
a twin within 0.5 um of its target.

Array letters: V vertices, B faces.
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

# the corners of one face lie at most this far off the other's plane for a twin: far above
# the float32 rounding of a hit point in a building (some micrometres), so a face that
# ties with another one within that rounding is always found
COPLANAR_M = 1e-3
# and their interiors overlap by more than this in every direction of the plane (two
# halves of a rectangle that share their diagonal only touch: they are not twins)
OVERLAP_DEPTH_M = 1e-7


def twin_pairs(vertices: NDArray[np.float64], faces: NDArray[np.integer[Any]],
               among: NDArray[np.integer[Any]]) -> NDArray[np.int64]:
    """(T, 2) int64: every pair of twins (indices into the (B, 3) ``faces`` of the (V, 3)
    ``vertices``) among the faces ``among`` (b,): the corners of each lie within
    :data:`COPLANAR_M` of the other's plane and their interiors overlap by more than
    :data:`OVERLAP_DEPTH_M`. Degenerate faces (no area) have no twin: no ray hits them."""
    among = np.asarray(among, np.int64)
    if len(among) < 2:
        return np.zeros((0, 2), np.int64)
    corners = np.asarray(vertices, np.float64)[np.asarray(faces)[among]]  # (b, 3, 3)
    low, high = corners.min(axis=1), corners.max(axis=1)  # (b, 3) bounds
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    length = np.linalg.norm(normal, axis=1)
    normal /= np.where(length > 0, length, 1.0)[:, None]
    order = np.argsort(low[:, 0], kind="stable")
    args = (corners[order], low[order], high[order], normal[order], length[order] > 0,
            COPLANAR_M, OVERLAP_DEPTH_M)
    pairs = np.zeros((_sweep(*args, np.zeros((0, 2), np.int64)), 2), np.int64)
    _sweep(*args, pairs)  # counted, then written
    twins: NDArray[np.int64] = among[order[pairs]].astype(np.int64, copy=False)
    return twins


def covered_pieces(centroids: NDArray[np.float64], source_face: NDArray[np.integer[Any]],
                   vertices: NDArray[np.float64], faces: NDArray[np.integer[Any]],
                   pairs: NDArray[np.int64]) -> NDArray[np.bool_]:
    """(F,) bool: the scene's faces whose centroid ((F, 3) ``centroids``) lies on a twin
    of their own face (``source_face`` (F,): the face of the (B, 3) ``faces`` of
    ``vertices`` each is part of, or the identity), within :data:`COPLANAR_M` of its
    plane and at most :data:`COPLANAR_M` outside its edges: a ray aimed at the centroid
    meets the twin there as well. ``pairs``: :func:`twin_pairs`."""
    covered = np.zeros(len(centroids), bool)
    if not len(pairs):
        return covered
    both = np.concatenate([pairs, pairs[:, ::-1]])  # (2T, 2): (face, its twin)
    both = both[np.argsort(both[:, 0], kind="stable")]
    # the scene's faces of each BVH face with a twin
    source = np.asarray(source_face, np.int64)
    mine = np.flatnonzero(np.isin(source, both[:, 0]))  # (m,)
    mine = mine[np.argsort(source[mine], kind="stable")]
    twin_corners = np.asarray(vertices, np.float64)[np.asarray(faces)[both[:, 1]]]
    _cover(source[mine], mine, both[:, 0], twin_corners, np.asarray(centroids, np.float64),
           COPLANAR_M, covered)
    return covered


@numba.njit(nogil=True, cache=True)
def _cover(piece_face: NDArray[np.int64], pieces: NDArray[np.int64],
           pair_face: NDArray[np.int64], twin_corners: NDArray[np.float64],
           centroids: NDArray[np.float64], margin_m: float,
           covered: NDArray[np.bool_]) -> None:  # compiled; see test_overlap_reuse
    """Mark the ``pieces`` (m,) (sorted by their BVH face ``piece_face``) whose centroid
    lies within ``margin_m`` of a twin of their face: the (2T,) ``pair_face`` sorted, with
    (2T, 3, 3) ``twin_corners`` of each one's twin."""
    n_pairs = pair_face.shape[0]
    p = 0
    for k in range(pieces.shape[0]):
        face = piece_face[k]
        while p < n_pairs and pair_face[p] < face:
            p += 1
        q = p
        c = centroids[pieces[k]]
        while q < n_pairs and pair_face[q] == face:
            if _near_triangle(c, twin_corners[q], margin_m):
                covered[pieces[k]] = True
                break
            q += 1


@numba.njit(nogil=True, cache=True)
def _near_triangle(c: NDArray[np.float64], t: NDArray[np.float64], margin_m: float) -> bool:
    """Point ``c`` (3,) lies within ``margin_m`` of the plane of triangle ``t`` (3, 3) and
    at most ``margin_m`` outside each of its edges."""
    ux, uy, uz = t[1, 0] - t[0, 0], t[1, 1] - t[0, 1], t[1, 2] - t[0, 2]
    vx, vy, vz = t[2, 0] - t[0, 0], t[2, 1] - t[0, 1], t[2, 2] - t[0, 2]
    nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    size = np.sqrt(nx * nx + ny * ny + nz * nz)
    if size == 0.0:
        return False
    nx, ny, nz = nx / size, ny / size, nz / size
    if abs((c[0] - t[0, 0]) * nx + (c[1] - t[0, 1]) * ny + (c[2] - t[0, 2]) * nz) > margin_m:
        return False
    for e in range(3):
        ex = t[(e + 1) % 3, 0] - t[e, 0]
        ey = t[(e + 1) % 3, 1] - t[e, 1]
        ez = t[(e + 1) % 3, 2] - t[e, 2]
        # the edge's outward normal in the plane: edge x normal (corners counterclockwise
        # about the normal)
        ox, oy, oz = ey * nz - ez * ny, ez * nx - ex * nz, ex * ny - ey * nx
        length = np.sqrt(ox * ox + oy * oy + oz * oz)
        if length == 0.0:
            continue
        out = ((c[0] - t[e, 0]) * ox + (c[1] - t[e, 1]) * oy + (c[2] - t[e, 2]) * oz) / length
        if out > margin_m:
            return False
    return True


@numba.njit(nogil=True, cache=True)
def _sweep(corners: NDArray[np.float64], low: NDArray[np.float64], high: NDArray[np.float64],
           normal: NDArray[np.float64], proper: NDArray[np.bool_], coplanar_m: float,
           depth_m: float, pairs: NDArray[np.int64]) -> int:  # compiled; see test_overlap_reuse
    """The twin pairs of the (b, 3, 3) ``corners`` sorted by their lowest x (``low``,
    ``high``: (b, 3) bounds; ``normal`` (b, 3) unit; ``proper`` (b,) not degenerate):
    written into ``pairs`` (n, 2) when it has room, counted either way."""
    n = corners.shape[0]
    found = 0
    for i in range(n):
        if not proper[i]:
            continue
        for j in range(i + 1, n):
            if low[j, 0] > high[i, 0] + coplanar_m:
                break  # sorted by low x: no later face reaches back to face i
            if not proper[j]:
                continue
            if (low[j, 1] > high[i, 1] + coplanar_m or low[i, 1] > high[j, 1] + coplanar_m
                    or low[j, 2] > high[i, 2] + coplanar_m
                    or low[i, 2] > high[j, 2] + coplanar_m):
                continue
            if not (_within_plane(corners, i, j, normal, coplanar_m)
                    and _within_plane(corners, j, i, normal, coplanar_m)):
                continue
            if _interiors_overlap(corners, i, j, normal, depth_m):
                if found < pairs.shape[0]:
                    pairs[found, 0] = i
                    pairs[found, 1] = j
                found += 1
    return found


@numba.njit(nogil=True, cache=True)
def _within_plane(corners: NDArray[np.float64], i: int, j: int, normal: NDArray[np.float64],
                  coplanar_m: float) -> bool:
    """Every corner of face j lies within ``coplanar_m`` of face i's plane."""
    for k in range(3):
        off = 0.0
        for a in range(3):
            off += (corners[j, k, a] - corners[i, 0, a]) * normal[i, a]
        if abs(off) > coplanar_m:
            return False
    return True


@numba.njit(nogil=True, cache=True)
def _interiors_overlap(corners: NDArray[np.float64], i: int, j: int,
                       normal: NDArray[np.float64], depth_m: float) -> bool:
    """Faces i and j, projected into face i's plane, overlap by more than ``depth_m``
    along each of their six edge normals (separating axes)."""
    for face in (i, j):
        for e in range(3):
            # the in-plane normal of the edge: face i's normal x the edge
            ex = corners[face, (e + 1) % 3, 0] - corners[face, e, 0]
            ey = corners[face, (e + 1) % 3, 1] - corners[face, e, 1]
            ez = corners[face, (e + 1) % 3, 2] - corners[face, e, 2]
            ax = normal[i, 1] * ez - normal[i, 2] * ey
            ay = normal[i, 2] * ex - normal[i, 0] * ez
            az = normal[i, 0] * ey - normal[i, 1] * ex
            size = np.sqrt(ax * ax + ay * ay + az * az)
            if size == 0.0:
                continue
            ax, ay, az = ax / size, ay / size, az / size
            low_i, high_i = np.inf, -np.inf
            low_j, high_j = np.inf, -np.inf
            for k in range(3):
                p = corners[i, k, 0] * ax + corners[i, k, 1] * ay + corners[i, k, 2] * az
                q = corners[j, k, 0] * ax + corners[j, k, 1] * ay + corners[j, k, 2] * az
                low_i, high_i = min(low_i, p), max(high_i, p)
                low_j, high_j = min(low_j, q), max(high_j, q)
            if min(high_i, high_j) - max(low_i, low_j) <= depth_m:
                return False
    return True
