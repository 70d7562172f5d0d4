"""Candidate-face pairs and the analytic limits, all known before any ray is cast.

A pair (candidate c, face f) *passes* when, with d the distance from c to the centroid of f
and alpha the incidence angle (``sin alpha = |ray . normal|``):

- ``dof_min_m <= d <= dof_max_m``;
- the ray's elevation above the scanner's horizontal plane lies in
  ``[elevation_min_deg, elevation_max_deg]`` (the blind cone under the scanner);
- ``alpha >= min_incidence_deg`` of the face's group;
- ``LPD >= min_density_pts_m2`` of the face's group.

Limits are inclusive. Angles are compared as their sines (the same order on [-90, 90]
degrees), so ``sin(90 deg)`` = 1 admits the zenith and no arcsin is taken per pair.
Only the pairs that
pass need an occlusion ray. Array letters: C candidates, F faces, P pairs.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, TypeVar

import numba
import numpy as np
from numpy.typing import NDArray

from planner.limits import FaceLimits
from planner.rays import ExactRays, Occlusion
from planner.scene import Scene, face_centroid
from planner.visibility.bundles import HiddenBundles
from planner.visibility.cells import MOST_PER_RUN, Points, RunGrid, float32_outward
from planner.visibility.solids import ClosedShells


@dataclass(frozen=True, eq=False)
class Pairs:
    """Pairs that pass the analytic limits, sorted by (candidate, face).

    Attributes
    ----------
    candidate : (P,) int32, candidate index
    face : (P,) int32, face index
    origin : (P, 3) float32, the candidate's position (ray origin)
    direction : (P, 3) float32, unit vector from candidate to face centroid (ray direction)
    distance_m : (P,) float32, from candidate to face centroid
    lpd_pts_m2 : (P,) float32

    The float32 columns are the rays as Embree takes them; every limit was decided in
    float64 before they were written.
    """

    candidate: NDArray[np.int32]
    face: NDArray[np.int32]
    origin: NDArray[np.float32]
    direction: NDArray[np.float32]
    distance_m: NDArray[np.float32]
    lpd_pts_m2: NDArray[np.float32]

    def __len__(self) -> int:
        return len(self.face)

    def subset(self, keep: NDArray[np.bool_] | NDArray[np.intp] | slice) -> Pairs:
        return Pairs(*(getattr(self, name)[keep] for name in _PAIR_COLUMNS))

    def exact_rays(self, positions_xyz: NDArray[np.float64], scene: Scene) -> ExactRays:
        """The float64 rays of any of these pairs, from the (C, 3) candidate positions the
        pairs were found for to the centroids of ``scene``'s faces (see
        :class:`ExactRays`)."""
        def rays(index: NDArray[np.int64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
            origins = np.asarray(positions_xyz, np.float64)[self.candidate[index]]
            offset = scene.centroids_of(self.face[index]) - origins
            return origins, offset / np.linalg.norm(offset, axis=1)[:, None]
        return rays


_PAIR_COLUMNS = ("candidate", "face", "origin", "direction", "distance_m", "lpd_pts_m2")
# rays cast at a time by :func:`visible_pairs`: Embree's output and the cast's scratch are
# some 60 bytes a ray, on each thread
RAYS_PER_CAST = 1 << 17


def visible_pairs(occlusion: Occlusion, pairs: Pairs, positions_xyz: NDArray[np.float64],
                  scene: Scene) -> NDArray[np.bool_]:
    """(P,) whether each of ``pairs`` (found for the (C, 3) ``positions_xyz``) reaches its
    face of ``scene``, cast :data:`RAYS_PER_CAST` at a time: each ray's verdict is its
    own, whatever else is cast with it (the float64 rays of :meth:`Pairs.exact_rays`
    decide where the casts disagree)."""
    exact_rays = pairs.exact_rays(positions_xyz, scene)
    visible = np.empty(len(pairs), bool)
    for first in range(0, len(pairs), RAYS_PER_CAST):
        part = slice(first, first + RAYS_PER_CAST)

        def part_rays(index: NDArray[np.int64], first: int = first
                      ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
            return exact_rays(index + first)

        visible[part] = occlusion.visible(
            pairs.origin[part], pairs.direction[part], pairs.distance_m[part],
            pairs.face[part], exact_rays=part_rays)
    return visible


def search_reach_m(limits: FaceLimits) -> float:
    """How far a candidate's pair search under ``limits`` reaches: no face beyond it can
    pass them."""
    return min(limits.reach_m, limits.dof_max_m)


def sorted_by_face(candidate: NDArray[np.int32], face: NDArray[np.int32]) -> NDArray[np.intp]:
    """(P,) the order that sorts P pairs by (candidate, face); a candidate holds a face
    once, so the order is unique.

    Where the candidate (less the lowest), the face and the pair's index fit in 63 bits
    (a block of candidates: some 6 + 24 + 24 bits on a 10 M-face model), the index rides in
    the low bits of the key and the keys themselves are sorted, which numpy does faster
    than an argsort (600,000 pairs of 16 candidates on a 9.7 M-face model: 6.1 ms instead
    of 14.3 ms); the order is the same, as no two keys are equal.
    """
    n = len(face)
    if n == 0:
        return np.zeros(0, np.intp)
    low = int(candidate.min())
    index_bits = (n - 1).bit_length()
    face_bits = int(face.max()).bit_length()
    if (int(candidate.max()) - low).bit_length() + face_bits + index_bits > 63:
        key = candidate.astype(np.int64) * (int(face.max()) + 1) + face
        order: NDArray[np.intp] = np.argsort(key)
        return order
    packed = candidate.astype(np.int64)
    packed -= low
    packed <<= face_bits + index_bits
    shifted_face = face.astype(np.int64)
    shifted_face <<= index_bits
    packed |= shifted_face
    del shifted_face
    packed |= np.arange(n, dtype=np.int64)
    packed.sort()
    packed &= (1 << index_bits) - 1
    return packed.astype(np.intp, copy=False)


@numba.njit(nogil=True, cache=True)
def _cell_keys(
    points: NDArray[np.float64], n_faces: int, reach_m: float,
    grid_origin: NDArray[np.float64], cell_m: float, grid_dims: NDArray[np.int64],
    cell_start: NDArray[np.int64],
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Which cells of the grid (:class:`PointGrid`) each of the (B, 3) ``points`` searches:
    (k,) sorted keys ``cell * B + point`` and (B,) how many faces each point tests.

    A point searches the cells whose cube comes within ``reach_m`` of it
    (:func:`_cells_within`), so every face within reach is among their faces; a point
    whose cells hold most of the ``n_faces`` faces tests every face instead (the key of
    the cell id one past the grid's).
    """
    n_points = points.shape[0]
    room = int((2 * np.ceil(reach_m / cell_m) + 1) ** 3)  # as _cells_within needs
    cells = np.empty(room, np.int64)
    every_face = cell_start.shape[0] - 1  # a cell id past the grid's: all the faces
    keys = np.empty(n_points * room, np.int64)
    tests = np.zeros(n_points, np.int64)
    n_keys = 0
    for b in range(n_points):
        n_cells = _cells_within(points[b, 0], points[b, 1], points[b, 2], grid_origin,
                                cell_m, grid_dims, reach_m, cells)
        near = 0
        for c in range(n_cells):
            near += cell_start[cells[c] + 1] - cell_start[cells[c]]
        if near * _GRID_WORTH > n_faces:  # the cells hold most faces: test them all
            n_cells, cells[0] = 1, every_face
            near = n_faces
        tests[b] = near
        for c in range(n_cells):
            keys[n_keys] = cells[c] * n_points + b
            n_keys += 1
    return np.sort(keys[:n_keys]), tests


