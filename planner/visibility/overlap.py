"""The overlap rows: which faces each candidate qualifies for at the overlap density.

Takes the scene, the (C, 3) candidate positions, the plan's limits and occlusion and
``overlap_density_pts_m2`` (the density at which a surface counts for cloud-to-cloud
registration, lower than the coverage density, so a row reaches farther: about 25 m at the
default); gives each candidate's row of faces, computed on demand and cached
(:class:`OverlapRows`), the whole (C, F) matrix (:func:`overlap_matrix`) and the rows cut to
the faces two of them share (:func:`shared_faces_only`). Whether two rows overlap enough to
register is the choice of stations' test (:mod:`planner.selection.connected`).

Array letters: C candidates, F faces, S stations.
"""

from __future__ import annotations

import dataclasses
import os
import time
from collections.abc import Iterable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Protocol

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from planner.limits import FaceLimits
from planner.memory import released_every
from planner.rays import Occlusion, make_occlusion
from planner.scene import Scene
from planner.visibility.bundles import BundleCuller, bundle_culler
from planner.visibility.pairs import (
    RAYS_PER_CAST,
    PairFinder,
    search_reach_m,
    visible_pairs,
)
from planner.visibility.solids import closed_shells
from planner.walkgraph import door_faces


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
    greedy pays only for the candidates it considers. With a ``fanout``
    (:class:`RowsFanout`, e.g. a Dask cluster: :mod:`planner.scaleout`) the rows are
    computed there, as many at a time as it has threads.
    """

    def __init__(self, scene: Scene, positions: NDArray[np.float64], limits: FaceLimits,
                 occlusion: Occlusion, overlap_density_pts_m2: float,
                 threads: int | None = None, *, file_faces: bool = False,
                 fanout: RowsFanout | None = None) -> None:
        doors = door_faces(scene)
        self._occludes = limits.occludes
        if (doors & limits.occludes).any():
            self._occludes = limits.occludes & ~doors
            occlusion = make_occlusion(scene, self._occludes, "embree", file_faces=file_faces,
                                       exact=occlusion.exact)
        self._scene = scene
        self._fanout = fanout
        self.n_faces = scene.n_faces
        self._positions = np.asarray(positions, np.float64)  # (C, 3)
        self._occlusion = occlusion
        self._limits = overlap_limits(limits, overlap_density_pts_m2)
        # the pair search and the bundles of the rows computed here, made with the first
        # of them: rows fanned out to a cluster never need them (a grid of every face and
        # the bundles' arrays, on a 13 M-face model some hundreds of MB and seconds)
        self._search: tuple[PairFinder, BundleCuller | None] | None = None
        self.workers = (threads or os.cpu_count() or 1) if fanout is None else fanout.threads
        self._rows: dict[int, NDArray[np.int32]] = {}  # candidate -> (k,) sorted face ids
        self.seconds = 0.0  # time spent computing rows
        self.rays_cast = 0

    def __len__(self) -> int:
        return len(self._positions)

    @property
    def n_computed(self) -> int:
        """How many candidates' rows have been computed."""
        return len(self._rows)

    def _local_search(self) -> tuple[PairFinder, BundleCuller | None]:
        """The pair search and the bundle culler of the rows computed here (made once)."""
        if self._search is None:
            # a row reaches far (25 m at the default overlap density), mostly into other
            # rooms: bundles hidden behind a wall are ruled out with four rays, not one a piece
            culler = bundle_culler(self._scene, search_reach_m(self._limits), self._occlusion)
            finder = PairFinder(self._scene, self._limits,
                                shells=closed_shells(self._scene, self._occlusion),
                                bundle_of=None if culler is None else culler.bundles.bundle_of)
            self._search = (finder, culler)
        return self._search

    def _row(self, candidate: int) -> tuple[NDArray[np.int32], int]:
        finder, culler = self._local_search()
        return overlap_row(finder, culler, self._occlusion, self._positions, self._scene,
                           candidate)

    @property
    def scene(self) -> Scene:
        return self._scene

    @property
    def positions(self) -> NDArray[np.float64]:
        """(C, 3) the candidates the rows are of."""
        return self._positions

    @property
    def limits(self) -> FaceLimits:
        """The limits of the rows (the overlap density's)."""
        return self._limits

    @property
    def reach_m(self) -> float:
        """The rows' pair search reach."""
        return search_reach_m(self._limits)

    @property
    def occlusion(self) -> Occlusion:
        """The rows' occlusion test (IFC doors open)."""
        return self._occlusion

    @property
    def occludes(self) -> NDArray[np.bool_]:
        """(F,) bool, the faces the rows' occlusion test holds (IFC doors open)."""
        return self._occludes

    def ensure(self, candidates: Iterable[int]) -> None:
        """Compute the rows of ``candidates`` not computed yet."""
        todo = [int(c) for c in dict.fromkeys(int(c) for c in candidates) if c not in self._rows]
        if not todo:
            return
        started = time.perf_counter()
        if self._fanout is not None:
            rows = self._fanout.overlap_rows(self, todo)
            if rows is not None:
                for c, (faces, rays) in zip(todo, rows, strict=True):
                    self._rows[c] = faces
                    self.rays_cast += rays
                self.seconds += time.perf_counter() - started
                return
        self._local_search()  # made here, before the threads that share it
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
        matrix are never held whole side by side. So does the pair search (made again
        should a row be asked for later): on the 9.7 M-face office its grid and bundles,
        some 110 MB, were held under the cut's peak."""
        self.ensure(candidates)
        rows = [self._rows[int(c)] for c in candidates]
        for c in {int(c) for c in candidates}:
            del self._rows[c]
        self._search = None
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


