"""Registration overlap between stations, and greedy selection that keeps it connected.

Two stations *overlap* when the faces both qualify for at ``overlap_density_pts_m2`` (the
density at which a surface counts for cloud-to-cloud registration; the occlusion ray and
the analytic limits apply as for coverage) have a total area of at least
``min_overlap_m2`` AND those shared faces constrain a rigid registration in all three
directions. The constraint test: with ``M = sum_f area_f * n_f n_f^T`` the area-weighted
scatter matrix of the shared faces' unit normals,

    constraint = smallest eigenvalue of M / trace(M)        (0 .. 1/3)

It is 0 when every normal lies in one plane (a corridor of parallel walls and floor slides
along its axis: point-to-plane registration cannot fix that translation) and 1/3 for three
equal orthogonal planes. An edge needs ``constraint >= MIN_CONSTRAINT``.

With the constraint on, :func:`connected_greedy` runs the paper's greedy (or weighted
greedy) but, after the first station, considers only candidates that overlap a chosen
station. When no such candidate adds area while area is left, it adds a *relay*: the
allowed candidate nearest to the best candidate not yet allowed (ties to the lowest index),
which adds no area but opens the way. It stops when no allowed candidate is left or a relay
would be no nearer to its target than the previous one (the rest cannot be registered:
the plan then reports ``goal_reached`` false).

Array letters: C candidates, F faces, S stations.
"""

from __future__ import annotations

import contextlib
import functools
import itertools
from collections.abc import Callable, Iterable
from typing import Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from planner.scene import Scene
from planner.selection.connectivity import OverlapGraph
from planner.selection.greedy import GOAL_SLACK_M2, GainOrder, Selection, gain_units
from planner.visibility.coverage import CoverageTable
from planner.visibility.overlap import OverlapRows

# smallest eigenvalue over trace of the normal scatter matrix for an edge to register in
# all three directions: the weakest direction carries at least 5 % of the normal weight
MIN_CONSTRAINT = 0.05


# the six terms of the packed symmetric normal scatter matrix: xx, yy, zz, xy, xz, yz
SCATTER_TERMS = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))


def scatter_weights(scene: Scene) -> NDArray[np.float64]:
    """(F, 6) float64: area * (nx nx, ny ny, nz nz, nx ny, nx nz, ny nz) per face."""
    return scatter_weights_of(scene, slice(None))


def scatter_weights_of(scene: Scene, faces: NDArray[np.integer[Any]] | slice
                        ) -> NDArray[np.float64]:
    """(n, 6) float64: the rows ``faces`` of :func:`scatter_weights`, without the (F, 6)
    array (48 bytes a face) when only some faces are wanted."""
    n, area_m2 = scene.normals_of(faces), scene.areas[faces]
    return np.stack([n[:, i] * n[:, j] * area_m2 for i, j in SCATTER_TERMS], axis=1)


def constraint_of(scatter6: NDArray[np.float64]) -> NDArray[np.float64]:
    """(N,) smallest eigenvalue / trace of the (N, 6) packed symmetric 3x3 matrices."""
    xx, yy, zz, xy, xz, yz = scatter6.T
    m = np.stack([np.stack([xx, xy, xz], -1), np.stack([xy, yy, yz], -1),
                  np.stack([xz, yz, zz], -1)], axis=-2)
    trace = xx + yy + zz
    smallest = np.linalg.eigvalsh(m)[:, 0] if len(m) else np.zeros(0)
    ratio: NDArray[np.float64] = np.divide(np.maximum(smallest, 0.0), trace,
                                           out=np.zeros_like(trace), where=trace > 0)
    return ratio


