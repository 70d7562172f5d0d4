"""Face classes: faces seen by exactly the same candidates, merged (a lossless reduction).

Whether a face is covered depends only on which candidates see it, so faces with the same
candidate set are covered together by every plan: one class of their summed area. The
selection's bounds and programs (:mod:`planner.selection.lower_bound`,
:mod:`planner.selection.optimal`) work on classes: the 9.7 M-face office has 808,000.

Array letters: C candidates, F faces, K classes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from planner.visibility.coverage import CoverageTable


@dataclass(frozen=True)
class _Merged:
    cover: sp.csr_matrix  # (C, K) bool
    area_m2: NDArray[np.float64]  # (K,)
    first_face: NDArray[np.int32]  # (K,) each class's lowest face index


def merged_classes(table: CoverageTable, faces: NDArray[np.bool_]
                   ) -> tuple[sp.csr_matrix, NDArray[np.float64]]:
    """Faces with identical candidate sets merged into classes, from the table's runs.

    Each face's candidate set is hashed twice: the sum (wrapping) of a random 64-bit word
    per candidate, added over each run of the candidate's faces by a difference array (a
    pass over the runs and the faces: no copy of the pairs). Two different sets share
    128 random bits with probability 2^-128 a pair of faces (below 1e-24 for 10 M faces);
    the words come from a fixed seed, so the same table always gives the same classes.
    The merge is made in two steps that hold a few bytes a face: neighbouring faces in the
    table's order with the same count and hashes first (the pieces of one file face mostly
    are), then those runs by sorting one hash (checked against the other and the count).
    Classes are numbered in the order of their first face. ``faces`` (F,) bool: the faces
    to merge (those of no candidate are left out).

    Returns
    -------
    cover : (C, K) CSR bool, which candidate covers which class (by candidate: 5 bytes a
        pair, and no second copy by class; a row's classes in the order its faces meet
        them, not sorted)
    area_m2 : (K,) float64, the area of each class
    """
    merged = _merge(table, faces)
    return merged.cover, merged.area_m2


@dataclass(frozen=True)
class ClassTable:
    """A coverage table whose "faces" are face classes, numbered by their first face.

    ``table`` covers the same area with every plan as the face table it came from (its
    faces' areas are the classes' areas), in fewer pairs: the whole selection can run on it.
    ``first_face`` (K,) int32 names a face of each class (its centroid places the class).
    """

    table: CoverageTable
    first_face: NDArray[np.int32]

    @property
    def n_classes(self) -> int:
        return self.table.n_faces


def class_table(table: CoverageTable, faces: NDArray[np.bool_]) -> ClassTable:
    """The classes of ``faces`` (F,) bool as a :class:`ClassTable` (faces of no candidate
    left out). Classes are numbered in the order of their first face, so the pieces of one
    part of the building keep neighbouring numbers (runs in the table)."""
    merged = _merge(table, faces)  # numbered by first face
    pattern = merged.cover
    pattern.sort_indices()
    return ClassTable(CoverageTable.from_csr(pattern, merged.area_m2), merged.first_face)


def _merge(table: CoverageTable, faces: NDArray[np.bool_]) -> _Merged:
    """:func:`merged_classes` and each class's first face (see there)."""
    # int32 face indices: 4 bytes a face less in the arrays the merge holds at its peak
    chosen = np.flatnonzero(faces & table.achievable).astype(np.int32)
    n, n_candidates = len(chosen), table.n_candidates
    if n == 0:
        return _Merged(sp.csr_matrix((n_candidates, 0), dtype=bool), np.zeros(0),
                       np.zeros(0, np.int32))
    rng = np.random.default_rng(20240601)
    words = rng.integers(0, np.iinfo(np.uint64).max, size=(2, n_candidates),
                         dtype=np.uint64, endpoint=True)
    count = table.candidates_per_face

    def face_hashes(word: NDArray[np.uint64], at: NDArray[np.int32]) -> NDArray[np.uint64]:
        """Each of the faces ``at``'s hash under the candidates' ``word``."""
        return table.sum_per_face(word)[at]

    # step 1: a run starts where a face's count or hashes differ from the chosen face
    # before (one (F,) value at a time, compared in place: a few bytes a face)
    starts = np.zeros(n, bool)
    starts[0] = True
    _mark_changes(count, chosen, starts)
    for word in words:
        _mark_changes(table.sum_per_face(word), chosen, starts)
    first = np.flatnonzero(starts).astype(np.int32)  # (R,) each run's first, in chosen
    del starts
    first_chosen = chosen[first]  # (R,) the runs' first faces
    run_length = np.diff(first, append=np.int32(n))  # (R,)
    del first
    # step 2: runs with the same (count, hashes) are one class (the hashes made again and
    # kept at the runs' first faces only). Grouped by one hash (a plain sort of 64-bit
    # words); the groups are checked against the other hash and the count in one compiled
    # pass (no gathered copies), and sorted by all three in the rare case (2^-64 a pair of
    # runs) that one group mixes them
    hashes = (face_hashes(words[1], first_chosen), face_hashes(words[0], first_chosen))
    order = np.argsort(hashes[0])
    same = np.empty(max(len(order) - 1, 0), bool)
    if _same_in_order(order, hashes[0], hashes[1], count, first_chosen, same):
        keys = (*hashes, count[first_chosen])
        order = np.lexsort(keys)
        same = ~(_changes(keys[0], order) | _changes(keys[1], order)
                 | _changes(keys[2], order))
        del keys
    del hashes
    group_starts = np.flatnonzero(np.concatenate(([True], ~same)))
    del same
    # classes numbered in the order of their first run, so of their first face (the runs
    # are in face order)
    first_run = np.minimum.reduceat(order, group_starts)  # (K,)
    rank = np.argsort(first_run)
    n_classes = len(group_starts)
    class_of_group = np.empty(n_classes, np.int32)
    class_of_group[rank] = np.arange(n_classes, dtype=np.int32)
    class_of_run = np.empty(len(first_chosen), np.int32)
    class_of_run[order] = np.repeat(class_of_group, np.diff(np.append(group_starts,
                                                                      len(first_chosen))))
    first_face = first_chosen[first_run[rank]]
    del order, group_starts, first_run, rank, class_of_group, first_chosen
    class_of = np.full(table.n_faces, -1, np.int32)
    class_of[chosen] = np.repeat(class_of_run, run_length)
    del class_of_run, run_length, chosen
    area = np.zeros(n_classes)
    _class_areas(class_of, table.face_area_m2, area)
    # which classes each candidate covers (bool: the bound's products read the pattern
    # only; PDHG sets its own float64 data; class_table sorts each row)
    return _Merged(labels_per_candidate(table, class_of, n_classes), area, first_face)


