"""The coverage table: which candidate qualifies for which face, and at what density.

A sparse candidates x faces matrix (C x F) whose stored values are the LPD (pts/m^2) of
every qualified pair: passes the analytic limits and the occlusion ray.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray


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


# pairs summed at a time by CoverageTable.sum_per_candidate (~50 MB of temporaries)
_SUM_BLOCK_PAIRS = 1 << 22


@dataclass(frozen=True, eq=False)
class CoverageTable:
    """Qualified pairs, both ways round.

    Attributes
    ----------
    by_candidate : (C, F) CSR float32, LPD of each qualified pair, rows = candidates
    by_face : (C, F) CSC bool, its pattern for column access (which candidates qualify
        for a face; 5 bytes a pair instead of 8: the densities are read by candidate)
    face_area_m2 : (F,) float64
    """

    by_candidate: sp.csr_matrix
    by_face: sp.csc_matrix
    face_area_m2: NDArray[np.float64]

    @classmethod
    def from_pairs(
        cls, qualified: QualifiedPairs, n_candidates: int, face_area_m2: NDArray[np.float64]
    ) -> CoverageTable:
        """Build from pairs sorted by (candidate, face) (the order the pipeline makes)."""
        shape = (n_candidates, len(face_area_m2))
        counts = np.bincount(qualified.candidate, minlength=n_candidates)
        indptr = np.concatenate([[0], np.cumsum(counts)])
        csr = sp.csr_matrix(
            (qualified.lpd_pts_m2, qualified.face, indptr.astype(np.int32)),
            shape=shape,
        )
        csr.has_sorted_indices = True
        pattern = sp.csr_matrix((np.ones(csr.nnz, bool), csr.indices, csr.indptr), shape=shape)
        return cls(by_candidate=csr, by_face=pattern.tocsc(), face_area_m2=face_area_m2)

    @property
    def n_candidates(self) -> int:
        return int(self.by_candidate.shape[0])

    @property
    def n_faces(self) -> int:
        return int(self.by_candidate.shape[1])

    @property
    def n_pairs(self) -> int:
        return int(self.by_candidate.nnz)

    @property
    def candidates_per_face(self) -> NDArray[np.int64]:
        """(F,) int64: how many candidates qualify for each face (k_f)."""
        return np.asarray(np.diff(self.by_face.indptr), dtype=np.int64)

    @property
    def achievable(self) -> NDArray[np.bool_]:
        """(F,) bool: qualified from at least one candidate."""
        return self.candidates_per_face > 0

    @property
    def max_achievable_area_m2(self) -> float:
        return float(self.face_area_m2[self.achievable].sum())

    def faces_of(self, candidate: int) -> NDArray[np.int32]:
        """Faces that ``candidate`` qualifies for, ascending."""
        start, stop = self.by_candidate.indptr[candidate], self.by_candidate.indptr[candidate + 1]
        return np.asarray(self.by_candidate.indices[start:stop], dtype=np.int32)

    def sum_per_candidate(self, per_face: NDArray[np.float64]) -> NDArray[np.float64]:
        """(C,) float64: the sum of (F,) ``per_face`` over the faces each candidate qualifies for.

        Summed entry by entry in (candidate, face) order, as a sparse product with the
        table's pattern would, in blocks of whole candidates: the temporaries stay at
        ``_SUM_BLOCK_PAIRS`` pairs however large the table (a 10 M-face interior with grid
        candidates holds 160 M pairs).
        """
        indptr = self.by_candidate.indptr
        sums = np.zeros(self.n_candidates, np.float64)
        first = 0
        while first < self.n_candidates:
            # whole candidates, at least one, up to about _SUM_BLOCK_PAIRS pairs
            last = int(np.searchsorted(indptr, indptr[first] + _SUM_BLOCK_PAIRS, "right")) - 1
            last = min(max(last, first + 1), self.n_candidates)
            start, stop = int(indptr[first]), int(indptr[last])
            rows = np.repeat(np.arange(last - first), np.diff(indptr[first:last + 1]))
            sums[first:last] = np.bincount(
                rows, weights=per_face[self.by_candidate.indices[start:stop]],
                minlength=last - first)
            first = last
        return sums
