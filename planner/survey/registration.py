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
import dataclasses
import functools
import itertools
import os
import time
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.csgraph import connected_components

from planner.memory import released_every
from planner.method.bundles import bundle_culler
from planner.method.connectivity import OverlapGraph
from planner.method.coverage import CoverageTable
from planner.method.pairs import FaceLimits, PairFinder
from planner.method.selection import GOAL_SLACK_M2, GainOrder, Selection, gain_units
from planner.method.visibility import Occlusion, make_occlusion
from planner.method.walkgraph import door_faces
from planner.scene import Scene

# smallest eigenvalue over trace of the normal scatter matrix for an edge to register in
# all three directions: the weakest direction carries at least 5 % of the normal weight
MIN_CONSTRAINT = 0.05


def overlap_limits(limits: FaceLimits, overlap_density_pts_m2: float) -> FaceLimits:
    """The plan's limits with the density requirement replaced by the overlap density."""
    return dataclasses.replace(
        limits, min_density_pts_m2=np.broadcast_to(np.float64(overlap_density_pts_m2),
                                                   limits.min_density_pts_m2.shape))


# rows computed between two trims of the heap: the rows' threads free the small scratch of
# their rays into their own arenas, where it stays resident (on the 9.7 M-face office the
# rows' peak went from 1,963 to 1,894 MiB with the trims, and the memory the tolerance
# starts with from 1,783 to 1,640 MiB)
_TRIM_EVERY_ROWS = 16


class OverlapRows:
    """Which faces each candidate qualifies for at the overlap density, computed on demand.

    A row is the set of faces candidate ``c`` of the (C, 3) ``positions`` qualifies for at
    ``overlap_density_pts_m2`` (same limits and occlusion as coverage otherwise, except that
    IFC doors are open: a crew scans with the doors open, and the route walks through them).
    ``file_faces``: the rays that skip the doors are cast against the file's faces, as the
    plan's (``occluders`` "file"), so the rows do not depend on how the faces were split.
    Rows are computed when first asked for (the compiled limits kernel, then the Embree
    occlusion rays; one candidate per task on a thread pool) and cached, so the connected
    greedy pays only for the candidates it considers.
    """

    def __init__(self, scene: Scene, positions: NDArray[np.float64], limits: FaceLimits,
                 occlusion: Occlusion, overlap_density_pts_m2: float,
                 threads: int | None = None, *, file_faces: bool = False) -> None:
        doors = door_faces(scene)
        if (doors & limits.occludes).any():
            occlusion = make_occlusion(scene, limits.occludes & ~doors, "embree",
                                       file_faces=file_faces)
        self.n_faces = scene.n_faces
        self._positions = np.asarray(positions, np.float64)  # (C, 3)
        self._centroids = scene.centroids  # (F, 3), for the float64 rays
        self._occlusion = occlusion
        self._finder = PairFinder(scene, overlap_limits(limits, overlap_density_pts_m2))
        # a row reaches far (25 m at the default overlap density), mostly into other rooms:
        # bundles hidden behind a wall are ruled out with four rays instead of one a piece
        self._culler = bundle_culler(scene, self._finder.reach_m, occlusion)
        self.workers = threads or os.cpu_count() or 1
        self._rows: dict[int, NDArray[np.int32]] = {}  # candidate -> (k,) sorted face ids
        self.seconds = 0.0  # time spent computing rows
        self.rays_cast = 0

    def __len__(self) -> int:
        return len(self._positions)

    @property
    def n_computed(self) -> int:
        """How many candidates' rows have been computed."""
        return len(self._rows)

    def _row(self, candidate: int) -> tuple[NDArray[np.int32], int]:
        point = self._positions[candidate:candidate + 1]
        hidden, bundle_rays = (None, 0) if self._culler is None else self._culler.hidden(point)
        pairs, _ = self._finder.find(point, candidate, hidden, ordered=False)  # sorted below
        visible = self._occlusion.visible(
            pairs.origin, pairs.direction, pairs.distance_m, pairs.face,
            exact_rays=pairs.exact_rays(self._positions, self._centroids))
        return np.sort(pairs.face[visible]), len(pairs) + bundle_rays

    def ensure(self, candidates: Iterable[int]) -> None:
        """Compute the rows of ``candidates`` not computed yet."""
        todo = [int(c) for c in dict.fromkeys(int(c) for c in candidates) if c not in self._rows]
        if not todo:
            return
        started = time.perf_counter()
        # no threads are started for one row or one worker (the pool starts them on demand)
        with ThreadPoolExecutor(max_workers=min(self.workers, len(todo))) as pool:
            parallel = len(todo) > 1 and self.workers > 1
            results = pool.map(self._row, todo) if parallel else map(self._row, todo)
            for c, (faces, rays) in zip(todo, released_every(results, _TRIM_EVERY_ROWS),
                                        strict=True):
                self._rows[c] = faces
                self.rays_cast += rays
        self.seconds += time.perf_counter() - started

    def shared_matrix(self, candidates: Sequence[int] | NDArray[np.integer[Any]]
                      ) -> sp.csr_matrix:
        """:meth:`matrix` cut to the faces two of the rows share (:func:`shared_faces_only`),
        made from the cached rows without the whole matrix. The rows it reads leave the
        cache: each is let go once its shared faces are copied, so the rows and the cut
        matrix are never held whole side by side."""
        self.ensure(candidates)
        rows = [self._rows[int(c)] for c in candidates]
        for c in {int(c) for c in candidates}:
            del self._rows[c]
        return _shared_only(rows, self.n_faces)

    def matrix(self, candidates: Sequence[int] | NDArray[np.integer[Any]]) -> sp.csr_matrix:
        """(len(candidates), F) CSR float64 of 1.0: the rows of ``candidates``, in order
        (int32 face indices: 12 bytes an entry)."""
        self.ensure(candidates)
        rows = [self._rows[int(c)] for c in candidates]
        indptr = np.zeros(len(rows) + 1, np.int64)
        np.cumsum([len(r) for r in rows], out=indptr[1:])
        indices = np.concatenate(rows) if rows else np.zeros(0, np.int32)
        return sp.csr_matrix((np.ones(len(indices), np.float64), indices, indptr),
                             shape=(len(rows), self.n_faces))


