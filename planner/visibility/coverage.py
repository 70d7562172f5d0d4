"""The coverage table: which candidate qualifies for which face.

The pattern of a sparse candidates x faces matrix (C x F): a pair is in it when it passes
the analytic limits and the occlusion ray. Pairs come from the visibility stage in blocks
(:class:`QualifiedPairs`, with their LPD in pts/m^2).
"""

from __future__ import annotations

import functools
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

import numba
import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from planner.memory import GrowingArray

# the data type a per-candidate value keeps when it is summed per face
_Number = TypeVar("_Number", bound=np.number[Any])


@dataclass(frozen=True, eq=False)
class QualifiedPairs:
    """Pairs that passed every test, sorted by (candidate, face).

    Attributes
    ----------
    candidate : (P,) int32
    face : (P,) int32
    lpd_pts_m2 : (P,) float32
    """

    candidate: NDArray[np.int32]
    face: NDArray[np.int32]
    lpd_pts_m2: NDArray[np.float32]

    @classmethod
    def concatenate(cls, parts: list[QualifiedPairs]) -> QualifiedPairs:
        """The parts end to end; ``parts`` is emptied as it goes, so the peak is the parts
        and one merged column (16 bytes a pair), not the parts and the whole result (24)."""
        if not parts:
            return cls(np.zeros(0, np.int32), np.zeros(0, np.int32), np.zeros(0, np.float32))
        columns = [[getattr(p, name) for p in parts]
                   for name in ("candidate", "face", "lpd_pts_m2")]
        parts.clear()
        merged = []
        for column in columns:
            merged.append(np.concatenate(column))
            column.clear()
        return cls(*merged)


# pairs expanded at a time by CoverageTable's blocks (~16 MB of temporaries)
_SUM_BLOCK_PAIRS = 1 << 20
# the run arrays _csr_runs's counting pass is given (it writes none)
_NO_RUNS = np.zeros(0, np.int32)


def _expand_runs(start: NDArray[np.int32], length: NDArray[np.int32]) -> NDArray[np.int32]:
    """(sum(length),) int32: the faces of the runs ``start[i] .. start[i] + length[i] - 1``,
    in order, written by a compiled loop: the output alone (4 bytes a pair), where
    numpy's repeat-and-add held two int64 arrays of the pairs beside it (20 bytes a pair at
    the peak: 420 MB for the 9.7 M-face office's 21 M class pairs)."""
    faces = np.empty(int(length.sum(dtype=np.int64)), np.int32)
    _write_runs(start, length, faces)
    return faces


@numba.njit(nogil=True, cache=True)
def _write_runs(start: NDArray[np.int32], length: NDArray[np.int32],
                faces: NDArray[np.int32]) -> None:  # compiled
    """``faces``: the runs' faces, one run after the other."""
    at = 0
    for i in range(len(start)):
        first = start[i]
        for j in range(length[i]):
            faces[at] = first + j
            at += 1


