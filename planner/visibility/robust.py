"""The robust coverage table (``robust: true``): a face counts for a candidate only when it
qualifies from the candidate and from every displaced setup of it.

Takes the plan's coverage table and the displaced setups of its candidates
(:func:`planner.candidates.placement.displaced_positions`); gives

- :func:`kept_faces`: which of a position's faces still qualify from each displaced setup
  (the same coverage model, limits and occlusion as the plan, tested only for the faces the
  position qualifies for: the others cannot be lost);
- :func:`robust_blocks`: the robust table's rows;
- :func:`disc_limits_hold`: the analytic limits over the whole disc of the tolerance;
- :func:`within_table`: a block of pairs cut to the table's rows of the stations.

Array letters: N positions, K displaced setups per position (K = 9, the first the position
itself), F faces.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Iterable, Iterator

import numpy as np
from numpy.typing import NDArray

from planner.candidates.placement import Displaced
from planner.limits import FaceLimits
from planner.scene import Scene
from planner.threads import in_block_order
from planner.visibility.coverage import CoverageTable, QualifiedPairs, StationRows

# (M, 3) positions, the limits with only the faces to test as targets -> the qualified
# pairs, numbered by position (0 .. M - 1), under the plan's coverage model
Qualify = Callable[[NDArray[np.float64], FaceLimits], Iterable[QualifiedPairs]]


def kept_faces(scene: Scene, displaced: Displaced,
               faces_of: Callable[[int], NDArray[np.int32]], limits: FaceLimits,
               qualify: Qualify, *, threads: int | None = None,
               notify: Callable[[float], None] | None = None,
               ) -> Iterator[tuple[NDArray[np.int32], NDArray[np.bool_]]]:
    """Per position, in order: its faces to test (``faces_of(n)``, ascending) and (K, f)
    bool, which of them qualify from each displaced setup. Setups that cannot stand
    (``displaced.valid`` false) and the position itself keep every face.

    Only the faces given are tested (the limits' targets are cut to them), so the cost is
    K - 1 rays per face of the position, not per face of the model. ``notify`` gets the
    fraction done after each position and may raise to stop.
    """
    def work(n: int) -> tuple[NDArray[np.int32], NDArray[np.bool_]]:
        faces = np.asarray(faces_of(n), np.int32)
        setups = np.flatnonzero(displaced.valid[n, 1:]) + 1
        kept = np.ones((len(displaced.offsets_m), len(faces)), bool)
        if len(faces) == 0 or len(setups) == 0:
            return faces, kept
        target = np.zeros(scene.n_faces, bool)
        target[faces] = True
        kept[setups] = False
        for block in qualify(displaced.positions[n, setups],
                             dataclasses.replace(limits, target=target)):
            kept[setups[block.candidate], np.searchsorted(faces, block.face)] = True
        return faces, kept

    return in_block_order(work, range(len(displaced.positions)), threads=threads,
                          notify=notify)


def robust_blocks(scene: Scene, table: CoverageTable, displaced: Displaced,
                  limits: FaceLimits, qualify: Qualify, *, disc_radius_m: float | None,
                  threads: int | None = None, notify: Callable[[float], None] | None = None,
                  ) -> Iterator[QualifiedPairs]:
    """The rows of the robust coverage table, a candidate at a time: the faces of
    ``table`` (each candidate's own) that qualify from every displaced setup of it too,
    and (``disc_radius_m``, the centroid model) pass the analytic limits from every point
    of the disc of that radius around it (:func:`disc_limits_hold`). The densities are not
    kept (the table keeps only the pattern)."""
    for candidate, (faces, kept) in enumerate(
            kept_faces(scene, displaced, table.faces_of, limits, qualify, threads=threads,
                       notify=notify)):
        keep = kept.all(axis=0)
        if disc_radius_m is not None:
            keep &= disc_limits_hold(scene, limits, displaced.positions[candidate, 0], faces,
                                     disc_radius_m)
        robust = faces[keep]
        yield QualifiedPairs(np.full(len(robust), candidate, np.int32), robust,
                             np.zeros(len(robust), np.float32))


def disc_limits_hold(scene: Scene, limits: FaceLimits, position: NDArray[np.float64],
                     faces: NDArray[np.int32], radius_m: float) -> NDArray[np.bool_]:
    """(f,) bool: the centroid of each of ``faces`` passes the analytic limits (range,
    elevation, incidence, density) from every point of the horizontal disc of ``radius_m``
    around ``position`` (the head at the same height), by bounds that hold over the disc:

    - the horizontal distance h to the centroid lies in [h - r, h + r] (not below 0), so the
      range in [hypot(h - r, dz), hypot(h + r, dz)], and the elevation's sine dz / range is
      extreme at the two ends;
    - the beam turns by at most asin(r / d) (d the distance from the disc's centre), so the
      incidence is at least the centre's minus that angle, and the density at least
      sin(that incidence) / (SPS * farthest range)^2.

    The occlusion ray cannot be bounded this way: it is tested at the setups only.
    """
    offset = scene.centroids_of(faces) - position  # (f, 3)
    dz = offset[:, 2]
    horizontal = np.hypot(offset[:, 0], offset[:, 1])
    distance = np.linalg.norm(offset, axis=1)
    near = np.hypot(np.maximum(horizontal - radius_m, 0.0), dz)
    far = np.hypot(horizontal + radius_m, dz)
    ok = (near >= limits.dof_min_m) & (far <= limits.dof_max_m) & (distance > radius_m)
    low = math.sin(math.radians(limits.elevation_min_deg))
    high = math.sin(math.radians(limits.elevation_max_deg))
    for reach in (near, far):
        sine = np.divide(dz, reach, out=np.zeros_like(dz), where=reach > 0)
        ok &= (sine >= low) & (sine <= high)
    unit = offset / np.maximum(distance, 1e-12)[:, None]
    incidence = np.arcsin(np.clip(np.abs(np.einsum("ij,ij->i", unit, scene.normals_of(faces))),
                                  0.0, 1.0))
    turn = np.arcsin(np.clip(radius_m / np.maximum(distance, 1e-12), 0.0, 1.0))
    worst = np.sin(np.maximum(incidence - turn, 0.0))
    ok &= worst >= np.sin(np.radians(limits.min_incidence_deg[faces]))
    ok &= worst / (limits.angular_step_rad * far) ** 2 >= limits.min_density_pts_m2[faces]
    return np.asarray(ok)


def within_table(blocks: Iterable[QualifiedPairs], table: CoverageTable | StationRows,
                 stations: tuple[int, ...]) -> Iterator[QualifiedPairs]:
    """The pairs of ``blocks`` (numbered by their place in ``stations``) that are in the
    table's rows of those stations: a robust table credits a station fewer faces than it
    qualifies for from its planned position."""
    for block in blocks:
        keep = np.zeros(len(block.face), bool)
        for order in np.unique(block.candidate):
            rows = np.flatnonzero(block.candidate == order)
            keep[rows] = np.isin(block.face[rows], table.faces_of(stations[int(order)]),
                                 assume_unique=True)
        yield QualifiedPairs(block.candidate[keep], block.face[keep], block.lpd_pts_m2[keep])