def overlap_with(overlap: sp.csr_matrix, row: int, scene: Scene,
                 weights6: NDArray[np.float64]) -> tuple[NDArray[np.float64],
                                                         NDArray[np.float64]]:
    """Overlap area (m^2) and constraint of row ``row`` with every row of ``overlap``.

    ``overlap``: (N, F) CSR float64 of 0/1 (float once, so each call is two products).
    """
    faces = overlap.indices[overlap.indptr[row]:overlap.indptr[row + 1]]
    mask = np.zeros(scene.n_faces)
    mask[faces] = 1.0
    area = np.asarray(overlap @ (scene.areas * mask)).reshape(-1)
    scatter = np.asarray(overlap @ (weights6 * mask[:, None]))
    return area, constraint_of(scatter)


def _shared_with(rows: sp.csr_matrix, faces: NDArray[np.int64], area_m2: NDArray[np.float64],
                 weights6: Callable[[NDArray[np.int32]], NDArray[np.float64]]
                 ) -> NDArray[np.float64]:
    """(N, 7) float64: overlap area and the six scatter sums of every row of the (N, F)
    0/1 ``rows`` with the (n,) ascending ``faces`` of one overlap row; ``weights6`` gives
    the (k, 6) scatter weights of k faces (:func:`scatter_weights_of`).

    Each sum runs over the row's faces in ascending order, as ``rows`` times the dense (F,)
    area and (F, 6) weights masked to ``faces`` would (there the other terms add 0.0), in
    memory of the rows' size rather than the model's.
    """
    entry_row = np.repeat(np.arange(rows.shape[0]), np.diff(rows.indptr))
    at = np.minimum(np.searchsorted(faces, rows.indices), max(len(faces) - 1, 0))
    hit = np.flatnonzero(faces[at] == rows.indices) if len(faces) else np.zeros(0, np.int64)
    shared_faces, shared_row = rows.indices[hit], entry_row[hit]
    columns = [area_m2[shared_faces], *weights6(shared_faces).T]
    # (an empty bincount is int64 whatever its weights)
    return np.stack([np.bincount(shared_row, weights=c, minlength=rows.shape[0])
                     for c in columns], axis=1).astype(np.float64, copy=False)


def overlaps(overlap: sp.csr_matrix, row: int, scene: Scene, weights6: NDArray[np.float64],
             min_overlap_m2: float) -> NDArray[np.bool_]:
    """(N,) bool: which rows of ``overlap`` row ``row`` has an edge with (overlap area and
    constraint test, see the module docstring; ``weights6`` from :func:`scatter_weights`)."""
    overlap_m2, constraint = overlap_with(overlap, row, scene, weights6)
    edge: NDArray[np.bool_] = (overlap_m2 >= min_overlap_m2) & (constraint >= MIN_CONSTRAINT)
    return edge


def overlap_graph(overlap: sp.csr_matrix, scene: Scene, min_overlap_m2: float
                  ) -> OverlapGraph:
    """The candidate overlap graph of the (C, F) ``overlap`` rows: an edge (a < b) where
    row a overlaps row b (one pass over ``overlap`` per candidate that sees a face)."""
    weights6 = scatter_weights(scene)
    n = overlap.shape[0]
    sees = np.flatnonzero(np.diff(overlap.indptr) > 0)
    pairs = [np.zeros((0, 2), np.int64)]
    for a in sees:
        b = np.flatnonzero(overlaps(overlap, int(a), scene, weights6, min_overlap_m2)[a + 1:])
        pairs.append(np.stack([np.full(len(b), a, np.int64), b.astype(np.int64) + a + 1], 1))
    return OverlapGraph(n, np.concatenate(pairs))