def overlap_row(finder: PairFinder, culler: BundleCuller | None, occlusion: Occlusion,
                positions: NDArray[np.float64], scene: Scene,
                candidate: int) -> tuple[NDArray[np.int32], int]:
    """The faces of ``scene`` candidate ``candidate`` of the (C, 3) ``positions``
    qualifies for under ``finder``'s limits (ascending) and the rays cast for them."""
    point = positions[candidate:candidate + 1]
    hidden, rays = (None, 0) if culler is None else culler.hidden(point)
    # a part of the row at a time, found and cast: a hall's row is a million pairs, and
    # its pairs (40 bytes each) and the cast's scratch (some 60 bytes a ray) on both
    # threads at once made the overlap rows' peak; each ray's verdict is its own, whatever
    # else is cast with it
    seen: list[NDArray[np.int32]] = []
    for pairs in finder.parts(point, candidate, hidden, most_tests=RAYS_PER_CAST):
        seen.append(pairs.face[visible_pairs(occlusion, pairs, positions, scene)])
        rays += len(pairs)
    row = np.concatenate(seen) if seen else np.zeros(0, np.int32)
    return np.sort(row), rays


class RowsFanout(Protocol):
    """Computes overlap rows elsewhere (a cluster: :mod:`planner.scaleout`)."""

    @property
    def threads(self) -> int:
        """How many rows it computes at a time."""
        ...

    def overlap_rows(self, rows: OverlapRows, candidates: list[int]
                     ) -> Iterator[tuple[NDArray[np.int32], int]] | None:
        """The rows of ``candidates`` (each: faces ascending, rays cast), in order; None
        when these rows cannot be computed there (they are then computed here)."""
        ...


def overlap_matrix(scene: Scene, positions: NDArray[np.float64], limits: FaceLimits,
                   occlusion: Occlusion, overlap_density_pts_m2: float,
                   threads: int | None = None, *, file_faces: bool = False) -> sp.csr_matrix:
    """(N, F) CSR float64 of 1.0: which face each of the (N, 3) positions qualifies for at the
    overlap density (every row of :class:`OverlapRows`)."""
    rows = OverlapRows(scene, positions, limits, occlusion, overlap_density_pts_m2, threads,
                       file_faces=file_faces)
    return rows.matrix(range(len(positions)))


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
