"""A simulated scan: the scanner's real angular pattern, every return counted on its face.

The plan's model (the paper's) promises a density from one ray to the face centroid. A
terrestrial laser scanner instead fires an azimuth x elevation grid of rays from each
station. This module fires that grid against the scene with Embree (closest hit) and
counts the returns per face, so that a plan can be checked against what a scan delivers.

The pattern of one station (all angles in radians):

- azimuth: ``A = round(2 pi / step)`` directions ``2 pi k / A``, k = 0 .. A - 1;
- elevation: ``E = round((elevation_max - elevation_min) / step)`` rows at
  ``elevation_min + (i + 1/2) step`` (half a step in, so no row sits on the zenith, where
  every azimuth would hit the same point);
- ``step = point_spacing_m / reference_distance_m`` (1 mrad with the defaults: A = 6283,
  E = 2618, 16.4 M rays per station).

A return counts for its face when the face is hit first and its range lies in
``[dof_min_m, dof_max_m]`` (the scanner records nothing outside; such faces still block
the rays behind them). Density of a face = returns / face area (pts/m^2). The incidence
requirement is applied by :mod:`planner.truth.verification`, per station and face.

Holes are measured on sub-face bins: each face is split into ``n x n`` equal triangles of
a barycentric grid (the triangles of ``n - 1`` evenly spaced lines parallel to each side),
``n = ceil(longest edge / HOLE_BIN_EDGE_M)``, so every bin has area ``area / n^2`` and an
edge of at most ``HOLE_BIN_EDGE_M``. A bin of a promised face is a hole when no station
samples it at half the face's required density.

Rays are cast in blocks of elevation rows on a thread pool (Embree releases the GIL), and
per-face counts are accumulated with ``np.bincount``: memory stays bounded by the block.
Counts are integers summed in a fixed order, so the result does not depend on threads.
Array letters: F faces, S stations, R rays of a block, B bins.
"""

from __future__ import annotations

import math
import os
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import NDArray

from planner.errors import CancelledError
from planner.limits import FaceLimits
from planner.parameters import PlanSpec
from planner.progress import ProgressCallback
from planner.scene import Scene

# Longest edge of a hole bin: 0.1 m is the size of a target or a bolt a survey must not
# miss, and still holds ~100 returns at the paper's 45,000 pts/m^2 requirement.
HOLE_BIN_EDGE_M = 0.1
# Bins per face at most (n <= 16): a 1.6 m face is split into 256 bins, larger faces get
# larger bins rather than unbounded memory.
_MAX_BIN_SPLITS = 16
# Rays per block of work: ~400 k rays keep a block's scratch arrays near 40 MB.
_RAYS_PER_BLOCK = 400_000
# A hole is a bin sampled below this fraction of the face's requirement.
HOLE_DENSITY_FRACTION = 0.5


@dataclass(frozen=True)
class ScanPattern:
    """The angular grid and range window of the scanner."""

    angular_step_rad: float
    elevation_min_deg: float
    elevation_max_deg: float
    range_min_m: float
    range_max_m: float

    @classmethod
    def from_spec(cls, spec: PlanSpec) -> ScanPattern:
        return cls(spec.angular_step_rad, spec.elevation_min_deg, spec.elevation_max_deg,
                   spec.dof_min_m, spec.dof_max_m)

    @property
    def azimuths_rad(self) -> NDArray[np.float64]:
        """(A,) float64: a full turn in equal steps as close to the angular step as fits."""
        n = max(1, round(2 * math.pi / self.angular_step_rad))
        return np.arange(n, dtype=np.float64) * (2 * math.pi / n)

    @property
    def elevations_rad(self) -> NDArray[np.float64]:
        """(E,) float64: rows half a step inside the elevation window."""
        low = math.radians(self.elevation_min_deg)
        span = math.radians(self.elevation_max_deg) - low
        n = max(1, round(span / self.angular_step_rad))
        return low + (np.arange(n, dtype=np.float64) + 0.5) * (span / n)

    @property
    def rays_per_station(self) -> int:
        return len(self.azimuths_rad) * len(self.elevations_rad)

    def to_dict(self) -> dict[str, float | int]:
        return {
            "angular_step_rad": self.angular_step_rad,
            "azimuth_steps": len(self.azimuths_rad),
            "elevation_rows": len(self.elevations_rad),
            "rays_per_station": self.rays_per_station,
            "elevation_min_deg": self.elevation_min_deg,
            "elevation_max_deg": self.elevation_max_deg,
            "range_min_m": self.range_min_m,
            "range_max_m": self.range_max_m,
        }