@numba.njit(nogil=True, cache=True)
def _pass_limits(  # compiled; its cases are in tests/planner/test_limits.py
    points: NDArray[np.float64], keys: NDArray[np.int64], first_index: int,
    faces: NDArray[np.int32], vertex_xyz: NDArray[np.float64],
    face_corners: NDArray[np.int32],
    face_normal: NDArray[np.float64], face_source: NDArray[np.int32],
    face_class: NDArray[np.integer[Any]], min_sin_incidence: NDArray[np.float64],
    min_density: NDArray[np.float64],
    dof_min_m: float, dof_max_m: float, min_sin_elevation: float, max_sin_elevation: float,
    reach_m: float, angular_step_rad: float,
    cell_runs: NDArray[np.int64], run_first: NDArray[np.int64],
    run_group: NDArray[np.int32], run_box: NDArray[np.float32], members: NDArray[np.int32],
    every_runs: tuple[int, int], run_plane_face: NDArray[np.int32],
    run_plane: NDArray[np.float32], hidden: NDArray[np.bool_],
    face_side: NDArray[np.int8], outside: NDArray[np.bool_], margin_m: float,
    out_candidate: NDArray[np.int32], out_face: NDArray[np.int32],
    out_origin: NDArray[np.float32], out_direction: NDArray[np.float32],
    out_distance: NDArray[np.float32], out_lpd: NDArray[np.float32],
) -> int:
    """Write the pairs of (B, 3) ``points`` x the candidate faces that pass every limit;
    returns how many.

    The f face indices ``faces`` are faces of the scene's (V, 3) ``vertex_xyz`` and (F, 3)
    ``face_corners``, whose centroids (:func:`planner.scene.face_centroid`) are computed
    a run at a time, when a point first reaches the run; ``face_normal`` is its (F0, 3)
    file faces' normals, read through the (F,) ``face_source`` (no per-plan copy: 48
    bytes a face saved);
    ``face_class`` (f,) picks each face's thresholds from the (K,) ``min_sin_incidence``
    and ``min_density`` (K: the distinct pairs of them, 1 without group requirements).
    Each point tests the faces of the cells its ``keys`` name (:func:`_cell_keys`), run by
    run (:class:`planner.visibility.cells.RunGrid`: ``cell_runs``, ``run_first``,
    ``run_group`` and ``run_box`` over the (f,) positions ``members``); the key past the
    grid's cells tests the runs ``every_runs`` (first, stop). A run is skipped with one
    test where none of its faces can pass: its box lies beyond the reach, or its faces lie
    on one plane (``run_plane_face`` (R,), the file face whose normal they share, -1: not
    one; ``run_plane`` (R, 2), the least and greatest offset n . c of their centroids c)
    and the point lies so near that plane, for the run's distance, that no face has the
    least incidence or density of any class: a face's sine of incidence is the point's
    distance from the plane over the face's distance d (at least the box's), its density
    that sine over (SPS d)^2. Each bound is widened well past the rounding of the values
    the faces' own tests compute. A run's group is its faces' finest bundle: a bundle
    hidden from the point (``hidden`` (B, K), K = 0 for none:
    :mod:`planner.visibility.bundles`) is left out untested, its faces' rays would end in
    the occluder that hides it. So is a face seen from inside its closed shell
    (``face_side`` (F,), empty for none: :mod:`planner.visibility.solids`) by a point
    ``outside`` (B,) every shell, more than ``margin_m`` behind the face's plane.

    The search runs cell by cell: each cell's runs are tested against every point of the
    block that searches the cell (the block's points stand close together, so they search
    mostly the same cells), a run's faces staying in cache from one point to the next. A
    run ruled out costs one test a point, not one a face: at the overlap reach most of a
    row's faces lie in hidden bundles. The pairs come out in no particular order
    (:func:`sorted_by_face` orders them).
    """
    n_points = points.shape[0]
    n = 0
    bundled = hidden.shape[1] > 0
    sided = face_side.shape[0] > 0
    reach2 = reach_m * reach_m * (1.0 + 1e-9)
    box_reach2 = reach_m * reach_m * (1.0 + 1e-6) + 1e-12
    every_cell = cell_runs.shape[0] - 1
    n_keys = keys.shape[0]
    least_sin_incidence = min_sin_incidence.min()
    least_density_step2 = min_density.min() * angular_step_rad * angular_step_rad
    # the centroids of a run's faces (a RunGrid's runs hold at most MOST_PER_RUN)
    run_xyz = np.empty((MOST_PER_RUN, 3))
    first = 0
    while first < n_keys:  # one cell: its points are keys[first:last]
        cell = keys[first] // n_points
        last = first
        while last < n_keys and keys[last] // n_points == cell:
            last += 1
        low, high = every_runs if cell == every_cell else (cell_runs[cell], cell_runs[cell + 1])
        for r in range(low, high):
            bundle = run_group[r] if bundled else -1
            run_start = run_first[r]
            centred = False
            for key in keys[first:last]:
                b = key - cell * n_points
                if bundle >= 0 and hidden[b, bundle]:
                    continue
                px, py, pz = points[b, 0], points[b, 1], points[b, 2]
                # the whole run ruled out at once: its box out of reach, or (its faces on
                # one plane) so far from the point and so close to the plane that no face
                # can have the least incidence or density of any class
                gx = max(run_box[r, 0] - px, 0.0, px - run_box[r, 3])
                gy = max(run_box[r, 1] - py, 0.0, py - run_box[r, 4])
                gz = max(run_box[r, 2] - pz, 0.0, pz - run_box[r, 5])
                box2 = gx * gx + gy * gy + gz * gz
                if box2 > box_reach2:
                    continue
                g = run_plane_face[r]
                if g >= 0 and box2 > 0.0:
                    on_plane = (px * face_normal[g, 0] + py * face_normal[g, 1]
                                + pz * face_normal[g, 2])
                    apart = max(abs(run_plane[r, 0] - on_plane),
                                abs(run_plane[r, 1] - on_plane)) * (1.0 + 1e-6) + 1e-6
                    near = np.sqrt(box2) * (1.0 - 1e-9)
                    if (apart < least_sin_incidence * near
                            or apart < least_density_step2 * near * near * near):
                        continue
                shelled = sided and outside[b]
                if not centred:
                    for m in range(run_start, run_first[r + 1]):
                        j = m - run_start
                        run_xyz[j, 0], run_xyz[j, 1], run_xyz[j, 2] = face_centroid(
                            vertex_xyz, face_corners, faces[members[m]])
                    centred = True
                for m in range(run_start, run_first[r + 1]):
                    i = members[m]
                    f = faces[i]
                    j = m - run_start
                    fx, fy, fz = run_xyz[j, 0], run_xyz[j, 1], run_xyz[j, 2]
                    ox, oy, oz = fx - px, fy - py, fz - pz
                    d2 = ox * ox + oy * oy + oz * oz
                    if d2 > reach2:
                        continue
                    d = np.sqrt(d2)
                    if d < dof_min_m or d > dof_max_m or d <= 0.0:
                        continue
                    uz = oz / d
                    if uz < min_sin_elevation or uz > max_sin_elevation:
                        continue
                    ux, uy = ox / d, oy / d
                    g = face_source[f]
                    nx, ny, nz = face_normal[g, 0], face_normal[g, 1], face_normal[g, 2]
                    toward = ux * nx + uy * ny + uz * nz
                    if shelled and face_side[f] * toward * d > margin_m:
                        continue  # seen from inside its closed shell: the ray ends in the shell
                    s = abs(toward)
                    k = face_class[i]
                    if s < min_sin_incidence[k]:
                        continue
                    spacing = angular_step_rad * d
                    lpd = s / (spacing * spacing)
                    if lpd < min_density[k]:
                        continue
                    out_candidate[n] = first_index + b
                    out_face[n] = f
                    out_distance[n] = d
                    out_origin[n, 0] = px
                    out_origin[n, 1] = py
                    out_origin[n, 2] = pz
                    out_direction[n, 0] = ux
                    out_direction[n, 1] = uy
                    out_direction[n, 2] = uz
                    out_lpd[n] = lpd
                    n += 1
        first = last
    return n