@dataclass(frozen=True, eq=False)
class CoverageTable:
    """Which candidate qualifies for which face: the pattern of the (C, F) table, by row.

    Only the pattern is kept: the choice of stations needs no more, and the densities of
    the chosen stations are computed again for the report (:func:`planner.pipeline.plan`).
    Each candidate's faces are kept as runs of consecutive face indices (the pieces of a
    remeshed face are numbered one after another, and a candidate mostly sees a face
    whole): 8 bytes a run. The 8.4 M-face floor of ``benchmarks/plan_scale.py`` with grid
    candidates holds 161.6 M pairs in 14.1 M runs: 113 MB instead of 646 MB at 4 bytes a
    pair.

    Attributes
    ----------
    run_ptr : (C + 1,) int64, candidate c's runs are ``run_ptr[c] .. run_ptr[c + 1] - 1``
    run_start : (R,) int32, first face of each run, ascending within each candidate
    run_length : (R,) int32, faces in each run (at least 1)
    pair_ptr : (C + 1,) int64, candidate c holds ``pair_ptr[c + 1] - pair_ptr[c]`` pairs
    face_area_m2 : (F,) float64
    """

    run_ptr: NDArray[np.int64]
    run_start: NDArray[np.int32]
    run_length: NDArray[np.int32]
    pair_ptr: NDArray[np.int64]
    face_area_m2: NDArray[np.float64]

    @classmethod
    def from_pairs(
        cls, qualified: QualifiedPairs, n_candidates: int, face_area_m2: NDArray[np.float64]
    ) -> CoverageTable:
        """Build from pairs sorted by (candidate, face) (the order the pipeline makes)."""
        return cls.from_blocks([qualified], n_candidates, face_area_m2)

    @classmethod
    def from_blocks(
        cls, blocks: Iterable[QualifiedPairs], n_candidates: int,
        face_area_m2: NDArray[np.float64],
    ) -> CoverageTable:
        """Build from blocks of pairs, each sorted by (candidate, face), that follow one
        another in candidate order; each block can be dropped once it is read.

        The runs grow in place, so the peak is the table and one block, not twice the table.
        """
        pairs = np.zeros(n_candidates, np.int64)
        runs = np.zeros(n_candidates, np.int64)
        run_start, run_length = GrowingArray(np.int32), GrowingArray(np.int32)
        for block in blocks:
            candidate, face = block.candidate, block.face
            del block
            if not len(face):
                continue
            # the block's candidates as the rows of a CSR over its faces, their runs found
            # and written by from_csr's compiled passes (no (P,) temporaries of the block)
            low, high = int(candidate[0]), int(candidate[-1]) + 1
            indptr = np.searchsorted(candidate, np.arange(low, high + 1)).astype(
                np.int64, copy=False)
            block_runs = np.zeros(high - low + 1, np.int64)  # (c + 1,) then cumulative
            _csr_runs(indptr, face, block_runs, _NO_RUNS, _NO_RUNS, False)
            np.cumsum(block_runs, out=block_runs)
            n_runs = int(block_runs[-1])
            _csr_runs(indptr, face, block_runs, run_start.extend(n_runs),
                      run_length.extend(n_runs), True)
            pairs[low:high] += np.diff(indptr)
            runs[low:high] += np.diff(block_runs)
        run_ptr = np.zeros(n_candidates + 1, np.int64)
        np.cumsum(runs, out=run_ptr[1:])
        pair_ptr = np.zeros(n_candidates + 1, np.int64)
        np.cumsum(pairs, out=pair_ptr[1:])
        return cls(run_ptr=run_ptr, run_start=run_start.done(), run_length=run_length.done(),
                   pair_ptr=pair_ptr, face_area_m2=face_area_m2)

    @classmethod
    def from_csr(cls, pattern: sp.csr_matrix, face_area_m2: NDArray[np.float64]
                 ) -> CoverageTable:
        """Build from a (C, F) CSR pattern with sorted indices (its values are ignored).

        Two compiled passes over the rows, counting the runs and then writing them: no
        (P,) temporaries beside the pattern (the 9.7 M-face office's class table, 21 M
        pairs, rose 340 MiB over its pattern with per-pair arrays of candidates and run
        starts)."""
        n_rows = pattern.shape[0]
        indptr = pattern.indptr.astype(np.int64)
        indices = pattern.indices.astype(np.int32, copy=False)
        run_ptr = np.zeros(n_rows + 1, np.int64)
        _csr_runs(indptr, indices, run_ptr, _NO_RUNS, _NO_RUNS, False)
        np.cumsum(run_ptr, out=run_ptr)
        run_start = np.empty(int(run_ptr[-1]), np.int32)
        run_length = np.empty(int(run_ptr[-1]), np.int32)
        _csr_runs(indptr, indices, run_ptr, run_start, run_length, True)
        return cls(run_ptr=run_ptr, run_start=run_start, run_length=run_length,
                   pair_ptr=indptr, face_area_m2=np.asarray(face_area_m2, np.float64))

    @property
    def n_candidates(self) -> int:
        return len(self.run_ptr) - 1

    @property
    def n_faces(self) -> int:
        return len(self.face_area_m2)

    @property
    def n_pairs(self) -> int:
        return int(self.pair_ptr[-1])

    @property
    def n_runs(self) -> int:
        return len(self.run_start)

    def _faces_of_candidates(self, first: int, last: int) -> NDArray[np.int32]:
        """(P',) int32: the faces of candidates ``first .. last - 1``, candidate by candidate."""
        runs = slice(int(self.run_ptr[first]), int(self.run_ptr[last]))
        return _expand_runs(self.run_start[runs], self.run_length[runs])

    def _candidate_blocks(self) -> Iterator[tuple[int, int]]:
        """(first, last): whole candidates, at least one, up to about _SUM_BLOCK_PAIRS pairs."""
        pair_ptr = self.pair_ptr
        first = 0
        while first < self.n_candidates:
            last = int(np.searchsorted(pair_ptr, pair_ptr[first] + _SUM_BLOCK_PAIRS,
                                       "right")) - 1
            last = min(max(last, first + 1), self.n_candidates)
            yield first, last
            first = last

    def blocks(self) -> Iterator[tuple[int, int, NDArray[np.int32]]]:
        """(first, last, faces): whole candidates ``first .. last - 1``, up to about
        _SUM_BLOCK_PAIRS pairs a block, and their (P',) faces candidate by candidate
        (``pair_ptr[first:last + 1] - pair_ptr[first]`` delimits each)."""
        for first, last in self._candidate_blocks():
            yield first, last, self._faces_of_candidates(first, last)

    @property
    def by_candidate(self) -> sp.csr_matrix:
        """(C, F) CSR bool, the table as a sparse matrix (made for the call, 5 bytes a pair)."""
        return self.pattern(np.bool_)

    def pattern(self, dtype: type[np.generic]) -> sp.csr_matrix:
        """(C, F) CSR of ones in ``dtype`` (float32 for products with areas: 8 bytes a
        pair), made for the call."""
        faces = self._faces_of_candidates(0, self.n_candidates)
        matrix = sp.csr_matrix((np.ones(self.n_pairs, dtype), faces, self.pair_ptr),
                               shape=(self.n_candidates, self.n_faces))
        matrix.has_sorted_indices = True
        return matrix

    @functools.cached_property
    def candidates_per_face(self) -> NDArray[np.int32]:
        """(F,) int32: how many candidates qualify for each face (k_f), kept once made
        (4 bytes a face: there are fewer than 2**31 candidates).

        Every candidate adds 1 over its runs (:meth:`sum_per_face`).
        """
        counts = self.sum_per_face(np.ones(self.n_candidates, np.int32))
        counts.flags.writeable = False  # shared: the plan's faces.npz holds it as is
        return counts

    def sum_per_face(self, per_candidate: NDArray[_Number]) -> NDArray[_Number]:
        """(F,) the sum of (C,) ``per_candidate`` over the candidates that qualify for each
        face, in its data type (unsigned integers wrap).

        Each candidate's value is added at the first face of each of its runs and taken off
        after the last, in place by a compiled loop (``np.add.at`` took 3.5 s for the
        9.7 M-face office's runs, while both greedy heuristics waited for it), then summed:
        a pass over the runs and one over the faces, no copy of the pairs.
        """
        steps = np.zeros(self.n_faces + 1, per_candidate.dtype)
        _add_run_values(self.run_ptr, self.run_start, self.run_length, per_candidate, steps)
        np.cumsum(steps, out=steps)
        return steps[:-1]

    @property
    def achievable(self) -> NDArray[np.bool_]:
        """(F,) bool: qualified from at least one candidate."""
        return self.candidates_per_face > 0

    @functools.cached_property
    def max_achievable_area_m2(self) -> float:
        """The area of the faces some candidate qualifies for (kept: every selection reads
        it, and its (F,) temporaries would come back each time)."""
        return float(self.face_area_m2[self.achievable].sum())

    def covered_by(self, candidates: Sequence[int]) -> NDArray[np.bool_]:
        """(F,) bool: the faces any of ``candidates`` qualifies for."""
        covered = np.zeros(self.n_faces, bool)
        for candidate in candidates:
            covered[self.faces_of(candidate)] = True
        return covered

    def faces_of(self, candidate: int) -> NDArray[np.int32]:
        """Faces that ``candidate`` qualifies for, ascending (a new array)."""
        return self._faces_of_candidates(candidate, candidate + 1)

    def sum_per_candidate(self, per_face: NDArray[np.float64]) -> NDArray[np.float64]:
        """(C,) float64: the sum of (F,) ``per_face`` over the faces each candidate qualifies for.

        Summed entry by entry in (candidate, face) order, as a sparse product with the
        table's pattern would, by a compiled pass over the runs (no pairs expanded: on the
        9.7 M-face office's 128 M pairs 1.8 s by blocks of expanded faces before).
        """
        sums = np.zeros(self.n_candidates, np.float64)
        _sum_over_runs(self.run_ptr, self.run_start, self.run_length,
                       np.asarray(per_face, np.float64), sums)
        return sums

    def station_rows(self, stations: Sequence[int]) -> StationRows:
        """The rows of ``stations`` alone, with this table's totals (:class:`StationRows`)."""
        runs = [slice(int(self.run_ptr[c]), int(self.run_ptr[c + 1])) for c in stations]
        run_ptr = np.zeros(len(stations) + 1, np.int64)
        np.cumsum([part.stop - part.start for part in runs], out=run_ptr[1:])
        pair_ptr = np.zeros(len(stations) + 1, np.int64)
        np.cumsum([int(self.pair_ptr[c + 1] - self.pair_ptr[c]) for c in stations],
                  out=pair_ptr[1:])
        rows = CoverageTable(
            run_ptr=run_ptr,
            run_start=np.concatenate([self.run_start[part] for part in runs] or [_NO_RUNS]),
            run_length=np.concatenate([self.run_length[part] for part in runs] or [_NO_RUNS]),
            pair_ptr=pair_ptr, face_area_m2=self.face_area_m2)
        return StationRows(stations=tuple(int(c) for c in stations), rows=rows,
                           n_candidates=self.n_candidates, n_pairs=self.n_pairs,
                           candidates_per_face=self.candidates_per_face,
                           max_achievable_area_m2=self.max_achievable_area_m2)