@dataclass(frozen=True, eq=False)
class HoleBins:
    """The sub-face bins of every face (see the module docstring).

    Attributes
    ----------
    splits : (F,) int64, n of each face (n x n bins)
    offset : (F,) int64, index of the face's first bin slot; a face has 2 n^2 slots, of
        which the n^2 valid ones are ``valid``
    valid : (2 sum n^2,) bool
    face : (2 sum n^2,) int64, the face of each slot
    """

    splits: NDArray[np.int64]
    offset: NDArray[np.int64]
    valid: NDArray[np.bool_]
    face: NDArray[np.int64]

    @classmethod
    def of(cls, scene: Scene) -> HoleBins:
        edges = scene.triangles - np.roll(scene.triangles, 1, axis=1)
        longest = np.linalg.norm(edges, axis=2).max(axis=1)
        splits = np.clip(np.ceil(longest / HOLE_BIN_EDGE_M - 1e-9), 1,
                         _MAX_BIN_SPLITS).astype(np.int64)
        slots = 2 * splits * splits
        offset = np.concatenate([[0], np.cumsum(slots)[:-1]]).astype(np.int64)
        face = np.repeat(np.arange(scene.n_faces, dtype=np.int64), slots)
        local = np.arange(int(slots.sum()), dtype=np.int64) - offset[face]
        n = splits[face]
        upper, cell = local % 2, local // 2
        row, col = cell // n, cell % n
        # slot (row, col, upper) is inside the triangle when row + col + upper <= n - 1
        valid = row + col + upper <= n - 1
        return cls(splits, offset, valid, face)


@dataclass(frozen=True, eq=False)
class ScanCounts:
    """What the simulated scan delivered.

    Attributes
    ----------
    returns : (S, F) int64, returns each station delivers on each face
    best_bin_lpd_pts_m2 : (2 sum n^2,) float64, the best station's density per bin slot
    rays : (S,) int64 rays fired, hits : (S,) int64 rays that hit a face
    """

    pattern: ScanPattern
    bins: HoleBins
    returns: NDArray[np.int64]
    best_bin_lpd_pts_m2: NDArray[np.float64]
    rays: NDArray[np.int64]
    hits: NDArray[np.int64]