@numba.njit(nogil=True, cache=True)
def _run_planes(faces: NDArray[np.int32], vertex_xyz: NDArray[np.float64],
                face_corners: NDArray[np.int32], face_source: NDArray[np.int32],
                face_normal: NDArray[np.float64],
                members: NDArray[np.int32], run_first: NDArray[np.int64],
                out_face: NDArray[np.int32], out_plane: NDArray[np.float32]) -> None:
    """Each run's plane into the (R,) ``out_face`` and (R, 2) ``out_plane``: the file face
    all its faces ``faces[members[run]]`` are pieces of (-1 where they are not of one), and
    the least and greatest offset n . c of their centroids c (faces of ``vertex_xyz``,
    ``face_corners``, as in :func:`_pass_limits`) along its normal n, rounded
    outward to float32 (:func:`planner.visibility.cells.float32_outward`)."""
    for r in range(run_first.shape[0] - 1):
        g = face_source[faces[members[run_first[r]]]]
        low, high = np.inf, -np.inf
        for m in range(run_first[r], run_first[r + 1]):
            f = faces[members[m]]
            if face_source[f] != g:
                g = -1
                break
            cx, cy, cz = face_centroid(vertex_xyz, face_corners, f)
            offset = cx * face_normal[g, 0] + cy * face_normal[g, 1] + cz * face_normal[g, 2]
            low = min(low, offset)
            high = max(high, offset)
        out_face[r] = g
        if g < 0:
            out_plane[r, 0], out_plane[r, 1] = 0.0, 0.0
            continue
        out_plane[r, 0], out_plane[r, 1] = float32_outward(low, high)