@dataclass(frozen=True, eq=False)
class StationRows:
    """What a plan reads of its coverage table once its stations are chosen: their rows
    and the whole table's totals (:meth:`CoverageTable.station_rows`).

    The per-face results and the outputs read no other candidate's row, so a plan keeps
    these instead of the table (the 9.7 M-piece office's table is 180 MB, held under the
    survey's peak and the outputs'; its stations' rows about 2 MB).

    Attributes
    ----------
    stations : (S,) the candidates whose rows are kept
    rows : their rows, row ``i`` being ``stations[i]``'s
    n_candidates, n_pairs : the whole table's
    candidates_per_face : (F,) int32, the whole table's (k_f)
    max_achievable_area_m2 : the whole table's
    """

    stations: tuple[int, ...]
    rows: CoverageTable
    n_candidates: int
    n_pairs: int
    candidates_per_face: NDArray[np.int32]
    max_achievable_area_m2: float

    @property
    def n_faces(self) -> int:
        return self.rows.n_faces

    @property
    def face_area_m2(self) -> NDArray[np.float64]:
        return self.rows.face_area_m2

    @property
    def achievable(self) -> NDArray[np.bool_]:
        """(F,) bool: qualified from at least one candidate."""
        return self.candidates_per_face > 0

    @functools.cached_property
    def _row_of(self) -> dict[int, int]:
        """Each station's row in ``rows`` (the per-face results ask for every station's)."""
        return {station: row for row, station in enumerate(self.stations)}

    def faces_of(self, candidate: int) -> NDArray[np.int32]:
        """Faces that station ``candidate`` qualifies for, ascending (a new array)."""
        row = self._row_of.get(candidate)
        if row is None:
            raise KeyError(f"candidate {candidate} is not a station of this plan: only the "
                           "stations' rows are kept (plan(..., keep_table=True) keeps the "
                           "whole coverage table)")
        return self.rows.faces_of(row)