def overlap_matrix(scene: Scene, positions: NDArray[np.float64], limits: FaceLimits,
                   occlusion: Occlusion, overlap_density_pts_m2: float,
                   threads: int | None = None, *, file_faces: bool = False) -> sp.csr_matrix:
    """(N, F) CSR float64 of 1.0: which face each of the (N, 3) positions qualifies for at the
    overlap density (every row of :class:`OverlapRows`)."""
    rows = OverlapRows(scene, positions, limits, occlusion, overlap_density_pts_m2, threads,
                       file_faces=file_faces)
    return rows.matrix(range(len(positions)))


# the six terms of the packed symmetric normal scatter matrix: xx, yy, zz, xy, xz, yz
_SCATTER_TERMS = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))


def _scatter_weights(scene: Scene) -> NDArray[np.float64]:
    """(F, 6) float64: area * (nx nx, ny ny, nz nz, nx ny, nx nz, ny nz) per face."""
    return _scatter_weights_of(scene, slice(None))


def _scatter_weights_of(scene: Scene, faces: NDArray[np.integer[Any]] | slice
                        ) -> NDArray[np.float64]:
    """(n, 6) float64: the rows ``faces`` of :func:`_scatter_weights`, without the (F, 6)
    array (48 bytes a face) when only some faces are wanted."""
    n, area_m2 = scene.normals[faces], scene.areas[faces]
    return np.stack([n[:, i] * n[:, j] * area_m2 for i, j in _SCATTER_TERMS], axis=1)


def _constraint(scatter6: NDArray[np.float64]) -> NDArray[np.float64]:
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
    return area, _constraint(scatter)


def _shared_with(rows: sp.csr_matrix, faces: NDArray[np.int64], area_m2: NDArray[np.float64],
                 weights6: Callable[[NDArray[np.int32]], NDArray[np.float64]]
                 ) -> NDArray[np.float64]:
    """(N, 7) float64: overlap area and the six scatter sums of every row of the (N, F)
    0/1 ``rows`` with the (n,) ascending ``faces`` of one overlap row; ``weights6`` gives
    the (k, 6) scatter weights of k faces (:func:`_scatter_weights_of`).

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
    constraint test, see the module docstring; ``weights6`` from :func:`_scatter_weights`)."""
    overlap_m2, constraint = overlap_with(overlap, row, scene, weights6)
    edge: NDArray[np.bool_] = (overlap_m2 >= min_overlap_m2) & (constraint >= MIN_CONSTRAINT)
    return edge


