"""The coverage table: which candidate qualifies for which face.

The pattern of a sparse candidates x faces matrix (C x F): a pair is in it when it passes
the analytic limits and the occlusion ray. Pairs come from the visibility stage in blocks
(:class:`QualifiedPairs`, with their LPD in pts/m^2).
"""

from __future__ import annotations

import functools
from collections.abc import Iterable
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
    """Which candidate qualifies for which face: the pattern of the (C, F) table, by row.

    Only the pattern is kept (4 bytes a qualified pair): the choice of stations needs no
    more, and the densities of the chosen stations are computed again for the report
    (:func:`planner.pipeline.plan`). A 10 M-face floor with grid candidates holds some
    250 M pairs.

    Attributes
    ----------
    indptr : (C + 1,) int64, candidate c's faces are ``faces[indptr[c]:indptr[c + 1]]``
    faces : (P,) int32, ascending within each candidate
    face_area_m2 : (F,) float64
    """

    indptr: NDArray[np.int64]
    faces: NDArray[np.int32]
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

        The faces column grows in place (``ndarray.resize``, a ``realloc``: large blocks
        are remapped, not copied), so the peak is the table and one block, not twice the
        table.
        """
        counts = np.zeros(n_candidates, np.int64)
        faces = np.empty(1 << 16, np.int32)
        n = 0
        for block in blocks:
            counts += np.bincount(block.candidate, minlength=n_candidates)
            if n + len(block.face) > len(faces):
                faces.resize(max(n + len(block.face), len(faces) * 3 // 2), refcheck=False)
            faces[n:n + len(block.face)] = block.face
            n += len(block.face)
            del block
        faces.resize(n, refcheck=False)
        indptr = np.zeros(n_candidates + 1, np.int64)
        np.cumsum(counts, out=indptr[1:])
        return cls(indptr=indptr, faces=faces, face_area_m2=face_area_m2)

    @property
    def n_candidates(self) -> int:
        return len(self.indptr) - 1

    @property
    def n_faces(self) -> int:
        return len(self.face_area_m2)

    @property
    def n_pairs(self) -> int:
        return len(self.faces)

    @property
    def by_candidate(self) -> sp.csr_matrix:
        """(C, F) CSR bool, the table as a sparse matrix (its data made for the call)."""
        matrix = sp.csr_matrix((np.ones(self.n_pairs, bool), self.faces, self.indptr),
                               shape=(self.n_candidates, self.n_faces))
        matrix.has_sorted_indices = True
        return matrix

    @functools.cached_property
    def by_face(self) -> sp.csc_matrix:
        """(C, F) CSC bool, the pattern by column (which candidates qualify for a face).

        Built on first use and kept (5 bytes a pair): the optimal method reads it, the
        greedy methods do not.
        """
        return self.by_candidate.tocsc()

    @functools.cached_property
    def candidates_per_face(self) -> NDArray[np.int64]:
        """(F,) int64: how many candidates qualify for each face (k_f)."""
        return np.bincount(self.faces, minlength=self.n_faces).astype(np.int64)

    @property
    def achievable(self) -> NDArray[np.bool_]:
        """(F,) bool: qualified from at least one candidate."""
        return self.candidates_per_face > 0

    @property
    def max_achievable_area_m2(self) -> float:
        return float(self.face_area_m2[self.achievable].sum())

    def faces_of(self, candidate: int) -> NDArray[np.int32]:
        """Faces that ``candidate`` qualifies for, ascending."""
        return self.faces[self.indptr[candidate]:self.indptr[candidate + 1]]

    def sum_per_candidate(self, per_face: NDArray[np.float64]) -> NDArray[np.float64]:
        """(C,) float64: the sum of (F,) ``per_face`` over the faces each candidate qualifies for.

        Summed entry by entry in (candidate, face) order, as a sparse product with the
        table's pattern would, in blocks of whole candidates: the temporaries stay at
        ``_SUM_BLOCK_PAIRS`` pairs however large the table.
        """
        indptr = self.indptr
        sums = np.zeros(self.n_candidates, np.float64)
        first = 0
        while first < self.n_candidates:
            # whole candidates, at least one, up to about _SUM_BLOCK_PAIRS pairs
            last = int(np.searchsorted(indptr, indptr[first] + _SUM_BLOCK_PAIRS, "right")) - 1
            last = min(max(last, first + 1), self.n_candidates)
            start, stop = int(indptr[first]), int(indptr[last])
            rows = np.repeat(np.arange(last - first), np.diff(indptr[first:last + 1]))
            sums[first:last] = np.bincount(
                rows, weights=per_face[self.faces[start:stop]], minlength=last - first)
            first = last
        return sums