def lpd_of_faces(scene: Scene, limits: FaceLimits, point_xyz: NDArray[np.float64],
                 faces: NDArray[np.int32]) -> NDArray[np.float32]:
    """(k,) float32 LPD in pts/m^2 of ``faces`` seen from the (3,) ``point_xyz``: the value
    the limits kernel (:func:`_pass_limits`) writes for these pairs, bit for bit (the same
    float64 operations in the same order), without the search or the rays. For faces the
    point is known to qualify for, such as a station's row of the coverage table."""
    out = np.empty(len(faces), np.float32)
    _face_lpd(np.ascontiguousarray(point_xyz, np.float64), np.asarray(faces, np.int32),
              scene.vertices, scene.faces, scene.file_normals, scene.source_face,
              limits.angular_step_rad, out)
    return out


@numba.njit(nogil=True, cache=True)
def _face_lpd(point: NDArray[np.float64], faces: NDArray[np.int32],
              vertex_xyz: NDArray[np.float64], face_corners: NDArray[np.int32],
              face_normal: NDArray[np.float64],
              face_source: NDArray[np.int32], angular_step_rad: float,
              out: NDArray[np.float32]
              ) -> None:  # compiled; compared with the limits kernel in test_limits
    """The LPD of :func:`_pass_limits` for each of ``faces`` from ``point``, into ``out``."""
    px, py, pz = point[0], point[1], point[2]
    for i in range(faces.shape[0]):
        f = faces[i]
        cx, cy, cz = face_centroid(vertex_xyz, face_corners, f)
        ox, oy, oz = cx - px, cy - py, cz - pz
        d = np.sqrt(ox * ox + oy * oy + oz * oz)
        uz = oz / d
        ux, uy = ox / d, oy / d
        g = face_source[f]
        s = abs(ux * face_normal[g, 0] + uy * face_normal[g, 1] + uz * face_normal[g, 2])
        spacing = angular_step_rad * d
        out[i] = s / (spacing * spacing)


