"""The sampled coverage model (``coverage_model: "sampled"``).

The paper's model (``"centroid"``) tests one ray to the face centroid with
``LPD = sin(alpha) / (SPS d)^2``. A scanner's azimuth x elevation grid is denser by
``1 / cos(elevation)`` off the horizon, and an obstacle edge can shadow part of a face
whose centroid is visible. The sampled model tests ``samples_per_face`` points per face
instead, each with its own occlusion ray, distance, elevation and incidence limits and the
density ``LPD / cos(elevation)``. A pair (candidate, face) qualifies when the samples that
pass every test stand for at least ``min_sampled_fraction`` of the face's area; its
density is the lowest density of those samples.

Each sample must meet the density itself. Requiring only the mean of the samples'
densities (the returns per m^2 the grid puts on the face) promised 0.64 m^2 (0.19 %) of
hall-full that the simulated scan did not deliver: faces at the threshold, where the
grid's points fall a few percent short.

Sample points: the centroids of the ``n x n`` equal triangles of a barycentric grid
(``samples_per_face = n^2``), so every sample stands for the same share of the face's
area and the pattern is the same for every run.

Pairs are first found with the analytic limits at the centroid, relaxed by what a sample
can differ from the centroid (see :func:`relaxed_limits`); the samples then decide.
Array letters: C candidates, F faces, P pairs, N samples per face.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import replace

import numba
import numpy as np
from numpy.typing import NDArray

from planner.errors import CancelledError
from planner.limits import FaceLimits
from planner.progress import ProgressCallback
from planner.rays import Occlusion
from planner.scene import Scene
from planner.threads import in_block_order
from planner.visibility.coverage import QualifiedPairs
from planner.visibility.pairs import PairFinder, Pairs

# The centroid pre-filter keeps pairs down to this fraction of the required density: the
# 1 / cos(elevation) gain of the grid reaches 5 at 78 deg elevation.
_PREFILTER_DENSITY_FRACTION = 0.2
# ... and, with that gain counted, down to this fraction: the samples of a face lie within
# its size of the centroid, which changes the density by far less than half on the faces
# a plan qualifies (0.2 m faces at 1.5 m or more).
_PREFILTER_CENTROID_FRACTION = 0.5
# candidates per block, and pairs per chunk of sample arithmetic (~16 samples each):
# bounds the (P, N, 3) float64 scratch arrays near 40 MB
_CANDIDATES_PER_BLOCK = 4
_PAIRS_PER_CHUNK = 100_000


def sample_weights(samples_per_face: int) -> NDArray[np.float64]:
    """(N, 3) float64 barycentric weights of the sample points (see the module docstring)."""
    n = math.isqrt(samples_per_face)
    weights = []
    for row in range(n):
        for col in range(n - row):
            # the "down" triangle (row, col) and, inside the face, the "up" one after it
            weights.append(((row + 1 / 3) / n, (col + 1 / 3) / n))
            if row + col < n - 1:
                weights.append(((row + 2 / 3) / n, (col + 2 / 3) / n))
    b = np.array(weights)
    return np.column_stack([1.0 - b.sum(axis=1), b[:, 0], b[:, 1]])


def sample_stages(samples_per_face: int) -> tuple[NDArray[np.int64], ...]:
    """The sample indices in the order their occlusion rays are cast: the first sample
    (the triangle in the first corner), then those in the two other corners, then the rest.
    A shadow that crosses a face usually covers a corner."""
    n = math.isqrt(samples_per_face)
    if n < 2:
        return (np.arange(samples_per_face, dtype=np.int64),)
    # "down" triangles (row, col) in sample_weights order: row 0 holds 2 n - 1 samples
    corners = np.array([2 * n - 2, samples_per_face - 1], np.int64)
    rest = np.setdiff1d(np.arange(1, samples_per_face, dtype=np.int64), corners)
    return np.array([0], np.int64), corners, rest


def relaxed_limits(scene: Scene, limits: FaceLimits) -> FaceLimits:
    """Centroid limits that every pair with a passing sample also passes.

    A sample lies within r (the largest centroid-to-corner distance of the target faces) of
    its centroid: distances widen by r, and directions differ by at most
    ``asin(r / dof_min_m)``, which widens the elevation and incidence limits. The density
    limit drops to a fifth (the grid's gain off the horizon, see the module constants).
    """
    target = limits.target
    corners = scene.vertices[scene.faces[target]]  # (T, 3, 3); not every face's corners
    centre = scene.centroids_of(np.flatnonzero(target))[:, None]  # (T, 1, 3)
    radius_m = float(np.linalg.norm(corners - centre, axis=2).max()) if target.any() else 0.0
    pad_deg = 90.0 if radius_m >= limits.dof_min_m else math.degrees(
        math.asin(radius_m / limits.dof_min_m)) if limits.dof_min_m > 0 else 90.0
    return replace(
        limits,
        dof_min_m=max(0.0, limits.dof_min_m - radius_m),
        dof_max_m=limits.dof_max_m + radius_m,
        elevation_min_deg=max(-90.0, limits.elevation_min_deg - pad_deg),
        elevation_max_deg=min(90.0, limits.elevation_max_deg + pad_deg),
        min_incidence_deg=np.maximum(limits.min_incidence_deg - pad_deg, 0.0),
        min_density_pts_m2=limits.min_density_pts_m2 * _PREFILTER_DENSITY_FRACTION,
    )


class SampledQualifier:
    """Decides the pairs of a block of candidates by their sample points."""

    def __init__(self, scene: Scene, limits: FaceLimits, occlusion: Occlusion,
                 samples_per_face: int, min_sampled_fraction: float) -> None:
        self.scene = scene
        self.limits = limits
        self.occlusion = occlusion
        self.finder = PairFinder(scene, relaxed_limits(scene, limits))
        self.weights = sample_weights(samples_per_face)
        self.stages = sample_stages(samples_per_face)
        # a pair qualifies with at most this many failing samples
        n = len(self.weights)
        self.max_failures = math.floor(n * (1.0 - min_sampled_fraction) + 1e-9)
        self.min_sin_elevation = math.sin(math.radians(limits.elevation_min_deg))
        self.max_sin_elevation = math.sin(math.radians(limits.elevation_max_deg))
        self.min_sin_incidence = np.sin(np.radians(limits.min_incidence_deg))
        self.triangles = np.ascontiguousarray(scene.triangles)
        self.normals = np.ascontiguousarray(scene.normals)

    def block(self, positions: NDArray[np.float64], first_index: int
              ) -> tuple[QualifiedPairs, int, int]:
        """Qualified pairs of (B, 3) candidates; pairs tested and rays cast."""
        pairs, tested = self.finder.find(positions, first_index)
        parts, rays = [], 0
        for start in range(0, len(pairs), _PAIRS_PER_CHUNK):
            part, cast = self._chunk(pairs.subset(slice(start, start + _PAIRS_PER_CHUNK)))
            parts.append(part)
            rays += cast
        return QualifiedPairs.concatenate(parts), tested, rays

    def sample_limits(self, pairs: Pairs) -> tuple[
            NDArray[np.int64], NDArray[np.bool_], NDArray[np.float32], NDArray[np.float32],
            NDArray[np.float32]]:
        """The analytic limits of every sample of the P ``pairs`` (no occlusion yet).

        Returns (P,) face, (P, N) passes, (P, N) LPD / cos(elevation), (P, N, 3) unit
        direction and (P, N) distance in metres of each sample.
        """
        lim = self.limits
        face = pairs.face.astype(np.int64)
        n_pairs, n = len(face), len(self.weights)
        passes = np.zeros((n_pairs, n), np.bool_)
        lpd = np.zeros((n_pairs, n), np.float32)
        direction = np.zeros((n_pairs, n, 3), np.float32)
        distance = np.zeros((n_pairs, n), np.float32)
        _sample_limits(
            pairs.origin, face, self.triangles, self.normals, self.weights,
            lim.dof_min_m, lim.dof_max_m, self.min_sin_elevation, self.max_sin_elevation,
            self.min_sin_incidence, lim.min_density_pts_m2, lim.angular_step_rad,
            _PREFILTER_CENTROID_FRACTION, passes, lpd, direction, distance)
        return face, passes, lpd, direction, distance

    def _chunk(self, pairs: Pairs) -> tuple[QualifiedPairs, int]:
        face, passes, lpd, direction, distance = self.sample_limits(pairs)
        n = passes.shape[1]
        alive = (n - passes.sum(axis=1)) <= self.max_failures
        # occlusion rays only where the pair can still qualify, in stages (see
        # sample_stages): a pair hidden at its first sample or at a corner usually stops
        # there. A pair's failures only grow, so the stages decide the same pairs.
        rays = 0
        for columns in self.stages:
            p_idx, s_idx = np.nonzero(passes[:, columns] & alive[:, None])
            s_idx = columns[s_idx]
            if len(p_idx):
                visible = self.occlusion.visible(
                    pairs.origin[p_idx], direction[p_idx, s_idx], distance[p_idx, s_idx],
                    face[p_idx])
                passes[p_idx[~visible], s_idx[~visible]] = False
                rays += len(p_idx)
            alive &= (n - passes.sum(axis=1)) <= self.max_failures
        keep = alive & passes.any(axis=1)
        lowest = np.where(passes, lpd, np.float32(np.inf)).min(axis=1)
        return QualifiedPairs(pairs.candidate[keep], pairs.face[keep],
                              lowest[keep].astype(np.float32)), rays


@numba.njit(nogil=True, cache=True)
def _sample_limits(  # compiled; its cases are in tests/planner/test_sampled.py
    origin: NDArray[np.float32], face: NDArray[np.int64], triangles: NDArray[np.float64],
    normals: NDArray[np.float64], weights: NDArray[np.float64],
    dof_min_m: float, dof_max_m: float, min_sin_elevation: float, max_sin_elevation: float,
    min_sin_incidence: NDArray[np.float64], min_density: NDArray[np.float64],
    angular_step_rad: float, centroid_fraction: float,
    out_passes: NDArray[np.bool_], out_lpd: NDArray[np.float32],
    out_direction: NDArray[np.float32], out_distance: NDArray[np.float32],
) -> None:
    """For (P,) pairs and (N, 3) barycentric weights: which samples pass every analytic
    limit, their density LPD / cos(elevation) and their rays ((P, N) and (P, N, 3)).

    A pair whose centroid density (with the grid's gain) is under ``centroid_fraction`` of
    the requirement is skipped: its samples, within a face's size of the centroid, cannot
    reach it.
    """
    n_samples = weights.shape[0]
    for p in range(face.shape[0]):
        f = face[p]
        ox, oy, oz = float(origin[p, 0]), float(origin[p, 1]), float(origin[p, 2])
        cx = (triangles[f, 0, 0] + triangles[f, 1, 0] + triangles[f, 2, 0]) / 3.0 - ox
        cy = (triangles[f, 0, 1] + triangles[f, 1, 1] + triangles[f, 2, 1]) / 3.0 - oy
        cz = (triangles[f, 0, 2] + triangles[f, 1, 2] + triangles[f, 2, 2]) / 3.0 - oz
        dc = np.sqrt(cx * cx + cy * cy + cz * cz)
        hc = np.sqrt(cx * cx + cy * cy)
        if dc <= 0.0:
            continue
        sc = abs(cx * normals[f, 0] + cy * normals[f, 1] + cz * normals[f, 2]) / dc
        spacing = angular_step_rad * dc
        if hc > 0.0 and sc * dc / (spacing * spacing * hc) < centroid_fraction * min_density[f]:
            continue
        for k in range(n_samples):
            x = (weights[k, 0] * triangles[f, 0, 0] + weights[k, 1] * triangles[f, 1, 0]
                 + weights[k, 2] * triangles[f, 2, 0]) - ox
            y = (weights[k, 0] * triangles[f, 0, 1] + weights[k, 1] * triangles[f, 1, 1]
                 + weights[k, 2] * triangles[f, 2, 1]) - oy
            z = (weights[k, 0] * triangles[f, 0, 2] + weights[k, 1] * triangles[f, 1, 2]
                 + weights[k, 2] * triangles[f, 2, 2]) - oz
            d = np.sqrt(x * x + y * y + z * z)
            if d <= 0.0 or d < dof_min_m or d > dof_max_m:
                continue
            uz = z / d
            if uz < min_sin_elevation or uz > max_sin_elevation:
                continue
            ux, uy = x / d, y / d
            s = abs(ux * normals[f, 0] + uy * normals[f, 1] + uz * normals[f, 2])
            if s < min_sin_incidence[f]:
                continue
            cos_elevation = np.sqrt(ux * ux + uy * uy)
            spacing = angular_step_rad * d
            lpd = np.inf if cos_elevation <= 0.0 else s / (spacing * spacing * cos_elevation)
            if lpd < min_density[f]:
                continue
            out_passes[p, k] = True
            out_lpd[p, k] = lpd
            out_direction[p, k, 0] = ux
            out_direction[p, k, 1] = uy
            out_direction[p, k, 2] = uz
            out_distance[p, k] = d


def qualify_sampled_pairs(
    scene: Scene,
    positions: NDArray[np.float64],
    limits: FaceLimits,
    occlusion: Occlusion,
    samples_per_face: int,
    min_sampled_fraction: float,
    *,
    progress: ProgressCallback | None = None,
    threads: int | None = None,
) -> Iterator[tuple[QualifiedPairs, int, int]]:
    """The qualified pairs of (C, 3) candidates under the sampled model, block by block in
    candidate order (each sorted by (candidate, face)), with the pairs tested and rays cast
    for it. Blocks run on a thread pool and come out in candidate order, so the result does
    not depend on timing."""
    qualifier = SampledQualifier(scene, limits, occlusion, samples_per_face,
                                 min_sampled_fraction)
    starts = range(0, len(positions), _CANDIDATES_PER_BLOCK)

    def notify(fraction: float) -> None:
        if progress is not None and progress("visibility", fraction):
            raise CancelledError("the plan was cancelled during visibility")

    return in_block_order(
        lambda s: qualifier.block(positions[s:s + _CANDIDATES_PER_BLOCK], s), starts,
        threads=threads, notify=notify)