@numba.njit(nogil=True, cache=True)
def _csr_runs(indptr: NDArray[np.int64], indices: NDArray[np.int32],
              run_ptr: NDArray[np.int64], run_start: NDArray[np.int32],
              run_length: NDArray[np.int32], fill: bool) -> None:  # compiled
    """The runs of consecutive indices in each row of a CSR pattern (sorted indices).
    Without ``fill``: each row's count into ``run_ptr[c + 1]``; with it (``run_ptr`` then
    the cumulative counts), each run's first index and length from ``run_ptr[c]`` on."""
    for c in range(len(indptr) - 1):
        at = run_ptr[c] - 1 if fill else -1  # the row's last run so far
        for j in range(indptr[c], indptr[c + 1]):
            if j == indptr[c] or indices[j] != indices[j - 1] + 1:
                at += 1
                if fill:
                    run_start[at] = indices[j]
                    run_length[at] = 1
            elif fill:
                run_length[at] += 1
        if not fill:
            run_ptr[c + 1] = at + 1


@numba.njit(nogil=True, cache=True)
def _sum_over_runs(run_ptr: NDArray[np.int64], run_start: NDArray[np.int32],
                   run_length: NDArray[np.int32], per_face: NDArray[np.float64],
                   sums: NDArray[np.float64]) -> None:  # compiled
    """``sums[c]``: ``per_face`` summed over candidate c's faces, one after the other in
    face order (the order of a sparse product's row)."""
    for c in range(len(run_ptr) - 1):
        total = 0.0
        for r in range(run_ptr[c], run_ptr[c + 1]):
            for f in range(run_start[r], run_start[r] + run_length[r]):
                total += per_face[f]
        sums[c] = total


@numba.njit(nogil=True, cache=True)
def _add_run_values(run_ptr: NDArray[np.int64], run_start: NDArray[np.int32],
                    run_length: NDArray[np.int32], per_candidate: NDArray[Any],
                    steps: NDArray[Any]) -> None:  # compiled
    """``steps[start] += value`` and ``steps[start + length] -= value`` for every run, the
    value of the run's candidate."""
    for c in range(len(run_ptr) - 1):
        value = per_candidate[c]
        for r in range(run_ptr[c], run_ptr[c + 1]):
            steps[run_start[r]] += value
            steps[run_start[r] + run_length[r]] -= value