def overlap_graph(overlap: sp.csr_matrix, scene: Scene, min_overlap_m2: float
                  ) -> OverlapGraph:
    """The candidate overlap graph of the (C, F) ``overlap`` rows: an edge (a < b) where
    row a overlaps row b (one pass over ``overlap`` per candidate that sees a face)."""
    weights6 = _scatter_weights(scene)
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

    Gains are the same exact integers as :func:`planner.method.selection.greedy` (ties go to the
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
    weights6 = functools.partial(_scatter_weights_of, scene)
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
                    overlap_m2, constraint = shared[:, 0], _constraint(shared[:, 1:])
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


@dataclass(frozen=True)
class Edge:
    a: int  # station ids (1-based, selection order)
    b: int
    overlap_m2: float
    constraint: float
    ok: bool


@dataclass(frozen=True)
class Registration:
    """The overlap graph of a plan's stations."""

    min_overlap_m2: float | None
    overlap_density_pts_m2: float
    edges: tuple[Edge, ...]
    components: tuple[tuple[int, ...], ...]  # station ids per connected component

    @property
    def connected(self) -> bool:
        return len(self.components) <= 1

    def to_dict(self) -> dict[str, Any]:
        return {
            "min_overlap_m2": self.min_overlap_m2,
            "overlap_density_pts_m2": self.overlap_density_pts_m2,
            "connected": self.connected,
            "components": [list(c) for c in self.components],
            "edges": [{"a": e.a, "b": e.b, "overlap_m2": round(e.overlap_m2, 6),
                       "constraint": round(e.constraint, 6), "ok": e.ok} for e in self.edges],
        }


@numba.njit(nogil=True, cache=True)
def _shared_sums(indptr: NDArray[np.int32], faces: NDArray[np.int32], n_faces: int,
                 areas: NDArray[np.float64], normals: NDArray[np.float64],
                 terms: NDArray[np.int64]) -> NDArray[np.float64]:  # compiled; see test_survey
    """(N, N, 1 + T) float64: for every two of the N rows (``indptr``, ascending ``faces``:
    a CSR pattern over ``n_faces`` faces), the area of the faces both hold and the T
    area-weighted normal products n_i n_j area of the (T, 2) ``terms`` (``_SCATTER_TERMS``,
    as :func:`_scatter_weights`), each summed over those faces
    in ascending order. That is the order of the sparse product ``rows @ rows.T`` with the
    weights on the left (and of :func:`overlap_with`), so the sums are the same bits,
    without the transposed copy and (nnz,) weights a product needs: only the rows holding
    each face, 4 bytes an entry and a face.
    """
    n = len(indptr) - 1
    # the rows holding each face, by a counting sort of the entries (rows stay ascending)
    first = np.zeros(n_faces + 1, np.int32)  # first[f] .. first[f + 1] - 1: f's holders
    for entry in range(len(faces)):
        first[faces[entry] + 1] += 1
    for face in range(n_faces):
        first[face + 1] += first[face]
    holder = np.empty(len(faces), np.int32)
    for row in range(n):
        for entry in range(indptr[row], indptr[row + 1]):
            face = faces[entry]
            holder[first[face]] = row
            first[face] += 1
    for face in range(n_faces, 0, -1):  # the filling moved every start to the next one
        first[face] = first[face - 1]
    first[0] = 0
    width = 1 + len(terms)
    sums = np.zeros((n, n, width))
    weight = np.empty(width)
    for row in range(n):
        for entry in range(indptr[row], indptr[row + 1]):
            face = faces[entry]
            area = areas[face]
            weight[0] = area
            for k in range(len(terms)):
                weight[1 + k] = normals[face, terms[k, 0]] * normals[face, terms[k, 1]] * area
            for at in range(first[face], first[face + 1]):
                other = holder[at]
                for k in range(width):
                    sums[row, other, k] += weight[k]
    flat = sums.reshape(-1)
    for at in range(len(flat)):  # a zero sum is +0.0, as in a dense or sparse product
        if flat[at] == 0.0:
            flat[at] = 0.0
    return sums


def shared_faces_only(overlap: sp.csr_matrix) -> sp.csr_matrix:
    """(N, F) CSR bool with sorted indices: ``overlap`` without the faces only one row
    holds. They add to a row's own total only, never to what two rows share, and the faces
    left keep their order, so every sum between two rows is bit for bit the same. (The
    survey keeps only these through the registration and the walk graph; on the 1 M-face
    interior of ``benchmarks/plan_scale.py`` they are 78 % of the 42 stations' entries.)"""
    overlap = overlap.tocsr()
    overlap.sort_indices()
    rows = [overlap.indices[overlap.indptr[r]:overlap.indptr[r + 1]]
            for r in range(overlap.shape[0])]
    twice = _held_twice(rows, overlap.shape[1])
    if overlap.dtype == bool and twice[overlap.indices].all():
        return overlap  # cut already (the survey's rows are): no copy of every entry
    return _shared_only(rows, overlap.shape[1], twice)


def _held_twice(rows: list[NDArray[np.int32]], n_faces: int) -> NDArray[np.bool_]:
    """(F,) bool: the faces two or more of the rows (ascending face ids) hold."""
    seen = np.zeros(n_faces, bool)  # (F,) in some row so far
    twice = np.zeros(n_faces, bool)
    for row in rows:
        twice[row] |= seen[row]
        seen[row] = True
    return twice


def _shared_only(rows: list[NDArray[np.int32]], n_faces: int,
                 twice: NDArray[np.bool_] | None = None) -> sp.csr_matrix:
    """:func:`shared_faces_only` of the rows given as ascending face ids, one array each
    (``twice``: their :func:`_held_twice`, when the caller has it already). ``rows`` is
    emptied as its rows are copied, so a row no one else holds is freed at once."""
    if twice is None:
        twice = _held_twice(rows, n_faces)
    n_rows = len(rows)
    indptr = np.zeros(n_rows + 1, np.int64)
    np.cumsum([np.count_nonzero(twice[row]) for row in rows], out=indptr[1:])
    indices = np.empty(int(indptr[-1]), np.int32)
    rows.reverse()  # popped from the end: first row first
    for r in range(n_rows):
        row = rows.pop()
        indices[indptr[r]:indptr[r + 1]] = row[twice[row]]
        del row
    if indptr[-1] < np.iinfo(np.int32).max:  # int32 throughout: scipy keeps the indices as is
        indptr = indptr.astype(np.int32)
    # bool: station_registration reads the pattern only (1 byte an entry, not 8)
    return sp.csr_matrix((np.ones(len(indices), bool), indices, indptr),
                         shape=(n_rows, n_faces))


def station_registration(scene: Scene, station_overlap: sp.csr_matrix,
                         min_overlap_m2: float | None,
                         overlap_density_pts_m2: float) -> Registration:
    """Edges between every two stations that share area, from their (S, F) overlap rows.

    ``ok`` needs the overlap (``min_overlap_m2``; any shared area when it is null) and the
    constraint test; components are taken over the ok edges. The rows may be cut to the
    faces two stations share (:func:`shared_faces_only`): the result is the same.
    """
    n = station_overlap.shape[0]
    shared = station_overlap.tocsr()  # rows the survey may have cut to shared faces already
    shared.sort_indices()
    # (S, S) the shared area, (S, S, 6) the shared faces' area-weighted normal scatter
    sums = _shared_sums(np.asarray(shared.indptr, np.int32),
                        np.asarray(shared.indices, np.int32), scene.n_faces, scene.areas,
                        np.ascontiguousarray(scene.normals), np.array(_SCATTER_TERMS))
    overlap_m2, scatter6 = sums[:, :, 0], sums[:, :, 1:]
    edges: list[Edge] = []
    rows: list[int] = []
    cols: list[int] = []
    for a in range(n):
        constraint = _constraint(scatter6[a])
        for b in range(a + 1, n):
            if overlap_m2[a, b] <= 0:
                continue
            ok = bool(overlap_m2[a, b] >= (min_overlap_m2 or 0.0)
                      and constraint[b] >= MIN_CONSTRAINT)
            edges.append(Edge(a + 1, b + 1, float(overlap_m2[a, b]), float(constraint[b]), ok))
            if ok:
                rows.append(a)
                cols.append(b)
    graph = sp.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))
    count, labels = connected_components(graph, directed=False)
    components = tuple(tuple(int(i) + 1 for i in np.flatnonzero(labels == c))
                       for c in range(count))
    # components in order of their first station
    return Registration(min_overlap_m2, overlap_density_pts_m2, tuple(edges),
                        tuple(sorted(components)) if n else ())