def labels_per_candidate(table: CoverageTable, label_of: NDArray[np.int32], n_labels: int
                         ) -> sp.csr_matrix:
    """(C, L) CSR bool: the labels of each candidate's faces, each once, in the order its
    faces meet them (not sorted). ``label_of`` (F,) int32 labels every face (a class, a
    voxel; -1: none). Two compiled passes over the table's runs, counting then writing: no
    pattern of the pairs is made (5 bytes a label and candidate)."""
    indptr = np.zeros(table.n_candidates + 1, np.int64)
    last = np.full(n_labels, -1, np.int64)
    _labels_per_candidate(table.run_ptr, table.run_start, table.run_length, label_of,
                          last, indptr, np.zeros(0, np.int32), False)
    indptr = np.cumsum(indptr)
    indices = np.empty(int(indptr[-1]), np.int32)
    last[:] = -1
    _labels_per_candidate(table.run_ptr, table.run_start, table.run_length, label_of,
                          last, indptr, indices, True)
    return sp.csr_matrix((np.ones(len(indices), bool), indices, indptr),
                         shape=(table.n_candidates, n_labels))


def _changes(key: NDArray[Any], order: NDArray[np.intp]) -> NDArray[np.bool_]:
    """(R - 1,) where ``key`` (R,), taken in ``order``, differs from the one before."""
    ordered = key[order]
    changed: NDArray[np.bool_] = ordered[1:] != ordered[:-1]
    return changed


@numba.njit(nogil=True, cache=True)
def _same_in_order(order: NDArray[np.intp], hash0: NDArray[np.uint64],
                   hash1: NDArray[np.uint64], count: NDArray[np.int32],
                   at: NDArray[np.int32], same: NDArray[np.bool_]) -> bool:  # compiled
    """``same[i]``: the runs ``order[i]`` and ``order[i + 1]`` have one ``hash0`` (R,);
    True when such a pair differs in ``hash1`` (R,) or in ``count`` (F,) at its faces
    ``at`` (R,)."""
    mixed = False
    for i in range(len(order) - 1):
        a, b = order[i], order[i + 1]
        equal = hash0[b] == hash0[a]
        same[i] = equal
        if equal and (hash1[b] != hash1[a] or count[at[b]] != count[at[a]]):
            mixed = True
    return mixed


@numba.njit(nogil=True, cache=True)
def _mark_changes(value: NDArray[Any], at: NDArray[np.int32], starts: NDArray[np.bool_]
                  ) -> None:  # compiled
    """``starts[j]`` set where ``value`` (F,) at face ``at[j]`` differs from at ``at[j - 1]``
    (no gathered (F',) copy of the values)."""
    for j in range(1, len(at)):
        if value[at[j]] != value[at[j - 1]]:
            starts[j] = True


@numba.njit(nogil=True, cache=True)
def _class_areas(class_of: NDArray[np.int32], area_m2: NDArray[np.float64],
                 out: NDArray[np.float64]) -> None:  # compiled
    """``out[k]``: the areas of the faces of class k (``class_of`` (F,), -1: none), added in
    face order (as ``np.bincount`` of the chosen faces adds them: the same sums)."""
    for f in range(len(class_of)):
        k = class_of[f]
        if k >= 0:
            out[k] += area_m2[f]


@numba.njit(nogil=True, cache=True)
def _labels_per_candidate(run_ptr: NDArray[np.int64], run_start: NDArray[np.int32],
                          run_length: NDArray[np.int32], label_of: NDArray[np.int32],
                          last: NDArray[np.int64], indptr: NDArray[np.int64],
                          indices: NDArray[np.int32], fill: bool) -> None:  # compiled
    """Each candidate's labels ``label_of`` (F,), each once (``last[k]``: the last
    candidate that met label k). Without ``fill``: their count into ``indptr[c + 1]``; with
    it, into ``indices`` from ``indptr[c]`` on (``indptr`` then the cumulative counts)."""
    for c in range(len(run_ptr) - 1):
        at = indptr[c]
        for r in range(run_ptr[c], run_ptr[c + 1]):
            for f in range(run_start[r], run_start[r] + run_length[r]):
                k = label_of[f]
                if k < 0 or last[k] == c:
                    continue
                last[k] = c
                if fill:
                    indices[at] = k
                    at += 1
                else:
                    indptr[c + 1] += 1