def simulate_scan(
    scene: Scene,
    limits: FaceLimits,
    pattern: ScanPattern,
    stations_xyz: NDArray[np.float64],
    *,
    progress: ProgressCallback | None = None,
    threads: int | None = None,
) -> ScanCounts:
    """Fire the pattern from every (S, 3) station and count the returns per face and bin."""
    from planner.rays.embree import EmbreeOcclusion

    caster = EmbreeOcclusion(scene, limits.occludes)
    stations = np.asarray(stations_xyz, np.float64).reshape(-1, 3)
    azimuths, elevations = pattern.azimuths_rad, pattern.elevations_rad
    rows_per_block = max(1, _RAYS_PER_BLOCK // len(azimuths))
    bins = HoleBins.of(scene)
    n_faces, n_slots = scene.n_faces, len(bins.valid)
    triangles = scene.triangles
    corner = triangles[:, 0]
    edge1, edge2 = triangles[:, 1] - corner, triangles[:, 2] - corner
    d00 = np.einsum("ij,ij->i", edge1, edge1)
    d01 = np.einsum("ij,ij->i", edge1, edge2)
    d11 = np.einsum("ij,ij->i", edge2, edge2)
    det = d00 * d11 - d01 * d01
    inv_det = np.divide(1.0, det, out=np.zeros_like(det), where=det > 0)
    normals = np.ascontiguousarray(scene.normals)
    # (A, 2) cos/sin of the azimuths, shared by every row
    cos_az, sin_az = np.cos(azimuths), np.sin(azimuths)

    def block(station: int, first_row: int) -> tuple[int, NDArray[np.int64], NDArray[np.int64],
                                                      int]:
        rows = elevations[first_row:first_row + rows_per_block]
        directions = np.empty((len(rows) * len(azimuths), 3), np.float32)
        _directions(np.cos(rows), np.sin(rows), cos_az, sin_az, directions)
        origins = np.empty_like(directions)
        origins[:] = stations[station].astype(np.float32)
        face = caster.first_face(origins, directions)
        per_face = np.zeros(n_faces, np.int64)
        per_slot = np.zeros(n_slots, np.int64)
        n_hits = _count_returns(
            face, directions, stations[station], normals, corner, edge1, edge2, d00, d01,
            d11, inv_det, pattern.range_min_m, pattern.range_max_m,
            bins.splits, bins.offset, per_face, per_slot)
        return station, per_face, per_slot, n_hits

    tasks = [(s, r) for s in range(len(stations))
             for r in range(0, len(elevations), rows_per_block)]
    returns = np.zeros((len(stations), n_faces), np.int64)
    slot_counts = np.zeros((len(stations), n_slots), np.int64)
    hits = np.zeros(len(stations), np.int64)
    workers = threads or os.cpu_count() or 1
    with ThreadPoolExecutor(max_workers=workers) as pool:
        # submitted a few at a time: the scratch arrays of queued blocks are never built
        pending = []
        done = 0
        for task in tasks:
            pending.append(pool.submit(block, *task))
            if len(pending) >= 2 * workers:
                done = _collect(pending.pop(0), returns, slot_counts, hits, done)
                _notify(progress, done / len(tasks))
        while pending:
            done = _collect(pending.pop(0), returns, slot_counts, hits, done)
            _notify(progress, done / len(tasks))
    bin_area_m2 = scene.areas[bins.face] / (bins.splits[bins.face] ** 2)
    best = slot_counts.max(axis=0, initial=0) if len(stations) else np.zeros(n_slots, np.int64)
    best_bin_lpd = np.divide(best, bin_area_m2, out=np.zeros(n_slots), where=bin_area_m2 > 0)
    return ScanCounts(pattern=pattern, bins=bins, returns=returns,
                      best_bin_lpd_pts_m2=best_bin_lpd,
                      rays=np.full(len(stations), pattern.rays_per_station, np.int64),
                      hits=hits)


@numba.njit(nogil=True, cache=True)
def _directions(cos_el: NDArray[np.float64], sin_el: NDArray[np.float64],
                cos_az: NDArray[np.float64], sin_az: NDArray[np.float64],
                out: NDArray[np.float32]) -> None:
    """Unit directions of (E,) rows x (A,) azimuths, row-major, into (E * A, 3) ``out``."""
    n_az = cos_az.shape[0]
    for i in range(cos_el.shape[0]):
        for k in range(n_az):
            r = i * n_az + k
            out[r, 0] = cos_el[i] * cos_az[k]
            out[r, 1] = cos_el[i] * sin_az[k]
            out[r, 2] = sin_el[i]


@numba.njit(nogil=True, cache=True)
def _count_returns(
    face: NDArray[np.int64], directions: NDArray[np.float32], origin: NDArray[np.float64],
    normals: NDArray[np.float64], corner: NDArray[np.float64], edge1: NDArray[np.float64],
    edge2: NDArray[np.float64], d00: NDArray[np.float64], d01: NDArray[np.float64],
    d11: NDArray[np.float64], inv_det: NDArray[np.float64],
    range_min_m: float, range_max_m: float,
    splits: NDArray[np.int64], offset: NDArray[np.int64],
    per_face: NDArray[np.int64], per_slot: NDArray[np.int64],
) -> int:
    """Add the returns of (R,) first-hit ``face`` ids (-1 a miss) to the per-face and per-bin
    counts; returns how many rays hit a face.

    A return counts when its range (ray to the face's plane) is inside the range window.
    """
    n_hits = 0
    for r in range(face.shape[0]):
        f = face[r]
        if f < 0:
            continue
        n_hits += 1
        dx, dy, dz = float(directions[r, 0]), float(directions[r, 1]), float(directions[r, 2])
        facing = normals[f, 0] * dx + normals[f, 1] * dy + normals[f, 2] * dz
        if facing == 0.0:  # the ray runs in the face's plane: an edge graze, no return
            continue
        ax = corner[f, 0] - origin[0]
        ay = corner[f, 1] - origin[1]
        az = corner[f, 2] - origin[2]
        range_m = (normals[f, 0] * ax + normals[f, 1] * ay + normals[f, 2] * az) / facing
        if range_m < range_min_m or range_m > range_max_m:
            continue
        # hit point relative to the face's first corner, then its barycentric coordinates
        px, py, pz = dx * range_m - ax, dy * range_m - ay, dz * range_m - az
        p1 = px * edge1[f, 0] + py * edge1[f, 1] + pz * edge1[f, 2]
        p2 = px * edge2[f, 0] + py * edge2[f, 1] + pz * edge2[f, 2]
        b1 = min(max((d11[f] * p1 - d01[f] * p2) * inv_det[f], 0.0), 1.0)
        b2 = min(max((d00[f] * p2 - d01[f] * p1) * inv_det[f], 0.0), 1.0)
        n = splits[f]
        a, b = b1 * n, b2 * n
        row = min(int(a), n - 1)
        col = min(int(b), n - 1 - row)
        upper = 1 if (a - row) + (b - col) > 1.0 and row + col < n - 1 else 0
        per_face[f] += 1
        per_slot[offset[f] + 2 * (row * n + col) + upper] += 1
    return n_hits


def _collect(future: Future[tuple[int, NDArray[np.int64], NDArray[np.int64], int]],
             returns: NDArray[np.int64], slot_counts: NDArray[np.int64],
             hits: NDArray[np.int64], done: int) -> int:
    station, per_face, per_slot, n_hits = future.result()
    returns[station] += per_face
    slot_counts[station] += per_slot
    hits[station] += n_hits
    return done + 1


def _notify(progress: ProgressCallback | None, fraction: float) -> None:
    if progress is not None and progress("simulation", min(max(fraction, 0.0), 1.0)):
        raise CancelledError("the verification was cancelled during the simulated scan")