def connected_greedy(table: CoverageTable, overlap: OverlapRows, scene: Scene,
                     positions: NDArray[np.float64], min_overlap_m2: float,
                     *, weighted: bool = False, goal: float = 1.0) -> Selection:
    """Greedy (or weighted greedy) whose stations form one connected overlap graph.

    Gains are the same exact integers as :func:`planner.selection.greedy.greedy` (ties go to the
    lowest index); a candidate is *allowed* once it overlaps a chosen station. Stops once
    ``goal`` of the achievable area is covered.

    Lazy: each step walks the open candidates in gain order (ties: lowest index) and tests
    only as many as it takes to find an allowed one, a few at a time (``overlap`` computes
    and caches their rows); a candidate found allowed stays allowed, and one that was not is
    tested again only against the stations chosen since. A relay likewise tests candidates
    in order of distance to its target. The stations are those of testing every candidate
    against every station (the same sums in the same order).
    """
    needed_m2 = goal * table.max_achievable_area_m2 - GOAL_SLACK_M2
    area = table.face_area_m2
    units, gains = gain_units(table, weighted=weighted)
    weights6 = functools.partial(scatter_weights_of, scene)
    n = table.n_candidates
    uncovered = np.ones(table.n_faces, bool)
    gain_order = GainOrder(table, units, gains, uncovered)
    del gains
    allowed = np.zeros(n, bool)  # (C,) known to overlap a chosen station
    tested = np.zeros(n, np.int64)  # (C,) how many stations each was tested against
    # per chosen station: the faces of its overlap row, ascending
    station_faces: list[NDArray[np.int64]] = []
    chosen = np.zeros(n, bool)
    stations: list[int] = []
    new_area: list[float] = []
    covered: list[float] = []
    total = 0.0
    batch = max(2, overlap.workers)  # rows computed together (one per worker)
    index = np.arange(n)

    def first_allowed(order: Iterable[int]) -> int | None:
        """The first candidate of ``order`` that overlaps a chosen station, or None."""
        candidates = iter(order)
        while len(block := np.fromiter(itertools.islice(candidates, batch), np.int64)):
            todo = block[~allowed[block] & (tested[block] < len(station_faces))]
            if len(todo):
                rows = overlap.matrix(todo)
                for k in range(int(tested[todo].min()), len(station_faces)):
                    shared = _shared_with(rows, station_faces[k], scene.areas, weights6)
                    overlap_m2, constraint = shared[:, 0], constraint_of(shared[:, 1:])
                    allowed[todo] |= ((tested[todo] <= k) & (overlap_m2 >= min_overlap_m2)
                                      & (constraint >= MIN_CONSTRAINT))
                tested[todo] = len(station_faces)
            hits = block[allowed[block]]
            if len(hits):
                return int(hits[0])
        return None

    relay_gap_m = np.inf  # distance of the last relay to its target; a relay must get closer
    while True:
        # open candidates (their gain is positive; a chosen one's is 0), best first
        with contextlib.closing(gain_order.ranked()) as ranking:
            best = next(ranking, None)
            if not stations or best is None:
                candidate = best  # the first station: any
            else:
                candidate = first_allowed(itertools.chain([best], ranking))
        if candidate is None:
            if best is None:
                break  # nothing adds area: every open candidate's gain is 0
            # no allowed candidate adds area: relay towards the best one not allowed
            target = positions[best]
            distance = np.linalg.norm(positions - target, axis=1)
            near = index[~chosen & (distance < relay_gap_m)]
            candidate = first_allowed(near[np.lexsort((near, distance[near]))])
            if candidate is None:
                break  # relaying makes no progress: the rest cannot be registered
            relay_gap_m = float(distance[candidate])
        else:
            relay_gap_m = np.inf
        faces = table.faces_of(candidate)
        fresh = faces[uncovered[faces]]
        uncovered[fresh] = False
        added = float(area[fresh].sum())
        total += added
        stations.append(candidate)
        new_area.append(added)
        covered.append(total)
        chosen[candidate] = True
        if total >= needed_m2:
            break
        station_faces.append(overlap.matrix([candidate]).indices)
    return Selection(
        method="weighted_greedy" if weighted else "greedy",
        stations=tuple(stations),
        new_area_m2=tuple(new_area),
        covered_area_m2=tuple(covered),
        max_achievable_area_m2=table.max_achievable_area_m2,
    )