# (beside the kernel that calls it: numba checks a cached function against its own file only)
@numba.njit(nogil=True, cache=True)
def _cells_within(px: float, py: float, pz: float, grid_origin: NDArray[np.float64],
                  cell_m: float, grid_dims: NDArray[np.int64], reach_m: float,
                  out: NDArray[np.int64]) -> int:
    """Write the ids of the grid cells (those inside the grid) that come within ``reach_m``
    of the point into ``out`` (room for (2 ceil(reach / cell) + 1)^3 of them), in
    increasing order; returns how many. A cell is kept when the nearest point of its cube
    is within reach (a hair more, for rounding), so no point within reach is missed."""
    span = int(np.ceil(reach_m / cell_m))
    cx = int(np.floor((px - grid_origin[0]) / cell_m))
    cy = int(np.floor((py - grid_origin[1]) / cell_m))
    cz = int(np.floor((pz - grid_origin[2]) / cell_m))
    limit2 = reach_m * reach_m * (1.0 + 1e-6) + 1e-12
    n = 0
    for gx in range(max(cx - span, 0), min(cx + span + 1, grid_dims[0])):
        x0 = grid_origin[0] + gx * cell_m
        dx = max(x0 - px, 0.0, px - (x0 + cell_m))
        for gy in range(max(cy - span, 0), min(cy + span + 1, grid_dims[1])):
            y0 = grid_origin[1] + gy * cell_m
            dy = max(y0 - py, 0.0, py - (y0 + cell_m))
            for gz in range(max(cz - span, 0), min(cz + span + 1, grid_dims[2])):
                z0 = grid_origin[2] + gz * cell_m
                dz = max(z0 - pz, 0.0, pz - (z0 + cell_m))
                if dx * dx + dy * dy + dz * dz <= limit2:
                    out[n] = (gx * grid_dims[1] + gy) * grid_dims[2] + gz
                    n += 1
    return n


_NO_SIDES = np.zeros(0, np.int8)
# candidates whose cells are looked up together when blocks are planned
_KEY_BLOCK_POINTS = 256
# pair tests a block of candidates makes at most (a block of one candidate may make
# more): its scratch pairs are 40 bytes each, of which some quarter pass and are written
TESTS_PER_BLOCK = 2_000_000
# grid cells a quarter of the reach wide: the cells that come within reach of a point
# hold some 2 to 3 times fewer faces than the 3 x 3 x 3 cells of a reach each around it
_CELLS_PER_REACH = 4
# the grid is used for a point when its cells hold less than this share of the faces
_GRID_WORTH = 4


class PairFinder:
    """Finds the passing pairs of a block of candidates (a compiled loop, GIL released).

    Every test is made in float64 exactly as the module docstring states; the loop only
    saves the memory traffic of C x F temporary arrays, and a grid of the faces leaves out
    those beyond reach before any arithmetic.
    """

    def __init__(self, scene: Scene, limits: FaceLimits, *,
                 reach_m: float | None = None, shells: ClosedShells | None = None,
                 bundle_of: NDArray[np.int32] | None = None) -> None:
        """``shells``: the closed shells of the occlusion the pairs' rays will be cast
        with (:func:`planner.visibility.solids.closed_shells`): faces seen from inside
        their shell are left out, as their rays would end in it. ``bundle_of``: the (F,)
        finest bundle of each face (:attr:`planner.visibility.bundles.Bundles.bundle_of`)
        of the culler whose hidden bundles the searches will be given: the faces of a
        bundle sit together in the grid, so a hidden one is skipped at once."""
        self.limits = limits
        self._shells = shells
        # a tile of a model (planner.visibility.tiles) searches as far as the whole model
        # does, whatever the densities of its own targets
        self.reach_m = search_reach_m(limits) if reach_m is None else reach_m
        self._faces = np.flatnonzero(limits.target).astype(np.int32)  # (f,) the targets
        # the scene's own arrays, read through self._faces: no (f, 3) copies
        self._points = Points.face_centroids(scene)
        self._face_normal = scene.file_normals  # (F0, 3), through source_face
        self._face_source = scene.source_face
        # (f,) class of each target's thresholds, (K,) incidence in degrees and density
        self._face_class, incidence_deg, self._min_density = threshold_classes(
            self._faces, limits.min_incidence_deg, limits.min_density_pts_m2)
        # angles compare as their sines (monotonic on [-90, 90] degrees): no arcsin per pair
        self._min_sin_incidence = np.sin(np.radians(incidence_deg))
        self._min_sin_elevation = math.sin(math.radians(limits.elevation_min_deg))
        self._max_sin_elevation = math.sin(math.radians(limits.elevation_max_deg))
        # only the faces within reach of a candidate are tested (on a 10 M-face building
        # a candidate reaches some thousandths of them): the cells around it
        self._bundle_of = bundle_of
        self._grid = RunGrid.grouped(self._points, self._faces, self.reach_m,
                                     _CELLS_PER_REACH, bundle_of)
        # each run's plane, where its faces share one (those of a bundle always do)
        n_runs = len(self._grid.run_group)
        self._run_plane_face = np.empty(n_runs, np.int32)  # (R,) file face, -1: none
        self._run_plane = np.empty((n_runs, 2), np.float32)  # (R, 2) least, greatest n . c
        _run_planes(self._faces, self._points.xyz, self._points.corners, self._face_source,
                    self._face_normal,
                    self._grid.members, self._grid.run_first, self._run_plane_face,
                    self._run_plane)

    def find(self, candidates_xyz: NDArray[np.float64], first_index: int,
             hidden: HiddenBundles | None = None, *, ordered: bool = True
             ) -> tuple[Pairs, int]:
        """Passing pairs of (B, 3) candidates numbered from ``first_index``, without the
        faces of the bundles ``hidden`` from them (:meth:`BundleCuller.hidden`: faces whose
        rays would all end in an occluder, so their pairs never qualify).

        Returns the pairs, when ``ordered`` sorted by (candidate, face), else in the order
        the search found them (cheaper where only some pairs are kept and sorted
        afterwards: :func:`sorted_by_face`), and how many pairs were tested.
        """
        points = np.ascontiguousarray(candidates_xyz, np.float64)
        keys, tests = self._cell_keys(points)
        tested = int(tests.sum())
        pairs = self._pass(points, first_index, hidden, self._sides(points), keys, tested,
                           (0, len(self._grid.run_group)))
        if ordered:
            pairs = pairs.subset(sorted_by_face(pairs.candidate, pairs.face))
        return pairs, tested

    def parts(self, candidate_xyz: NDArray[np.float64], index: int,
              hidden: HiddenBundles | None = None, *, most_tests: int) -> Iterator[Pairs]:
        """The pairs of one candidate (the (1, 3) ``candidate_xyz``, numbered ``index``)
        that :meth:`find` gives unordered, in parts of at most ``most_tests`` pair tests
        (a grid cell of more, or where every face is tested a run of the grid of more, is a
        part of its own): the same pairs in the same order, concatenated. A row of the
        overlap density reaches 25 m, most of a sports hall's 3.8 M pieces; found at once
        its pairs (40 bytes each) made the overlap rows' peak."""
        points = np.ascontiguousarray(candidate_xyz, np.float64).reshape(1, 3)
        keys, _ = self._cell_keys(points)
        sides = self._sides(points)
        grid = self._grid
        every_face = len(grid.start) - 1  # the key of a point that tests every face
        if len(keys) == 1 and int(keys[0]) == every_face:
            # consecutive runs of at most most_tests faces (a longer run: a part alone)
            first, n_runs = 0, len(grid.run_group)
            while first < n_runs:
                stop = int(np.searchsorted(grid.run_first, grid.run_first[first] + most_tests,
                                           "right")) - 1
                stop = min(max(stop, first + 1), n_runs)
                yield self._pass(points, index, hidden, sides, keys,
                                 int(grid.run_first[stop] - grid.run_first[first]),
                                 (first, stop))
                first = stop
            return
        # one point: its keys are its cells, in order; consecutive cells make a part
        counts = grid.start[keys + 1] - grid.start[keys]
        for first, stop in _consecutive_blocks(counts, len(counts), most_tests):
            yield self._pass(points, index, hidden, sides, keys[first:stop],
                             int(counts[first:stop].sum()), (0, 0))

    def _sides(self, points: NDArray[np.float64]
               ) -> tuple[NDArray[np.int8], NDArray[np.bool_], float]:
        """The shells' (F,) side of each face, (B,) whether each of the (B, 3) ``points``
        is outside every shell, and the shells' margin (none without shells)."""
        shells = self._shells
        if shells is None:
            return _NO_SIDES, np.zeros(len(points), bool), 0.0
        return shells.side, shells.outside(points), shells.margin_m

    def _pass(self, points: NDArray[np.float64], first_index: int,
              hidden: HiddenBundles | None,
              sides: tuple[NDArray[np.int8], NDArray[np.bool_], float],
              keys: NDArray[np.int64], tested: int, every_runs: tuple[int, int]) -> Pairs:
        """The pairs of (B, 3) ``points`` that pass the limits (:func:`_pass_limits`), in
        the order found, testing the cells ``keys`` names (``tested`` tests; the key that
        tests every face: the grid's runs ``every_runs``, first and stop);
        ``sides``: :meth:`_sides` of the points."""
        lim, grid = self.limits, self._grid
        if hidden is None:
            hidden_mask = np.zeros((len(points), 0), bool)
        elif hidden[0] is not self._bundle_of:
            raise ValueError("hidden bundles of another bundling than this search's "
                             "(PairFinder's bundle_of)")
        else:
            hidden_mask = hidden[1]
        face_side, outside, margin_m = sides
        # no more pairs than tests: untouched pages cost nothing
        pairs = Pairs(np.empty(tested, np.int32), np.empty(tested, np.int32),
                      np.empty((tested, 3), np.float32), np.empty((tested, 3), np.float32),
                      np.empty(tested, np.float32), np.empty(tested, np.float32))
        n = _pass_limits(
            points, keys, first_index, self._faces, self._points.xyz, self._points.corners,
            self._face_normal, self._face_source, self._face_class, self._min_sin_incidence,
            self._min_density, lim.dof_min_m, lim.dof_max_m, self._min_sin_elevation,
            self._max_sin_elevation, self.reach_m, lim.angular_step_rad, grid.cell_runs,
            grid.run_first, grid.run_group, grid.run_box, grid.members, every_runs,
            self._run_plane_face, self._run_plane, hidden_mask,
            face_side, outside, margin_m,
            pairs.candidate, pairs.face, pairs.origin, pairs.direction, pairs.distance_m,
            pairs.lpd_pts_m2,
        )
        # views of the first n rows: the block's arrays are short-lived
        return pairs.subset(slice(0, n))

    def _cell_keys(self, points: NDArray[np.float64]
                   ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        grid = self._grid
        return _cell_keys(points, len(self._faces), self.reach_m, grid.origin, grid.cell_m,
                          grid.dims, grid.start)

    def blocks(self, candidates_xyz: NDArray[np.float64], *, most_points: int = 64,
               most_tests: int = TESTS_PER_BLOCK) -> list[tuple[int, int]]:
        """(start, stop) of consecutive blocks of the (C, 3) candidates, each of at most
        ``most_points`` candidates and ``most_tests`` pair tests (at least one candidate):
        a block of neighbouring candidates shares the search of its cells, while its
        scratch (40 bytes a pair that passes, some of the tests) stays bounded. Depends on
        the candidates only, never on timing."""
        points = np.ascontiguousarray(candidates_xyz, np.float64)
        tests = np.concatenate([self._cell_keys(points[s:s + _KEY_BLOCK_POINTS])[1]
                                for s in range(0, len(points), _KEY_BLOCK_POINTS)]
                               or [np.zeros(0, np.int64)])
        return _consecutive_blocks(tests, most_points, most_tests)


def _consecutive_blocks(tests: NDArray[np.int64], most_points: int, most_tests: int
                        ) -> list[tuple[int, int]]:
    """(start, stop) of the blocks :meth:`PairFinder.blocks` describes, for the (C,) tests
    each candidate makes."""
    blocks = []
    start, total = 0, 0
    for c, count in enumerate(tests.tolist()):
        if c > start and (c - start >= most_points or total + count > most_tests):
            blocks.append((start, c))
            start, total = c, 0
        total += count
    if len(tests):
        blocks.append((start, len(tests)))
    return blocks


_Number = TypeVar("_Number", bound=np.number[Any])

# faces per block when the threshold classes are gathered: bounds the (b,) scratch keys
_CLASS_BLOCK_FACES = 1 << 20


def _distinct(values: NDArray[_Number]) -> NDArray[_Number]:
    """``np.unique(values)``, without its sort when every value is the same (a model
    without per-group requirements: each of a 10 M-face plan's pair searches sorted three
    (F,) arrays for one value, some 1.5 s before its threads could start)."""
    if len(values) and values.min() == values.max():
        return values[:1].copy()
    return np.unique(values)


def threshold_classes(
    faces: NDArray[np.int32], incidence_deg: NDArray[np.float64],
    density_pts_m2: NDArray[np.float64],
) -> tuple[NDArray[np.integer[Any]], NDArray[np.float64], NDArray[np.float64]]:
    """(f,) class of each of ``faces`` and the (K,) incidence and density of each class.

    A model has a handful of distinct requirements (its groups, IFC classes and GlobalIds
    with their own), so a face needs a 2-byte class instead of two float64 thresholds: 2
    instead of 16 bytes a face. The thresholds keep their float64 values; nothing is
    rounded. Computed a block of faces at a time (no (f,) sort).
    """
    blocks = [faces[s:s + _CLASS_BLOCK_FACES] for s in range(0, len(faces), _CLASS_BLOCK_FACES)]
    incidence_values = np.unique(np.concatenate(
        [_distinct(incidence_deg[b]) for b in blocks] or [np.zeros(0)]))
    density_values = np.unique(np.concatenate(
        [_distinct(density_pts_m2[b]) for b in blocks] or [np.zeros(0)]))

    def keys(block: NDArray[np.int32]) -> NDArray[np.int64]:
        """(b,) incidence rank x number of densities + density rank."""
        return (np.searchsorted(incidence_values, incidence_deg[block]).astype(np.int64)
                * len(density_values) + np.searchsorted(density_values, density_pts_m2[block]))

    present = np.unique(np.concatenate([_distinct(keys(b)) for b in blocks]
                                       or [np.zeros(0, np.int64)]))
    dtype = np.uint16 if len(present) <= np.iinfo(np.uint16).max else np.int32
    face_class: NDArray[np.integer[Any]] = np.empty(len(faces), dtype)
    for start, block in zip(range(0, len(faces), _CLASS_BLOCK_FACES), blocks, strict=True):
        face_class[start:start + len(block)] = np.searchsorted(present, keys(block))
    n_density = max(1, len(density_values))
    incidence: NDArray[np.float64] = incidence_values[present // n_density]
    density: NDArray[np.float64] = np.ascontiguousarray(density_values[present % n_density])
    return face_class, incidence, density
